//! Helpers the subcommands share: loading a formula (file, `-` for stdin, or `--expr`), parsing and
//! applying `name=value,…` lists, hints for misspelt names, `--json` documents, recognising lobe's own
//! output files, and the CLI's error, which words the library's structured hints with this CLI's flags.

use lobe::base::diag::{Diagnostic, Diagnostics, Hint, Setting, Wording};
use lobe::ir::Formula;
use lobe::{Backend, Kernel, Options};
use std::fmt;

/// An error a subcommand reports: rendered diagnostics, or one message with its hints.
#[derive(Debug)]
pub enum CliError {
    Diagnostics(Diagnostics),
    Error(Diagnostic),
    /// The command ran, and its verdict is "fail" (e.g. `check --sweep --deny nan` found NaN); already printed.
    Failed,
}

impl CliError {
    pub fn msg(msg: impl Into<String>) -> CliError {
        CliError::Error(Diagnostic::error(msg))
    }
    pub fn hint(msg: impl Into<String>, hint: impl Into<String>) -> CliError {
        CliError::Error(Diagnostic::error(msg).hint(hint.into()))
    }
    /// Process exit code: 1 for bad input and failed verdicts.
    pub fn exit_code(&self) -> i32 {
        1
    }
    pub fn render(&self, color: bool) -> String {
        match self {
            CliError::Diagnostics(d) => d.render_with(color, &Flags),
            CliError::Error(d) => {
                let hints = d.hint_texts(&Flags);
                if hints.is_empty() {
                    format!("error: {}\n", d.text(&Flags))
                } else {
                    format!("error: {}\n  = help: {}\n", d.text(&Flags), hints.join("; "))
                }
            }
            CliError::Failed => String::new(),
        }
    }
}

impl CliError {
    /// The error as the one JSON object a `--json` run prints instead of its report: `error` (the message),
    /// `file`, `line`, `column` (1-based; null without a place), `hint` (null without one) of the first error,
    /// and `diagnostics`, every item as `lobe serve` and Python give them. None for [`CliError::Failed`], whose
    /// report was printed.
    pub fn to_json(&self) -> Option<serde_json::Value> {
        let items = match self {
            CliError::Diagnostics(d) => d.to_json_with(&Flags),
            CliError::Error(d) => Diagnostics::single("", d.clone()).to_json_with(&Flags),
            CliError::Failed => return None,
        };
        let empty = serde_json::Value::Null;
        let list = items.as_array().map(Vec::as_slice).unwrap_or_default();
        let first = list.iter().find(|d| d["severity"] == "error").or(list.first()).unwrap_or(&empty);
        let or_null = |v: &serde_json::Value| if v.is_null() { serde_json::Value::Null } else { v.clone() };
        let file = match &first["file"] {
            serde_json::Value::String(f) if !f.is_empty() => serde_json::Value::String(f.clone()),
            _ => serde_json::Value::Null,
        };
        let hints: Vec<&str> = first["hints"].as_array().map(|h| h.iter().filter_map(|x| x.as_str()).collect()).unwrap_or_default();
        Some(serde_json::json!({
            "error": or_null(&first["message"]),
            "file": file,
            "line": or_null(&first["line"]),
            "column": or_null(&first["col"]),
            "hint": if hints.is_empty() { serde_json::Value::Null } else { hints.join("; ").into() },
            "diagnostics": items,
        }))
    }
}

impl fmt::Display for CliError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.render(false))
    }
}

/// The library's hints and settings in this CLI's words: each names the flag that changes it.
pub struct Flags;

