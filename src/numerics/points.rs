//! Many points from CSV text, evaluated by the batched kernel (the eval command on a points file).
//!
//! The CSV has a header naming its columns: inputs and, optionally, parameters of the formula (which then stay
//! live: no recompilation per row; [`evaluate_varying`] is the same evaluation for parameter columns held
//! elsewhere, such as the Python module's per-point arrays). The inputs are either the six direction components
//! `Lx,Ly,Lz,Vx,Vy,Vz` (local frame: N = +z, X = +x, Y = +y), from which every input is computed as the renderer does
//! ([`super::inputs_from_dirs`]; non-unit directions are normalised and counted, a zero vector is an
//! error), or cosine columns (NL, NV, NH, VR, VH; those not named are 0), which only a formula that reads no
//! direction can take. Parameters not named take their baked or declared values. Rows of equal parameter values
//! (bit for bit: 0 and −0 differ) that follow each other form one batch, so a file with no parameter columns is
//! a single call of the batched kernel; the batched kernel's value at a point does not depend on the batch it
//! is in, so every grouping gives the bits of evaluating point by point. Errors point at the CSV's line and
//! column with the usual caret diagnostics.

use super::{dot, inputs_from_dirs, V3};
use crate::base::diag::{Diagnostic, Diagnostics, Setting};
use crate::base::span::Span;
use crate::ir::{Formula, Input, InputSet, N_INPUTS};
use crate::{Columns, Evaluator, Kernel};

/// What a header column names.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Column {
    Input(Input),
    Param(usize),
}

/// Parsed points: input columns (empty when not named) and per-row parameter values.
pub struct Points {
    /// Rows whose L or V was not of unit length (normalised before use).
    pub normalised: usize,
    pub inputs: [Vec<f64>; N_INPUTS],
    /// Parameter indices named by the header.
    pub param_columns: Vec<usize>,
    /// The values of each of `param_columns`, one per point (column-major: `param_values[c][row]`).
    pub param_values: Vec<Vec<f64>>,
    pub len: usize,
    /// `len` zeros, read in place of every input column the file does not give (built once at parse, so an
    /// evaluation allocates nothing but its output).
    zeros: Vec<f64>,
    /// The runs of consecutive rows with equal parameter values, each one batch (found once at parse: scanning
    /// `param_values` per evaluation cost more than a cheap kernel at 2²⁰ rows).
    runs: Vec<std::ops::Range<usize>>,
}

fn span(start: usize, len: usize) -> Span {
    Span { start: start as u32, end: (start + len.max(1)) as u32 }
}

/// `v` scaled to unit length, and whether it had to be; `None` for a zero or non-finite vector.
pub fn unit(v: V3) -> Option<(V3, bool)> {
    let len = dot(v, v).sqrt();
    if !(len > 0.0 && len.is_finite()) {
        return None;
    }
    // Within a few ulp of 1 the vector is taken as given (text of a unit vector rarely has length exactly 1).
    if (len - 1.0).abs() <= 4.0 * f64::EPSILON {
        return Some((v, false));
    }
    Some((v.map(|c| c / len), true))
}

