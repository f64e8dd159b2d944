//! The signatures generated code is called with, and the one place it is called: every native tier compiles
//! the same four functions, and the safe wrappers here check every length before the `unsafe` call.
//!
//! * prepare: `fn(params: *const f64, block: *mut f64)`: the plan's carried parameter-only nodes;
//! * scalar: `fn(x: *const f64 /* NL NV NH VR VH */, params, block: *const f64) -> f64`;
//! * batch: `fn(cols: *const *const f64 /* 5 column pointers */, params, block, out: *mut f64, len: usize)`;
//! * program: `fn(cols: *const *const f64, params, block, outs: *const *mut f64, len: usize)`.
//!
//! All in the host's C calling convention; none checks anything at run time (the math library's table lookups
//! mask their index inside the generated code, so no input value makes them read outside a table).

use super::{NativeError, Plan};
use crate::backend::program::{Program, MAX_COLUMNS, MAX_OUTPUTS};
use crate::backend::{Backend, Columns, Evaluator, Prepared};
use crate::base::diag::Diagnostic;
use crate::ir::{InputSet, Ir, N_INPUTS};
use std::cell::RefCell;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::Duration;

pub(crate) type ScalarFn = unsafe extern "C" fn(*const f64, *const f64, *const f64) -> f64;
pub(crate) type PrepareFn = unsafe extern "C" fn(*const f64, *mut f64);
pub(crate) type BatchFn = unsafe extern "C" fn(*const *const f64, *const f64, *const f64, *mut f64, usize);
pub(crate) type ProgramFn = unsafe extern "C" fn(*const *const f64, *const f64, *const f64, *const *mut f64, usize);

/// What owns a kernel's machine code (a Cranelift module, an LLVM execution engine), freeing it when dropped.
///
/// # Safety
/// [`KernelCode::batch`] must return the entry of a function with exactly [`BatchFn`]'s signature (the host's
/// C calling convention) that computes the kernel the owner was built for: it reads `len` elements of the
/// columns of the inputs the formula reads, the parameter slots it reads and the plan's block, and writes `len`
/// elements of `out`. The entry must stay valid while `self` lives.
pub(crate) unsafe trait KernelCode: Send + Sync {
    /// The batched kernel: compiled into the owned code now (a tier may build it on the first batch call) or
    /// already there.
    fn batch(&self) -> Result<BatchFn, NativeError>;
}

/// A kernel's machine code from either tier: its entries, what the safe wrappers check, and its owner.
pub(crate) struct NativeCode {
    scalar: ScalarFn,
    /// Computes the prepared parameter block (`None` when nothing is carried: `block_len` = 0).
    prepare: Option<PrepareFn>,
    /// Number of `f64`s in the prepared parameter block.
    block_len: usize,
    /// Unique per compiled kernel (keys the per-thread cache of prepared blocks; addresses can be reused).
    id: u64,
    /// The batched kernel, or `None` when it could not be built (then batches run through scalar calls).
    batch: OnceLock<Option<BatchFn>>,
    /// Parameter slots the code reads (`max index + 1`).
    params_read: usize,
    /// Inputs the code reads (their columns must be full length).
    inputs: InputSet,
    /// Size of the compiled IR (for reports).
    nodes: usize,
    /// The tier that compiled it and the lanes of its batch loop.
    backend: Backend,
    lanes: u32,
    compile_time: Duration,
    /// The memory the entries point into: the last field, so it is dropped after every pointer into it.
    owner: Box<dyn KernelCode>,
}

/// What the safe wrappers check of a kernel's code, from its compacted IR and plan.
pub(crate) struct Shape {
    block_len: usize,
    params_read: usize,
    inputs: InputSet,
    nodes: usize,
}

impl Shape {
    pub(crate) fn of(ir: &Ir, plan: &Plan) -> Shape {
        let root = plan.root;
        Shape {
            block_len: plan.carried.len(),
            params_read: ir.used_params(root).last().map_or(0, |p| *p as usize + 1),
            inputs: ir.used_inputs(root),
            nodes: root.index() + 1,
        }
    }
}

