//! One run of a sampler at one incidence, as `lobe sample` reports it: seeded samples (the counter-based
//! [`counter_unit`] stream, so any split over threads draws the same samples), the χ² test of the samples
//! against the sampler's own pdf ([`super::chi2`]), the efficiency E\[w\]²/E\[w²\], the Monte-Carlo albedo ∫f·cos
//! and its standard error (luminance for a colour formula; per channel too), and the cost of `sample` and `pdf`
//! per call in batches, as thread CPU time (wall time on a shared machine counts other processes' work).

use super::chi2::{self, Chi2};
use super::{Sampler, Samples};
use crate::base::diag::Diagnostic;
use crate::base::rng::counter_unit;
use crate::frame::V3;

/// Samples per parallel chunk.
const CHUNK: u64 = 1 << 16;
/// Histogram rows of the χ² test (columns: twice as many), Mitsuba's default.
pub const CHI2_RES: usize = 101;

/// Sample i's uniforms: counters 2i and 2i + 1 of stream `seed`.
pub fn uniforms(seed: u64, range: std::ops::Range<u64>) -> Vec<[f64; 2]> {
    range.map(|i| [counter_unit(seed, 2 * i), counter_unit(seed, 2 * i + 1)]).collect()
}

/// Samples 0..count of stream `seed` at `wi`, in parallel chunks; the same samples whatever the thread count.
pub fn sample_seeded(s: &Sampler, wi: V3, seed: u64, count: u64) -> Result<Samples, Diagnostic> {
    use rayon::prelude::*;
    let chunks: Vec<u64> = (0..count.div_ceil(CHUNK)).collect();
    let parts: Result<Vec<Samples>, Diagnostic> =
        chunks.par_iter().map(|&c| s.sample_many(&[wi], &uniforms(seed, c * CHUNK..((c + 1) * CHUNK).min(count)))).collect();
    let mut out = Samples { channels: s.channels(), ..Samples::default() };
    for p in parts? {
        out.wo.extend(p.wo);
        out.pdf.extend(p.pdf);
        out.weight.extend(p.weight);
    }
    Ok(out)
}

/// What [`validate`] measured.
#[derive(Clone, Debug)]
pub struct Validation {
    pub samples: Samples,
    pub chi2: Chi2,
    pub efficiency: f64,
    /// Mean luminance weight: the Monte-Carlo estimate of ∫ f·cosθₒ dωₒ.
    pub albedo: f64,
    pub albedo_stderr: f64,
    /// Per channel (one entry for a scalar formula).
    pub albedo_channels: Vec<f64>,
    /// Thread CPU time per `sample` and per `pdf` call, in batches of 4096 (`None` where the platform has no
    /// per-thread clock).
    pub ns_per_sample: Option<f64>,
    pub ns_per_pdf: Option<f64>,
}

fn thread_time() -> Option<std::time::Duration> {
    cpu_time::ThreadTime::try_now().ok().map(|t| t.as_duration())
}

/// `count` seeded samples at `wi`, the χ² test with [`CHI2_RES`] rows, and the summary statistics.
pub fn validate(s: &Sampler, wi: V3, count: u64, seed: u64) -> Result<Validation, Diagnostic> {
    let samples = sample_seeded(s, wi, seed, count)?;
    let n = samples.pdf.len();
    let lum: Vec<f64> = (0..n).map(|i| samples.luminance(i)).collect();
    let efficiency = super::efficiency(lum.iter().copied());
    let (mean, var) = mean_var(&lum);
    let albedo_channels = (0..samples.channels).map(|c| mean_var(&samples.weight.iter().skip(c).step_by(samples.channels).copied().collect::<Vec<_>>()).0).collect();
    let pdf = s.pdf_at(wi)?;
    let mut probs = chi2::cell_probabilities(&pdf, CHI2_RES, n);
    let hist = chi2::histogram(&samples.wo, CHI2_RES);
    chi2::resolve_empty_cells(&pdf, CHI2_RES, &hist, &mut probs);
    let chi2 = chi2::chi2(&hist, &probs, n);
    // Timing: one thread, batches of 4096, up to 2¹⁷ calls.
    let m = (count.min(1 << 17)) as usize;
    let us = uniforms(seed ^ 0x7105, 0..m as u64);
    let t0 = thread_time();
    let mut wos = Vec::with_capacity(m);
    for b in us.chunks(4096) {
        wos.extend(s.sample_many(&[wi], b)?.wo);
    }
    let t1 = thread_time();
    let mut acc = 0.0;
    for b in wos.chunks(4096) {
        acc += s.pdf_many(&[wi], b)?.iter().sum::<f64>();
    }
    let t2 = thread_time();
    std::hint::black_box(acc);
    let per = |a: Option<std::time::Duration>, b: Option<std::time::Duration>| Some((b? - a?).as_secs_f64() * 1e9 / m.max(1) as f64);
    Ok(Validation {
        chi2,
        efficiency,
        albedo: mean,
        albedo_stderr: (var / n.max(1) as f64).sqrt(),
        albedo_channels,
        ns_per_sample: per(t0, t1),
        ns_per_pdf: per(t1, t2),
        samples,
    })
}