impl Wording for Flags {
    fn hint(&self, h: &Hint) -> String {
        use lobe::numerics::NumericsAdvice as N;
        use lobe::CompileAdvice as C;
        if let Some(a) = h.advice::<N>() {
            return match a {
                N::BakeEveryParam => "give every parameter a value (--set) before normalising".into(),
                N::FitSomeParam => "name at least one parameter: --param a=1..1000".into(),
                N::PositiveStep => "e.g. --step 1".into(),
                N::SweepForUndefined => "run `lobe sweep` on the file to see where it is undefined".into(),
                N::RunAccuracyPass => "run `lobe check` on the file: the accuracy pass may remove the NaN".into(),
            };
        }
        if let Some(a) = h.advice::<C>() {
            return match a {
                C::InputNotParam { name } => format!("`{name}` is an input (a cosine), not a parameter; `lobe eval` takes inputs with --at {name}=…"),
                C::BuildWithLlvm => format!("rebuild with `cargo build --release --features llvm` ({}), or use `--tier cranelift`", lobe::LLVM_PACKAGES),
            };
        }
        if let Some(lobe::measured::MeasuredAdvice::GiveMerlTable) = h.advice() {
            return "give a MERL BRDF database .binary file (90×90×180 entries), or write one with `lobe tabulate`".into();
        }
        if h.advice::<lobe::base::output::AllowOverwrite>().is_some() {
            return "choose another output path, or pass --force to replace it".into();
        }
        match h {
            Hint::Text(t) => t.clone(),
            Hint::UseInterpreter => "the interpreter computes the same values: rerun with `--backend interp`".into(),
            // Advice this CLI has no words of its own for.
            Hint::Advice(a) => a.plain(),
        }
    }
    fn setting(&self, s: &Setting) -> String {
        match s {
            Setting::Param { name, value: None } => format!("--set {name}"),
            Setting::Param { name, value: Some(v) } => format!("--set {name}={v}"),
        }
    }
}

/// A single located-nowhere diagnostic (an unreadable file, a failed numerical check) prints as a plain
/// message with its hints.
impl From<Diagnostic> for CliError {
    fn from(d: Diagnostic) -> CliError {
        CliError::Error(d)
    }
}

impl From<Diagnostics> for CliError {
    fn from(d: Diagnostics) -> CliError {
        CliError::Diagnostics(d)
    }
}

pub use lobe::base::source::{read_source, source_from_bytes};

/// Loads and lowers a formula from a path (or `-`), or from `--expr` text when given; warnings go to stderr.
pub fn load_formula(path: Option<&str>, expr: Option<&str>) -> Result<Formula, CliError> {
    load_formula_with(path, expr, true)
}

/// [`load_formula`], optionally without printing warnings (for formulas whose warnings are expected, such as a
/// fitted normalisation coefficient, which by design reads no input).
pub fn load_formula_with(path: Option<&str>, expr: Option<&str>, show_warnings: bool) -> Result<Formula, CliError> {
    let (name, src) = match (path, expr) {
        (_, Some(e)) => ("<expr>".to_string(), source_from_bytes("<expr>", e.as_bytes().to_vec())?),
        (Some(p), None) => super::catalogue::read(p)?,
        (None, None) => {
            return Err(CliError::hint("no formula given", "pass a .brdf file, `-` for standard input, or --expr '…'"))
        }
    };
    let (f, warnings) = lobe::front::parse_with_warnings(&name, &src)?;
    if show_warnings && !warnings.items.is_empty() {
        use std::io::IsTerminal;
        let color = std::io::stderr().is_terminal() && std::env::var_os("NO_COLOR").is_none();
        eprint!("{}", warnings.render_with(color, &Flags));
    }
    Ok(f)
}

/// Loads a formula and compiles it with `--set` values baked in, in math mode `math`, through the accuracy pass
/// at its defaults (`numerics::robust`: rewrites that lower the measured error within 1.3× the fastest form's cost).
pub fn load_kernel(
    path: Option<&str>,
    expr: Option<&str>,
    set: &[(String, f64)],
    backend: Backend,
    math: lobe::Mode,
) -> Result<Kernel, CliError> {
    compile_kernel(load_formula(path, expr)?, set, backend, math)
}

