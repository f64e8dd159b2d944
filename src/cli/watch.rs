//! `lobe watch FILE --scene SCENE -o out.png [--size 512] [--set n=50]`: recompile and re-render whenever
//! the .brdf file changes. On an error the diagnostics are printed and the last good image is kept (before the
//! first good one, the message says there is no image yet).

use super::args::{Json, Output, Params};
use super::common::{self, CliError};
use lobe::render::image;
use lobe::render::scene::{self, LoadOptions};
use lobe::render::{self as r, RenderOptions};
use lobe::base::watch::{watch, Next};
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
    /// Poll interval in milliseconds.
    #[arg(long, default_value_t = 100)]
    pub interval_ms: u64,
    /// Stop after this many reloads (for scripts; default: run until interrupted).
    #[arg(long)]
    pub count: Option<usize>,
    /// One JSON object per reload on standard output, a line each: `reload`, `ok`, and `ms`, `compile_ms`,
    /// `render_ms`, `nan`, `output` after a render, or the error object `--json` errors carry.
    #[command(flatten)]
    pub json: Json,
}

/// One successful reload's numbers.
struct Reloaded {
    total_ms: f64,
    compile_ms: f64,
    render_ms: f64,
    nan: u64,
}

/// One reload: compile the formula into the scene, render, write. Returns a one-line summary.
fn reload(a: &WatchArgs, src: String) -> Result<Reloaded, CliError> {
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
    let compile = t0.elapsed();
    let ropts = RenderOptions::default();
    let (frame, stats) = r::render(&sc, &ropts).map_err(CliError::msg)?;
    let png = frame.image.encode_png().map_err(CliError::msg)?;
    a.out.force.write(a.out.required(), &png, image::is_lobe_png)?;
    Ok(Reloaded {
        total_ms: t0.elapsed().as_secs_f64() * 1e3,
        compile_ms: compile.as_secs_f64() * 1e3,
        render_ms: stats.render_wall.as_secs_f64() * 1e3,
        nan: stats.nan,
    })
}

impl Reloaded {
    fn line(&self, out: &std::path::Path) -> String {
        let nan = if self.nan > 0 { format!(", {} NaN/inf shaded as no light", self.nan) } else { String::new() };
        format!("reloaded in {:.1} ms (scene + compile {:.1} ms, render {:.1} ms){nan} → {}", self.total_ms, self.compile_ms, self.render_ms, out.display())
    }

    fn json(&self, reload: usize, out: &std::path::Path) -> serde_json::Value {
        serde_json::json!({"reload": reload, "ok": true, "ms": self.total_ms, "compile_ms": self.compile_ms, "render_ms": self.render_ms, "nan": self.nan, "output": out.display().to_string()})
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
                match common::source_from_bytes(&name, b).map_err(CliError::from).and_then(|src| reload(a, src)) {
                    Ok(r) => {
                        (last_failed, rendered) = (false, true);
                        if a.json.on {
                            json_line(&r.json(reloads, a.out.required()));
                        } else {
                            eprintln!("{}", r.line(a.out.required()));
                        }
                    }
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
