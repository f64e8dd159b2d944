//! `[materials.*]` tables → [`Material`]s: where the formula comes from (a `brdf` file, an inline `formula`, or
//! the caller's override), parameter values (the formula's defaults, then the table's `params`, then the run's,
//! each checked against the declared range), compilation, and the optional energy normalisation
//! ([`crate::numerics::normalize::coefficient`]) and cut-off ([`crate::render::plan::Cutoff`]).
//!
//! Formulas go through a [`BrdfCompiler`] rather than straight to [`crate::compile_source`]: [`LobeCompiler`] is
//! the real front end and backends, and the trait lets embedders and tests supply kernels of their own. This is
//! the only step that depends on parameter values, so it is the one step [`super::Geometry::with_materials`]
//! repeats.
//!
//! A colour formula (`Formula.rgb`) compiles to one kernel per channel, each through the same pipeline as a
//! scalar formula; normalisation is per channel, and a cut-off is found per channel and the widest kept (no
//! channel is cut above its own 2^−q level).

use super::schema::MaterialDef;
use crate::backend::{Backend, Evaluator};
use crate::builtins::Mode;
use crate::base::diag::{Diagnostic, Diagnostics, Setting};
use crate::base::span::Span;
use crate::ir::{InputSet, ParamDecl};
use crate::render::Material;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use toml::Spanned;

/// Turns formula source into an evaluator. `declare` lists the parameters (to check scene values against);
/// `build` bakes `values` (all parameters, by name) into the kernel.
pub trait BrdfCompiler: Sync {
    fn declare(&self, file: &str, src: &str) -> Result<Vec<ParamDecl>, Diagnostics>;
    /// `math`: the material's own `math = "…"` key, if it has one (else the compiler's default).
    fn build(&self, file: &str, src: &str, values: &[(String, f64)], math: Option<Mode>) -> Result<CompiledBrdf, Diagnostics>;
}

/// A compiled material formula.
#[derive(Clone)]
pub struct CompiledBrdf {
    /// The scalar formula's kernel, or a colour formula's red channel.
    pub evaluator: Arc<dyn Evaluator>,
    /// A colour formula's green and blue kernels.
    pub green_blue: Option<[Arc<dyn Evaluator>; 2]>,
    /// Inputs read by any channel.
    pub used: InputSet,
    /// The math mode the kernel runs.
    pub math: Mode,
    /// The formulas behind the kernels, for the renderer's shading programs.
    pub program: crate::render::ProgramSource,
}

/// The real pipeline: `lobe::compile_source` with the chosen backend, in `math` unless a material says otherwise,
/// through `accuracy` when one is given (the accuracy pass's choice, as `eval` and `energy` compile: a render
/// then shades with the form that has no NaN where the value is finite).
#[derive(Clone, Debug)]
pub struct LobeCompiler {
    pub backend: Backend,
    pub math: Mode,
    pub accuracy: Option<Arc<dyn crate::FormulaChooser>>,
}

impl LobeCompiler {
    /// The scene compiler of the commands that render: the backend's kernels through the accuracy pass in
    /// `math`, as [`crate::numerics::pass_cache::command_channels`] compiles (cached when `cached`, so a
    /// second render of a scene pays nothing for it).
    pub fn for_commands(backend: Backend, math: Mode, cached: bool) -> LobeCompiler {
        let pass = crate::numerics::robust::PassOptions { math, ..Default::default() };
        LobeCompiler { backend, math, accuracy: crate::numerics::pass_cache::command_pass(crate::Options::default(), pass, cached).accuracy }
    }

    /// The plain simplification's kernels on `backend` in `math`, without an accuracy pass.
    pub const fn plain(backend: Backend, math: Mode) -> LobeCompiler {
        LobeCompiler { backend, math, accuracy: None }
    }
}

impl BrdfCompiler for LobeCompiler {
    fn declare(&self, file: &str, src: &str) -> Result<Vec<ParamDecl>, Diagnostics> {
        Ok(crate::front::parse(file, src)?.params)
    }
    fn build(&self, file: &str, src: &str, values: &[(String, f64)], math: Option<Mode>) -> Result<CompiledBrdf, Diagnostics> {
        let math = math.unwrap_or(self.math);
        let opts = crate::Options { backend: self.backend, bake: values.to_vec(), math, accuracy: self.accuracy.clone(), ..crate::Options::default() };
        compile_channels(crate::front::parse(file, src)?, &opts)
    }
}

/// Compiles a formula's channels ([`crate::ir::Formula::channels`]: itself, or red, green, blue) into a
/// [`CompiledBrdf`], each kernel warmed up (the batched kernel is built on first use; build it now, at load
/// time, not inside the timed render).
pub fn compile_channels(f: crate::ir::Formula, opts: &crate::Options) -> Result<CompiledBrdf, Diagnostics> {
    let ks = f.channels().into_iter().map(|c| crate::compile_formula(c, opts).map(Arc::new)).collect::<Result<Vec<_>, _>>()?;
    ks.iter().for_each(|k| k.warm_up());
    Ok(CompiledBrdf::from_kernels(&ks))
}

