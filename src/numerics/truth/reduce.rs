//! Payne–Hanek argument reduction for the truth's sin and cos of large arguments: x·(2/π) mod 4 from the bits
//! of 2/π that matter at x's exponent (a 256-bit window of a 1 408-bit table), in integer arithmetic, so the
//! reduced argument r = x − k·π/2 keeps ~2⁻¹⁰⁶ relative accuracy however large x is (below the table's end at
//! |x| ≈ 2¹¹⁵⁰), where a subtraction of k·π/2 with π/2 in three parts holds only for k < 2⁴¹.

use super::Xf;
use crate::builtins::dd;

type Dd = dd::Dd<f64>;
use crate::builtins::math::Direct;

/// The bits of 2/π after the binary point, 64 to a word (from mpmath at 1 600 bits).
const TWO_OVER_PI: [u64; 22] = [
    0xA2F9836E4E441529, 0xFC2757D1F534DDC0, 0xDB6295993C439041, 0xFE5163ABDEBBC561, 0xB7246E3A424DD2E0, 0x06492EEA09D1921C,
    0xFE1DEB1CB129A73E, 0xE88235F52EBB4484, 0xE99C7026B45F7E41, 0x3991D639835339F4, 0x9C845F8BBDF9283B, 0x1FF897FFDE05980F,
    0xEF2F118B5A0A6D1F, 0x6D367ECF27CB09B7, 0x4F463F669E5FEA2D, 0x7527BAC7EBE5F17B, 0x3D0739F78A5292EA, 0x6BFB5FB11F8D5D08,
    0x56033046FC7B6BAB, 0xF0CFBC209AF4361D, 0xA9E391615EE61B08, 0x6599855F14A06840,
];

/// π/2 as a double-double.
const HALF_PI: Dd = (std::f64::consts::FRAC_PI_2, 6.123233995736766e-17);

/// A point on the circle of 4 quadrants: the quadrant count (mod 4) and the fraction of a quadrant in [0, 1) as
/// a 192-bit binary fraction (most significant word first).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Turn {
    k: u64,
    frac: [u64; 3],
}

impl Turn {
    fn add(self, b: Turn) -> Turn {
        let mut frac = [0u64; 3];
        let mut carry = 0u64;
        for i in (0..3).rev() {
            let (s1, c1) = self.frac[i].overflowing_add(b.frac[i]);
            let (s2, c2) = s1.overflowing_add(carry);
            frac[i] = s2;
            carry = u64::from(c1) + u64::from(c2);
        }
        Turn { k: (self.k + b.k + carry) & 3, frac }
    }

    /// −self (mod 4 quadrants).
    fn neg(self) -> Turn {
        let not = Turn { k: !self.k & 3, frac: self.frac.map(|w| !w) };
        // −t = !t + 2⁻¹⁹² (two's complement of the fixed-point number k.frac).
        not.add(Turn { k: 0, frac: [0, 0, 1] })
    }
}

/// `off` bits into the table, the next 256 bits (`None` past its end).
fn window(off: usize) -> Option<[u64; 4]> {
    if off + 256 > TWO_OVER_PI.len() * 64 {
        return None;
    }
    let word = |bit: usize| -> u64 {
        let (w, b) = (bit / 64, bit % 64);
        let next = TWO_OVER_PI.get(w + 1).copied().unwrap_or(0);
        if b == 0 {
            TWO_OVER_PI[w]
        } else {
            (TWO_OVER_PI[w] << b) | (next >> (64 - b))
        }
    };
    Some(std::array::from_fn(|i| word(off + 64 * i)))
}

