//! lobe's integration tests: one binary, one module per area.
mod benched;
mod browser;
mod cancel;
mod catalogue;
mod cli;
mod deep;
mod differential;
mod directions;
mod explorer;
mod export;
mod front;
mod fuzz;
mod grad;
mod hostile;
mod jit;
mod mitsuba;
mod json_keys;
mod measured;
mod layers;
mod mathlib;
mod parse_errors;
mod simplify;
mod accuracy;
mod energy;
mod envcompare;
mod envlight;
mod everywhere;
mod explorer_render;
mod fixtures;
mod fit_grad;
mod render;
mod robust;
mod serve;
mod sample;
mod shading;
mod truth_mpmath;

/// A fresh, empty scratch directory `lobe-AREA-TAG-PID` under the system's temporary directory.
pub fn scratch_dir(area: &str, tag: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("lobe-{area}-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}
