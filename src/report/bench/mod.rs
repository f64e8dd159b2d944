//! The speed-versus-error table of `lobe bench`: rows, the Pareto front, text and JSON output.
//!
//! A row is one formula at the benchmark values in one math mode, and its columns describe one kernel: the
//! accuracy pass's choice, which every command compiles (the plain simplification's speed and error sit
//! beside it as `plain_*`). A formula is on the Pareto front when no other formula is at least as fast *and*
//! at least as accurate with one of the two strictly better. Speed is the scalar JIT's median ns/eval, error
//! the mean |Δ| against the reference on the papers' 91 × 1000 grid; the reference itself (error 0) is on the
//! front by definition, which is the honest answer: nothing beats it on accuracy. A speed difference counts
//! only past the measured noise (see [`mark_pareto`]), so two runs draw the same front. A row is measured by
//! [`bench_row`] ([`row`]).

mod row;

pub use row::{bench_row, RowOptions};
use serde::Serialize;

/// The papers' catalogue (`examples/brdfs`) compiled in: every file's path in the checkout and its text (the
/// default files and reference of `lobe bench`, from any directory).
pub const CATALOGUE: [(&str, &str); 16] = [
    ("examples/brdfs/beckmann.brdf", include_str!("../../../examples/brdfs/beckmann.brdf")),
    ("examples/brdfs/blinn.brdf", include_str!("../../../examples/brdfs/blinn.brdf")),
    ("examples/brdfs/cook_torrance.brdf", include_str!("../../../examples/brdfs/cook_torrance.brdf")),
    ("examples/brdfs/dsh.brdf", include_str!("../../../examples/brdfs/dsh.brdf")),
    ("examples/brdfs/fst.brdf", include_str!("../../../examples/brdfs/fst.brdf")),
    ("examples/brdfs/gaussian.brdf", include_str!("../../../examples/brdfs/gaussian.brdf")),
    ("examples/brdfs/kutlog.brdf", include_str!("../../../examples/brdfs/kutlog.brdf")),
    ("examples/brdfs/modified_schlick.brdf", include_str!("../../../examples/brdfs/modified_schlick.brdf")),
    ("examples/brdfs/modified_schlick_vr.brdf", include_str!("../../../examples/brdfs/modified_schlick_vr.brdf")),
    ("examples/brdfs/phong.brdf", include_str!("../../../examples/brdfs/phong.brdf")),
    ("examples/brdfs/quadratic.brdf", include_str!("../../../examples/brdfs/quadratic.brdf")),
    ("examples/brdfs/schlick.brdf", include_str!("../../../examples/brdfs/schlick.brdf")),
    ("examples/brdfs/schlick_vr.brdf", include_str!("../../../examples/brdfs/schlick_vr.brdf")),
    ("examples/brdfs/scos.brdf", include_str!("../../../examples/brdfs/scos.brdf")),
    ("examples/brdfs/scos2.brdf", include_str!("../../../examples/brdfs/scos2.brdf")),
    ("examples/brdfs/ward.brdf", include_str!("../../../examples/brdfs/ward.brdf")),
];

/// One formula's measurements. Times are medians over repeated runs in this process; `*_spread` is the
/// relative half-width between the 25th and 75th percentiles.
#[derive(Clone, Debug, Serialize)]
pub struct BenchRow {
    pub name: String,
    pub file: String,
    /// The math mode the kernel was compiled in (`precise` or `fast`).
    pub math: String,
    #[serde(serialize_with = "crate::base::json::num")]
    pub compile_us: f64,
    /// The accuracy pass's search for this formula at these values (uncached), ms.
    #[serde(serialize_with = "crate::base::json::num")]
    pub pass_ms: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    pub jit_ns: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    pub jit_spread: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    pub jit_batch_ns: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    pub interp_ns: f64,
    /// Hand-written Rust (`numerics::twins`), where lobe has a twin of the formula, called like the kernel.
    #[serde(serialize_with = "crate::base::json::opt_num")]
    pub native_ns: Option<f64>,
    #[serde(serialize_with = "crate::base::json::num")]
    pub mean_abs_grid: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    pub epicenter_max_rel_pct: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    pub max_abs: f64,
    /// Normalisation coefficient at n = 50 (lobe mode).
    #[serde(serialize_with = "crate::base::json::opt_num")]
    pub coef_n50: Option<f64>,
    /// Maximum hemispherical-directional albedo at n = 50 (unnormalised).
    #[serde(serialize_with = "crate::base::json::opt_num")]
    pub albedo_max: Option<f64>,
    /// The batched kernel's largest distance from the precise interpreter over the timed points, in ulps
    /// (0 in precise mode: the JIT computes the interpreter's bits), and relative.
    #[serde(serialize_with = "crate::base::json::num")]
    pub max_ulp_vs_precise: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    pub max_rel_vs_precise: f64,
    /// Bits of error against the higher-precision truth (`numerics::robust`, 4096 domain points, the same for
    /// both kernels): average and maximum.
    #[serde(serialize_with = "crate::base::json::num")]
    pub bits_error_avg: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    pub bits_error_max: f64,
    /// The plain simplification's kernel, measured the same way.
    #[serde(flatten)]
    pub plain: PlainKernel,
    pub pareto: bool,
    /// The batched tiers side by side (the `llvm` or `auto` tier in a build with the LLVM tier; absent otherwise).
    #[serde(flatten)]
    pub tiers: Option<TierColumns>,
}

