//! Output arrays from a small pool of warm buffers.
//!
//! A new 8 MiB result per call cost ~0.5 ns per point (fresh zero pages faulted in as the kernel writes, or a
//! memset of reused ones): as much as the cheapest formulas' own work. A result is instead a numpy array over a
//! [`Buffer`], a Python object holding a `Vec<f64>`; when numpy lets go of it (the array and every view of it
//! gone), the vector goes back to a process-wide pool, and the next call of a similar size takes it, its pages
//! already mapped and warm, without clearing it: the caller writes every element before the array is made.
//!
//! Each call still returns a fresh array that it alone owns: a buffer is either in the pool or held by exactly
//! one [`Buffer`], and it enters the pool only once that [`Buffer`] is dropped, which numpy does only when no
//! array refers to it. The pool is bounded ([`MAX_BUFFERS`], [`MAX_BYTES`]) and locked (Dask's threads call
//! kernels at once); results shorter than [`MIN_LEN`] or longer than [`MAX_BYTES`] are plain allocations.

use numpy::ndarray::ArrayViewMut1;
use numpy::PyArray1;
use pyo3::prelude::*;
use std::sync::Mutex;

/// Buffers the pool keeps at most.
const MAX_BUFFERS: usize = 4;
/// Bytes the pool keeps at most (a larger result is allocated, and freed, as any other).
const MAX_BYTES: usize = 256 << 20;
/// Results shorter than this (in f64s, 32 KiB) are not pooled: the allocator keeps such blocks warm itself, and
/// a pooled buffer kept alive by a small result would hold memory the pool cannot count on.
const MIN_LEN: usize = 1 << 12;

/// Idle buffers, the most recently returned last; each one's whole length is initialised (it held a result).
static POOL: Mutex<Vec<Vec<f64>>> = Mutex::new(Vec::new());

fn pooled(len: usize) -> bool {
    (MIN_LEN..=MAX_BYTES / 8).contains(&len)
}

/// The pool, even if a thread panicked while holding it (its list of vectors is valid at every step).
fn pool() -> std::sync::MutexGuard<'static, Vec<Vec<f64>>> {
    POOL.lock().unwrap_or_else(|e| e.into_inner())
}

/// An output of `len` f64s, initialised but holding stale values (a previous result's, or zeros): the caller
/// writes every element before handing it to Python ([`Buffer::into_pyarray`]).
#[pyclass(frozen, module = "lobe._lobe")]
pub struct Buffer {
    /// At least `len` elements, all initialised; never resized while a numpy array points into it.
    vec: Vec<f64>,
    len: usize,
}

impl Buffer {
    /// A buffer of `len` values: the smallest idle one holding `len` and at most twice as many (so that a small
    /// result does not keep a large buffer from the pool), else a new zeroed allocation.
    pub fn new(len: usize) -> Buffer {
        if pooled(len) {
            let mut p = pool();
            let fit = p.iter().enumerate().filter(|(_, v)| v.len() >= len && v.len() / 2 <= len).min_by_key(|(_, v)| v.len()).map(|(i, _)| i);
            if let Some(i) = fit {
                return Buffer { vec: p.remove(i), len };
            }
        }
        Buffer { vec: vec![0.0; len], len }
    }

    /// The `len` values, to be written.
    pub fn as_mut_slice(&mut self) -> &mut [f64] {
        &mut self.vec[..self.len]
    }

    /// A numpy array of the `len` values whose base object is this buffer: the vector returns to the pool when
    /// the array and its views are gone.
    pub fn into_pyarray(mut self, py: Python<'_>) -> PyResult<Bound<'_, PyArray1<f64>>> {
        let (ptr, len) = (self.vec.as_mut_ptr(), self.len);
        let owner = Bound::new(py, self)?;
        // Safety: `ptr` points to `len` initialised f64s (`vec` is initialised over its whole length, which is ≥
        // `len`) in the vector's heap block, which moving the `Buffer` into `owner` did not move. That vector is
        // never resized or touched again until `owner` is dropped (the pyclass is frozen and has no method that
        // reaches `vec`), and `borrow_from_array` makes `owner` the array's base, so numpy keeps it alive as long
        // as the array or any view of it. The block is reachable from no other array: it left the pool (or was
        // allocated) for this buffer alone. The pointer comes from `as_mut_ptr`, so numpy may write through it.
        unsafe {
            let view = ArrayViewMut1::from_shape_ptr(len, ptr);
            Ok(PyArray1::borrow_from_array(&view, owner.into_any()))
        }
    }
}

impl Drop for Buffer {
    /// The vector back to the pool (no array refers to it any more), the oldest idle ones freed past the bounds.
    fn drop(&mut self) {
        let vec = std::mem::take(&mut self.vec);
        if !pooled(vec.len()) {
            return;
        }
        let evicted = {
            let mut p = pool();
            p.push(vec);
            let mut total: usize = p.iter().map(Vec::len).sum();
            let mut n = 0;
            while p.len() - n > MAX_BUFFERS || total * 8 > MAX_BYTES {
                total -= p[n].len();
                n += 1;
            }
            p.drain(..n).collect::<Vec<_>>()
        };
        // Freed outside the lock.
        drop(evicted);
    }
}
