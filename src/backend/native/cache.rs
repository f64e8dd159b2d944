//! A bounded cache of compiled code keyed by the simplified IR's structure, for either tier's kernels and
//! programs.
//!
//! Key: the nodes reachable from the root, in topological order (what [`Ir::compact`] produces), plus the root
//! index and the math mode. Spans and names are not part of the key, so the same formula from two files, or compiled twice,
//! hits. Constants are keyed by bit pattern, so `0` and `-0` are different formulas, as they are to IEEE.
//!
//! Bounded LRU: at most `capacity` entries; inserting into a full cache evicts the least recently used one
//! (an O(capacity) scan, negligible next to a compile). Entries hold `Arc`s, so evicted code lives on until
//! the last kernel using it is dropped, then its JIT memory is freed.

use super::NativeError;
use crate::builtins::Mode;
use crate::ir::{Ir, Node};
use std::collections::HashMap;
use std::sync::{Arc, Mutex, MutexGuard, OnceLock};

/// Default bound of each compiled-code cache (entries; each is a few KiB of code).
pub(crate) const DEFAULT_CAPACITY: usize = 128;

/// A process-wide cache of compiled code (a `static` per tier and kind): a bounded [`Lru`] behind a lock, so
/// compiling the same structure twice is free.
pub(crate) struct Cache<V> {
    lru: OnceLock<Mutex<Lru<V>>>,
}

impl<V> Cache<V> {
    pub(crate) const fn new() -> Cache<V> {
        Cache { lru: OnceLock::new() }
    }

    fn lock(&self) -> MutexGuard<'_, Lru<V>> {
        // A panic while holding the lock cannot leave the map inconsistent (each operation is one map call).
        self.lru.get_or_init(|| Mutex::new(Lru::new(DEFAULT_CAPACITY))).lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The code under `key`, or `compile`'s (then kept); whether it came from the cache. The lock is not held
    /// while compiling: two threads compiling the same structure at once both compile, and one result is kept.
    pub(crate) fn get_or_compile(&self, key: Key, compile: impl FnOnce() -> Result<V, NativeError>) -> Result<(Arc<V>, bool), NativeError> {
        let hit = self.lock().get(&key);
        if let Some(v) = hit {
            return Ok((v, true));
        }
        let v = Arc::new(compile()?);
        self.lock().insert(key, v.clone());
        Ok((v, false))
    }

    /// Changes the bound (0 disables the cache); returns the previous bound.
    pub(crate) fn set_capacity(&self, capacity: usize) -> usize {
        let mut c = self.lock();
        let old = c.capacity();
        c.set_capacity(capacity);
        old
    }

    /// (hits, misses, entries) since the process started.
    pub(crate) fn stats(&self) -> (u64, u64, usize) {
        let c = self.lock();
        (c.hits, c.misses, c.len())
    }
}

/// Structural key of a compacted IR.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub(crate) struct Key {
    nodes: Vec<Node>,
    root: u32,
    mode: Mode,
    /// A shading program's further roots (its outputs after the first), empty for a formula.
    more: Vec<u32>,
}

impl Key {
    /// `ir` must be compacted (nodes reachable from `root` only).
    pub(crate) fn new(ir: &Ir, root: crate::ir::NodeId, mode: Mode) -> Key {
        Key { nodes: ir.nodes().to_vec(), root: root.0, mode, more: vec![] }
    }

    /// The key of a multi-output program: its roots, then its shape (output count, each region's), so two
    /// programs that list the same roots differently never share code.
    pub(crate) fn of_program(p: &crate::backend::program::Program, mode: Mode) -> Key {
        let mut roots = p.roots();
        roots.push(crate::ir::NodeId(p.outputs.len() as u32));
        roots.extend(p.regions.iter().map(|r| crate::ir::NodeId(r.outputs.len() as u32)));
        Key::of_roots(&p.ir, &roots, mode)
    }

    /// The key of a compacted program with several roots (`roots` non-empty).
    pub(crate) fn of_roots(ir: &Ir, roots: &[crate::ir::NodeId], mode: Mode) -> Key {
        let more = roots.iter().skip(1).map(|r| r.0).collect();
        Key { nodes: ir.nodes().to_vec(), root: roots.first().map_or(u32::MAX, |r| r.0), mode, more }
    }
}

