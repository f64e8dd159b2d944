//! Source text → `lobe::compile_source` → evaluation on a few points, with both backends.
//!
//! Invariants checked: no panic anywhere (front end, simplifier, JIT, evaluation); when both backends accept
//! the text, they agree (within 4 ulp, both NaN, or the same infinity) in scalar and batched form.
//!
//! Run: `cargo +nightly fuzz run compile_eval -- -max_len=4096` from the repository root; seed corpus:
//! `cp ../tests/corpus/* corpus/compile_eval/` (and examples/brdfs/*.brdf).
#![no_main]

use libfuzzer_sys::fuzz_target;
use lobe::{Backend, Columns, Evaluator, Options};

fn agree(a: f64, b: f64) -> bool {
    if a.is_nan() || b.is_nan() {
        return a.is_nan() && b.is_nan();
    }
    if a.is_infinite() || b.is_infinite() {
        return a == b;
    }
    let key = |x: f64| {
        let b = x.to_bits() as i64;
        if b < 0 {
            i64::MIN.wrapping_sub(b)
        } else {
            b
        }
    };
    key(a).abs_diff(key(b)) <= 4
}

fuzz_target!(|data: &[u8]| {
    let src = String::from_utf8_lossy(data);
    let build = |backend| lobe::compile_source("fuzz.brdf", &src, &Options { backend, ..Options::default() });
    let (jit, interp) = match (build(Backend::Jit), build(Backend::Interp)) {
        (Ok(j), Ok(i)) => (j, i),
        (Err(d), _) | (_, Err(d)) => {
            let _ = d.render(false);
            return;
        }
    };
    let pts = [[0.0; 5], [1.0; 5], [0.5, 1e-8, 0.999, 0.25, 0.75], [0.1, 0.9, 0.3, 0.6, 0.0]];
    let p = jit.default_params();
    let cols: Vec<Vec<f64>> = (0..5).map(|i| pts.iter().map(|x| x[i]).collect()).collect();
    let mut out = vec![0.0; pts.len()];
    jit.eval_batch(&Columns::new(std::array::from_fn(|i| cols[i].as_slice())), &p, &mut out);
    for (k, x) in pts.iter().enumerate() {
        let want = interp.eval(x, &p);
        assert!(agree(want, jit.eval(x, &p)), "scalar disagrees at {x:?}");
        assert!(agree(want, out[k]), "batched disagrees at {x:?}");
    }
});