/// Mean and (unbiased) variance.
fn mean_var(x: &[f64]) -> (f64, f64) {
    let n = x.len() as f64;
    if x.is_empty() {
        return (0.0, 0.0);
    }
    let mean = x.iter().sum::<f64>() / n;
    let var = if x.len() > 1 { x.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / (n - 1.0) } else { 0.0 };
    (mean, var)
}

/// ∫ f·cosθₒ dωₒ at (θᵢ, φᵢ) by quadrature ([`crate::numerics::energy::albedo_at`], what the full-mode energy
/// check reports): per channel, then as luminance for a colour formula. A formula that reads directions is
/// integrated at its azimuth φᵢ; one of cosines only by the isotropic rule, as the full mode does.
pub fn albedo_quadrature(s: &Sampler, theta_i: f64, phi_i: f64) -> Result<f64, Diagnostic> {
    let t = &s.target;
    let phi = t.used.reads_directions().then_some(phi_i);
    let per: Result<Vec<f64>, Diagnostic> = t.kernels.iter().map(|k| crate::numerics::energy::albedo_at(k.as_ref(), &t.params, theta_i, phi)).collect();
    Ok(t.luminance(&per?))
}

/// [`albedo_quadrature`] of a sampler built from a measured table's lookups (isotropic by construction), by the
/// midpoint rule over the table's own cells ([`crate::numerics::energy::albedo_tabulated`], the full
/// energy check's rule for tables): the adaptive rule on piecewise-linear lookups takes tens of seconds.
pub fn albedo_quadrature_tabulated(s: &Sampler, theta_i: f64) -> f64 {
    let t = &s.target;
    let per: Vec<f64> = t.kernels.iter().map(|k| crate::numerics::energy::albedo_tabulated(k.as_ref(), &t.params, theta_i)).collect();
    t.luminance(&per)
}

/// `lobe sample`'s summary (JSON keys stable; docs/commands.md).
#[derive(Clone, Debug, serde::Serialize)]
pub struct SampleReport {
    pub params: crate::base::json::Named,
    #[serde(serialize_with = "crate::base::json::num")]
    pub theta_i_deg: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    pub phi_i_deg: f64,
    pub count: u64,
    pub seed: u64,
    pub mechanism: &'static str,
    pub isotropic: bool,
    #[serde(serialize_with = "crate::base::json::num")]
    pub cosine_fraction: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    pub chi2_p: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    pub chi2_statistic: f64,
    pub chi2_dof: usize,
    pub chi2_pooled: usize,
    pub chi2_failure: Option<String>,
    #[serde(serialize_with = "crate::base::json::num")]
    pub efficiency: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    pub albedo: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    pub albedo_stderr: f64,
    pub albedo_channels: Vec<f64>,
    #[serde(serialize_with = "crate::base::json::num")]
    pub albedo_quadrature: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    pub build_ms: f64,
    #[serde(serialize_with = "crate::base::json::opt_num")]
    pub ns_per_sample: Option<f64>,
    #[serde(serialize_with = "crate::base::json::opt_num")]
    pub ns_per_pdf: Option<f64>,
    /// Incidence nodes with empty tables (θᵢ, φᵢ in degrees): the formula is 0 there.
    pub empty_nodes: Vec<(f64, f64)>,
    /// The automatic choice's probe: mechanism → mean efficiency.
    pub candidates: crate::base::json::Named,
}

impl SampleReport {
    pub fn new(s: &Sampler, v: &Validation, params: crate::base::json::Named, incidence_deg: (f64, f64), count: u64, seed: u64, albedo_quadrature: f64) -> SampleReport {
        SampleReport {
            params,
            theta_i_deg: incidence_deg.0,
            phi_i_deg: incidence_deg.1,
            count,
            seed,
            mechanism: s.report.mechanism.name(),
            isotropic: s.report.isotropic,
            cosine_fraction: s.cosine_fraction(),
            chi2_p: v.chi2.p_value,
            chi2_statistic: v.chi2.statistic,
            chi2_dof: v.chi2.dof,
            chi2_pooled: v.chi2.pooled,
            chi2_failure: v.chi2.failure.clone(),
            efficiency: v.efficiency,
            albedo: v.albedo,
            albedo_stderr: v.albedo_stderr,
            albedo_channels: v.albedo_channels.clone(),
            albedo_quadrature,
            build_ms: s.report.build.as_secs_f64() * 1e3,
            ns_per_sample: v.ns_per_sample,
            ns_per_pdf: v.ns_per_pdf,
            empty_nodes: s.report.empty_nodes.iter().map(|&(t, p)| (t.to_degrees(), p.to_degrees())).collect(),
            candidates: crate::base::json::Named::new(s.report.candidates.iter().map(|(m, e)| (m.name(), *e))),
        }
    }
}
