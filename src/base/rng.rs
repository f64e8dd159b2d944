//! A tiny deterministic generator (xorshift64) for samples that must be the same on every run: the accuracy
//! pass's domain points and the tests' random expressions. Not for anything statistical beyond that.

/// xorshift64 state; seed it non-zero.
#[derive(Clone, Debug)]
pub struct Rng(pub u64);

impl Rng {
    pub(crate) fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    /// Uniform in [0, 1) with 53 random bits.
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Uniform in 0..n (n > 0; modulo bias is irrelevant at the sizes used).
    pub fn below(&mut self, n: u64) -> u64 {
        self.next_u64() % n
    }
}

/// A counter-based generator (SplitMix64 read at a position): the `counter`-th uniform of stream `seed` is a
/// pure function of the pair, `mix(mix(seed) + (counter + 1)·γ)` with γ = 0x9E3779B97F4A7C15 (the golden-ratio
/// increment) and `mix` SplitMix64's finaliser, 53 bits into [0, 1). Samples split over any number of threads
/// draw the same numbers: sample `i`'s two uniforms are counters `2i` and `2i + 1`, whoever computes them.
pub fn counter_unit(seed: u64, counter: u64) -> f64 {
    const GAMMA: u64 = 0x9E37_79B9_7F4A_7C15;
    let state = mix64(seed).wrapping_add(counter.wrapping_add(1).wrapping_mul(GAMMA));
    (mix64(state) >> 11) as f64 / (1u64 << 53) as f64
}

/// SplitMix64's output function (Steele, Lea, Flood 2014): a bijection of u64 with full avalanche.
fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counter_stream_is_a_function_of_seed_and_position_and_looks_uniform() {
        assert_eq!(counter_unit(7, 12345), counter_unit(7, 12345));
        assert_ne!(counter_unit(7, 0), counter_unit(8, 0));
        assert_ne!(counter_unit(7, 0), counter_unit(7, 1));
        let n = 100_000;
        let (mut sum, mut sq, mut bins) = (0.0, 0.0, [0usize; 10]);
        for k in 0..n {
            let u = counter_unit(1, k);
            assert!((0.0..1.0).contains(&u));
            sum += u;
            sq += u * u;
            bins[(u * 10.0) as usize] += 1;
        }
        let nf = n as f64;
        assert!((sum / nf - 0.5).abs() < 0.005, "mean {}", sum / nf);
        assert!((sq / nf - 1.0 / 3.0).abs() < 0.005);
        // Each decile within 5 standard deviations of 10 000.
        assert!(bins.iter().all(|&b| (b as f64 - 10_000.0).abs() < 5.0 * 95.0), "{bins:?}");
    }
}