/// m·2^q·(2/π) mod 4 for an integer m < 2⁵³ (`None` past the table).
fn turn_of(m: u64, q: i64) -> Option<Turn> {
    // Bits j ≥ 1 of 2/π weigh 2^−j; those with q − j ≥ 2 give multiples of 4 and drop. The window starts at
    // bit s = max(1, q − 1) and the product m·w is the value times 2^shift.
    let s = (q - 1).max(1);
    let w = window(usize::try_from(s - 1).ok()?)?;
    let shift = s + 255 - q;
    if !(2..=318).contains(&shift) {
        return None;
    }
    // m·w as 320 bits, most significant word first.
    let mut p = [0u64; 5];
    let mut carry = 0u128;
    for i in (0..4).rev() {
        let t = u128::from(m) * u128::from(w[i]) + carry;
        p[i + 1] = t as u64;
        carry = t >> 64;
    }
    p[0] = carry as u64;
    // Bit `n` from the least significant (0 ≤ n < 320).
    let bit = |n: i64| -> u64 { (p[4 - (n / 64) as usize] >> (n % 64)) & 1 };
    let k = bit(shift) | (bit(shift + 1) << 1);
    // The 192 bits below `shift`: p shifted left by 320 − shift, its top three words.
    let l = (320 - shift) as usize;
    let (wl, bl) = (l / 64, l % 64);
    let get = |i: usize| p.get(i).copied().unwrap_or(0);
    let frac = std::array::from_fn(|i| if bl == 0 { get(i + wl) } else { (get(i + wl) << bl) | (get(i + wl + 1) >> (64 - bl)) });
    Some(Turn { k, frac })
}

/// An f64 `v` times 2^e as a [`Turn`].
fn turn_of_f64(v: f64, e: i64) -> Option<Turn> {
    if v == 0.0 {
        return Some(Turn { k: 0, frac: [0; 3] });
    }
    let bits = v.abs().to_bits();
    let field = ((bits >> 52) & 0x7ff) as i64;
    let (m, q) = if field == 0 { (bits & ((1 << 52) - 1), -1074) } else { ((bits & ((1 << 52) - 1)) | (1 << 52), field - 1075) };
    let t = turn_of(m, q.checked_add(e)?)?;
    Some(if v < 0.0 { t.neg() } else { t })
}

/// (k mod 4, r) with x = k·π/2 + r, |r| ≤ π/4, r as a double-double: `None` beyond the table.
pub(super) fn reduce(x: Xf) -> Option<(u64, Dd)> {
    let t = turn_of_f64(x.hi, x.e)?.add(turn_of_f64(x.lo, x.e)?);
    // The nearest quadrant: a fraction of ½ or more is a step back from the next one.
    let (k, frac, neg) = if t.frac[0] >> 63 == 1 {
        let n = Turn { k: 0, frac: t.frac }.neg();
        ((t.k + 1) & 3, n.frac, true)
    } else {
        (t.k, t.frac, false)
    };
    // The fraction as a double-double: six exact 32-bit pieces summed.
    let mut f: Dd = (0.0, 0.0);
    for (i, w) in frac.iter().enumerate() {
        for (j, half) in [(w >> 32) as f64, (w & 0xffff_ffff) as f64].into_iter().enumerate() {
            let scale = f64::powi(2.0, -32 * (2 * i as i32 + j as i32 + 1));
            f = dd::add(&mut Direct, f, (half * scale, 0.0));
        }
    }
    let r = dd::mul(&mut Direct, f, HALF_PI);
    Some((k, if neg { dd::neg(&mut Direct, r) } else { r }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn small_arguments_reduce_as_the_three_part_subtraction_does() {
        // Where both hold (|x| < 2⁴⁰), the same quadrant and r to 2⁻¹⁰⁰ of π/4.
        let mut rng = crate::base::rng::Rng(0xB17);
        for _ in 0..2000 {
            let x = (rng.unit() - 0.5) * f64::powi(2.0, (rng.unit() * 40.0) as i32);
            let (k, r) = reduce(Xf::from_f64(x)).unwrap();
            let kk = (x / std::f64::consts::FRAC_PI_2).round();
            let rr = dd::add(&mut Direct, (x, 0.0), dd::neg(&mut Direct, dd::mul(&mut Direct, (kk, 0.0), HALF_PI)));
            assert_eq!(k, (kk as i64).rem_euclid(4) as u64, "{x}");
            assert!((r.0 - rr.0).abs() <= 2f64.powi(-95), "{x}: {r:?} vs {rr:?}");
        }
        assert_eq!(reduce(Xf::from_f64(0.0)), Some((0, (0.0, 0.0))));
    }
}
