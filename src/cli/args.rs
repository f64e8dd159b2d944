//! The flags several commands share, each a clap struct flattened into the commands that take it
//! (`#[command(flatten)]`), so it is spelled, parsed and documented once. Where a flag means something
//! narrower in one command (which parameters `--set` fixes, what `-o` writes), that command rewords the help
//! with `#[command(mut_arg("set", args::help("…")))]`; the name, syntax and parsing stay the shared ones.

use super::common::{self, CliError};
use lobe::ir::{Formula, Input, InputSet};
use lobe::base::output;
use lobe::{Backend, Kernel};
use std::path::{Path, PathBuf};

/// Parses `lo..hi` (both numbers) as `--range` and `--param` take it.
pub fn parse_range(s: &str) -> Result<(f64, f64), String> {
    let (a, b) = s.split_once("..").ok_or_else(|| format!("`{s}` is not a range; write lo..hi, e.g. 1..1000"))?;
    let p = |t: &str| t.trim().parse::<f64>().map_err(|_| format!("`{}` is not a number in the range `{s}`", t.trim()));
    let (lo, hi) = (p(a)?, p(b)?);
    if !(lo.is_finite() && hi.is_finite()) || lo > hi {
        return Err(format!("`{s}`: need finite lo ≤ hi"));
    }
    Ok((lo, hi))
}

/// A help text for `mut_arg`, written without a final full stop (clap drops it from doc comments).
pub fn help(text: &'static str) -> impl FnOnce(clap::Arg) -> clap::Arg {
    move |a| a.help(text)
}

/// The formula a command reads: a file, `-` for standard input, or `--expr` text.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct FormulaSource {
    /// Formula file (.brdf), or `-` for standard input.
    pub file: Option<String>,
    /// The formula inline instead of a file (may start with `-`: `--expr -NH`).
    #[arg(long, conflicts_with = "file", allow_hyphen_values = true)]
    pub expr: Option<String>,
}

impl FormulaSource {
    /// Loads and lowers the formula; warnings go to stderr.
    pub fn load(&self) -> Result<Formula, CliError> {
        common::load_formula(self.file.as_deref(), self.expr.as_deref())
    }

    /// Loads the formula and simplifies it with `set` baked in, without the accuracy pass (what exports write).
    pub fn plain(&self, set: &[(String, f64)]) -> Result<Formula, CliError> {
        common::load_plain(self.file.as_deref(), self.expr.as_deref(), set)
    }
}

/// `--set name=value,…`, repeatable.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct Params {
    /// Parameter values, e.g. `n=50,a=16`.
    #[arg(id = "set", long = "set", value_name = "SET", value_parser = common::parse_assignments, action = clap::ArgAction::Append)]
    pub groups: Vec<Vec<(String, f64)>>,
}

impl Params {
    /// Every assignment, one per name, in the order given. A name in several `--set` flags with the same value
    /// counts once; with different values it is refused (a later flag does not silently win), as a name
    /// twice within one flag is when parsing.
    pub fn list(&self) -> Result<Vec<(String, f64)>, CliError> {
        merge_repeated("--set", &self.groups, |v| common::short_number(*v))
    }
}

/// The items of a repeatable `name=value` flag (`--set`, `--at`) given as several flags, merged into one list:
/// a name repeated with an equal value counts once, with a different value it is an error naming the flag,
/// the name and both values. `show` writes a value as the user would.
pub fn merge_repeated<T: Clone + PartialEq>(flag: &str, groups: &[Vec<(String, T)>], show: impl Fn(&T) -> String) -> Result<Vec<(String, T)>, CliError> {
    let mut out: Vec<(String, T)> = Vec::new();
    for (k, v) in groups.iter().flatten() {
        match out.iter().find(|(j, _)| j == k) {
            Some((_, w)) if w == v => {}
            Some((_, w)) => {
                return Err(CliError::hint(
                    format!("{flag} gives `{k}` twice: {k}={} and {k}={}", show(w), show(v)),
                    format!("give `{k}` once; a later {flag} does not replace an earlier one"),
                ))
            }
            None => out.push((k.clone(), v.clone())),
        }
    }
    Ok(out)
}