/// [`load_kernel`]'s compilation of an already loaded formula (e.g. one channel of a colour formula).
pub fn compile_kernel(f: Formula, set: &[(String, f64)], backend: Backend, math: lobe::Mode) -> Result<Kernel, CliError> {
    let opts = Options { backend, bake: set.to_vec(), math, ..Options::default() };
    Ok(lobe::compile_formula(f, &with_pass(opts, Default::default()))?)
}

static USE_CACHE: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(true);

/// `--no-cache` turns the accuracy pass's decision cache off for this process.
pub fn use_cache(on: bool) {
    USE_CACHE.store(on, std::sync::atomic::Ordering::Relaxed);
}

/// Compile options with the accuracy pass on, its search bounded by 2 s (it keeps the best form so far), its
/// decisions cached unless `--no-cache` was given.
pub fn with_pass(opts: Options, pass: lobe::numerics::robust::PassOptions) -> Options {
    lobe::numerics::pass_cache::command_pass(opts, pass, USE_CACHE.load(std::sync::atomic::Ordering::Relaxed))
}

/// The scene compiler of `render`, `compare` and `watch`: the backend's kernels through the accuracy pass in
/// `math`, as `eval` compiles (cached unless `--no-cache`).
pub fn scene_compiler(backend: lobe::Backend, math: lobe::Mode) -> lobe::render::scene::LobeCompiler {
    lobe::render::scene::LobeCompiler::for_commands(backend, math, USE_CACHE.load(std::sync::atomic::Ordering::Relaxed))
}

/// `--no-cache` as given: whether the accuracy pass's decisions are cached.
pub fn cache_on() -> bool {
    USE_CACHE.load(std::sync::atomic::Ordering::Relaxed)
}

/// Loads a formula and simplifies it with `set`'s values baked in, without the accuracy pass: the plain
/// simplification, which shader exports are made from (the pass's rewrites are for f64).
pub fn load_plain(path: Option<&str>, expr: Option<&str>, set: &[(String, f64)]) -> Result<Formula, CliError> {
    let f = load_formula(path, expr)?;
    Ok(lobe::simplified(&f, &Options { bake: set.to_vec(), ..Options::default() })?)
}

pub use lobe::front::parse_assignments;

/// Refuses a `--threads` count the renderer would refuse, in the flag's words.
/// The shortest text that reads back to `v` exactly: the plain decimal, or the exponent form where that is
/// shorter (1.2e-300, not a 300-digit decimal).
pub fn short_number(v: f64) -> String {
    let (d, e) = (format!("{v}"), format!("{v:e}"));
    if e.len() < d.len() { e } else { d }
}

pub fn check_threads(threads: usize) -> Result<(), CliError> {
    use lobe::render::MAX_THREADS;
    if threads > MAX_THREADS {
        return Err(CliError::msg(format!("--threads {threads} is more than {MAX_THREADS}; 0 uses one per core")));
    }
    Ok(())
}

/// Parameter values for a kernel: defaults, overridden by `set` (names already checked by compilation).
pub fn param_values(f: &Formula, set: &[(String, f64)]) -> Vec<f64> {
    let mut p = f.default_params();
    for (k, v) in set {
        if let Some(i) = f.param_index(k) {
            p[i] = *v;
        }
    }
    p
}


/// A `--json` document. Serialising lobe's result types does not fail; should it, the error is reported,
/// not unwrapped.
pub fn to_json<T: serde::Serialize + ?Sized>(v: &T) -> Result<String, CliError> {
    serde_json::to_string(v).map_err(|e| CliError::msg(format!("cannot write JSON: {e}")))
}

/// Recognises files lobe wrote: PNGs carry a `Software: lobe` tEXt chunk, SVGs and text exports a lobe header.
pub fn is_lobe_output(bytes: &[u8]) -> bool {
    let head = String::from_utf8_lossy(&bytes[..bytes.len().min(400)]);
    lobe::render::image::is_lobe_png(bytes) || head.contains("made by lobe") || head.contains("exported by lobe")
}