impl CompiledBrdf {
    /// A material's kernels from a formula's channel kernels ([`crate::ir::Formula::channels`] order: one, or
    /// red, green, blue).
    pub(crate) fn from_kernels(ks: &[Arc<crate::Kernel>]) -> CompiledBrdf {
        let dynamic = |k: &Arc<crate::Kernel>| k.clone() as Arc<dyn Evaluator>;
        CompiledBrdf {
            evaluator: dynamic(&ks[0]),
            green_blue: (ks.len() == 3).then(|| [dynamic(&ks[1]), dynamic(&ks[2])]),
            used: ks.iter().map(|k| k.used_inputs()).collect(),
            math: ks[0].math,
            program: crate::render::ProgramSource {
                channels: ks.iter().map(|k| k.formula.clone()).collect(),
                evaluated: None,
                backend: ks[0].backend,
                math: ks[0].math,
            },
        }
    }
}

/// The scene file the tables came from: its name and text (for spans and notes) and the directory relative
/// `brdf` paths are resolved against.
pub(super) struct SceneText<'a> {
    pub name: &'a str,
    pub src: &'a str,
    pub base: &'a Path,
    /// What the formula files and measured tables are read through.
    pub files: &'a crate::base::source::Files,
}

/// What to compile: `set` applies to every material whose formula declares the name (an error if none does);
/// `formula` = (file name, source) replaces every material's formula, and then scene `params` it does not
/// declare are ignored.
pub(super) struct Choice<'a> {
    pub set: &'a [(String, f64)],
    pub formula: Option<(&'a str, &'a str)>,
}

/// Builds every material, in table (name) order. Scene errors are pushed onto `ds`, which holds whatever the
/// load found before the materials. A formula that fails to compile ends the load at once: the result is then
/// `ds` if it has errors, else the formula's own diagnostics (with a note naming the scene key).
pub(super) fn build_all(
    at: &SceneText,
    tables: &BTreeMap<String, Spanned<MaterialDef>>,
    choice: &Choice,
    compiler: &dyn BrdfCompiler,
    ds: &mut Diagnostics,
) -> Result<Vec<Material>, Diagnostics> {
    let mut materials = vec![];
    let mut set_used = vec![false; choice.set.len()];
    // A material that failed may not have reached the set values: then "no material declares `k`" is unknown.
    let mut all_built = true;
    for (mname, m) in tables {
        match build_material(at, mname, m, choice, compiler, &mut set_used) {
            Ok(mat) => materials.push(mat),
            Err(MatError::Scene(d)) => {
                ds.push(d);
                all_built = false;
            }
            Err(MatError::Formula(fd)) => return Err(if ds.has_errors() { ds.clone() } else { fd }),
        }
    }
    for (i, (k, _)) in choice.set.iter().enumerate() {
        if !set_used[i] && !tables.is_empty() && all_built {
            ds.push(
                Diagnostic::error(format!("no material's formula declares a parameter `{k}`"))
                    .about(Setting::Param { name: k.clone(), value: None })
                    .hint("every formula has `n`; see each .brdf file's `param` lines"),
            );
        }
    }
    Ok(materials)
}

fn span_of(r: std::ops::Range<usize>) -> Span {
    Span::new(r.start, r.end)
}

enum MatError {
    Scene(Diagnostic),
    Formula(Diagnostics),
}

fn here(s: std::ops::Range<usize>, msg: String, label: &str) -> MatError {
    MatError::Scene(Diagnostic::error(msg).at(span_of(s), label.to_string()))
}

/// Checks the material's weights, colours and tangent angle; returns the angle (degrees).
fn check_weights(mname: &str, m: &Spanned<MaterialDef>) -> Result<f64, MatError> {
    let d = m.get_ref();
    for (k, val) in [("ka", d.ka), ("kd", d.kd), ("ks", d.ks)] {
        if !(val.is_finite() && val >= 0.0) {
            return Err(here(m.span(), format!("materials.{mname}.{k} = {val} must be a finite number ≥ 0"), "this material"));
        }
    }
    for (k, rgb) in [("color", d.color), ("specular", d.specular)] {
        if !super::schema::is_colour(&rgb) {
            return Err(here(m.span(), format!("materials.{mname}.{k} = {rgb:?} must be three finite numbers ≥ 0"), "this material"));
        }
    }
    if let Some(a) = d.tangent_angle_deg.as_ref().filter(|a| !a.get_ref().is_finite()) {
        return Err(here(a.span(), format!("materials.{mname}.tangent_angle_deg must be a finite angle in degrees"), "tangent angle"));
    }
    Ok(d.tangent_angle_deg.as_ref().map_or(0.0, |a| *a.get_ref()))
}

