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