impl NativeCode {
    /// The code of the kernel of shape `shape` (its IR and plan), compiled by `tier` (backend, lanes).
    ///
    /// # Safety
    /// `scalar` and `prepare` must be entries of functions with exactly the C signatures of their types, valid
    /// while `owner` lives, compiled from the IR and plan `shape` describes: `scalar` reads the five inputs at
    /// `x`, the parameter slots the IR reads and the plan's block slots; `prepare` reads the parameters and
    /// writes exactly those block slots.
    pub(crate) unsafe fn new(scalar: ScalarFn, prepare: Option<PrepareFn>, shape: Shape, tier: (Backend, u32), compile_time: Duration, owner: Box<dyn KernelCode>) -> NativeCode {
        static NEXT_ID: AtomicU64 = AtomicU64::new(1);
        NativeCode {
            scalar,
            prepare,
            block_len: shape.block_len,
            id: NEXT_ID.fetch_add(1, Ordering::Relaxed),
            batch: OnceLock::new(),
            params_read: shape.params_read,
            inputs: shape.inputs,
            nodes: shape.nodes,
            backend: tier.0,
            lanes: tier.1,
            compile_time,
            owner,
        }
    }

    /// The batched kernel, compiled on first use (concurrent first callers wait for one compile).
    fn batch(&self) -> Option<BatchFn> {
        *self.batch.get_or_init(|| self.owner.batch().ok())
    }

    /// Computes the prepared block for `params` into `block` (`block_len` long; nothing when empty).
    fn prepare_into(&self, params: &[f64], block: &mut [f64]) {
        if let (Some(prepare), true, true) = (self.prepare, block.len() == self.block_len, params.len() >= self.params_read) {
            // Safety: `params` has every slot the code reads and `block` exactly the `block_len` slots the
            // prepare function writes (both checked just above); the code lives as long as `self`.
            unsafe { prepare(params.as_ptr(), block.as_mut_ptr()) }
        }
    }

    /// Runs `f` with the prepared block for `params`: from this thread's cache when the same kernel ran with
    /// the same parameters recently, else freshly computed (and kept). Kernels with nothing to carry skip it.
    fn with_block<R>(&self, params: &[f64], f: impl FnOnce(&[f64]) -> R) -> R {
        if self.block_len == 0 {
            return f(&[]);
        }
        let same = |e: &CachedBlock| e.id == self.id && e.params.len() == params.len() && e.params.iter().zip(params).all(|(a, b)| *a == b.to_bits());
        PREPARED.with(|cache| match cache.try_borrow_mut() {
            Ok(mut c) => {
                match c.iter().position(same) {
                    Some(0) => {}
                    Some(i) => {
                        let e = c.remove(i);
                        c.insert(0, e);
                    }
                    None => {
                        let mut block = vec![0.0; self.block_len];
                        self.prepare_into(params, &mut block);
                        c.insert(0, CachedBlock { id: self.id, params: params.iter().map(|p| p.to_bits()).collect(), block });
                        c.truncate(PREPARED_KEEP);
                    }
                }
                f(&c[0].block)
            }
            Err(_) => {
                let mut block = vec![0.0; self.block_len];
                self.prepare_into(params, &mut block);
                f(&block)
            }
        })
    }
}

/// A prepared parameter block: what the prepare function computed for one kernel and one parameter vector.
struct CachedBlock {
    id: u64,
    /// The parameters' bit patterns (so −0/+0 and NaN payloads count as different, as they may to the code).
    params: Vec<u64>,
    block: Vec<f64>,
}

/// Blocks kept per thread (most recent first): a scalar evaluation with the same parameters as a recent one
/// reuses its block, which is how parameter-only work runs once per parameter set and not per call.
const PREPARED_KEEP: usize = 8;

