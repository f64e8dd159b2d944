//! Deep recursion on any caller's stack.
//!
//! Formulas are trees up to the 1 MiB source cap (a 600 000-node sum, a 10⁶-deep unary minus), and some passes
//! recurse over them (the simplifier's term collection, the accuracy pass's rules, the truth, the printers).
//! Each recursive step runs inside [`deep`], which continues on a fresh stack segment from the heap when less
//! than [`RED_ZONE`] is left (the `stacker` crate, as rustc does): the library needs no big stack from whoever
//! calls it — Python, a server's worker thread, rayon's default pool — and a shallow formula pays one compare.

/// Stack one recursive step may use before the next check (the deepest non-recursive callee included).
pub(crate) const RED_ZONE: usize = 256 * 1024;
/// Size of each new segment (address space; only the pages touched are used).
pub(crate) const SEGMENT: usize = 16 << 20;

/// Runs `f`, on a new stack segment if this one is nearly used up.
#[inline]
pub fn deep<R>(f: impl FnOnce() -> R) -> R {
    stacker::maybe_grow(RED_ZONE, SEGMENT, f)
}

#[cfg(test)]
mod tests {
    use super::deep;

    fn depth(n: u64) -> u64 {
        // A frame with some weight, so the recursion would need ~1 GiB of stack without segments.
        let pad = std::hint::black_box([n; 64]);
        deep(|| if n == 0 { 0 } else { 1 + depth(n - 1) + pad[0] - n })
    }

    #[test]
    fn a_million_levels_fit_on_a_small_thread() {
        let t = std::thread::Builder::new().stack_size(256 * 1024).spawn(|| depth(1_000_000)).unwrap();
        assert_eq!(t.join().unwrap(), 1_000_000);
    }
}