/// `--backend jit|interp`, `--tier cranelift|llvm|auto` and `--math precise|fast`.
#[derive(clap::Args, Clone, Copy, Debug)]
pub struct BackendArg {
    #[command(flatten)]
    pub engine: EngineArg,
    #[command(flatten)]
    pub math: MathArg,
}

impl BackendArg {
    /// The backend `--backend` with `--tier` means ([`EngineArg::backend`]).
    pub fn backend(&self) -> Result<Backend, CliError> {
        self.engine.backend()
    }

    /// Compile options for this backend and math mode with `bake` baked in.
    pub fn options(&self, bake: Vec<(String, f64)>) -> Result<lobe::Options, CliError> {
        self.engine.options(bake, self.math.mode)
    }

    /// The backend of a command whose work is large whatever its input ([`EngineArg::bulk_backend`]).
    pub fn bulk_backend(&self) -> Result<Backend, CliError> {
        self.engine.bulk_backend()
    }
}

/// `--backend jit|interp` and `--tier cranelift|llvm|auto`, without `--math` (for a command that has its own).
#[derive(clap::Args, Clone, Copy, Debug)]
pub struct EngineArg {
    /// Evaluation backend: `jit` (compiled by the `--tier`) or `interp` (the reference interpreter).
    #[arg(id = "backend", long = "backend", value_name = "BACKEND", default_value = "jit")]
    kind: Backend,
    /// JIT tier: `auto` (the default: Cranelift, and in a build with `--features llvm` LLVM for renders and
    /// for batches of 4096 points or more), `cranelift`, or `llvm` (LLVM 19 in the host's widest f64 lanes).
    #[arg(id = "tier", long = "tier", value_name = "TIER", default_value = "auto")]
    tier: lobe::Tier,
}

impl EngineArg {
    /// The backend `--backend` with `--tier` means; `llvm` in a build without the LLVM tier is an error with
    /// the rebuild hint (not a failure later, at the first compile).
    pub fn backend(&self) -> Result<Backend, CliError> {
        // The contradiction of flags is said in terms of the flags; the rest is the library's.
        self.tier.resolve(self.kind).map_err(|e| CliError::hint(e, "drop --tier, or use --backend jit"))?;
        Ok(lobe::resolve_backend(self.kind, self.tier)?)
    }

    /// Compile options for this backend and `math` with `bake` baked in.
    pub fn options(&self, bake: Vec<(String, f64)>, math: lobe::Mode) -> Result<lobe::Options, CliError> {
        Ok(lobe::Options { backend: self.backend()?, bake, math, ..lobe::Options::default() })
    }

    /// The backend of a command whose work is large whatever its input (a fit, a sweep, a table, a quadrature:
    /// millions of evaluations in batches of any size): automatic tiering's LLVM from the start when the build
    /// has it (docs/performance.md, "Automatic tiering"), else what [`EngineArg::backend`] says.
    pub fn bulk_backend(&self) -> Result<Backend, CliError> {
        Ok(match self.backend()? {
            Backend::Auto => Backend::Llvm,
            b => b,
        })
    }

    /// [`EngineArg::options`] with [`EngineArg::bulk_backend`].
    pub fn bulk_options(&self, bake: Vec<(String, f64)>, math: lobe::Mode) -> Result<lobe::Options, CliError> {
        Ok(lobe::Options { backend: self.bulk_backend()?, bake, math, ..lobe::Options::default() })
    }
}

/// `--math precise|fast`.
#[derive(clap::Args, Clone, Copy, Debug)]
pub struct MathArg {
    /// Math mode: `precise` (every builtin within a few ulp, the default) or `fast` (within 1e-6, fewer
    /// operations); `lobe check` lists each builtin's bound.
    #[arg(id = "math", long = "math", value_name = "MODE", default_value = "precise")]
    pub mode: lobe::Mode,
}