thread_local! {
    static PREPARED: RefCell<Vec<CachedBlock>> = const { RefCell::new(Vec::new()) };
}

/// Either tier's compiled kernel as an [`Evaluator`], or its failure as a diagnostic on the formula's file.
pub(crate) fn evaluator(k: Result<NativeKernel, NativeError>) -> Result<Arc<dyn Evaluator>, Diagnostic> {
    k.map(|k| Arc::new(k) as Arc<dyn Evaluator>).map_err(|e| e.to_diagnostic())
}

/// A natively compiled formula behind the [`Evaluator`] interface, whichever tier compiled it.
#[derive(Clone)]
pub struct NativeKernel {
    /// Copy of `code.scalar`, saving a dependent load per call (valid while `code` lives).
    scalar: ScalarFn,
    code: Arc<NativeCode>,
    /// Parameter slots the caller must supply: max(declared, read by the code).
    n_params: usize,
    /// Whether this kernel came from a compiled-code cache.
    pub cached: bool,
    /// The compiler's time for this kernel (zero for a cache hit).
    pub compile_time: Duration,
}

impl NativeKernel {
    /// A kernel of `code` for a formula declaring `declared` parameters.
    pub(crate) fn new(code: Arc<NativeCode>, declared: usize, cached: bool) -> NativeKernel {
        let compile_time = if cached { Duration::ZERO } else { code.compile_time };
        NativeKernel { scalar: code.scalar, n_params: declared.max(code.params_read), code, cached, compile_time }
    }

    /// Whether two kernels share the same machine code (a cache hit).
    pub fn same_code(&self, other: &NativeKernel) -> bool {
        Arc::ptr_eq(&self.code, &other.code)
    }

    /// Number of live IR nodes compiled.
    pub fn nodes(&self) -> usize {
        self.code.nodes
    }

    /// The tier that compiled the kernel ([`Backend::Jit`] or [`Backend::Llvm`]).
    pub fn backend(&self) -> Backend {
        self.code.backend
    }

    /// Lanes of the batch loop.
    pub fn lanes(&self) -> u32 {
        self.code.lanes
    }

    /// `params` padded with NaN to the declared count: a missing parameter is NaN, as in the interpreter.
    fn padded(&self, params: &[f64]) -> Vec<f64> {
        let mut p = params.to_vec();
        p.resize(p.len().max(self.n_params), f64::NAN);
        p
    }

    /// Compiles the batched kernel now rather than on the first batch call (e.g. before timing a render).
    /// Returns whether it is available (if not, batches run through the scalar kernel).
    pub(crate) fn prepare_batch(&self) -> bool {
        self.code.batch().is_some()
    }

    /// Scalar calls over a batch: for ragged columns (interpreter semantics: a missing element reads as 0)
    /// and in the unlikely case that the batched kernel failed to build.
    fn batch_by_scalar(&self, cols: &Columns, params: &[f64], out: &mut [f64]) {
        let mut x = [0.0; N_INPUTS];
        for (i, o) in out.iter_mut().enumerate() {
            for (k, c) in cols.cols.iter().enumerate() {
                x[k] = c.get(i).copied().unwrap_or(0.0);
            }
            *o = self.eval(&x, params);
        }
    }

    /// Batch call with every read column `out.len()` long and `params.len() >= n_params` (checked by the caller).
    fn batch_checked(&self, cols: &Columns, params: &[f64], out: &mut [f64]) {
        let Some(batch) = self.code.batch() else {
            return self.batch_by_scalar(cols, params, out);
        };
        let ptrs: [*const f64; N_INPUTS] = std::array::from_fn(|i| cols.cols[i].as_ptr());
        // A small block lives on the stack: short batches (per-point parameters are batches of one point) then
        // allocate nothing, which was a quarter of their time.
        let (mut small, mut large) = ([0.0; 16], vec![]);
        let block: &mut [f64] = if self.code.block_len <= small.len() {
            &mut small[..self.code.block_len]
        } else {
            large.resize(self.code.block_len, 0.0);
            &mut large
        };
        self.code.prepare_into(params, block);
        // Safety: the caller checked `params.len() >= self.n_params` (every slot the code reads) and that every
        // column the code reads has exactly `out.len()` elements; `block` has the `block_len` slots the code
        // reads. The code reads `len` elements of those columns and writes `len` elements of `out`, which is
        // exclusively borrowed. Unread columns are never dereferenced. The code is alive as long as `self.code`.
        unsafe { batch(ptrs.as_ptr(), params.as_ptr(), block.as_ptr(), out.as_mut_ptr(), out.len()) }
    }
}