/// Parses `text` (named `file` in diagnostics) for formula `f`, whose compiled channels read `used`; `baked` are
/// parameters baked for this run, which cannot also be columns.
pub fn parse(file: &str, text: &str, f: &Formula, used: InputSet, baked: &[String]) -> Result<Points, Diagnostics> {
    let fail = |d: Diagnostic| Diagnostics::single_in(file, text, d);
    let text_start = if text.starts_with('\u{feff}') { 3 } else { 0 };
    let mut lines = text[text_start..].split('\n').scan(text_start, |off, line| {
        let start = *off;
        *off += line.len() + 1;
        Some((start, line.strip_suffix('\r').unwrap_or(line)))
    });
    let Some((hstart, header)) = lines.by_ref().find(|(_, l)| !l.trim().is_empty()) else {
        return Err(fail(Diagnostic::error("no header line: the CSV is empty").hint("the first line names the columns, e.g. `NH,NL,n`")));
    };
    let names: Vec<String> = f.params.iter().map(|p| p.name.clone()).collect();
    let mut columns = vec![];
    let mut at = hstart;
    for cell in header.split(',') {
        let name = cell.trim();
        let s = span(at + (cell.len() - cell.trim_start().len()), name.len());
        at += cell.len() + 1;
        let col = if let Some(i) = Input::from_name(name) {
            Column::Input(i)
        } else if let Some(p) = f.param_index(name) {
            if baked.iter().any(|b| b == name) {
                return Err(fail(Diagnostic::error(format!("parameter `{name}` is both baked and a column")).about(Setting::Param { name: name.to_string(), value: None })
                    .at(s, "a column here")
                    .hint("bake it or give it as a column, not both (a column keeps it live)")));
            }
            Column::Param(p)
        } else {
            let mut known: Vec<&str> = Input::ALL.map(Input::name).to_vec();
            known.extend(names.iter().map(String::as_str));
            let hint = crate::front::did_you_mean(name, &known, "columns may be inputs or parameters: ");
            return Err(fail(Diagnostic::error(format!("`{name}` is neither an input nor a parameter of the formula")).at(s, "unknown column").hint(hint)));
        };
        if columns.contains(&col) {
            return Err(fail(Diagnostic::error(format!("column `{name}` appears twice")).at(s, "again here")));
        }
        columns.push(col);
    }
    let param_columns: Vec<usize> = columns.iter().filter_map(|c| if let Column::Param(p) = c { Some(*p) } else { None }).collect();
    let named = |i: Input| columns.contains(&Column::Input(i));
    let header_span = span(hstart, header.len());
    let directions = Input::DIRECTIONS.iter().any(|i| named(*i));
    if directions {
        let missing: Vec<&str> = Input::DIRECTIONS.iter().filter(|i| !named(**i)).map(|i| i.name()).collect();
        if !missing.is_empty() {
            return Err(fail(Diagnostic::error(format!("direction columns without {}", missing.join(", ")))
                .at(header_span, "this header")
                .hint("give all six components Lx,Ly,Lz,Vx,Vy,Vz (local frame: N = +z, X = +x, Y = +y)")));
        }
        if let Some(c) = Input::ALL.iter().find(|i| !i.is_direction() && named(**i)) {
            return Err(fail(Diagnostic::error(format!("both directions and the cosine column {}", c.name()))
                .at(header_span, "this header")
                .hint("with Lx..Vz every cosine is computed from the directions; drop the cosine columns")));
        }
    } else if used.reads_directions() {
        let reads: Vec<&str> = used.iter().filter(|i| i.is_direction()).map(Input::name).collect();
        return Err(fail(Diagnostic::error(format!("the formula reads directions ({}), but the CSV has no direction columns", reads.join(", ")))
            .at(header_span, "this header")
            .hint("give the columns Lx,Ly,Lz,Vx,Vy,Vz (unit L and V in the local frame: N = +z, X = +x, Y = +y); cosines follow from them")));
    } else {
        // A cosine the formula reads and the CSV does not give would be taken as 0: a wrong value with no word.
        let missing: Vec<&str> = used.iter().filter(|i| !named(*i)).map(Input::name).collect();
        if !missing.is_empty() {
            let reads: Vec<&str> = used.iter().map(Input::name).collect();
            return Err(fail(Diagnostic::error(format!("the CSV has no column for {} (the formula reads {})", missing.join(", "), reads.join(", ")))
                .at(header_span, "this header")
                .hint(format!("add the column{} {}, or give the directions Lx,Ly,Lz,Vx,Vy,Vz instead", if missing.len() > 1 { "s" } else { "" }, missing.join(",")))));
        }
    }
    let param_values = vec![vec![]; param_columns.len()];
    let mut pts = Points { normalised: 0, inputs: Default::default(), param_columns, param_values, len: 0, zeros: vec![], runs: vec![] };
    let mut row_inputs = [0.0; N_INPUTS];
    for (start, line) in lines {
        if line.trim().is_empty() {
            continue;
        }
        let mut next_param = 0;
        let mut at = start;
        let mut n = 0;
        let mut cells = [Span::default(); N_INPUTS];
        for cell in line.split(',') {
            let s = span(at + (cell.len() - cell.trim_start().len()), cell.trim().len());
            at += cell.len() + 1;
            let Some(col) = columns.get(n) else {
                return Err(fail(Diagnostic::error(format!("more values than the header's {} columns", columns.len())).at(s, "extra value")));
            };
            n += 1;
            let v: f64 = cell.trim().parse().map_err(|_| {
                fail(Diagnostic::error(format!("`{}` is not a number", cell.trim())).at(s, "expected a number").hint("values are decimal numbers such as 0.95, 1e-3, nan or inf"))
            })?;
            match *col {
                Column::Input(i) => {
                    row_inputs[i.index()] = v;
                    cells[i.index()] = s;
                }
                Column::Param(p) => {
                    let d = &f.params[p];
                    if !d.admits(v) {
                        return Err(fail(Diagnostic::error(format!(
                            "{} = {v} is outside its declared range {}..{}",
                            d.name,
                            crate::ir::print::number(d.lo),
                            crate::ir::print::number(d.hi)
                        ))
                        .at(s, "out of range")));
                    }
                    pts.param_values[next_param].push(v);
                    next_param += 1;
                }
            }
        }
        if n < columns.len() {
            return Err(fail(Diagnostic::error(format!("{n} values where the header has {}", columns.len())).at(span(start, line.len()), "short row")));
        }
        if directions {
            let mut dirs = [[0.0; 3]; 2];
            let mut scaled_any = false;
            for (k, (d, first)) in dirs.iter_mut().zip([Input::Lx, Input::Vx]).enumerate() {
                let raw: V3 = std::array::from_fn(|c| row_inputs[first.index() + c]);
                let Some((u, scaled)) = unit(raw) else {
                    let (a, b) = (cells[first.index()], cells[first.index() + 2]);
                    let name = ["L", "V"][k];
                    return Err(fail(Diagnostic::error(format!("{name} = ({}, {}, {}) has no direction", raw[0], raw[1], raw[2]))
                        .at(Span { start: a.start, end: b.end }, "a zero or non-finite vector")
                        .hint(format!("{name} is a direction: give three finite components, not all 0"))));
                };
                scaled_any |= scaled;
                *d = u;
            }
            pts.normalised += usize::from(scaled_any);
            let x = inputs_from_dirs(dirs[0], dirs[1]);
            for (col, v) in pts.inputs.iter_mut().zip(x) {
                col.push(v);
            }
        } else {
            for c in &columns {
                if let Column::Input(i) = c {
                    pts.inputs[i.index()].push(row_inputs[i.index()]);
                }
            }
        }
        pts.len += 1;
    }
    if pts.inputs.iter().any(Vec::is_empty) {
        pts.zeros = vec![0.0; pts.len];
    }
    let cols: Vec<&[f64]> = pts.param_values.iter().map(Vec::as_slice).collect();
    pts.runs = param_runs(&cols, pts.len);
    Ok(pts)
}

