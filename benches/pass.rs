//! The accuracy pass's cost on one core, per file: every catalogue formula, every `examples/explorer` file, and
//! any BRDF Explorer files in `$LOBE_BRDF_EXPLORER_DIR` (github wdas/brdf `src/brdfs`: compare.brdf and
//! disney.brdf are its largest). Per file: the search with every parameter live (median of 3), the same
//! command's second run from the decision cache (load and replay, median of 5), and `lobe check`'s default
//! report (10⁵ points, conditioning measured everywhere). One rayon thread: the figures are CPU time.
//!
//! Run: `cargo bench --bench pass` (a few minutes). Targets (issue): median ≤ 50 ms per catalogue formula,
//! ≤ 500 ms per explorer file, ≤ 5 ms from the cache, check ≤ 10 s.

use lobe::numerics::pass_cache::Cache;
use lobe::numerics::robust::{self, Conditioning, DecisionStore, PassOptions};
use std::path::PathBuf;
use std::time::Instant;

fn files(dir: &std::path::Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir).map(|r| r.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.extension().is_some_and(|x| x == "brdf")).collect()).unwrap_or_default();
    v.sort();
    v
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    rayon::ThreadPoolBuilder::new().num_threads(1).build_global().expect("one thread");
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut groups = vec![("catalogue", files(&root.join("examples/brdfs"))), ("explorer", files(&root.join("examples/explorer")))];
    if let Some(d) = std::env::var_os("LOBE_BRDF_EXPLORER_DIR") {
        groups.push(("BRDF Explorer", files(std::path::Path::new(&d))));
    }
    let cache_dir = std::env::temp_dir().join(format!("lobe-pass-bench-{}", std::process::id()));
    println!("| group | file | pass ms (live, median of 3) | from cache ms | check s (10⁵ points) | truncated |");
    println!("|---|---|---|---|---|---|");
    for (group, paths) in groups {
        let mut pass_ms = vec![];
        for p in paths {
            let text = std::fs::read_to_string(&p).expect("readable");
            let Ok(f) = lobe::front::parse(&p.display().to_string(), &text) else { continue };
            // A colour formula: its red channel, as `lobe check` does.
            let f = f.named_channels().remove(0);
            let o = PassOptions::default();
            let mut runs = vec![];
            let mut truncated = false;
            for _ in 0..3 {
                let t = Instant::now();
                let out = robust::improve(&f, &[], &o);
                runs.push(t.elapsed().as_secs_f64() * 1e3);
                truncated |= out.truncated;
            }
            let ms = median(runs);
            pass_ms.push(ms);
            let cache = Cache::at(&cache_dir);
            let d = robust::improve(&f, &[], &o).decision;
            cache.store(&f, &[], &o, &d);
            let cached = median(
                (0..5)
                    .map(|_| {
                        let t = Instant::now();
                        let d = cache.load(&f, &[], &o).expect("stored");
                        let g = robust::replay(&f, &[], &d, o.prefer);
                        std::hint::black_box(g.ir.len());
                        t.elapsed().as_secs_f64() * 1e3
                    })
                    .collect(),
            );
            let t = Instant::now();
            let check = robust::improve(&f, &[], &PassOptions { points: 100_000, conditioning: Conditioning::Everywhere, budget: std::time::Duration::from_secs(10), ..o });
            let check_s = t.elapsed().as_secs_f64();
            let name = p.file_name().unwrap().to_string_lossy();
            println!("| {group} | {name} | {ms:.1} | {cached:.2} | {check_s:.2} | {} |", if truncated || check.truncated { "yes" } else { "" });
        }
        if !pass_ms.is_empty() {
            println!("| {group} | **median** | **{:.1}** | | | |", median(pass_ms));
        }
    }
    let _ = std::fs::remove_dir_all(&cache_dir);
}
