//! Integer powers as multiplication chains.
//!
//! `x^k` for 2 ≤ k ≤ 16 uses a shortest addition chain (Knuth, TAOCP 4.6.3; e.g. x^15 in 5 multiplies, not the
//! 6 of binary exponentiation); larger k uses left-to-right binary exponentiation (⌊log2 k⌋ squarings plus one
//! multiply per set bit: x^268 in 8 + 2 = 10 multiplies). Every intermediate power is a node in the hash-consed
//! arena, so `x^8 · x^4` reuses the x^4 computed on the way to x^8, and two powers of the same base share
//! their common steps.
//!
//! Rounding: each multiply rounds once, and a product's relative error is the sum of its factors' plus one
//! rounding, so a chain for x^k is within (k − 1)·u of the exact power (u = 2^−53) — the bound grows with k,
//! unlike libm `pow` (< 1 ulp). Measured (the `accuracy_*` tests in `tests/it/simplify.rs`): see the
//! simplifier's module docs.

/// Shortest addition chains for k ≤ 16 (index k); each element after the first is a sum of two earlier ones.
const CHAINS: [&[u32]; 17] = [
    &[],
    &[1],
    &[1, 2],
    &[1, 2, 3],
    &[1, 2, 4],
    &[1, 2, 4, 5],
    &[1, 2, 3, 6],
    &[1, 2, 4, 6, 7],
    &[1, 2, 4, 8],
    &[1, 2, 4, 8, 9],
    &[1, 2, 4, 5, 10],
    &[1, 2, 3, 5, 10, 11],
    &[1, 2, 3, 6, 12],
    &[1, 2, 3, 5, 10, 13],
    &[1, 2, 3, 5, 7, 14],
    &[1, 2, 3, 6, 12, 15],
    &[1, 2, 4, 8, 16],
];

/// The largest |k| turned into a chain; above it `pow` stays a libm call (a chain would be long and inexact).
pub const MAX_EXPONENT: u32 = 1024;

/// The steps computing x^k (k ≥ 1): each step `(a, b)` makes x^(a+b) from the already computed x^a and x^b.
/// The last step produces x^k; an empty list means k = 1.
pub(crate) fn steps(k: u32) -> Vec<(u32, u32)> {
    let chain: Vec<u32> = if (k as usize) < CHAINS.len() {
        CHAINS[k as usize].to_vec()
    } else {
        // Left-to-right binary: square, and multiply by x for each set bit below the top one.
        let mut c = vec![1u32];
        let mut cur = 1u32;
        for bit in (0..(31 - k.leading_zeros())).rev() {
            cur *= 2;
            c.push(cur);
            if k & (1 << bit) != 0 {
                cur += 1;
                c.push(cur);
            }
        }
        c
    };
    let mut out = Vec::with_capacity(chain.len());
    for (i, &e) in chain.iter().enumerate().skip(1) {
        // Find two earlier elements summing to e (prefer the largest, which is the previous element).
        let prev = &chain[..i];
        let pair = prev
            .iter()
            .rev()
            .find_map(|&a| prev.contains(&(e - a)).then_some((a, e - a)))
            .unwrap_or((e - 1, 1));
        out.push(pair);
    }
    out
}

/// Number of multiplications for x^k.
pub(crate) fn cost(k: u32) -> usize {
    steps(k).len()
}

/// How many times each step's power enters x^k (indexed like [`steps`]): to first order the chain's relative
/// error is Σ mⱼ·δⱼ over the steps' rounding errors δⱼ (|δⱼ| ≤ u), and Σ mⱼ = k − 1 for every chain. The early
/// steps weigh most (binary x^1000: x² and x³ enter 256 times each, the last step once).
pub(crate) fn multiplicities(k: u32) -> Vec<u32> {
    let st = steps(k);
    let mut m = vec![0u32; st.len()];
    if let Some(last) = m.last_mut() {
        *last = 1;
    }
    for j in (0..st.len()).rev() {
        let (a, b) = st[j];
        // x^a·x^a counts x^a twice; exponent 1 is the base, which no step computes.
        for e in [a, b] {
            if let Some(i) = st[..j].iter().position(|&(p, q)| p + q == e) {
                m[i] += m[j];
            }
        }
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chains_compute_the_right_power() {
        for k in 1..=MAX_EXPONENT {
            // Evaluate the chain on exponents (a sum of exponents is the product of powers).
            let mut have = vec![1u32];
            for (a, b) in steps(k) {
                assert!(have.contains(&a) && have.contains(&b), "k={k}: step uses an uncomputed power");
                have.push(a + b);
            }
            assert_eq!(*have.last().unwrap_or(&0), k, "k={k}");
        }
    }

    #[test]
    fn multiplicities_sum_to_the_multiplications_of_the_expanded_product() {
        for k in 1..=MAX_EXPONENT {
            assert_eq!(multiplicities(k).iter().sum::<u32>(), k - 1, "k={k}");
        }
        // 50 = 1, 2, 3, 6, 12, 24, 25, 50.
        assert_eq!(multiplicities(50), [16, 16, 8, 4, 2, 2, 1]);
    }

    #[test]
    fn small_chains_are_shortest_known() {
        // l(k) for k = 1..16 (OEIS A003313).
        let l = [0, 1, 2, 2, 3, 3, 4, 3, 4, 4, 5, 4, 5, 5, 5, 4];
        for k in 1..=16u32 {
            assert_eq!(cost(k), l[k as usize - 1], "k={k}");
        }
        assert_eq!(cost(268), 10);
        assert_eq!(cost(1024), 10);
    }
}