/// A native kernel bound to one parameter vector (from [`Evaluator::prepare`]): the parameters padded and the
/// prepared block computed once, so a call is the generated code and nothing else. Borrows the kernel, which
/// keeps the code alive.
pub struct NativeCall<'a> {
    /// Copy of `kernel.scalar`.
    scalar: ScalarFn,
    /// At least `kernel.n_params` slots (missing ones NaN, as in `eval`).
    params: Vec<f64>,
    /// `kernel.code.block_len` slots, computed from `params`.
    block: Vec<f64>,
    kernel: &'a NativeKernel,
}

impl NativeCall<'_> {
    #[inline(always)]
    pub(crate) fn eval(&self, x: &[f64; N_INPUTS]) -> f64 {
        // Safety: `x` has the inputs the code may read; `params` has every slot it reads (padded to `n_params`
        // in `prepare`); `block` was computed from these `params` by this code's prepare function and has its
        // `block_len` slots; `scalar` is `kernel.code.scalar`, alive while `kernel` (borrowed by `self`) lives.
        unsafe { (self.scalar)(x.as_ptr(), self.params.as_ptr(), self.block.as_ptr()) }
    }

    /// The tier whose code this calls.
    pub fn backend(&self) -> Backend {
        self.kernel.backend()
    }
}

impl Evaluator for NativeKernel {
    fn prepare(&self, params: &[f64]) -> Prepared<'_> {
        let params = self.padded(params);
        let mut block = vec![0.0; self.code.block_len];
        self.code.prepare_into(&params, &mut block);
        Prepared::Native(NativeCall { scalar: self.scalar, params, block, kernel: self })
    }

    fn eval(&self, x: &[f64; N_INPUTS], params: &[f64]) -> f64 {
        if params.len() >= self.n_params {
            self.code.with_block(params, |block| {
                // Safety: `x` has the 5 inputs the code may read; `params` has every slot it reads (checked just
                // above); `block` is the prepared block for `params` with the `block_len` slots the code reads
                // (`with_block` guarantees it); `self.scalar` is `self.code.scalar`, alive as long as `self.code`.
                unsafe { (self.scalar)(x.as_ptr(), params.as_ptr(), block.as_ptr()) }
            })
        } else {
            let p = self.padded(params);
            self.eval(x, &p)
        }
    }

    fn warm_up(&self) {
        self.prepare_batch();
    }

    fn eval_batch(&self, cols: &Columns, params: &[f64], out: &mut [f64]) {
        let columns_ok = self.code.inputs.iter().all(|i| cols.col(i).len() == out.len());
        if !columns_ok {
            self.batch_by_scalar(cols, params, out);
        } else if params.len() >= self.n_params {
            self.batch_checked(cols, params, out);
        } else {
            let p = self.padded(params);
            self.batch_checked(cols, &p, out);
        }
    }
}

