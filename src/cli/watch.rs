//! `lobe watch FILE --scene SCENE -o out.png [--size 512] [--set n=50] [--spp N]`: recompile and re-render
//! whenever the .brdf file changes. On an error the diagnostics are printed and the last good image is kept
//! (before the first good one, the message says there is no image yet).
//!
//! A scene the ray tracer renders (an `[environment]` or `shadows = true`) refines progressively: each reload
//! renders at 1, 4, 16, … samples per pixel up to the scene's `spp` or `--spp` ([`levels`]), writing the
//! PNG after each level, so the first image comes at the cost of one sample per pixel. A poller beside the
//! renders reads the file every interval; once it no longer holds the text being rendered, the level in
//! progress stops at its next row ([`Cancel`]) and the watch reloads at once. The last level is one render at
//! the full spp (a pixel's samples do not depend on who renders them), so its image is `lobe render`'s byte for
//! byte, and the whole series costs at most 4/3 of that render.

use super::args::{Json, Output, Params};
use super::common::{self, CliError};
use lobe::render::image;
use lobe::render::scene::{self, LoadOptions};
use lobe::render::{self as r, RenderOptions};
use lobe::base::cancel::Cancel;
use lobe::base::watch::{differs, watch, Next};
use lobe::render::trace::levels;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// `--scene`'s default, built in as [`scene::PAPER_SCENE`] for runs outside a checkout.
const DEFAULT_SCENE: &str = "examples/scenes/paper_sphere.toml";

#[derive(clap::Args, Debug)]
#[command(mut_arg("output", |a| a.required(true).help("Output PNG, rewritten after every successful reload")))]
pub struct WatchArgs {
    /// The formula file to watch.
    pub file: PathBuf,
    /// The scene to render it in (every material's formula is replaced by FILE).
    /// The scene (default: the papers' sphere, from the checkout or built in).
    #[arg(long, default_value = DEFAULT_SCENE)]
    pub scene: PathBuf,
    #[command(flatten)]
    pub out: Output,
    /// Image size: `N` or `WxH`.
    #[arg(long, value_parser = super::render::parse_size, default_value = "512")]
    pub size: (usize, usize),
    #[command(flatten)]
    pub set: Params,
    /// Samples per pixel of the ray tracer's last level (1..=65536; default the scene's `spp`): a traced scene
    /// refines through 1, 4, 16, … up to it. Rasterised scenes ignore it.
    #[arg(long, value_name = "N", value_parser = super::render::parse_spp)]
    pub spp: Option<usize>,
    /// Poll interval in milliseconds.
    #[arg(long, default_value_t = 100)]
    pub interval_ms: u64,
    /// Stop after this many reloads (for scripts; default: run until interrupted).
    #[arg(long)]
    pub count: Option<usize>,
    /// One JSON object per image written on standard output, a line each: `reload`, `ok`, and `ms`,
    /// `compile_ms`, `render_ms`, `nan`, `output` after a render (for a traced scene also `spp`, this level's
    /// samples per pixel, and `final_spp`, the series' last), or the error object `--json` errors carry.
    #[command(flatten)]
    pub json: Json,
}

/// One image written by a reload.
struct Reloaded {
    total_ms: f64,
    compile_ms: f64,
    render_ms: f64,
    nan: u64,
    /// A traced scene's level: this image's samples per pixel and the series' last; `None` when rasterised.
    spp: Option<(usize, usize)>,
}

/// One reload: compile the formula into the scene, render, write; `wrote` hears of every image written (one,
/// or a traced scene's levels). A traced series stops early, without an error, once the file no longer holds
/// `bytes`.
fn reload(a: &WatchArgs, src: String, bytes: &[u8], mut wrote: impl FnMut(&Reloaded)) -> Result<(), CliError> {
    let t0 = Instant::now();
    let name = a.file.display().to_string();
    let opts = LoadOptions { size: Some(a.size), set: a.set.list()?, formula_override: Some((name, src)), ..LoadOptions::default() };
    let compiler = super::common::scene_compiler(lobe::Backend::Jit, lobe::Mode::Precise);
    let sc = if a.scene.is_file() {
        scene::load_scene(&a.scene, &opts, &compiler)?
    } else {
        // The default scene outside a checkout: the built-in copy (the watched file replaces its formula).
        scene::parse_scene("<builtin paper_sphere.toml>", scene::PAPER_SCENE, std::path::Path::new("."), &opts, &compiler)?
    };
    let compile_ms = t0.elapsed().as_secs_f64() * 1e3;
    let render = |ropts: &RenderOptions, spp: Option<(usize, usize)>| -> Result<Reloaded, CliError> {
        let (frame, stats) = r::render(&sc, ropts).map_err(CliError::msg)?;
        let png = frame.image.encode_png().map_err(CliError::msg)?;
        a.out.force.write(a.out.required(), &png, image::is_lobe_png)?;
        let (total_ms, render_ms) = (t0.elapsed().as_secs_f64() * 1e3, stats.render_wall.as_secs_f64() * 1e3);
        Ok(Reloaded { total_ms, compile_ms, render_ms, nan: stats.nan, spp })
    };
    if !r::trace::traced(&sc) {
        wrote(&render(&RenderOptions::default(), None)?);
        return Ok(());
    }
    let last = a.spp.unwrap_or(sc.spp);
    // No deadline; tripped by the poller when the file changes.
    let cancel = Cancel::with_timeout(Duration::MAX);
    let (stop, stopped) = std::sync::mpsc::channel::<()>();
    let interval = Duration::from_millis(a.interval_ms.max(10));
    let poll = cancel.clone();
    std::thread::scope(move |s| {
        // Ends when `stop` is dropped (the series is over), or trips `cancel` when the file changes.
        s.spawn(move || loop {
            match stopped.recv_timeout(interval) {
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) if !differs(&a.file, bytes) => {}
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) => return poll.cancel(),
                _ => return,
            }
        });
        let mut series = || -> Result<(), CliError> {
            for spp in levels(last) {
                let ropts = RenderOptions { spp: Some(spp), cancel: cancel.clone(), ..RenderOptions::default() };
                match render(&ropts, Some((spp, last))) {
                    Ok(r) => wrote(&r),
                    Err(_) if cancel.is_cancelled() => break,
                    Err(e) => return Err(e),
                }
                if cancel.is_cancelled() {
                    break;
                }
            }
            if cancel.is_cancelled() && !a.json.on {
                eprintln!("{} changed: refining stopped; reloading", a.file.display());
            }
            Ok(())
        };
        let r = series();
        drop(stop);
        r
    })
}

