//! The Mitsuba 3 export: a Python module that registers a formula as a Mitsuba BSDF plugin whose eval, pdf,
//! sample and eval_pdf are lobe's — the formula through the Dr.Jit emitter ([`crate::backend::drjit`]), and the
//! [`Sampler`]'s tables embedded, with its sample and pdf written again in Dr.Jit operations
//! (`mitsuba_runtime.py`, appended to every module).
//!
//! What the module holds: a header (the formula, the baked parameters, the mechanism, how to use it), the
//! sampler's constants (mechanism, cosine fraction, table sizes, incidence nodes, which nodes are empty), the
//! tables' cell densities as base64 of little-endian f64 (the module rebuilds the cumulative sums from them at
//! import) and, for the tabulated mechanism, the corner densities the cells interpolate, and the formula as `_formula(NL, …, Vz)`. Everything computes in Float64, so the module's
//! `pdf_f64` equals [`Sampler::pdf_many`] and `eval_f64` lobe's values to rounding; the plugin converts to and
//! from Mitsuba's f32 at its edges.
//!
//! Conventions: Mitsuba's `si.wi` is the formula's L and the plugin's `wo` its V (the sampler's wi and wo; the
//! same thing for a reciprocal formula); directions in the local frame (N = +z). `eval` returns f·cosθₒ as
//! Mitsuba's BSDFs do; below either horizon eval and pdf are 0 and a sample has weight 0. The plugin's `pdf` and
//! `sample` follow Mitsuba's convention that a sample of weight 0 is invalid and pdf counts only valid samples:
//! where every channel's weight f·cosθₒ/pdf is below the smallest normal f32 (the formula is 0 there, or below
//! the horizon) `sample` returns weight 0 and pdf 0 and `pdf` returns 0; elsewhere both report lobe's pdf, so
//! Mitsuba's stock `mi.chi2.BSDFAdapter` tests the plugin as it is. Every parameter is
//! baked (the tables are built at fixed values): the module has no live parameters.

use super::{Body, Mechanism, Sampler, COLS, EXACT_CELLS, ROWS};
use crate::backend::drjit;
use crate::base::diag::Diagnostic;
use crate::ir::{Formula, Input};
use std::fmt::Write;

/// The runtime every module ends with.
const RUNTIME: &str = include_str!("mitsuba_runtime.py");