/// The runs of consecutive points (of `len`) whose values in every one of `cols` (each `len` long) are equal
/// bit for bit; one run of all points when `cols` is empty.
pub(crate) fn param_runs(cols: &[&[f64]], len: usize) -> Vec<std::ops::Range<usize>> {
    // No varying column: one run, found without looking at every point.
    if cols.is_empty() {
        return (len > 0).then_some(0..len).into_iter().collect();
    }
    let same = |a: usize, b: usize| cols.iter().all(|c| c[a].to_bits() == c[b].to_bits());
    let mut runs = vec![];
    let mut start = 0;
    while start < len {
        let mut end = start + 1;
        while end < len && same(end, start) {
            end += 1;
        }
        runs.push(start..end);
        start = end;
    }
    runs
}

/// `k` at every point of `cols` (each column `out.len()` long or empty, as [`Evaluator::eval_batch`] takes
/// them) with parameters `base`, except the parameters in `varying` (index, one value per point), which take
/// each point's value: one batched call per run of equal values ([`param_runs`]), as the eval command
/// evaluates a CSV's parameter columns. The caller checks the values against the declared ranges.
pub fn evaluate_varying(k: &dyn Evaluator, cols: &Columns, base: &[f64], varying: &[(usize, &[f64])], out: &mut [f64]) {
    let values: Vec<&[f64]> = varying.iter().map(|(_, v)| *v).collect();
    evaluate_runs(k, cols, base, varying, &param_runs(&values, out.len()), out);
}

