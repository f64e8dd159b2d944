//! The exact mechanism for a formula of one cosine (the module docs of [`super`]): a 1-D table over the lobe
//! angle θ about the lobe axis (R for VR, N for NH), θ uniform in sin²(θ/2) within a cell.

use super::dist::Dist1D;
use super::*;
use std::f64::consts::{FRAC_PI_2, PI};

/// The exact mechanism: a 1-D table in the lobe angle about the lobe axis.
#[derive(Clone, Debug)]
pub(super) struct Exact {
    pub(super) lobe: Input,
    pub(super) theta_max: f64,
    pub(super) dist: Dist1D,
    /// sin²(θ/2) at the cell edges ([`band_edges`]): within a cell θ is drawn uniform in this (uniform in solid
    /// angle about the axis), so the density in solid angle is constant over each cell and bounded.
    pub(super) bands: Vec<f64>,
    /// [`EXACT_CELLS`]·4π·(bands\[i + 1\] − bands\[i\]): a cell density (∫ over θ/θmax = 1) over this is the
    /// density in solid angle about the axis.
    pub(super) measure: Vec<f64>,
}

/// An orthonormal basis with `n` its third axis (Duff et al. 2017).
fn basis(n: V3) -> [V3; 3] {
    let sign = 1f64.copysign(n[2]);
    let a = -1.0 / (sign + n[2]);
    let b = n[0] * n[1] * a;
    [[1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0]], [b, sign + n[1] * n[1] * a, -n[1]], n]
}

impl Exact {
    #[inline]
    fn axis(&self, wi: V3) -> V3 {
        if self.lobe == Input::VR {
            [-wi[0], -wi[1], wi[2]]
        } else {
            [0.0, 0.0, 1.0]
        }
    }

    pub(super) fn sample(&self, wi: V3, u1: f64, u2: f64) -> V3 {
        let (i, f) = self.dist.sample_cell(u1);
        let s = self.bands[i] + f * (self.bands[i + 1] - self.bands[i]);
        let d = dir(theta_of_band(s), 2.0 * PI * u2);
        if self.lobe == Input::NH {
            return reflect(wi, d);
        }
        let [t, b, n] = basis(self.axis(wi));
        std::array::from_fn(|k| t[k] * d[0] + b[k] * d[1] + n[k] * d[2])
    }

    #[inline]
    pub(super) fn pdf(&self, wi: V3, wo: V3) -> f64 {
        // The angle to the axis by atan2(|d × a|, d·a): acos loses digits near the axis, where the lobe is.
        let (d, a, jac) = if self.lobe == Input::NH {
            let s = [wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]];
            let len = dot(s, s).sqrt();
            if len.is_nan() || len <= 0.0 {
                return 0.0;
            }
            let sign = if s[2] < 0.0 { -1.0 / len } else { 1.0 / len };
            let h = [s[0] * sign, s[1] * sign, s[2] * sign];
            (h, [0.0, 0.0, 1.0], 4.0 * dot(wi, h).abs())
        } else {
            (wo, self.axis(wi), 1.0)
        };
        let x = [d[1] * a[2] - d[2] * a[1], d[2] * a[0] - d[0] * a[2], d[0] * a[1] - d[1] * a[0]];
        let th = dot(x, x).sqrt().atan2(dot(d, a));
        let v = th / self.theta_max;
        if !(0.0..1.0).contains(&v) {
            return 0.0;
        }
        let i = ((v * EXACT_CELLS as f64) as usize).min(EXACT_CELLS - 1);
        let den = self.measure[i] * jac;
        if den.is_nan() || den <= 0.0 {
            return 0.0;
        }
        self.dist.pdf(v) / den
    }
}

/// [`band_edges`] of n bands and n·4π·(width of each band in sin²(θ/2)).
fn bands_and_measure(n: usize, theta: impl Fn(usize) -> f64) -> (Vec<f64>, Vec<f64>) {
    let bands = band_edges(n, theta);
    let measure = bands.windows(2).map(|w| n as f64 * 4.0 * PI * (w[1] - w[0])).collect();
    (bands, measure)
}

/// The exact path's table for a formula of the one input `lobe` (NH or VR); `None` when it is 0 everywhere.
pub(super) fn build_exact(target: &Target, lobe: Input) -> Result<Option<Exact>, Diagnostic> {
    let theta_max = if lobe == Input::VR { PI } else { FRAC_PI_2 };
    let np = 2 * EXACT_CELLS + 1;
    let theta = |a: usize| theta_max * a as f64 / (2 * EXACT_CELLS) as f64;
    let mut vals = vec![];
    target.eval_inputs(
        np,
        |a| {
            let mut x = [0.0; N_INPUTS];
            x[lobe.index()] = theta(a).cos();
            x
        },
        &mut vals,
    );
    let nch = target.channels();
    let mut q = vec![0.0; np];
    for a in 0..np {
        let v = &vals[a * nch..(a + 1) * nch];
        let c = theta(a).cos();
        check_point(v, || format!("{} = {c:.9} (the formula's only input)", lobe.name()))?;
        q[a] = target.luminance(v);
    }
    // A cell's mass: the largest value at its ends and middle times its solid angle about the axis.
    let (bands, measure) = bands_and_measure(EXACT_CELLS, |i| theta_max * i as f64 / EXACT_CELLS as f64);
    let cells: Vec<f64> = (0..EXACT_CELLS).map(|i| q[2 * i].max(q[2 * i + 1]).max(q[2 * i + 2]) * (bands[i + 1] - bands[i])).collect();
    Ok(Dist1D::new(&cells).map(|dist| Exact { lobe, theta_max, dist, bands, measure }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn basis_is_orthonormal() {
        for n in [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], dir(1.0, 2.0), dir(2.5, -1.0)] {
            let [t, b, nn] = basis(n);
            for (x, y, want) in [(t, t, 1.0), (b, b, 1.0), (t, b, 0.0), (t, nn, 0.0), (b, nn, 0.0)] {
                assert!((dot(x, y) - want).abs() < 1e-14);
            }
        }
    }
}