impl Reloaded {
    fn line(&self, out: &std::path::Path) -> String {
        let nan = if self.nan > 0 { format!(", {} NaN/inf shaded as no light", self.nan) } else { String::new() };
        let level = self.spp.map(|(s, last)| format!(" at {s} of {last} spp")).unwrap_or_default();
        format!("reloaded in {:.1} ms (scene + compile {:.1} ms, render {:.1} ms{level}){nan} → {}", self.total_ms, self.compile_ms, self.render_ms, out.display())
    }

    fn json(&self, reload: usize, out: &std::path::Path) -> serde_json::Value {
        let mut j = serde_json::json!({"reload": reload, "ok": true, "ms": self.total_ms, "compile_ms": self.compile_ms, "render_ms": self.render_ms, "nan": self.nan, "output": out.display().to_string()});
        if let Some((spp, last)) = self.spp {
            (j["spp"], j["final_spp"]) = (spp.into(), last.into());
        }
        j
    }
}

/// What a failed reload leaves at the output: the last image this session rendered; before the first success,
/// the image an earlier run left there, or no image at all.
fn failed_note(rendered: bool, out: &std::path::Path) -> String {
    if rendered {
        "(keeping the last good image; fix the file and save again)".to_string()
    } else if out.exists() {
        format!("(keeping the last good image, {}, from before this watch started; fix the file and save again)", out.display())
    } else {
        format!("(no image yet: {} is written after the first successful reload; fix the file and save again)", out.display())
    }
}

pub fn run(a: &WatchArgs) -> Result<(), CliError> {
    a.set.list()?;
    a.out.force.check(a.out.required(), image::is_lobe_png)?;
    Output::png_only(a.out.required())?;
    if !a.scene.is_file() && a.scene != std::path::Path::new(DEFAULT_SCENE) {
        return Err(CliError::hint(format!("scene `{}` not found", a.scene.display()), "examples are in examples/scenes/"));
    }
    eprintln!("watching {} (scene {}); Ctrl-C to stop", a.file.display(), a.scene.display());
    let mut reloads = 0;
    let mut last_failed = false;
    // Whether this session has written an image yet (only then is there a "last good image" to keep).
    let mut rendered = false;
    watch(&a.file, Duration::from_millis(a.interval_ms.max(10)), |bytes| {
        match bytes {
            None => eprintln!("{} is missing; waiting for it to appear", a.file.display()),
            Some(b) => {
                reloads += 1;
                let name = a.file.display().to_string();
                let wrote = |r: &Reloaded| {
                    rendered = true;
                    if a.json.on {
                        json_line(&r.json(reloads, a.out.required()));
                    } else {
                        eprintln!("{}", r.line(a.out.required()));
                    }
                };
                match common::source_from_bytes(&name, b.clone()).map_err(CliError::from).and_then(|src| reload(a, src, &b, wrote)) {
                    Ok(()) => last_failed = false,
                    Err(e) => {
                        last_failed = true;
                        if let Some(mut j) = e.to_json().filter(|_| a.json.on) {
                            j["reload"] = reloads.into();
                            j["ok"] = false.into();
                            json_line(&j);
                        }
                        let color = std::io::IsTerminal::is_terminal(&std::io::stderr());
                        eprint!("{}", e.render(color));
                        eprintln!("{}", failed_note(rendered, a.out.required()));
                    }
                }
            }
        }
        if a.count.is_some_and(|c| reloads >= c) {
            Next::Stop
        } else {
            Next::Continue
        }
    });
    // With --count (scripts), the exit status says whether the last reload produced an image.
    if a.count.is_some() && last_failed {
        return Err(CliError::Failed);
    }
    Ok(())
}

/// One JSON line, flushed at once: a reader of the pipe sees each reload as it happens.
fn json_line(j: &serde_json::Value) {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "{j}");
    let _ = out.flush();
}