/// For commands over several formulas: the `--set` values each formula declares. A name no formula declares
/// is an error (a typo), not silently ignored.
pub fn set_for(f: &Formula, set: &[(String, f64)]) -> Vec<(String, f64)> {
    set.iter().filter(|(k, _)| f.param_index(k).is_some()).cloned().collect()
}

/// Checks that every `--set` name is declared by at least one of the formulas.
pub fn check_set_names(formulas: &[&Formula], set: &[(String, f64)]) -> Result<(), CliError> {
    for (k, _) in set {
        if !formulas.iter().any(|f| f.param_index(k).is_some()) {
            let names: Vec<&str> = formulas.iter().flat_map(|f| f.params.iter().map(|p| p.name.as_str())).collect();
            let hint = did_you_mean(k, &names, "the formulas' parameters are: ");
            return Err(CliError::hint(format!("--set: no formula has a parameter `{k}`"), hint));
        }
    }
    Ok(())
}

pub use lobe::front::did_you_mean;

/// Whether `f` reads the parameter `n` (the papers' metrics sweep it) in any channel.
pub fn reads_n(f: &Formula) -> bool {
    f.reads_param("n")
}

/// Which of a formula and its reference reads no `n`, as a clause: "A reads no n", "the reference B reads no
/// n", "A and the reference B read no n".
pub fn which_reads_no_n(f: &Formula, r: &Formula) -> String {
    match (reads_n(f), reads_n(r)) {
        (true, _) => format!("the reference {} reads no n", r.display_name()),
        (false, true) => format!("{} reads no n", f.display_name()),
        (false, false) => format!("{} and the reference {} read no n", f.display_name(), r.display_name()),
    }
}

/// What a long run is doing, on stderr, once it has run for a second (a quick run prints nothing): a spinner
/// with a label, the stage and the elapsed time, cleared before the report.
pub struct Spinner {
    bar: Option<indicatif::ProgressBar>,
    done: std::sync::Arc<(std::sync::Mutex<bool>, std::sync::Condvar)>,
}

impl Spinner {
    pub fn new(enabled: bool, label: &str) -> Spinner {
        let done = std::sync::Arc::new((std::sync::Mutex::new(false), std::sync::Condvar::new()));
        let bar = enabled.then(|| {
            let b = indicatif::ProgressBar::with_draw_target(None, indicatif::ProgressDrawTarget::hidden());
            if let Ok(style) = indicatif::ProgressStyle::with_template(&format!("{{spinner}} {label}: {{msg}} {{elapsed}}")) {
                b.set_style(style);
            }
            let (b2, done2) = (b.clone(), done.clone());
            std::thread::spawn(move || {
                let (lock, cv) = &*done2;
                let Ok(guard) = lock.lock() else { return };
                let Ok((finished, _)) = cv.wait_timeout_while(guard, std::time::Duration::from_secs(1), |d| !*d) else { return };
                if !*finished {
                    b2.set_draw_target(indicatif::ProgressDrawTarget::stderr());
                    b2.enable_steady_tick(std::time::Duration::from_millis(120));
                }
            });
            b
        });
        Spinner { bar, done }
    }

    pub fn show(&self, stage: String) {
        if let Some(b) = &self.bar {
            b.set_message(stage);
        }
    }

    pub fn finish(&self) {
        let (lock, cv) = &*self.done;
        if let Ok(mut d) = lock.lock() {
            *d = true;
        }
        cv.notify_all();
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn assignments_parse_and_reject() {
        assert_eq!(parse_assignments("n=200, a=16").unwrap(), vec![("n".into(), 200.0), ("a".into(), 16.0)]);
        assert!(parse_assignments("n").is_err());
        assert!(parse_assignments("n=abc").is_err());
        assert!(parse_assignments("n=inf").is_err());
        assert!(parse_assignments("n=5,n=6").unwrap_err().contains("twice"));
    }

}