/// A least-recently-used map from [`Key`] to shared values.
pub(crate) struct Lru<V> {
    map: HashMap<Key, (Arc<V>, u64)>,
    clock: u64,
    capacity: usize,
    pub hits: u64,
    pub misses: u64,
}

impl<V> Lru<V> {
    pub(crate) fn new(capacity: usize) -> Lru<V> {
        Lru { map: HashMap::new(), clock: 0, capacity, hits: 0, misses: 0 }
    }

    pub(crate) fn get(&mut self, k: &Key) -> Option<Arc<V>> {
        self.clock += 1;
        match self.map.get_mut(k) {
            Some((v, stamp)) => {
                *stamp = self.clock;
                self.hits += 1;
                Some(v.clone())
            }
            None => {
                self.misses += 1;
                None
            }
        }
    }

    pub(crate) fn insert(&mut self, k: Key, v: Arc<V>) {
        if self.capacity == 0 {
            return;
        }
        self.clock += 1;
        if self.map.len() >= self.capacity && !self.map.contains_key(&k) {
            let oldest = self.map.iter().min_by_key(|(_, (_, s))| *s).map(|(k, _)| k.clone());
            if let Some(old) = oldest {
                self.map.remove(&old);
            }
        }
        self.map.insert(k, (v, self.clock));
    }

    pub(crate) fn len(&self) -> usize {
        self.map.len()
    }

    #[cfg(test)]
    fn is_empty(&self) -> bool {
        self.map.is_empty()
    }

    pub(crate) fn capacity(&self) -> usize {
        self.capacity
    }

    /// Changes the bound (0 disables caching), evicting the oldest entries as needed.
    pub(crate) fn set_capacity(&mut self, capacity: usize) {
        self.capacity = capacity;
        while self.map.len() > capacity {
            let oldest = self.map.iter().min_by_key(|(_, (_, s))| *s).map(|(k, _)| k.clone());
            match oldest {
                Some(old) => self.map.remove(&old),
                None => break,
            };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::span::Span;
    use crate::ir::Input;

    fn key(c: f64) -> Key {
        let mut ir = Ir::new();
        let x = ir.input(Input::NH, Span::default());
        let k = ir.konst(c, Span::default());
        let r = ir.bin(crate::ir::BinOp::Mul, x, k, Span::default());
        Key::new(&ir, r, crate::Mode::Precise)
    }

    #[test]
    fn evicts_least_recently_used() {
        let mut c = Lru::new(2);
        c.insert(key(1.0), Arc::new(1));
        c.insert(key(2.0), Arc::new(2));
        assert!(c.get(&key(1.0)).is_some()); // 1 is now newer than 2
        c.insert(key(3.0), Arc::new(3));
        assert_eq!(c.len(), 2);
        assert!(c.get(&key(2.0)).is_none());
        assert_eq!(c.get(&key(1.0)).as_deref(), Some(&1));
        assert_eq!(c.get(&key(3.0)).as_deref(), Some(&3));
    }

    #[test]
    fn signed_zero_constants_are_distinct_keys() {
        assert_ne!(key(0.0), key(-0.0));
        assert_eq!(key(0.5), key(0.5));
    }

    #[test]
    fn a_cache_compiles_once_per_key_and_reports_errors() {
        let c: Cache<u32> = Cache::new();
        let (a, hit) = c.get_or_compile(key(1.0), || Ok(7)).expect("compiles");
        assert_eq!((*a, hit), (7, false));
        let (b, hit) = c.get_or_compile(key(1.0), || Err(NativeError::internal("not called"))).expect("cached");
        assert!(hit && Arc::ptr_eq(&a, &b));
        assert!(c.get_or_compile(key(2.0), || Err(NativeError::internal("no"))).is_err());
        assert_eq!(c.stats(), (1, 2, 1));
        assert_eq!(c.set_capacity(0), DEFAULT_CAPACITY);
        assert_eq!(c.stats().2, 0);
    }

    #[test]
    fn zero_capacity_disables() {
        let mut c = Lru::new(0);
        c.insert(key(1.0), Arc::new(1));
        assert!(c.is_empty());
    }
}