/// `--prefer speed|accuracy` and `--max-cost RATIO`: what the accuracy pass keeps (`numerics::robust`).
#[derive(clap::Args, Clone, Copy, Debug)]
pub struct PreferArg {
    /// `accuracy`: keep rewrites that lower the measured error within --max-cost × the fastest form's cost;
    /// `speed`: keep only rewrites that cost nothing.
    #[arg(id = "prefer", long = "prefer", value_name = "PREFER", default_value = "accuracy")]
    pub prefer: lobe::numerics::robust::Prefer,
    /// Cost budget of `--prefer accuracy`, as a multiple of the fastest form's static cost (≥ 1).
    #[arg(id = "max_cost", long = "max-cost", value_name = "RATIO", default_value_t = 1.3, value_parser = parse_ratio)]
    pub max_cost: f64,
}

/// A positive number of seconds.
pub fn parse_seconds(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v > 0.0 && v.is_finite() => Ok(v),
        _ => Err(format!("`{s}` is not a positive number of seconds (e.g. 2 or 0.5)")),
    }
}

fn parse_ratio(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v >= 1.0 && !v.is_nan() => Ok(v),
        _ => Err(format!("`{s}` is not a cost ratio ≥ 1 (e.g. 1.3, or inf for the most accurate form)")),
    }
}

impl PreferArg {
    /// The pass settings, measured on `points` domain points.
    pub fn pass(&self, points: usize) -> lobe::numerics::robust::PassOptions {
        lobe::numerics::robust::PassOptions { prefer: self.prefer, max_cost: self.max_cost, points, ..Default::default() }
    }
}

/// `--json`: one JSON object on standard output instead of the report.
#[derive(clap::Args, Clone, Copy, Debug)]
pub struct Json {
    /// Print one JSON object (its keys are listed in docs/commands.md).
    #[arg(id = "json", long = "json")]
    pub on: bool,
}

/// `--lookup linear|nearest`: how a measured table is read between its entries ([`lobe::measured::Lookup`]).
#[derive(clap::Args, Clone, Copy, Debug)]
pub struct LookupArg {
    /// How a measured table (.binary) is read between its entries: `linear` (multilinear in the table's
    /// index coordinates, default) or `nearest` (the entry whose bin holds the angles, as MERL's code reads it).
    #[arg(id = "lookup", long = "lookup", value_name = "HOW", value_parser = parse_lookup)]
    pub given: Option<lobe::measured::Lookup>,
}

impl LookupArg {
    pub fn how(&self) -> lobe::measured::Lookup {
        self.given.unwrap_or_default()
    }

    /// Refuses `--lookup` where no measured table is read.
    pub fn only_for_tables(&self, tables: usize) -> Result<(), CliError> {
        match self.given {
            Some(h) if tables == 0 => Err(CliError::hint(format!("--lookup {} reads measured tables, and none is given", h.name()), "drop --lookup, or give a .binary file")),
            _ => Ok(()),
        }
    }
}

fn parse_lookup(s: &str) -> Result<lobe::measured::Lookup, String> {
    s.parse()
}

/// `--lobe NH|VR`: the lobe variable of the formula under a lobe check.
#[derive(clap::Args, Clone, Debug)]
pub struct LobeVar {
    /// The lobe variable (NH or VR); default: the one the formula reads.
    #[arg(id = "lobe", long = "lobe", value_name = "LOBE")]
    pub name: Option<String>,
}

impl LobeVar {
    /// The lobe variable from `--lobe`, or the one a formula reading `used` reads (printing a note on stderr
    /// about an ambiguous choice unless `quiet`).
    pub fn resolve(&self, used: InputSet, quiet: bool) -> Result<Input, CliError> {
        match &self.name {
            Some(s) => Input::from_name(s).ok_or_else(|| {
                CliError::hint(format!("--lobe: `{s}` is not an input"), "the lobe variable is NH (Blinn-style) or VR (Phong-style)")
            }),
            None => {
                let (lobe, note) = lobe::numerics::choose_lobe_input(used);
                if let (Some(n), false) = (note, quiet) {
                    eprintln!("note: {n}");
                }
                Ok(lobe)
            }
        }
    }
}