/// [`evaluate_varying`] with its runs already found.
fn evaluate_runs(k: &dyn Evaluator, cols: &Columns, base: &[f64], varying: &[(usize, &[f64])], runs: &[std::ops::Range<usize>], out: &mut [f64]) {
    assert!(varying.iter().all(|(_, v)| v.len() == out.len()), "one parameter value per point");
    let mut params = base.to_vec();
    for run in runs {
        for (slot, v) in varying {
            params[*slot] = v[run.start];
        }
        let part: [&[f64]; N_INPUTS] = std::array::from_fn(|i| if cols.cols[i].is_empty() { cols.cols[i] } else { &cols.cols[i][run.clone()] });
        k.eval_batch(&Columns::new(part), &params, &mut out[run.clone()]);
    }
}

/// The value and gradient ([`super::grad::Gradient`]) at every point: one run of the program per run of rows with
/// equal parameter values, as [`evaluate`] does for a kernel.
pub fn evaluate_grad(g: &super::grad::Gradient, pts: &Points, base_params: &[f64]) -> super::grad::GradValues {
    let m = g.vars.len();
    let mut out = super::grad::GradValues { value: vec![vec![0.0; pts.len]; g.channels], grad: vec![vec![vec![0.0; pts.len]; g.channels]; m] };
    let mut params = base_params.to_vec();
    for run in &pts.runs {
        for (slot, v) in pts.param_columns.iter().zip(&pts.param_values) {
            params[*slot] = v[run.start];
        }
        let cols: [&[f64]; N_INPUTS] = std::array::from_fn(|i| if pts.inputs[i].is_empty() { &[][..] } else { &pts.inputs[i][run.clone()] });
        let r = g.run(&cols, &params, run.len());
        for c in 0..g.channels {
            out.value[c][run.clone()].copy_from_slice(&r.value[c]);
            for v in 0..m {
                out.grad[v][c][run.clone()].copy_from_slice(&r.grad[v][c]);
            }
        }
    }
    out
}

/// The ground truth ([`super::truth`]) of `f` (the formula as written, baked values folded) at every point, in
/// parallel: what a kernel's values at these points are measured against. An input the file does not give is 0.
pub fn truth(f: &Formula, pts: &Points, base_params: &[f64]) -> Vec<f64> {
    use rayon::prelude::*;
    (0..pts.len)
        .into_par_iter()
        .map(|i| {
            let x: [f64; N_INPUTS] = std::array::from_fn(|k| pts.inputs[k].get(i).copied().unwrap_or(0.0));
            let mut params = base_params.to_vec();
            for (slot, v) in pts.param_columns.iter().zip(&pts.param_values) {
                params[*slot] = v[i];
            }
            super::truth::eval(f, &x, &params)
        })
        .collect()
}

/// Evaluates every point with the batched kernel: one batch per run of rows with equal parameter values.
pub fn evaluate(k: &Kernel, pts: &Points, base_params: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; pts.len];
    evaluate_into(k, pts, base_params, &mut out);
    out
}

