//! A bounded cache of compiled code keyed by the simplified IR's structure.
//!
//! Key: the nodes reachable from the root, in topological order (what [`Ir::compact`] produces), plus the root
//! index and the math mode. Spans and names are not part of the key, so the same formula from two files, or compiled twice,
//! hits. Constants are keyed by bit pattern, so `0` and `-0` are different formulas, as they are to IEEE.
//!
//! Bounded LRU: at most `capacity` entries; inserting into a full cache evicts the least recently used one
//! (an O(capacity) scan, negligible next to a compile). Entries hold `Arc`s, so evicted code lives on until
//! the last kernel using it is dropped, then its JIT memory is freed.

use crate::builtins::Mode;
use crate::ir::{Ir, Node};
use std::collections::HashMap;
use std::sync::Arc;

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
    fn zero_capacity_disables() {
        let mut c = Lru::new(0);
        c.insert(key(1.0), Arc::new(1));
        assert!(c.is_empty());
    }
}
