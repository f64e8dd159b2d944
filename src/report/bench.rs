//! The speed-versus-error table of `lobe bench`: rows, the Pareto front, text and JSON output.
//!
//! A formula is on the Pareto front when no other formula is at least as fast *and* at least as accurate with
//! one of the two strictly better. Speed is the scalar JIT's median ns/eval, error the mean |Δ| against the
//! reference on the papers' 91 × 1000 grid; the reference itself (error 0) is on the front by definition, which
//! is the honest answer: nothing beats it on accuracy.

use serde::Serialize;

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
    /// Bits of error against the higher-precision truth (`numerics::robust`, 4096 domain points) of the kernel
    /// the accuracy pass chose: average and maximum; `bits_error_max_before` is the plain simplification's max.
    #[serde(serialize_with = "crate::base::json::num")]
    pub bits_error_avg: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    pub bits_error_max: f64,
    #[serde(serialize_with = "crate::base::json::num")]
    pub bits_error_max_before: f64,
    /// Scalar JIT ns/eval of the accuracy pass's kernel (equal to `jit_ns` when it kept no rewrite).
    #[serde(serialize_with = "crate::base::json::num")]
    pub robust_jit_ns: f64,
    pub pareto: bool,
    /// The batched tiers side by side (the `llvm` or `auto` tier in a build with the LLVM tier; absent otherwise).
    #[serde(flatten)]
    pub tiers: Option<TierColumns>,
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

/// Marks `pareto` on every row (by `jit_ns` and `mean_abs_grid`).
pub fn mark_pareto(rows: &mut [BenchRow]) {
    let pts: Vec<(f64, f64)> = rows.iter().map(|r| (r.jit_ns, r.mean_abs_grid)).collect();
    for (i, r) in rows.iter_mut().enumerate() {
        let (c, e) = pts[i];
        r.pareto = c.is_finite()
            && e.is_finite()
            && !pts.iter().enumerate().any(|(j, &(c2, e2))| j != i && c2 <= c && e2 <= e && (c2 < c || e2 < e));
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

fn fmt_opt(v: Option<f64>, prec: usize) -> String {
    match v {
        Some(x) if x.is_finite() => format!("{x:.prec$}"),
        Some(_) => "nan".into(),
        None => "—".into(),
    }
}

/// The table, sorted by cost, Pareto rows marked with `*`.
pub fn table(rows: &[BenchRow]) -> String {
    let mut rows: Vec<&BenchRow> = rows.iter().collect();
    rows.sort_by(|a, b| a.jit_ns.total_cmp(&b.jit_ns));
    let mut out = String::new();
    out.push_str(&format!(
        "{:<2}{:<28} {:<7} {:>9} {:>11} {:>9} {:>9} {:>9} {:>8} {:>9} {:>11} {:>9} {:>9} {:>8} {:>8} {:>12} {:>8}\n",
        "", "formula", "math", "compile", "jit ns", "batch ns", "interp", "rust ns", "interp/", "ulp vs", "mean |Δ|", "epic. %", "max |Δ|", "coef50", "albedo", "bits error", "robust"
    ));
    out.push_str(&format!(
        "{:<2}{:<28} {:<7} {:>9} {:>11} {:>9} {:>9} {:>9} {:>8} {:>9} {:>11} {:>9} {:>9} {:>8} {:>8} {:>12} {:>8}\n",
        "", "", "", "µs", "(±spread)", "/elem", "ns", "", "jit", "precise", "vs ref", "max", "", "n=50", "max", "avg/max", "ns ×"
    ));
    for r in rows {
        out.push_str(&format!(
            "{:<2}{:<28} {:<7} {:>9.1} {:>6.2} ±{:>2.0}% {:>9.2} {:>9.1} {:>9} {:>7.1}× {:>9} {:>11.3e} {:>9.2} {:>9.3e} {:>8} {:>8} {:>5.2}/{:<6.2} {:>7.2}×\n",
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
            r.mean_abs_grid,
            r.epicenter_max_rel_pct,
            r.max_abs,
            fmt_opt(r.coef_n50, 3),
            fmt_opt(r.albedo_max, 3),
            r.bits_error_avg,
            r.bits_error_max,
            r.robust_jit_ns / r.jit_ns,
        ));
    }
    out.push_str("* = Pareto front: no other formula is both faster and more accurate.\n");
    out.push_str("bits error: numerical error of the accuracy pass's kernel vs the higher-precision truth (log2(ulps + 1)); robust ns ×: its ns/eval over jit ns.\n");
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
            bits_error_max_before: 0.0,
            robust_jit_ns: ns,
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
}