/// A material whose reflectance is the measured table at `path` (a MERL `.binary`, [`crate::measured`]):
/// its three channels are the evaluators, shaded by the renderer's Rust-side lookup. A table has no
/// parameters, normalisation, cut-off or math mode: the scene keys for them are refused, except that the
/// formula-replacing run (`choice.formula`) ignores `params` as it ignores the ones a formula does not declare.
fn measured_material(
    at: &SceneText,
    mname: &str,
    m: &Spanned<MaterialDef>,
    path: &str,
    span: std::ops::Range<usize>,
    replacing: bool,
) -> Result<Material, MatError> {
    let d = m.get_ref();
    let refuse = |key: &str| here(m.span(), format!("materials.{mname}.{key}: a measured material (`{path}`) has no {key}"), "this material");
    if let Some((k, _)) = d.params.iter().next().filter(|_| !replacing) {
        return Err(here(k.span(), format!("materials.{mname}.params: a measured material (`{path}`) has no parameters"), "remove `params`"));
    }
    if d.normalize {
        return Err(refuse("normalize"));
    }
    if d.cutoff.is_some() {
        return Err(refuse("cutoff"));
    }
    if d.math.is_some() {
        return Err(refuse("math"));
    }
    let angle = check_weights(mname, m)?;
    let table = crate::measured::Measured::read_through(path, at.files).map_err(|mut e| {
        e.message = format!("materials.{mname}.brdf: {}", e.message);
        MatError::Scene(e.at(span_of(span), "this measured file (relative to the scene file)"))
    })?;
    let how = match &d.lookup {
        Some(h) => h.get_ref().parse::<crate::measured::Lookup>().map_err(|e| here(h.span(), format!("materials.{mname}.lookup: {e}"), "lookup"))?,
        None => crate::measured::Lookup::default(),
    };
    let [r, g, b] = std::sync::Arc::new(table).channels_with(how);
    Ok(Material {
        name: mname.to_string(),
        evaluator: r.clone(),
        green_blue: Some([g.clone(), b.clone()]),
        used: crate::measured::used_inputs(),
        params: vec![],
        ka: d.ka,
        kd: d.kd,
        ks: d.ks,
        color: d.color.into(),
        specular: d.specular.into(),
        coef: [1.0; 3].into(),
        tangent_angle_deg: angle,
        times_nl: d.times_nl,
        cutoff: None,
        math: Mode::default(),
        program: crate::render::ProgramSource { channels: vec![], evaluated: Some([r, g, b]), backend: Backend::Interp, math: Mode::default() },
    })
}

