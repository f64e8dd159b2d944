//! Unit tests of what the simplifier decides without evaluating a formula: the exact-reciprocal guard and the
//! libm facts behind `pow-zero` and `pow-one`. The tests built from s-expressions (exact policy, spans, program
//! text) and those that compare values before and after simplifying need a test fixture or an evaluator, which
//! live outside the library, so they are integration tests: `tests/it/simplify.rs` (modules `decisions` and
//! `rewrites`: one per rewrite, the refusals, the fixpoint, baking, used inputs, and the accuracy measurements
//! quoted in the module docs).

use super::*;

#[test]
fn division_by_a_non_power_of_two_is_not_an_exact_reciprocal() {
    // (`tests/it/simplify.rs` checks that `NH / 3` stays a division.)
    // 2^-1030 is subnormal; its reciprocal overflows: refused.
    assert!(!exact_reciprocal(f64::from_bits(1 << 20)));
    assert!(!exact_reciprocal(2f64.powi(1023)), "1/2^1023 is subnormal");
    assert!(exact_reciprocal(-0.125));
}

#[test]
fn pow_zero_and_one_are_exact_in_libm() {
    // The justification for pow-zero and pow-one: the builtin (libm pow) gives 1 and x for every x.
    for x in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, -0.0, 0.0, -3.5, 1e-310] {
        assert_eq!(Builtin::Pow.eval(&[x, 0.0]), 1.0, "pow({x}, 0)");
        assert_eq!(Builtin::Pow.eval(&[x, -0.0]), 1.0, "pow({x}, -0)");
        let p1 = Builtin::Pow.eval(&[x, 1.0]);
        assert!(p1.to_bits() == x.to_bits() || (x.is_nan() && p1.is_nan()), "pow({x}, 1) = {p1}");
    }
    // And pow(-0, 0.5) = +0 while sqrt(-0) = -0, pow(-inf, 0.5) = inf while sqrt(-inf) = NaN: why pow-half is guarded.
    assert!(Builtin::Pow.eval(&[-0.0, 0.5]).is_sign_positive() && (-0.0f64).sqrt().is_sign_negative());
    assert_eq!(Builtin::Pow.eval(&[f64::NEG_INFINITY, 0.5]), f64::INFINITY);
}