/// A formula measured against a reference lobe (`accuracy`, `fit`): the formula, `--reference` and `--lobe`.
#[derive(clap::Args, Clone, Debug)]
pub struct AgainstReference {
    #[command(flatten)]
    pub formula: FormulaSource,
    /// The reference lobe (normally Blinn, cos^n); for `accuracy`, also a measured table (MERL .binary).
    #[arg(long)]
    pub reference: String,
    #[command(flatten)]
    pub lobe: LobeVar,
}

impl AgainstReference {
    /// The formula's kernel in `b`'s backend and math mode and the reference's (precise: it is the yardstick),
    /// each with the `--set` values of the parameters it declares baked (a name neither declares is an error).
    /// `n` cannot be set: the papers' metrics sweep it over 1..n_max in both.
    pub fn kernels(&self, set: &[(String, f64)], b: &BackendArg) -> Result<(Kernel, Kernel), CliError> {
        if set.iter().any(|(k, _)| k == "n") {
            return Err(CliError::hint(
                "--set n: the papers' metrics sweep n over 1..n_max in the formula and the reference, so a value of n would be ignored",
                "drop n from --set (--n-max sets the sweep's end)",
            ));
        }
        let f = common::load_formula(self.formula.file.as_deref(), self.formula.expr.as_deref())?;
        let rf = common::load_formula(Some(&self.reference), None)?;
        common::check_set_names(&[&f, &rf], set)?;
        let k = common::compile_kernel(f.clone(), &common::set_for(&f, set), b.bulk_backend()?, b.math.mode)?;
        let r = common::compile_kernel(rf.clone(), &common::set_for(&rf, set), b.bulk_backend()?, lobe::Mode::Precise)?;
        Ok((k, r))
    }


    /// The lobe variables of the formula `k` ([`LobeVar::resolve`]) and of the reference `r` (the one it reads).
    pub fn lobes(&self, k: &Kernel, r: &Kernel, quiet: bool) -> Result<(Input, Input), CliError> {
        Ok((self.lobe.resolve(k.used_inputs(), quiet)?, lobe::numerics::choose_lobe_input(r.used_inputs()).0))
    }
}

/// `--force`: replace an output file lobe did not write.
#[derive(clap::Args, Clone, Copy, Debug)]
pub struct Force {
    /// Replace an existing output file even if lobe did not write it.
    #[arg(id = "force", long = "force")]
    pub on: bool,
}

impl Force {
    /// Refuses `path` if it is not a regular file, its directory is missing, or it exists and is neither
    /// recognised by `is_ours` nor `--force`d ([`output::check`]). Commands call this before doing the work, so
    /// a bad path costs nothing.
    pub fn check(&self, path: &Path, is_ours: fn(&[u8]) -> bool) -> Result<(), CliError> {
        output::check(path, self.on, is_ours)
            .map_err(|d| if d.hints.is_empty() { d.hint(lobe::base::output::AllowOverwrite) } else { d }.into())
    }

    /// Checks `path` as [`Force::check`] does, then writes `bytes` to a temporary file in the same directory
    /// and renames it over `path`: a failure never leaves a half-written file at the user's path.
    pub fn write(&self, path: &Path, bytes: &[u8], is_ours: fn(&[u8]) -> bool) -> Result<(), CliError> {
        self.check(path, is_ours)?;
        output::write_atomic(path, bytes).map_err(CliError::msg)
    }
}

/// `-o/--output FILE` with `--force`. Commands that must have an output mark it required with `mut_arg`.
#[derive(clap::Args, Clone, Debug)]
pub struct Output {
    /// Write to this file.
    #[arg(id = "output", short = 'o', long = "output", value_name = "OUTPUT")]
    pub path: Option<PathBuf>,
    #[command(flatten)]
    pub force: Force,
}