/// [`evaluate`] into `out` (`pts.len` long), allocating only the parameter vector: the steady state a timing
/// should measure.
pub fn evaluate_into(k: &Kernel, pts: &Points, base_params: &[f64], out: &mut [f64]) {
    assert_eq!(out.len(), pts.len, "one output per point");
    let cols: [&[f64]; N_INPUTS] = std::array::from_fn(|i| if pts.inputs[i].is_empty() { pts.zeros.as_slice() } else { pts.inputs[i].as_slice() });
    let varying: Vec<(usize, &[f64])> = pts.param_columns.iter().zip(&pts.param_values).map(|(p, v)| (*p, v.as_slice())).collect();
    evaluate_runs(k, &Columns::new(cols), base_params, &varying, &pts.runs, out);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::rng::Rng;

    #[test]
    fn runs_split_where_any_column_changes_bit_for_bit() {
        let a = [1.0, 1.0, 2.0, 2.0, 0.0, -0.0];
        let b = [5.0, 5.0, 5.0, 6.0, 6.0, 6.0];
        assert_eq!(param_runs(&[&a, &b], 6), vec![0..2, 2..3, 3..4, 4..5, 5..6]);
        assert_eq!(param_runs(&[], 4), vec![0..4]);
        assert!(param_runs(&[&[]], 0).is_empty());
    }

    /// Random per-point parameters, in runs of random lengths (1 to many), on both backends: every value is the
    /// scalar evaluation's at that point's parameters, bit for bit.
    #[test]
    fn varying_parameters_give_each_points_own_value() {
        let f = crate::front::parse("v.brdf", "param n = 10 in 1..1000\nparam a = 0.5 in 0..1\na * NH^n + (1 - a) * NL / (n + NV)").unwrap();
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        let len = 3000;
        let col = |rng: &mut Rng| (0..len).map(|_| rng.unit()).collect::<Vec<f64>>();
        let (nl, nv, nh) = (col(&mut rng), col(&mut rng), col(&mut rng));
        let (mut n, mut a) = (vec![], vec![]);
        while n.len() < len {
            let run = [1, 1, 2, 7, 300][rng.below(5) as usize].min(len - n.len());
            let (nv_, av) = (1.0 + 999.0 * rng.unit(), rng.unit());
            n.extend(std::iter::repeat_n(nv_, run));
            a.extend(std::iter::repeat_n(if rng.below(3) == 0 { 0.25 } else { av }, run));
        }
        for backend in [crate::Backend::Interp, crate::Backend::Jit] {
            let k = crate::compile_formula(f.clone(), &crate::Options { backend, ..Default::default() }).unwrap();
            let cols = Columns::new(std::array::from_fn(|i| match Input::ALL[i] {
                Input::NL => nl.as_slice(),
                Input::NV => nv.as_slice(),
                Input::NH => nh.as_slice(),
                _ => &[],
            }));
            let mut out = vec![0.0; len];
            evaluate_varying(&k, &cols, &[10.0, 0.5], &[(0, &n), (1, &a)], &mut out);
            for i in 0..len {
                let x: [f64; N_INPUTS] = std::array::from_fn(|c| cols.cols[c].get(i).copied().unwrap_or(0.0));
                assert_eq!(out[i].to_bits(), k.eval(&x, &[n[i], a[i]]).to_bits(), "{backend:?} point {i}");
            }
            // Only `a` varying: `n` stays at its base value.
            evaluate_varying(&k, &cols, &[3.0, 0.5], &[(1, &a)], &mut out);
            let x: [f64; N_INPUTS] = std::array::from_fn(|c| cols.cols[c].get(7).copied().unwrap_or(0.0));
            assert_eq!(out[7].to_bits(), k.eval(&x, &[3.0, a[7]]).to_bits());
        }
    }
}
