//! Timing a kernel's three evaluation paths in one run (for `lobe bench`): scalar JIT, batched JIT, and the
//! interpreter, each as ns per evaluation, median and spread over repeated samples. The scalar paths are timed
//! through [`Evaluator::prepare`] (parameters bound once), the way the checks and fits loop over points.
//!
//! Method: a fixed pseudo-random set of `n` input points in [0, 1] (SoA columns and AoS rows from the same
//! numbers); each sample times one pass over all points; the first sample of each path is a discarded warm-up.
//! Results go through `black_box` so nothing is optimised away. Numbers are only comparable within one run on
//! one machine; tests never assert on them.

use crate::backend::native::NativeError;
use crate::backend::interp::Interp;
use crate::ir::N_INPUTS;
use crate::backend::{Columns, Evaluator, Kernel, Prepared};
use std::hint::black_box;
use std::time::{Duration, Instant};

/// Nanoseconds per evaluation over the samples.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Timing {
    pub median_ns: f64,
    /// 25th and 75th percentiles: the spread.
    pub p25_ns: f64,
    pub p75_ns: f64,
    pub min_ns: f64,
}

impl Timing {
    /// The relative half-width of the interquartile range: the measured noise of the median.
    pub fn spread(&self) -> f64 {
        (self.p75_ns - self.p25_ns) / 2.0 / self.median_ns
    }

    fn from_samples(mut ns: Vec<f64>) -> Timing {
        ns.sort_by(f64::total_cmp);
        let at = |q: f64| ns.get(((ns.len() - 1) as f64 * q).round() as usize).copied().unwrap_or(f64::NAN);
        if ns.is_empty() {
            return Timing { median_ns: f64::NAN, p25_ns: f64::NAN, p75_ns: f64::NAN, min_ns: f64::NAN };
        }
        Timing { median_ns: at(0.5), p25_ns: at(0.25), p75_ns: at(0.75), min_ns: ns[0] }
    }
}

impl std::fmt::Display for Timing {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:.2} ns (IQR {:.2}–{:.2})", self.median_ns, self.p25_ns, self.p75_ns)
    }
}

/// How much to measure.
#[derive(Clone, Copy, Debug)]
pub struct MeasureOptions {
    /// Points per sample.
    pub points: usize,
    /// Timed samples per path (after one warm-up).
    pub samples: usize,
}

impl Default for MeasureOptions {
    fn default() -> Self {
        MeasureOptions { points: 4096, samples: 31 }
    }
}

/// The three paths of one kernel.
#[derive(Clone, Copy, Debug)]
pub struct Measurement {
    pub scalar_jit: Timing,
    /// Per element.
    pub batched_jit: Timing,
    pub interp: Timing,
    /// Uncached JIT compile time of the formula (median of 5).
    pub compile: Duration,
}

impl Measurement {
    /// How many times faster the scalar JIT is than the interpreter (medians).
    pub fn speedup_vs_interp(&self) -> f64 {
        self.interp.median_ns / self.scalar_jit.median_ns
    }
}