/// The plain simplification's kernel beside the row's (JSON keys `plain_*`).
#[derive(Clone, Debug, Serialize)]
pub struct PlainKernel {
    #[serde(rename = "plain_jit_ns", serialize_with = "crate::base::json::num")]
    pub jit_ns: f64,
    #[serde(rename = "plain_jit_spread", serialize_with = "crate::base::json::num")]
    pub jit_spread: f64,
    #[serde(rename = "plain_jit_batch_ns", serialize_with = "crate::base::json::num")]
    pub jit_batch_ns: f64,
    #[serde(rename = "plain_bits_error_avg", serialize_with = "crate::base::json::num")]
    pub bits_error_avg: f64,
    #[serde(rename = "plain_bits_error_max", serialize_with = "crate::base::json::num")]
    pub bits_error_max: f64,
}

/// Cranelift's and LLVM's batched kernels of one formula, timed on the same points.
#[derive(Clone, Debug, Serialize)]
pub struct TierColumns {
    /// ns per element, Cranelift's batched kernel (2 lanes) and LLVM's.
    #[serde(serialize_with = "crate::base::json::num")]
    pub cranelift_batch_ns: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    pub llvm_batch_ns: f64,
    pub llvm_lanes: u32,
    /// Compile time of everything a batch call needs (Cranelift: scalar, prepare and batched kernels; LLVM:
    /// prepare and batched kernels), median of three compiles, ms.
    #[serde(serialize_with = "crate::base::json::num")]
    pub cranelift_compile_ms: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    pub llvm_compile_ms: f64,
    /// Elements per timed pass.
    pub points: usize,
}

/// The batched tiers' table: one line per row that has them (empty when none has).
pub fn tiers_table(rows: &[BenchRow]) -> String {
    let with: Vec<(&BenchRow, &TierColumns)> = rows.iter().filter_map(|r| r.tiers.as_ref().map(|t| (r, t))).collect();
    if with.is_empty() {
        return String::new();
    }
    let mut out = format!("\nbatched tiers ({} points per pass, 1 thread):\n", with[0].1.points);
    out.push_str(&format!(
        "{:<28} {:<7} {:>12} {:>12} {:>8} {:>5} {:>12} {:>10}\n",
        "formula", "math", "cranelift ns", "llvm ns", "speedup", "lanes", "cranelift ms", "llvm ms"
    ));
    for (r, t) in with {
        out.push_str(&format!(
            "{:<28} {:<7} {:>12.2} {:>12.2} {:>7.2}× {:>5} {:>12.2} {:>10.1}\n",
            truncate(&r.name, 28),
            r.math,
            t.cranelift_batch_ns,
            t.llvm_batch_ns,
            t.cranelift_batch_ns / t.llvm_batch_ns,
            t.llvm_lanes,
            t.cranelift_compile_ms,
            t.llvm_compile_ms
        ));
    }
    out
}

/// The smallest relative noise a speed difference must exceed: two runs of `lobe bench` on the same machine
/// move single medians by a few per cent even where a run's own quartiles are tighter.
pub(crate) const MIN_NOISE: f64 = 0.05;