impl Output {
    /// A command's text output (an export, an import): written to `-o` (refusing a file lobe did not write
    /// unless `--force`) or printed; with `json` (the object's other keys), one object with `output` (the path or
    /// null) and `text` is printed instead of the text.
    pub fn emit_text(&self, text: &str, is_ours: fn(&[u8]) -> bool, json: Option<serde_json::Value>) -> Result<(), CliError> {
        if let Some(p) = &self.path {
            self.force.write(p, text.as_bytes(), is_ours)?;
        }
        match json {
            Some(mut j) => {
                j["output"] = self.path.as_ref().map(|p| p.display().to_string()).into();
                j["text"] = text.into();
                println!("{j}");
            }
            None if self.path.is_none() => print!("{text}"),
            None => {}
        }
        Ok(())
    }

    /// Refuses a name whose extension says another format than the PNG lobe writes (`x.jpg`, `x.svg`).
    pub fn png_only(path: &Path) -> Result<(), CliError> {
        match path.extension().and_then(|e| e.to_str()) {
            Some(e) if !e.eq_ignore_ascii_case("png") => Err(CliError::hint(
                format!("`{}`: this command writes PNG images, not .{e}", path.display()),
                "name the output .png",
            )),
            _ => Ok(()),
        }
    }

    /// The path of a command whose `-o` is required (clap has rejected the command line without it).
    pub fn required(&self) -> &Path {
        self.path.as_deref().expect("-o is a required argument of this command")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::{Args, FromArgMatches};

    #[derive(clap::Args, Debug)]
    #[command(mut_arg("set", help("Narrower help")))]
    struct Every {
        #[command(flatten)]
        formula: FormulaSource,
        #[command(flatten)]
        set: Params,
        #[command(flatten)]
        backend: BackendArg,
        #[command(flatten)]
        json: Json,
        #[command(flatten)]
        out: Output,
    }

    fn parse(argv: &[&str]) -> Result<Every, clap::Error> {
        let cmd = Every::augment_args(clap::Command::new("t"));
        cmd.clone().debug_assert();
        Every::from_arg_matches(&cmd.try_get_matches_from(argv)?)
    }

    #[test]
    fn flattened_flags_parse_as_one_command() {
        let a = parse(&["t", "f.brdf", "--set", "n=2,a=3", "--set", "k=1", "--backend", "interp", "--json", "-o", "x", "--force"])
            .unwrap();
        assert_eq!(a.formula.file.as_deref(), Some("f.brdf"));
        assert_eq!(a.set.list().unwrap(), vec![("n".into(), 2.0), ("a".into(), 3.0), ("k".into(), 1.0)]);
        assert_eq!((a.backend.engine.kind, a.json.on, a.out.force.on), (Backend::Interp, true, true));
        assert_eq!(a.out.path.as_deref(), Some(Path::new("x")));
        let d = parse(&["t"]).unwrap();
        assert_eq!((d.backend.engine.kind, d.json.on, d.out.path, d.set.list().unwrap()), (Backend::Jit, false, None, vec![]));
        // The same name in two flags: once with the same value, an error naming both with different ones.
        let a = parse(&["t", "--set", "n=5", "--set", "a=3,n=5"]).unwrap();
        assert_eq!(a.set.list().unwrap(), vec![("n".into(), 5.0), ("a".into(), 3.0)]);
        let e = parse(&["t", "--set", "n=5", "--set", "n=6"]).unwrap().set.list().unwrap_err().render(false);
        assert!(e.contains("--set gives `n` twice: n=5 and n=6") && e.contains("help"), "{e}");
        assert!(parse(&["t", "f.brdf", "--expr", "NH"]).is_err());
        assert!(parse(&["t", "--set", "n"]).is_err());
        let help = Every::augment_args(clap::Command::new("t")).render_help().to_string();
        assert!(help.contains("Narrower help") && !help.contains("e.g. `n=50,a=16`"), "{help}");
    }
}
