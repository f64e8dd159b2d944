//! The figure `lobe plot` draws (and Python's `lobe.plot`): formulas at the values they declare, measured tables
//! one curve per channel, optionally a reference formula (last) or each curve's error against it, drawn as lobes
//! or in the plane of incidence; with the plotted numbers.

use super::{incidence_lobes, incidence_points, lobe_points, lobes, Format, LobeOptions, Series, DIFFERENCE, INCIDENCE_ANGLE, LOBE_ANGLE, VALUE};
use crate::base::diag::{Diagnostic, Diagnostics};
use crate::ir::Formula;
use crate::measured::{Lookup, Measured};
use std::sync::Arc;

/// What to plot.
pub struct LobePlot<'a> {
    /// The formulas, in legend order.
    pub formulas: &'a [Formula],
    /// Measured tables (a name for the legend, the table), drawn after the formulas.
    pub tables: &'a [(String, Arc<Measured>)],
    /// A reference formula, drawn last.
    pub reference: Option<&'a Formula>,
    /// Plot each curve minus the reference instead (requires `reference`).
    pub error: bool,
    /// Parameter values; each formula takes those it declares (baked).
    pub set: &'a [(String, f64)],
    /// The light's angle from the normal (degrees, 0..=90): value against the signed view angle in the plane
    /// of incidence; `None`: value against the angle from the lobe axis.
    pub incidence: Option<f64>,
    /// How tables are read between entries.
    pub lookup: Lookup,
    pub polar: bool,
    pub log: bool,
    pub ylim: Option<(f64, f64)>,
    pub size: (u32, u32),
}

/// The drawn figure and what it shows.
pub struct Plotted {
    pub bytes: Vec<u8>,
    pub title: String,
    /// The x axis's meaning.
    pub x: &'static str,
    /// The y axis's meaning.
    pub y: &'static str,
    pub series: Vec<Series>,
}

/// `name = value` pairs as a title or a legend shows them.
fn values(set: &[(String, f64)]) -> String {
    set.iter().map(|(k, v)| format!("{k} = {v}")).collect::<Vec<_>>().join(", ")
}

/// Draws `p` as `format`.
pub fn plot_lobes(p: &LobePlot, format: Format) -> Result<Plotted, Diagnostics> {
    let fail = |d: Diagnostic| Diagnostics::single("", d);
    if let Some(t) = p.incidence.filter(|t| !(0.0..=90.0).contains(t)) {
        return Err(fail(Diagnostic::error(format!("the incidence {t} is outside 0..90 degrees")).hint("e.g. 30")));
    }
    if p.polar && p.log {
        return Err(fail(Diagnostic::error("a log axis applies to cartesian plots only (a log radius has no zero)")));
    }
    if p.error && p.reference.is_none() {
        return Err(fail(Diagnostic::error("an error plot needs a reference formula")));
    }
    let points = |ev: &dyn crate::Evaluator, used, params: &[f64]| match p.incidence {
        Some(t) => incidence_points(ev, params, t),
        None => lobe_points(ev, used, params),
    };
    let mut series = Vec::new();
    for f in p.formulas.iter().chain(p.reference) {
        let s: Vec<(String, f64)> = p.set.iter().filter(|(k, _)| f.param_index(k).is_some()).cloned().collect();
        let mut params = f.default_params();
        for (k, v) in &s {
            if let Some(i) = f.param_index(k) {
                params[i] = *v;
            }
        }
        // The legend names the values set on this formula (the title says which were set at all).
        let name = if s.is_empty() { f.display_name() } else { format!("{} ({})", f.display_name(), values(&s)) };
        let k = crate::compile_formula(f.clone(), &crate::Options { backend: crate::Backend::Jit, bake: s, ..Default::default() })?;
        series.push(Series { name, points: points(&k, k.used_inputs(), &params) });
    }
    // Measured tables after the formulas (and before the reference, which stays last).
    let at = if p.reference.is_some() { series.len() - 1 } else { series.len() };
    let mut measured = vec![];
    for (name, t) in p.tables {
        for (ev, c) in t.channels_with(p.lookup).iter().zip(["r", "g", "b"]) {
            measured.push(Series { name: format!("{name} ({c})"), points: points(ev.as_ref(), crate::measured::used_inputs(), &[]) });
        }
    }
    series.splice(at..at, measured);
    let n_label = if p.set.is_empty() { "default parameters".to_string() } else { values(p.set) };
    let mut title = format!("Lobes, {n_label}");
    if p.error {
        let reference = series.pop().unwrap_or(Series { name: String::new(), points: vec![] });
        for s in &mut series {
            for (q, r) in s.points.iter_mut().zip(&reference.points) {
                q.1 -= r.1;
            }
            s.name = format!("{} − {}", s.name, reference.name);
        }
        title = format!("Error against {}, {n_label}", reference.name);
    }
    let value = if p.error { DIFFERENCE } else { VALUE };
    let o = LobeOptions { title: title.clone(), polar: p.polar, log: p.log, size: p.size, ylim: p.ylim, value };
    let bytes = match p.incidence {
        Some(t) => incidence_lobes(&series, &o, t, format),
        None => lobes(&series, &o, format),
    }
    .map_err(|e| fail(Diagnostic::error(e)))?;
    let x = if p.incidence.is_some() { INCIDENCE_ANGLE } else { LOBE_ANGLE };
    Ok(Plotted { bytes, title, x, y: value, series })
}