/// Marks `pareto` on every row (by `jit_ns` and `mean_abs_grid`). Row j dominates row i when it is not
/// measurably slower, no less accurate, and measurably faster or more accurate; "measurably" means by more than
/// both rows' noise (their `jit_spread`, at least [`MIN_NOISE`]) for speed, and by more than a relative 10⁻⁹
/// for the error (a deterministic number; closer values are the same model error rounded differently).
pub fn mark_pareto(rows: &mut [BenchRow]) {
    let pts: Vec<(f64, f64, f64)> = rows.iter().map(|r| (r.jit_ns, r.mean_abs_grid, r.jit_spread.max(MIN_NOISE))).collect();
    for (i, r) in rows.iter_mut().enumerate() {
        let (c, e, nc) = pts[i];
        let dominated = pts.iter().enumerate().any(|(j, &(c2, e2, n2))| {
            let tol = c.max(c2) * (nc + n2);
            let (faster, slower) = (c2 < c - tol, c2 > c + tol);
            let etol = 1e-9 * e.abs().max(e2.abs());
            let (better, worse) = (e2 < e - etol, e2 > e + etol);
            j != i && !slower && !worse && (faster || better)
        });
        r.pareto = c.is_finite() && e.is_finite() && !dominated;
    }
}

/// What machine the numbers come from.
pub fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| s.lines().find(|l| l.starts_with("model name")).and_then(|l| l.split(':').nth(1)).map(|s| s.trim().to_string()))
        .unwrap_or_else(|| std::env::consts::ARCH.to_string());
    let threads = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
    format!("{cpu}, {threads} hardware threads, {} {}", std::env::consts::OS, std::env::consts::ARCH)
}

/// A metric of the papers' n-sweep, or — where it does not apply (a formula or reference that reads no n).
fn swept(v: f64, f: impl Fn(f64) -> String) -> String {
    if v.is_nan() { "—".into() } else { f(v) }
}

fn fmt_opt(v: Option<f64>, prec: usize) -> String {
    match v {
        Some(x) if x.is_finite() => format!("{x:.prec$}"),
        Some(_) => "nan".into(),
        None => "—".into(),
    }
}

/// The table, sorted by cost, Pareto rows marked with `*`.
pub fn table(rows: &[BenchRow]) -> String {
    let unswept = rows.iter().any(|r| r.mean_abs_grid.is_nan());
    let mut rows: Vec<&BenchRow> = rows.iter().collect();
    rows.sort_by(|a, b| a.jit_ns.total_cmp(&b.jit_ns));
    let mut out = String::new();
    out.push_str(&format!(
        "{:<2}{:<28} {:<7} {:>9} {:>11} {:>9} {:>9} {:>9} {:>8} {:>9} {:>11} {:>9} {:>9} {:>8} {:>8} {:>12} {:>8}\n",
        "", "formula", "math", "compile", "jit ns", "batch ns", "interp", "rust ns", "interp/", "ulp vs", "mean |Δ|", "epic. %", "max |Δ|", "coef50", "albedo", "bits error", "plain"
    ));
    out.push_str(&format!(
        "{:<2}{:<28} {:<7} {:>9} {:>11} {:>9} {:>9} {:>9} {:>8} {:>9} {:>11} {:>9} {:>9} {:>8} {:>8} {:>12} {:>8}\n",
        "", "", "", "µs", "(±spread)", "/elem", "ns", "", "jit", "precise", "vs ref", "max", "", "n=50", "max", "avg/max", "ns/max"
    ));
    for r in rows {
        out.push_str(&format!(
            "{:<2}{:<28} {:<7} {:>9.1} {:>6.2} ±{:>2.0}% {:>9.2} {:>9.1} {:>9} {:>7.1}× {:>9} {:>11} {:>9} {:>9} {:>8} {:>8} {:>5.2}/{:<6.2} {:>6.2}/{:<5.2}\n",
            if r.pareto { "*" } else { "" },
            truncate(&r.name, 28),
            r.math,
            r.compile_us,
            r.jit_ns,
            r.jit_spread * 100.0,
            r.jit_batch_ns,
            r.interp_ns,
            fmt_opt(r.native_ns, 2),
            r.interp_ns / r.jit_ns,
            fmt_ulps(r.max_ulp_vs_precise),
            swept(r.mean_abs_grid, |x| format!("{x:.3e}")),
            swept(r.epicenter_max_rel_pct, |x| format!("{x:.2}")),
            swept(r.max_abs, |x| format!("{x:.3e}")),
            fmt_opt(r.coef_n50, 3),
            fmt_opt(r.albedo_max, 3),
            r.bits_error_avg,
            r.bits_error_max,
            r.plain.jit_ns,
            r.plain.bits_error_max,
        ));
    }
    out.push_str("* = Pareto front: no other formula is both faster (beyond the measured noise) and more accurate.\n");
    if unswept {
        out.push_str("— vs ref: the formula or the reference reads no n, so the papers' n-sweep does not apply (an accuracy run compares the two over the whole hemisphere instead); coef: only a one-cosine lobe has a lobe coefficient.\n");
    }
    out.push_str("Each row is the kernel the commands compile (the accuracy pass's choice); bits error: its numerical error vs the higher-precision truth (log2(ulps + 1)); plain: the plain simplification's jit ns and max bits.\n");
    out
}