fn build_material(
    at: &SceneText,
    mname: &str,
    m: &Spanned<MaterialDef>,
    choice: &Choice,
    compiler: &dyn BrdfCompiler,
    set_used: &mut [bool],
) -> Result<Material, MatError> {
    let d = m.get_ref();
    let measured = match (choice.formula, &d.brdf, &d.formula) {
        (Some((f, _)), ..) if crate::measured::is_measured_path(f) => Some((f.to_string(), m.span())),
        (None, Some(p), None) if crate::measured::is_measured_path(p.get_ref()) => Some((at.base.join(p.get_ref()).display().to_string(), p.span())),
        _ => None,
    };
    if let Some((path, span)) = measured {
        return measured_material(at, mname, m, &path, span, choice.formula.is_some());
    }
    // A formula replacing the scene's (compare, fit images) leaves a `lookup` meant for the scene's table alone.
    if let Some(h) = d.lookup.as_ref().filter(|_| choice.formula.is_none()) {
        return Err(here(h.span(), format!("materials.{mname}.lookup: this material is a formula; `lookup` reads measured tables (.binary)"), "remove `lookup`"));
    }
    // Where the formula comes from, and the scene span to blame.
    let (file, src, key_span) = if let Some((f, s)) = choice.formula {
        (f.to_string(), s.to_string(), m.span())
    } else {
        match (&d.brdf, &d.formula) {
            (Some(p), None) => {
                let path: PathBuf = at.base.join(p.get_ref());
                let file = path.display().to_string();
                let src = match at.files.read_formula(&file) {
                    Ok(s) => s,
                    Err(mut d) => {
                        d.message = format!("materials.{mname}.brdf: {}", d.message);
                        return Err(MatError::Scene(d.at(span_of(p.span()), "this path (relative to the scene file)")));
                    }
                };
                (file, src, p.span())
            }
            (None, Some(f)) => (format!("{} [materials.{mname}.formula]", at.name), f.get_ref().clone(), f.span()),
            (Some(_), Some(f)) => return Err(here(f.span(), format!("materials.{mname}: give `brdf` or `formula`, not both"), "second source")),
            (None, None) => return Err(here(m.span(), format!("materials.{mname}: needs `brdf = \"path.brdf\"` or `formula = \"…\"`"), "this material")),
        }
    };
    let (line, col) = crate::base::span::line_col(at.src, key_span.start);
    let with_note = |mut fd: Diagnostics| {
        for it in &mut fd.items {
            it.hints.push(format!("used by [materials.{mname}] at {}:{line}:{col}", at.name).into());
        }
        MatError::Formula(fd)
    };
    let decls = compiler.declare(&file, &src).map_err(with_note)?;
    let mut values: Vec<(String, f64)> = decls.iter().map(|p| (p.name.clone(), p.default)).collect();
    let mut assign = |name: &str, v: f64| -> Result<bool, String> {
        match decls.iter().position(|p| p.name == name) {
            Some(i) => {
                let p = &decls[i];
                if !p.admits(v) {
                    let num = crate::ir::print::number;
                    return Err(format!("value {} for `{name}` is outside the formula's declared range {}..{}", num(v), num(p.lo), num(p.hi)));
                }
                values[i].1 = v;
                Ok(true)
            }
            None => Ok(false),
        }
    };
    for (k, v) in &d.params {
        match assign(k.get_ref(), *v.get_ref()) {
            Ok(true) => {}
            Ok(false) if choice.formula.is_some() => {}
            Ok(false) => {
                let names: Vec<&str> = decls.iter().map(|p| p.name.as_str()).collect();
                let hint = crate::front::did_you_mean(k.get_ref(), &names, "the formula's parameters are: ");
                return Err(MatError::Scene(
                    Diagnostic::error(format!("materials.{mname}.params: the formula has no parameter `{}`", k.get_ref()))
                        .at(span_of(k.span()), "unknown parameter")
                        .hint(hint),
                ));
            }
            Err(msg) => return Err(here(v.span(), format!("materials.{mname}.params.{}: {msg}", k.get_ref()), "out of range")),
        }
    }
    for (i, (k, v)) in choice.set.iter().enumerate() {
        match assign(k, *v) {
            Ok(true) => set_used[i] = true,
            Ok(false) => {}
            Err(msg) => {
                // The formula declares the name (the value is what is wrong).
                set_used[i] = true;
                let d = Diagnostic::error(format!("material `{mname}`: {msg}")).about(Setting::Param { name: k.clone(), value: Some(*v) });
                return Err(MatError::Scene(d.at(span_of(m.span()), "this material")));
            }
        }
    }
    let math = match &d.math {
        None => None,
        Some(m) => Some(m.get_ref().parse::<Mode>().map_err(|msg| here(m.span(), format!("materials.{mname}.math: {msg}"), "unknown math mode"))?),
    };
    let compiled = compiler.build(&file, &src, &values, math).map_err(with_note)?;
    let angle = check_weights(mname, m)?;
    let params: Vec<f64> = values.iter().map(|(_, v)| *v).collect();
    let channels: Vec<&dyn Evaluator> =
        std::iter::once(compiled.evaluator.as_ref()).chain(compiled.green_blue.iter().flat_map(|gb| gb.iter().map(|e| e.as_ref()))).collect();
    let mut coef = [1.0; 3];
    if d.normalize {
        for (c, ev) in channels.iter().enumerate() {
            coef[c] = crate::numerics::normalize::coefficient(*ev, compiled.used, &params)
                .map_err(|e| e.to_string())
                .map_err(|msg| here(m.span(), format!("materials.{mname}.normalize: {msg}"), "this material"))?;
        }
        if channels.len() == 1 {
            coef = [coef[0]; 3];
        }
    }
    let cutoff = match &d.cutoff {
        Some(q) => {
            let mut widest: Option<crate::render::plan::Cutoff> = None;
            for ev in &channels {
                let c = crate::render::plan::Cutoff::find(*ev, compiled.used, &params, *q.get_ref())
                    .map_err(|msg| here(q.span(), format!("materials.{mname}.cutoff: {msg}"), "cut-off exponent"))?;
                widest = Some(match widest {
                    Some(w) if w.cos <= c.cos => w,
                    _ => c,
                });
            }
            widest
        }
        None => None,
    };
    Ok(Material {
        name: mname.to_string(),
        evaluator: compiled.evaluator,
        green_blue: compiled.green_blue,
        used: compiled.used,
        params,
        ka: d.ka,
        kd: d.kd,
        ks: d.ks,
        color: d.color.into(),
        specular: d.specular.into(),
        coef: coef.into(),
        tangent_angle_deg: angle,
        times_nl: d.times_nl,
        cutoff,
        math: compiled.math,
        program: compiled.program,
    })
}
