//! The table of precise exp (`math.rs`): 2^(j/16) as a rounded head and a relative tail, generated once
//! with 80-digit decimal arithmetic and checked in; `tests/it/mathlib.rs` re-derives every entry with lobe's
//! own double-double evaluator.
//!
//! Cost: 16 rows ([`EXP_T`], 256 bytes): one 16-byte load per lane from the generated code, or, on AVX-512,
//! one permutation of two registers per column and vector of eight lanes (the LLVM tier).

// Each constant is printed as the shortest decimal that reads back to the intended bits (2^(8/16) is √2 on
// purpose).
#![allow(clippy::excessive_precision, clippy::unreadable_literal, clippy::approx_constant)]

/// 2^(j/16), rounded, j = 0..16.
pub const EXP_T_HI: [f64; 16] = [
    1.0, 1.0442737824274138, 1.0905077326652577, 1.1387886347566916,
    1.189207115002721, 1.241857812073484, 1.2968395546510096, 1.3542555469368927,
    1.4142135623730951, 1.4768261459394993, 1.5422108254079407, 1.6104903319492543,
    1.681792830507429, 1.7562521603732995, 1.8340080864093424, 1.9152065613971474,
];
/// (2^(j/16) − `EXP_T_HI`)/`EXP_T_HI`, rounded.
pub const EXP_T_TAIL: [f64; 16] = [
    0.0, 8.189317638195515e-17, -2.7939114859515733e-17, 7.826573258636076e-17,
    3.3484623336251524e-17, 3.750854201303127e-17, 1.9572585293112036e-17, 5.68648095791174e-17,
    -6.835808657661922e-17, -2.3591094770850053e-17, 5.1548301170786783e-17, 1.5341410053603723e-17,
    4.875160526227062e-17, 1.685487290628973e-17, 1.790126907604513e-17, -5.545065618639427e-17,
];

/// `EXP_T_HI` and `EXP_T_TAIL` as rows, for `Emit::lookup_pair`.
pub(crate) static EXP_T: [[f64; 2]; 16] = pairs(&EXP_T_HI, &EXP_T_TAIL);

/// Two tables as one table of rows `[a[j], b[j]]`, padded to `M` rows (a power of two, ≥ N) with copies of
/// the last row: [`Emit::lookup_pair`](super::math::Emit::lookup_pair) masks its index to the table, which
/// costs one vector `and` where a clamp took a compare and a conditional move per lane.
pub(crate) const fn pairs<const N: usize, const M: usize>(a: &[f64; N], b: &[f64; N]) -> [[f64; 2]; M] {
    assert!(N > 0 && M >= N && M.is_power_of_two(), "a lookup table has a power-of-two length");
    let mut out = [[0.0; 2]; M];
    let mut j = 0;
    while j < M {
        let k = if j < N { j } else { N - 1 };
        out[j] = [a[k], b[k]];
        j += 1;
    }
    out
}