/// A compiled multi-output program ([`crate::backend::program`]), by either tier: the loop function, the
/// prepare function of its parameter-only work, and what owns their machine code.
pub struct ShadeCode {
    run: ProgramFn,
    prepare: Option<PrepareFn>,
    block_len: usize,
    columns: usize,
    /// Output columns the code writes.
    outputs: usize,
    /// Parameter slots the code reads (`max index + 1`).
    params_read: usize,
    /// The compiler's time for the program (when it was compiled; a cache hit costs nothing).
    pub compile_time: Duration,
    /// The tier that compiled it ([`Backend::Jit`] or [`Backend::Llvm`]).
    pub backend: Backend,
    /// The memory `run` and `prepare` point into, freed when this is dropped (the last field).
    _owner: Box<dyn Send + Sync>,
}

impl ShadeCode {
    /// The code of program `p`, compiled by `backend` with `plan`.
    ///
    /// # Safety
    /// `run` and `prepare` must be entries of functions with exactly the C signatures of their types, valid
    /// while `owner` lives; `run` reads at most `p.columns` columns, `Program::params_read` parameters and the
    /// `plan.carried.len()` block slots, and writes `p.outputs.len()` outputs, `len` elements of each;
    /// `prepare` reads the parameters and writes exactly the block slots.
    pub(crate) unsafe fn new(run: ProgramFn, prepare: Option<PrepareFn>, p: &Program, plan: &Plan, backend: Backend, compile_time: Duration, owner: Box<dyn Send + Sync>) -> ShadeCode {
        ShadeCode {
            run,
            prepare,
            block_len: plan.carried.len(),
            columns: p.columns,
            outputs: p.outputs.len(),
            params_read: p.params_read(),
            compile_time,
            backend,
            _owner: owner,
        }
    }

    /// The prepared parameter block for `params` (computed once per render and material; a missing parameter
    /// is NaN, as in the interpreter).
    pub(crate) fn prepare(&self, params: &[f64]) -> Vec<f64> {
        let mut p = params.to_vec();
        p.resize(p.len().max(self.params_read), f64::NAN);
        let mut block = vec![0.0; self.block_len];
        if let Some(prepare) = self.prepare {
            // Safety: `p` has every slot the code reads (padded just above); `block` has exactly the
            // `block_len` slots the prepare function writes.
            unsafe { prepare(p.as_ptr(), block.as_mut_ptr()) }
        }
        block
    }

    /// Runs the program on `len` elements. Checked: at least the program's columns, each `len` long or more,
    /// one output per program output, each `len` long or more, `params` with every slot read, `block` from
    /// [`ShadeCode::prepare`].
    pub(crate) fn run(&self, cols: &[&[f64]], params: &[f64], block: &[f64], outs: &mut [&mut [f64]], len: usize) -> Result<(), String> {
        if cols.len() < self.columns || cols[..self.columns].iter().any(|c| c.len() < len) {
            return Err(format!("a program needs {} data columns of {len} elements", self.columns));
        }
        if outs.len() != self.outputs || outs.iter().any(|o| o.len() < len) || block.len() != self.block_len {
            return Err("program outputs or block too short".into());
        }
        if params.len() < self.params_read {
            // A missing parameter is NaN, as in the interpreter.
            let mut p = params.to_vec();
            p.resize(self.params_read, f64::NAN);
            return self.run(cols, &p, block, outs, len);
        }
        let mut ptrs = [std::ptr::null::<f64>(); MAX_COLUMNS];
        for (p, c) in ptrs.iter_mut().zip(cols) {
            *p = c.as_ptr();
        }
        let mut out_ptrs = [std::ptr::null_mut::<f64>(); MAX_OUTPUTS];
        for (p, o) in out_ptrs.iter_mut().zip(outs.iter_mut()) {
            *p = o.as_mut_ptr();
        }
        // Safety: checked just above: the `columns` column pointers the code reads each have `len` elements,
        // each of the `outputs` outputs the code writes has `len` elements and is exclusively borrowed
        // (distinct `&mut` slices), `params` has every slot the code reads and `block` the `block_len` slots;
        // the code lives as long as `self`.
        unsafe { (self.run)(ptrs.as_ptr(), params.as_ptr(), block.as_ptr(), out_ptrs.as_ptr(), len) };
        Ok(())
    }
}
