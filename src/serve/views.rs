//! The page's BRDF Explorer views, sampled from the same compiled kernel the render shades with (the live cache
//! of [`super::api`], through the accuracy pass, parameters live): the page draws them itself, so the server
//! answers numbers, not pictures.
//!
//! - `POST /api/lobe`: the BRDF over the outgoing hemisphere for one incident direction (θᵢ, φᵢ), on a θₒ × φₒ
//!   grid, for the 3D lobe (BRDF Explorer's "3D plot");
//! - `POST /api/slice`: the BRDF over (θ_h, θ_d) at one φ_d (BRDF Explorer's "Image Slice", the half/difference
//!   parametrisation of [`crate::measured::dirs_from_angles`], the one MERL tables use);
//!
//! ρ(θᵢ) comes with `/api/analyze` (the energy check's rows), the plane-of-incidence curves with `/api/plot`.
//! Grid sizes are capped here and priced with [`api::check_cost`] before any evaluation; the work runs under
//! [`api::limited`] like every computation. A grid of 33 × 64 directions is ~2 000 kernel calls: well under a
//! millisecond on the JIT, so the views follow a slider as the render does.

use super::api::{self, State};
use super::http::{ApiError, Reply};
use crate::base::cancel::Cancel;
use crate::Evaluator;
use serde_json::Value;
use std::sync::Arc;

/// A whole number field in `lo..=hi`, `default` when absent.
fn count_field(v: &Value, k: &str, default: usize, lo: usize, hi: usize) -> Result<usize, ApiError> {
    match v.get(k) {
        None => Ok(default),
        Some(x) => x
            .as_u64()
            .map(|n| n as usize)
            .filter(|n| (lo..=hi).contains(n))
            .ok_or_else(|| ApiError::bad(format!("`{k}` must be a whole number in {lo}..={hi}"))),
    }
}

/// The formula's first kernel (a colour formula's red channel, as the plots show) and its parameter values.
fn kernel_and_params(st: &api::Job, req: &Value) -> Result<(Arc<crate::Kernel>, Vec<f64>), ApiError> {
    let (name, text) = api::formula_field(req)?;
    let set = api::params_field(req)?;
    let k = st.compiled(&name, &text)?.kernel().clone();
    let params = api::values(&k, &set)?;
    Ok((k, params))
}

/// The `/api/lobe` reply (non-finite values as `null`).
#[derive(serde::Serialize)]
struct LobeReply {
    theta_i: f64,
    phi_i: f64,
    n_theta: usize,
    n_phi: usize,
    light: [f64; 3],
    values: Vec<f64>,
    max: f64,
    nonfinite: usize,
}

/// The `/api/slice` reply (non-finite values as `null`).
#[derive(serde::Serialize)]
struct SliceReply {
    res: usize,
    phi_d: f64,
    values: Vec<f64>,
    max: f64,
    nonfinite: usize,
}

/// The largest finite value (0 if none) and the count of non-finite ones.
fn summary(values: &[f64]) -> (f64, usize) {
    let max = values.iter().copied().filter(|v| v.is_finite()).fold(0.0f64, f64::max);
    (max, values.iter().filter(|v| !v.is_finite()).count())
}

/// `POST /api/lobe {name, text, params, theta_i, phi_i, n_theta, n_phi}`: f(L, V) with L at (θᵢ, φᵢ) (degrees)
/// and V at θₒ = 90°·i/(n_theta − 1), φₒ = 360°·j/n_phi, row by row in θₒ (`values`, NaN/inf as `null`); the
/// light's direction `light`, the largest finite value `max` and the count of non-finite values `nonfinite`.
pub(crate) fn lobe(st: &Arc<State>, gone: &Cancel, req: Value) -> Result<Reply, ApiError> {
    api::limited(st, gone, move |st| {
        let (ti, pi) = api::incidence_field(&req)?.unwrap_or((0.0, 0.0));
        let nt = count_field(&req, "n_theta", 33, 3, 91)?;
        let np = count_field(&req, "n_phi", 64, 4, 360)?;
        let (k, params) = kernel_and_params(st, &req)?;
        api::check_cost(st, &k, (nt * np) as f64, "this lobe")?;
        let l = crate::numerics::dir(ti.to_radians(), pi.to_radians());
        let values: Vec<f64> = (0..nt)
            .flat_map(|i| (0..np).map(move |j| (i, j)))
            .map(|(i, j)| {
                let (to, po) = (90.0 * i as f64 / (nt - 1) as f64, 360.0 * j as f64 / np as f64);
                let v = crate::numerics::dir(to.to_radians(), po.to_radians());
                k.eval(&crate::frame::inputs_from_dirs(l, v), &params)
            })
            .collect();
        let (max, nonfinite) = summary(&values);
        Ok(Reply::ok_report(&LobeReply { theta_i: ti, phi_i: pi, n_theta: nt, n_phi: np, light: l, values, max, nonfinite }))
    })
}

/// `POST /api/slice {name, text, params, res, phi_d}`: f at θ_h = 90°·i/res (columns) and θ_d = 90°·j/res
/// (rows), at φ_d (degrees, default 90 as BRDF Explorer) and φ_h = 0; `null` where L or V is below the horizon
/// or the value is not finite. `max` and `nonfinite` as for `/api/lobe`.
pub(crate) fn slice(st: &Arc<State>, gone: &Cancel, req: Value) -> Result<Reply, ApiError> {
    api::limited(st, gone, move |st| {
        let res = count_field(&req, "res", 64, 8, 256)?;
        let pd = match req.get("phi_d") {
            None => 90.0,
            Some(p) => {
                let p = p.as_f64().filter(|p| p.is_finite());
                p.ok_or_else(|| ApiError::bad("`phi_d` must be a finite angle in degrees"))?
            }
        };
        let (k, params) = kernel_and_params(st, &req)?;
        api::check_cost(st, &k, (res * res) as f64, "this image slice")?;
        let values: Vec<f64> = (0..res)
            .flat_map(|j| (0..res).map(move |i| (i, j)))
            .map(|(i, j)| {
                let a = |n: usize| (90.0 * n as f64 / res as f64).to_radians();
                let (l, v) = crate::measured::dirs_from_angles([a(i), a(j), pd.to_radians()]);
                if l[2] <= 0.0 || v[2] <= 0.0 {
                    return f64::NAN;
                }
                k.eval(&crate::frame::inputs_from_dirs(l, v), &params)
            })
            .collect();
        let (max, nonfinite) = summary(&values);
        Ok(Reply::ok_report(&SliceReply { res, phi_d: pd, values, max, nonfinite }))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn incidence_and_counts_are_checked() {
        assert_eq!(api::incidence_field(&json!({})).unwrap(), None);
        assert_eq!(api::incidence_field(&json!({"theta_i": 30, "phi_i": 45})).unwrap(), Some((30.0, 45.0)));
        assert_eq!(api::incidence_field(&json!({"theta_i": 90})).unwrap_err().status, 400);
        assert_eq!(api::incidence_field(&json!({"theta_i": 10, "phi_i": "x"})).unwrap_err().status, 400);
        assert_eq!(count_field(&json!({"res": 1000}), "res", 64, 8, 256).unwrap_err().status, 400);
        assert_eq!(count_field(&json!({}), "res", 64, 8, 256).unwrap(), 64);
    }
}