/// Deterministic points (xorshift64*), so runs are comparable: the five cosines independent in [0, 1], and L, V
/// unit directions of the upper hemisphere (uniform in cos θ and φ) for formulas that read directions.
pub fn sample_points(n: usize, seed: u64) -> Vec<[f64; N_INPUTS]> {
    let mut s = seed.max(1);
    let mut next = move || {
        s ^= s >> 12;
        s ^= s << 25;
        s ^= s >> 27;
        (s.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..n)
        .map(|_| {
            let mut x = [0.0; N_INPUTS];
            for c in &mut x[..5] {
                *c = next();
            }
            let mut dir = || {
                let (z, phi) = (next(), std::f64::consts::TAU * next());
                let r = (1.0 - z * z).max(0.0).sqrt();
                [r * phi.cos(), r * phi.sin(), z]
            };
            let (l, v) = (dir(), dir());
            x[5..8].copy_from_slice(&l);
            x[8..].copy_from_slice(&v);
            x
        })
        .collect()
}

fn time_per_eval(samples: usize, evals: usize, mut pass: impl FnMut()) -> Timing {
    pass(); // warm-up
    let ns = (0..samples.max(1))
        .map(|_| {
            let t = Instant::now();
            pass();
            t.elapsed().as_nanos() as f64 / evals.max(1) as f64
        })
        .collect();
    Timing::from_samples(ns)
}

/// A steady-state measurement on two clocks, over the same passes.
#[derive(Clone, Copy, Debug)]
pub struct Steady {
    /// Wall time per element.
    pub wall: Timing,
    /// The calling thread's CPU time per element (the wall clock where the platform has no thread clock): what a
    /// shared machine does not inflate when the work runs on this thread.
    pub cpu: Timing,
}

/// This thread's CPU time, or `None` where the platform has no thread clock.
fn thread_cpu() -> Option<Duration> {
    cpu_time::ThreadTime::try_now().ok().map(|t| t.as_duration())
}

/// ns per element of `pass` (which does `evals` elements) in its steady state: the caller has run it once
/// (compiled, warm, output touched); passes repeat until at least 3 and 20 ms, or 1 s, have gone by.
pub fn steady_state(evals: usize, mut pass: impl FnMut()) -> Steady {
    let start = Instant::now();
    let (mut wall, mut cpu) = (vec![], vec![]);
    let per = |d: Duration| d.as_nanos() as f64 / evals.max(1) as f64;
    while wall.len() < 3 || (start.elapsed() < Duration::from_millis(20) && wall.len() < 1000) {
        let (t, c) = (Instant::now(), thread_cpu());
        pass();
        let w = t.elapsed();
        wall.push(per(w));
        cpu.push(per(c.zip(thread_cpu()).map_or(w, |(a, b)| b.saturating_sub(a))));
        if start.elapsed() > Duration::from_secs(1) {
            break;
        }
    }
    Steady { wall: Timing::from_samples(wall), cpu: Timing::from_samples(cpu) }
}

/// Measures scalar JIT, batched JIT and interpreter ns/eval for `k`'s formula with `params`.
pub fn measure_kernel(k: &Kernel, params: &[f64], opts: MeasureOptions) -> Result<Measurement, NativeError> {
    let f = &k.formula;
    let mut compiles: Vec<Duration> = (0..5)
        .map(|_| {
            let t = Instant::now();
            crate::backend::jit::jit_kernel_uncached(f, k.math).map(|_| t.elapsed())
        })
        .collect::<Result<_, _>>()?;
    compiles.sort();
    let jit = crate::backend::jit::jit_kernel(f, k.math)?;
    let interp = Interp::with_mode(f, k.math);

    let n = opts.points.max(1);
    let rows = sample_points(n, 0x5EED);
    let cols: Vec<Vec<f64>> = (0..N_INPUTS).map(|i| rows.iter().map(|r| r[i]).collect()).collect();
    let columns = Columns::new(std::array::from_fn(|i| cols[i].as_slice()));
    let mut out = vec![0.0; n];

    // Both backends through the same prepared path (parameters bound once, as the checks and fits call them).
    let scalar = |ev: &Prepared| {
        let mut acc = 0.0;
        for r in &rows {
            acc += ev.eval(black_box(r));
        }
        black_box(acc);
    };
    let (jit_p, interp_p) = (jit.prepare(params), interp.prepare(params));
    let scalar_jit = time_per_eval(opts.samples, n, || scalar(&jit_p));
    let interp_t = time_per_eval(opts.samples, n, || scalar(&interp_p));
    let batched_jit = time_per_eval(opts.samples, n, || {
        jit.eval_batch(black_box(&columns), black_box(params), &mut out);
        black_box(&out);
    });
    Ok(Measurement { scalar_jit, batched_jit, interp: interp_t, compile: compiles[compiles.len() / 2] })
}

/// Median ns per element of `k`'s batched evaluation over `opts.points` sample points (the kernel warmed up
/// first, so a lazily built batched kernel is not timed).
pub fn time_batched(k: &Kernel, params: &[f64], opts: MeasureOptions) -> Timing {
    let n = opts.points.max(1);
    let rows = sample_points(n, 0x5EED);
    let cols: Vec<Vec<f64>> = (0..N_INPUTS).map(|i| rows.iter().map(|r| r[i]).collect()).collect();
    let columns = Columns::new(std::array::from_fn(|i| cols[i].as_slice()));
    let mut out = vec![0.0; n];
    k.warm_up();
    time_per_eval(opts.samples, n, || {
        k.eval_batch(black_box(&columns), black_box(params), &mut out);
        black_box(&out);
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timing_orders_samples() {
        let t = Timing::from_samples(vec![5.0, 1.0, 3.0, 2.0, 4.0]);
        assert_eq!(t.median_ns, 3.0);
        assert_eq!(t.min_ns, 1.0);
        assert_eq!((t.p25_ns, t.p75_ns), (2.0, 4.0));
    }

    #[test]
    fn sample_points_are_cosines() {
        let p = sample_points(1000, 7);
        assert!(p.iter().all(|x| x[..5].iter().all(|v| (0.0..1.0).contains(v))));
        for x in &p {
            for d in [&x[5..8], &x[8..]] {
                assert!((d.iter().map(|c| c * c).sum::<f64>() - 1.0).abs() < 1e-12 && d[2] >= 0.0);
            }
        }
        assert_ne!(p[0], p[1]);
    }
}