/// Ulps as a short number: "0", "3", "1.2e5"; "nan" when a value was NaN on one side only.
fn fmt_ulps(u: f64) -> String {
    if !u.is_finite() {
        "nan".into()
    } else if u < 1e4 {
        format!("{u:.0}")
    } else {
        format!("{u:.1e}")
    }
}

fn truncate(s: &str, n: usize) -> String {
    if s.chars().count() <= n {
        s.to_string()
    } else {
        let mut t: String = s.chars().take(n - 1).collect();
        t.push('…');
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(name: &str, ns: f64, err: f64) -> BenchRow {
        BenchRow {
            name: name.into(),
            file: String::new(),
            math: "precise".into(),
            compile_us: 0.0,
            pass_ms: 0.0,
            jit_ns: ns,
            jit_spread: 0.0,
            jit_batch_ns: 0.0,
            interp_ns: 10.0 * ns,
            native_ns: None,
            mean_abs_grid: err,
            epicenter_max_rel_pct: 0.0,
            max_abs: 0.0,
            coef_n50: None,
            albedo_max: None,
            max_ulp_vs_precise: 0.0,
            max_rel_vs_precise: 0.0,
            bits_error_avg: 0.0,
            bits_error_max: 0.0,
            plain: PlainKernel { jit_ns: ns, jit_spread: 0.0, jit_batch_ns: 0.0, bits_error_avg: 0.0, bits_error_max: 0.0 },
            pareto: false,
            tiers: None,
        }
    }

    #[test]
    fn pareto_front_is_the_undominated_set() {
        let mut rows = vec![row("ref", 10.0, 0.0), row("fast", 1.0, 0.1), row("mid", 3.0, 0.01), row("bad", 4.0, 0.2), row("tie", 3.0, 0.01)];
        mark_pareto(&mut rows);
        let front: Vec<&str> = rows.iter().filter(|r| r.pareto).map(|r| r.name.as_str()).collect();
        // "mid" and "tie" are equal: neither strictly dominates the other, both stay on the front.
        assert_eq!(front, vec!["ref", "fast", "mid", "tie"]);
        let t = table(&rows);
        assert!(t.contains("* fast") || t.starts_with("  "), "{t}");
    }

    /// Speed differences within the measured noise decide nothing: a formula a hair faster and less accurate
    /// than another does not push it off the front, and jittering every time by less than the noise (as a
    /// second run does) leaves the front as it was.
    #[test]
    fn the_front_does_not_move_with_noise() {
        let mut rng = crate::base::rng::Rng(0xFACE);
        // Costs on levels 30 % apart (decided) with up to 2 % between rows of one level (noise), random errors.
        let base: Vec<(String, f64, f64)> = (0..40)
            .map(|k| (format!("f{k}"), 1.3f64.powi(rng.below(12) as i32) * (1.0 + 0.02 * rng.unit()), rng.unit().powi(3)))
            .collect();
        let front = |jitter: &mut dyn FnMut() -> f64| {
            let mut rows: Vec<BenchRow> = base.iter().map(|(n, c, e)| row(n, c * jitter(), *e)).collect();
            mark_pareto(&mut rows);
            rows.iter().filter(|r| r.pareto).map(|r| r.name.clone()).collect::<Vec<_>>()
        };
        let want = front(&mut || 1.0);
        for _ in 0..20 {
            // ±2 % per median, as between two runs.
            let got = front(&mut || 1.0 + 0.04 * (rng.unit() - 0.5));
            assert_eq!(got, want);
        }
        // Two rows 1 % apart in speed: the faster, less accurate one does not dominate, the more accurate stays.
        let mut rows = vec![row("a", 1.00, 0.1), row("b", 1.01, 0.01)];
        mark_pareto(&mut rows);
        assert!(!rows[0].pareto && rows[1].pareto, "b is as fast within the noise and more accurate");
        // 3× apart: both on the front.
        let mut rows = vec![row("a", 1.0, 0.1), row("b", 3.0, 0.01)];
        mark_pareto(&mut rows);
        assert!(rows[0].pareto && rows[1].pareto);
    }
}