/// Standard base64 (RFC 4648, with padding).
fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for c in bytes.chunks(3) {
        let n = (u32::from(c[0]) << 16) | (u32::from(*c.get(1).unwrap_or(&0)) << 8) | u32::from(*c.get(2).unwrap_or(&0));
        for k in 0..4 {
            if k <= c.len() {
                out.push(A[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// Text safe in a `#` comment: control characters (a CR would end it) become spaces.
fn comment(s: &str) -> String {
    s.chars().map(|c| if c.is_control() || matches!(c, '\u{2028}' | '\u{2029}' | '\u{85}') { ' ' } else { c }).collect()
}

/// The plugin's name for a formula: `lobe_` + the file stem (as the GLSL export names its function).
pub fn plugin_name(f: &Formula) -> String {
    crate::backend::glsl::function_name(f)
}

/// A list of f64 as a Python literal (exact).
fn list(v: impl Iterator<Item = f64>) -> String {
    let items: Vec<String> = v.map(drjit::literal).collect();
    format!("[{}]", items.join(", "))
}

/// A formula exported as a Mitsuba module ([`export`]).
pub struct Export {
    pub text: String,
    /// The plugin's name ([`plugin_name`]).
    pub plugin: String,
    /// The sampler's mechanism.
    pub mechanism: Mechanism,
    /// Whether the sampler's tables are isotropic.
    pub isotropic: bool,
}

/// The Mitsuba export of the command line and of Python: the module of `f` with every parameter baked (the `set` values, else the
/// defaults), its sampler (mechanism `choice`) built from the formula's kernels with the accuracy pass on (its
/// decisions cached when `cache`), as `lobe sample` builds it, and the plain simplification at the same values.
pub fn export(f: &Formula, set: &[(String, f64)], choice: super::Choice, cache: bool) -> Result<Export, crate::base::diag::Diagnostics> {
    use crate::base::diag::Diagnostics;
    let opts = crate::numerics::pass_cache::command_pass(crate::Options { bake: set.to_vec(), ..crate::Options::default() }, Default::default(), cache);
    let ks = f.channels().into_iter().map(|c| crate::compile_formula(c, &opts)).collect::<Result<Vec<_>, _>>()?;
    let mut values = ks[0].formula.default_params();
    for (k, v) in set {
        if let Some(i) = ks[0].formula.param_index(k) {
            values[i] = *v;
        }
    }
    let all: Vec<(String, f64)> = f.params.iter().zip(&values).map(|(p, v)| (p.name.clone(), *v)).collect();
    let plain = crate::simplified(f, &crate::Options { bake: all.clone(), ..crate::Options::default() })?;
    let s = Sampler::build_channels(&ks, &values, &super::Options { choice, ..super::Options::default() }).map_err(|d| Diagnostics::single(&f.file, d))?;
    let text = module(&plain, &s, &all).map_err(|d| Diagnostics::single_in(&plain.file, &plain.source, d))?;
    Ok(Export { text, plugin: plugin_name(&plain), mechanism: s.report.mechanism, isotropic: s.report.isotropic })
}

/// The module for `plain` (the formula simplified with every parameter baked, without the accuracy pass) and
/// the sampler built from its kernels at the same parameters; `params` names the values baked, for the header.
pub fn module(plain: &Formula, sampler: &Sampler, params: &[(String, f64)]) -> Result<String, Diagnostic> {
    let name = plugin_name(plain);
    let body = drjit::function(plain, "_formula")?;
    let channels = plain.channels();
    if channels.len() != sampler.channels() {
        return Err(Diagnostic::error(format!(
            "the formula has {} channels and its sampler {}",
            channels.len(),
            sampler.channels()
        )));
    }
    let mut o = String::new();
    let _ = writeln!(o, "# {} — exported by lobe {} as a Mitsuba 3 BSDF plugin `{name}`.", comment(&plain.display_name()), env!("CARGO_PKG_VERSION"));
    if let Some(c) = &plain.meta.citation {
        let _ = writeln!(o, "# Source: {}", comment(c));
    }
    for (k, c) in channels.iter().enumerate() {
        let which = if channels.len() == 1 { String::new() } else { format!(", {} channel", ["red", "green", "blue"][k.min(2)]) };
        let _ = writeln!(o, "# Formula (simplified){which}:");
        for l in c.to_program_text().lines() {
            let _ = writeln!(o, "#   {}", comment(l));
        }
    }
    if !params.is_empty() {
        let shown: Vec<String> = params.iter().map(|(n, v)| format!("{}={}", comment(n), drjit::literal(*v))).collect();
        let _ = writeln!(o, "# Parameters baked (the sampling tables are built at these values): {}", shown.join(", "));
    }
    let r = &sampler.report;
    let _ = writeln!(
        o,
        "# Sampling: {} ({}), cosine fraction {}; the tables are lobe's (src/bsdf), embedded.",
        r.mechanism.name(),
        if r.isotropic { "isotropic" } else { "anisotropic" },
        sampler.cosine_fraction()
    );
    let _ = writeln!(o, "#");
    let _ = writeln!(o, "# Use: mi.set_variant('llvm_ad_rgb') (or 'scalar_rgb'), then `import` this file: it registers");
    let _ = writeln!(o, "# the plugin `{name}` (call its register() again after switching variants), e.g.");
    let _ = writeln!(o, "# mi.load_dict({{'type': '{name}'}}). si.wi is the formula's L and wo its V (local frame, N = +z);");
    let _ = writeln!(o, "# eval returns f·cos(θo) as Mitsuba's BSDFs do. Computed in Float64; RGB variants only.");
    let _ = writeln!(o, "\n_NAME = {name:?}");
    let _ = writeln!(o, "_CHANNELS = {}", channels.len());
    let _ = writeln!(o, "_MECHANISM = '{}'", r.mechanism.name());
    let _ = writeln!(o, "_COS_FRAC = {}", drjit::literal(sampler.cosine_fraction()));
    let _ = writeln!(o, "_ROWS = {ROWS}\n_COLS = {COLS}\n_EXACT_CELLS = {EXACT_CELLS}");
    let (mut cells, mut corners): (Vec<f64>, Vec<f64>) = (vec![], vec![]);
    let (mut thetas, mut empty, mut nphi, mut iso) = (vec![0.0, 1.0], vec![], 1, r.isotropic);
    let (mut lobe, mut theta_max) = ("None".to_string(), 0.0);
    let (mut bands, mut measure): (&[f64], &[f64]) = (&[], &[]);
    match &sampler.body {
        Body::Cosine => {}
        Body::Tabulated(t) => {
            thetas = t.thetas.clone();
            nphi = t.phis;
            iso = t.isotropic;
            bands = &t.bands;
            for n in &t.nodes {
                match n {
                    Some(d) => {
                        cells.extend_from_slice(d.cells.densities());
                        corners.extend_from_slice(&d.corners);
                        empty.push(0);
                    }
                    None => {
                        cells.extend(std::iter::repeat_n(0.0, ROWS * COLS));
                        corners.extend(std::iter::repeat_n(0.0, (ROWS + 1) * COLS));
                        empty.push(1);
                    }
                }
            }
        }
        Body::Exact(e) => {
            lobe = format!("'{}'", if e.lobe == Input::VR { "VR" } else { "NH" });
            theta_max = e.theta_max;
            (bands, measure) = (&e.bands, &e.measure);
            if e.lobe == Input::VR {
                thetas = e.thetas.clone();
            }
            for n in &e.nodes {
                match n {
                    Some(d) => {
                        cells.extend_from_slice(d.densities());
                        empty.push(0);
                    }
                    None => {
                        cells.extend(std::iter::repeat_n(0.0, EXACT_CELLS));
                        empty.push(1);
                    }
                }
            }
        }
    }
    debug_assert_eq!(sampler.report.mechanism == Mechanism::Cosine, empty.is_empty());
    let _ = writeln!(o, "_ISOTROPIC = {}", if iso { "True" } else { "False" });
    let _ = writeln!(o, "_NPHI = {nphi}");
    let _ = writeln!(o, "_THETAS = {}", list(thetas.iter().copied()));
    let _ = writeln!(o, "_EMPTY = {:?}", empty);
    let _ = writeln!(o, "_EXACT_LOBE = {lobe}");
    let _ = writeln!(o, "_EXACT_THETA_MAX = {}", drjit::literal(theta_max));
    let _ = writeln!(o, "_BANDS = {}", list(bands.iter().copied()));
    let _ = writeln!(o, "_MEASURE = {}", list(measure.iter().copied()));
    for (name, values) in [("_TABLE", &cells), ("_CORNERS", &corners)] {
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        let b64 = base64(&bytes);
        if b64.is_empty() {
            let _ = write!(o, "{name} = ''\n\n\n");
        } else {
            let _ = writeln!(o, "{name} = (");
            for chunk in b64.as_bytes().chunks(100) {
                let _ = writeln!(o, "    '{}'", String::from_utf8_lossy(chunk));
            }
            o.push_str(")\n\n\n");
        }
    }
    o.push_str(&body);
    o.push_str(RUNTIME);
    Ok(o)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_matches_the_rfc_vectors() {
        for (i, o) in [("", ""), ("f", "Zg=="), ("fo", "Zm8="), ("foo", "Zm9v"), ("foob", "Zm9vYg=="), ("fooba", "Zm9vYmE="), ("foobar", "Zm9vYmFy")] {
            assert_eq!(base64(i.as_bytes()), o);
        }
    }

    #[test]
    fn comments_cannot_end_early() {
        assert_eq!(comment("a\rb\nc\u{2028}d"), "a b c d");
    }

    /// Metadata cannot inject code: a name with a vertical tab, a form feed or a Unicode line separator stays in
    /// its comment; the module's code lines are the generated ones.
    #[test]
    fn hostile_metadata_stays_in_comments() {
        let src = "@name \"x\u{2028}import os\x0b\x0cos.system('true')\"\nparam k = 2\nNH^k\n";
        let src = src.replace("\\u{2028}", "\u{2028}").replace("\\x0b", "\x0b").replace("\\x0c", "\x0c");
        let f = crate::front::parse("hostile.brdf", &src).unwrap_or_else(|d| panic!("{}", d.render(false)));
        let k = crate::compile_formula(f.clone(), &crate::Options::default()).unwrap();
        let s = Sampler::build(&k, &vec![2.0; f.params.len()], &super::super::Options { choice: super::super::Choice::Force(Mechanism::Cosine), ..Default::default() }).unwrap();
        let bake: Vec<(usize, f64)> = (0..f.params.len()).map(|i| (i, 2.0)).collect();
        let plain = crate::simplify::simplify(&f, &bake);
        let text = module(&plain, &s, &[("k".into(), 2.0)]).unwrap();
        assert!(!text.contains(['\u{2028}', '\x0b', '\x0c', '\r']));
        for line in text.lines().filter(|l| l.contains("os.system")) {
            assert!(line.starts_with("# "), "{line}");
        }
        assert!(text.contains("_MECHANISM = 'cosine'") && text.contains("_TABLE = ''"), "{}", &text[..1500]);
    }
}
