//! The Cranelift JIT: a simplified [`Formula`] → native scalar and batched kernels.
//!
//! Design (after bytecodealliance/cranelift-jit-demo, stricter):
//! - a [`Jit`] owns the reusable Cranelift contexts; one per thread (compiles run in parallel);
//! - `codegen` has one translator, generic over the lane type (`F64` for the scalar kernel and the batch tail,
//!   `F64X2` for the batch loop), with one method per IR node kind; it never sees user text, never panics;
//! - builtins come from the one table: `Lowering::Inline` becomes a native instruction, `Lowering::Math` the
//!   math library's code (`builtins::math`) emitted inline in the kernel's lanes — the definition the
//!   interpreter runs on `f64`, so the two backends agree bit for bit in each math mode; the only calls are the
//!   trigonometric fallbacks to libm for huge arguments and, on a host without FMA, Cranelift's `fma` libcall
//!   (a correctly rounded fma: same bits), registered with `JITBuilder::symbol` before anything is finalized
//!   (an unresolved import would panic inside Cranelift);
//! - parameter-only work is computed once per parameter set by a prepare function into a block the kernels
//!   load (the prepared parameter block: held by a [`PreparedJit`] from `Evaluator::prepare`, cached per thread
//!   for plain scalar calls, computed once per batch);
//! - one `JITModule` per compiled formula: the scalar kernel and the prepare function are compiled at once,
//!   the batched kernel is added to the same module on the first batch call; its memory is freed when the
//!   last kernel using it is dropped;
//! - a bounded LRU cache keyed by the simplified IR's structure, so compiling a formula twice is free;
//! - live parameters are loads from the `params` slice, so changing them needs no recompilation; baked ones
//!   are already constants in the IR.
//!
//! The only `unsafe` in lobe is here: calling the generated code (the safe wrapper validates every length
//! first, so no input from safe code can make it read or write out of bounds; the math library's table
//! lookups clamp their index inside the generated code) and freeing its memory.
//!
//! Cost model. Compiling is Cranelift's work: a fixed per-module cost plus roughly linear in the nodes; the
//! batched kernel (a loop and two copies of the body) costs more than the scalar one, hence built lazily. A
//! plain scalar call pays a fixed dispatch (`Kernel` → `dyn Evaluator` → length check → per-thread block
//! lookup → generated code) on top of the body, which dominates short arithmetic formulas; a prepared call
//! ([`PreparedJit`]) pays only a `match` and the indirect call; the batched kernel pays it once per batch, runs two
//! lanes per instruction, and does each clamp against a constant as one `maxpd`/`minpd`. A transcendental
//! builtin is 20–200 vector instructions (pow the most: double-double in precise mode), straight-line except
//! for rarely taken special-case blocks; scalar code runs the same instructions one lane at a time, where its
//! selects become branches. Measured compile times and ns/eval against the interpreter and hand-written Rust:
//! BENCHMARKS.md.

// The one module allowed `unsafe`: calling and freeing generated code (each block has its `# Safety` note).
#![allow(unsafe_code)]

pub(crate) mod cache;
pub use codegen::OUTLINE_AT;
mod codegen;
// Where each node is computed and when the library is called rather than inlined: the LLVM tier's too.
#[cfg(feature = "llvm")]
pub(crate) use codegen::{outlines, Plan};
#[cfg(feature = "llvm")]
pub(crate) use codegen::shade::{outlines as program_outlines, plan as program_plan};

use crate::base::diag::Diagnostic;
use crate::ir::{Formula, InputSet, Ir, NodeId, N_INPUTS};
use crate::backend::program::{MAX_COLUMNS, MAX_OUTPUTS};
use crate::backend::{Columns, Evaluator, Prepared};
use crate::builtins::Mode;
use cranelift_codegen::ir::UserFuncName;
use cranelift_codegen::isa::OwnedTargetIsa;
use cranelift_codegen::settings::{self, Configurable};
use cranelift_codegen::Context;
use cranelift_frontend::FunctionBuilderContext;
use cranelift_jit::{JITBuilder, JITModule};
use cranelift_module::{default_libcall_names, FuncId, Module, ModuleError};
use std::cell::RefCell;
use std::fmt;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};

/// Why code generation failed. None of these is caused by the formula's text (the front end rejects bad
/// input); they mean an unsupported host or an internal error, and are reported as a [`Diagnostic`].
#[derive(Debug)]
pub enum JitError {
    /// The host CPU is not supported by Cranelift, or a flag was rejected.
    Host(String),
    /// Cranelift rejected the generated function or could not allocate executable memory.
    Module(String),
    /// A broken invariant in lobe itself (a bug): reported instead of panicking.
    Internal(String),
}

impl fmt::Display for JitError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            JitError::Host(m) => write!(f, "the JIT cannot target this machine: {m}"),
            JitError::Module(m) => write!(f, "the JIT failed to compile the formula: {m}"),
            JitError::Internal(m) => write!(f, "internal JIT error: {m}"),
        }
    }
}

impl std::error::Error for JitError {}

impl From<ModuleError> for JitError {
    fn from(e: ModuleError) -> JitError {
        JitError::Module(e.to_string())
    }
}

impl JitError {
    /// The error as a diagnostic, with a hint to fall back to the interpreter.
    pub(crate) fn to_diagnostic(&self) -> Diagnostic {
        Diagnostic::error(self.to_string()).hint(crate::base::diag::Hint::UseInterpreter)
    }
}

/// The target ISA for this host, built once per process (cloning it is an `Arc` clone).
fn host_isa() -> Result<OwnedTargetIsa, JitError> {
    static ISA: OnceLock<Result<OwnedTargetIsa, String>> = OnceLock::new();
    ISA.get_or_init(|| {
        let mut fb = settings::builder();
        let flags: [(&str, &str); 5] = [
            ("opt_level", "speed"),
            ("use_colocated_libcalls", "false"),
            ("is_pic", "false"),
            // The verifier costs ~30% of compile time; keep it in debug builds (tests), drop it in release.
            ("enable_verifier", if cfg!(debug_assertions) { "true" } else { "false" }),
            // Generated code never unwinds (builtins do not panic), so no unwind tables.
            ("unwind_info", "false"),
        ];
        for (k, v) in flags {
            fb.set(k, v).map_err(|e| format!("flag {k}={v}: {e}"))?;
        }
        let isa = cranelift_native::builder().map_err(|e| e.to_string())?;
        isa.finish(settings::Flags::new(fb)).map_err(|e| e.to_string())
    })
    .clone()
    .map_err(JitError::Host)
}

/// Whether the host ISA has a native fused multiply-add (the math library's two-products use it then).
fn host_fma() -> bool {
    host_isa().is_ok_and(|isa| isa.has_native_fma())
}

extern "C" fn fma_libcall(a: f64, b: f64, c: f64) -> f64 {
    a.mul_add(b, c)
}

/// Symbols Cranelift's own lowering may call: `fma` (per lane, on a host without the instruction) as Rust's
/// correctly rounded `mul_add`, so the math library's `fma` has the same bits everywhere.
fn runtime_symbols(builder: &mut JITBuilder) {
    builder.symbol("fma", fma_libcall as *const u8);
}

type ScalarFn = unsafe extern "C" fn(*const f64, *const f64, *const f64) -> f64;
pub(crate) type PrepareFn = unsafe extern "C" fn(*const f64, *mut f64);
type BatchFn = unsafe extern "C" fn(*const *const f64, *const f64, *const f64, *mut f64, usize);

/// Finalized machine code for one formula: the module that owns the memory and the entry points.
///
/// The scalar kernel is compiled eagerly; the batched kernel (about 60% of the compile time: a loop and two
/// copies of the body) is defined in the same module on the first batch call, so kernels that are only ever
/// evaluated point by point (the numerical checks) never pay for it.
pub(crate) struct Compiled {
    /// The memory the entry points below point into.
    code: Code,
    scalar: ScalarFn,
    /// Computes the prepared parameter block (`None` when nothing is carried: `block_len` = 0).
    prepare: Option<PrepareFn>,
    /// Number of `f64`s in the prepared parameter block.
    block_len: usize,
    /// Unique per compiled module (keys the per-thread cache of prepared blocks; addresses can be reused).
    id: u64,
    /// The batched kernel, or why it could not be built (then batches fall back to scalar calls).
    batch: OnceLock<Result<BatchFn, String>>,
    /// The compacted IR, its plan and the imports, kept to build the batched kernel later.
    ir: Ir,
    plan: codegen::Plan,
    imports: codegen::Imports,
    /// The math mode the code was generated in.
    mode: Mode,
    /// Number of parameter slots the code reads (`max index + 1`).
    params_read: usize,
    /// Inputs the code reads (their columns must be full length).
    inputs: InputSet,
    /// Size of the compiled IR (for reports).
    pub nodes: usize,
}

impl Compiled {
    /// The batched kernel, compiled on first use (concurrent first callers wait for one compile).
    fn batch(&self) -> Option<BatchFn> {
        let r = self.batch.get_or_init(|| {
            let w = codegen::Build { ir: &self.ir, plan: &self.plan, imports: &self.imports, mode: self.mode, fma: host_fma(), outline: codegen::outlines(&self.ir) };
            self.code.with_module(|module| with_jit(|j| j.define_batch(module, &w))).map_err(|e| e.to_string())
        });
        r.as_ref().ok().copied()
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

impl Compiled {
    /// Computes the prepared block for `params` into `block` (`block_len` long; nothing when empty).
    fn prepare_into(&self, params: &[f64], block: &mut [f64]) {
        if let (Some(prepare), true) = (self.prepare, block.len() == self.block_len) {
            // Safety: callers pass `params` with every slot the code reads (`JitKernel` pads it to `n_params`);
            // `block` has exactly the `block_len` slots the prepare function writes (checked just above).
            unsafe { prepare(params.as_ptr(), block.as_mut_ptr()) }
        }
    }

    /// Runs `f` with the prepared block for `params`: from this thread's cache when the same kernel ran with
    /// the same parameters recently, else freshly computed (and kept). Formulas with nothing to carry skip it.
    fn with_block<R>(&self, params: &[f64], f: impl FnOnce(&[f64]) -> R) -> R {
        if self.block_len == 0 {
            return f(&[]);
        }
        let same = |e: &CachedBlock| {
            e.id == self.id && e.params.len() == params.len() && e.params.iter().zip(params).all(|(a, b)| *a == b.to_bits())
        };
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

/// JIT memory: one `JITModule` for the host, its code freed when this is dropped. The one owner of
/// generated code, for kernels ([`Compiled`]) and multi-output programs ([`ShadeCode`]) alike.
///
/// Function pointers into the module are handed out only to the struct that holds this `Code` as a field
/// (and to nobody when a compile fails: then the `Code` is dropped inside the compile function). Dropping a
/// `JITModule` without `free_memory` would leak it (cranelift-jit keeps escaped pointers valid that way), so
/// this frees it explicitly.
pub(crate) struct Code {
    /// Locked only to add a function to a finalized module (the batched kernel) and to free the code; the
    /// `Mutex` also makes the holder `Sync` without `unsafe`.
    module: Mutex<Option<JITModule>>,
}

impl Code {
    /// A fresh module for the host ISA resolving `ir`'s math symbols in `mode` and the runtime's (`fma`).
    fn for_ir(ir: &Ir, mode: Mode, outline: bool) -> Result<Code, JitError> {
        let mut builder = JITBuilder::with_isa(host_isa()?, default_libcall_names());
        for (sym, ptr) in codegen::used_symbols(ir, mode, outline) {
            builder.symbol(sym, ptr);
        }
        runtime_symbols(&mut builder);
        Ok(Code::owning(JITModule::new(builder)))
    }

    /// Takes ownership of `module` (its memory is freed with this `Code`).
    fn owning(module: JITModule) -> Code {
        Code { module: Mutex::new(Some(module)) }
    }

    /// The module, while this `Code` is exclusively held (during a compile).
    fn module_mut(&mut self) -> Result<&mut JITModule, JitError> {
        match self.module.get_mut() {
            Ok(m) => m.as_mut(),
            Err(poisoned) => poisoned.into_inner().as_mut(),
        }
        .ok_or(JitError::Internal("JIT module already freed".into()))
    }

    /// Runs `f` on the module under its lock (to add a function to shared code).
    fn with_module<R>(&self, f: impl FnOnce(&mut JITModule) -> Result<R, JitError>) -> Result<R, JitError> {
        let mut guard = self.module.lock().map_err(|_| JitError::Internal("JIT module lock poisoned".into()))?;
        f(guard.as_mut().ok_or(JitError::Internal("JIT module already freed".into()))?)
    }
}

impl Drop for Code {
    fn drop(&mut self) {
        let module = match self.module.get_mut() {
            Ok(m) => m.take(),
            Err(poisoned) => poisoned.into_inner().take(),
        };
        if let Some(m) = module {
            // Safety: every pointer into this module's memory is a field of the struct that owns this `Code`
            // (`Compiled`, `ShadeCode`), or never left a failed compile; that struct is being dropped, and its
            // users hold it through an `Arc`, so no code can be called after this point and no call is running
            // (a running call borrows its owner).
            unsafe { m.free_memory() };
        }
    }
}

/// Owns the reusable Cranelift contexts (one per thread, see [`with_jit`]).
pub(crate) struct Jit {
    ctx: Context,
    fctx: FunctionBuilderContext,
    /// When set, the machine code listing of each function compiled is kept in `listing`.
    disasm: bool,
    listing: Vec<String>,
}

impl Default for Jit {
    fn default() -> Self {
        Jit::new()
    }
}

impl Jit {
    pub(crate) fn new() -> Jit {
        Jit { ctx: Context::new(), fctx: FunctionBuilderContext::new(), disasm: false, listing: vec![] }
    }

    fn keep_listing(&mut self) {
        if self.disasm {
            let text = self.ctx.compiled_code().and_then(|c| c.vcode.clone()).unwrap_or_default();
            self.listing.push(text);
        }
    }

    /// Defines one function of signature `sig` in `module`, built by `build`.
    fn define(
        &mut self,
        module: &mut JITModule,
        sig: &cranelift_codegen::ir::Signature,
        build: impl FnOnce(&mut JITModule, &mut Context, &mut FunctionBuilderContext) -> Result<(), JitError>,
    ) -> Result<FuncId, JitError> {
        let id = module.declare_anonymous_function(sig)?;
        module.clear_context(&mut self.ctx);
        self.ctx.func.name = UserFuncName::user(0, id.as_u32());
        let built = build(module, &mut self.ctx, &mut self.fctx);
        let defined = built.and_then(|()| {
            self.ctx.set_disasm(self.disasm);
            module.define_function(id, &mut self.ctx).map_err(JitError::from)
        });
        self.keep_listing();
        module.clear_context(&mut self.ctx);
        defined.map(|()| id)
    }

    /// The finalized address of `id`, checked.
    fn address(module: &JITModule, id: FuncId) -> Result<*const u8, JitError> {
        let p = module.get_finalized_function(id);
        if p.is_null() {
            return Err(JitError::Internal("finalized function has no address".into()));
        }
        Ok(p)
    }

    /// Defines the scalar kernel and, when the plan carries nodes, the prepare function; finalizes them.
    fn define_scalar(&mut self, module: &mut JITModule, w: &codegen::Build) -> Result<(ScalarFn, Option<PrepareFn>), JitError> {
        let scalar = self.define(module, &codegen::scalar_signature(module), |m, c, f| codegen::build_scalar(m, c, f, w))?;
        let prepare = if w.plan.carried.is_empty() {
            None
        } else {
            Some(self.define(module, &codegen::prepare_signature(module), |m, c, f| codegen::build_prepare(m, c, f, w))?)
        };
        module.finalize_definitions()?;
        let scalar = Self::address(module, scalar)?;
        let prepare = prepare.map(|id| Self::address(module, id)).transpose()?;
        // Safety: each address is the entry of a function just compiled with exactly the signature of the type it
        // becomes (declared with the host's C calling convention); it stays valid while `module` lives, and the
        // caller's `Compiled` owns the module.
        Ok(unsafe {
            (
                std::mem::transmute::<*const u8, ScalarFn>(scalar),
                prepare.map(|p| std::mem::transmute::<*const u8, PrepareFn>(p)),
            )
        })
    }

    /// Adds the batched kernel to an already finalized module (new code goes to new pages; the scalar
    /// kernel's pages are untouched, so it may run concurrently).
    fn define_batch(&mut self, module: &mut JITModule, w: &codegen::Build) -> Result<BatchFn, JitError> {
        let id = self.define(module, &codegen::batch_signature(module), |m, c, f| codegen::build_batch(m, c, f, w))?;
        module.finalize_definitions()?;
        let p = Self::address(module, id)?;
        // Safety: `p` is the entry of the function just compiled with exactly `BatchFn`'s signature (declared
        // with the host's C calling convention); it stays valid while the module lives, which `Compiled` owns.
        Ok(unsafe { std::mem::transmute::<*const u8, BatchFn>(p) })
    }

    /// Compiles a compacted IR (every node reachable from `root`, root last) into a fresh module. Only the
    /// scalar kernel (and the prepare function) is built now; the batched one on the first batch call.
    pub(crate) fn translate(&mut self, ir: &Ir, root: NodeId, mode: Mode) -> Result<Compiled, JitError> {
        if root.index() >= ir.len() {
            return Err(JitError::Internal("root outside the arena".into()));
        }
        let outline = codegen::outlines(ir);
        // On an error below, `code` is dropped (its memory freed) before any pointer into it escapes.
        let mut code = Code::for_ir(ir, mode, outline)?;
        let module = code.module_mut()?;
        let plan = codegen::Plan::new(ir, root);
        let imports = codegen::declare_imports(module, ir, mode, outline)?;
        let w = codegen::Build { ir, plan: &plan, imports: &imports, mode, fma: host_fma(), outline };
        let (scalar, prepare) = self.define_scalar(module, &w)?;
        let params_read = ir.used_params(root).last().map_or(0, |p| *p as usize + 1);
        static NEXT_ID: AtomicU64 = AtomicU64::new(1);
        Ok(Compiled {
            code,
            scalar,
            prepare,
            block_len: plan.carried.len(),
            id: NEXT_ID.fetch_add(1, Ordering::Relaxed),
            batch: OnceLock::new(),
            ir: ir.clone(),
            plan,
            imports,
            mode,
            params_read,
            inputs: ir.used_inputs(root),
            nodes: root.index() + 1,
        })
    }
}

thread_local! {
    static JIT: RefCell<Jit> = RefCell::new(Jit::new());
}

/// Runs `f` with this thread's [`Jit`] (a fresh one if it is already in use, e.g. re-entrantly).
pub(crate) fn with_jit<R>(f: impl FnOnce(&mut Jit) -> R) -> R {
    JIT.with(|j| match j.try_borrow_mut() {
        Ok(mut j) => f(&mut j),
        Err(_) => f(&mut Jit::new()),
    })
}

/// Default bound of the compiled-code cache (entries; each is a few KiB of code).
pub(crate) const DEFAULT_CACHE_CAPACITY: usize = 128;

fn cache() -> &'static Mutex<cache::Lru<Compiled>> {
    static CACHE: OnceLock<Mutex<cache::Lru<Compiled>>> = OnceLock::new();
    CACHE.get_or_init(|| Mutex::new(cache::Lru::new(DEFAULT_CACHE_CAPACITY)))
}

fn lock_cache() -> std::sync::MutexGuard<'static, cache::Lru<Compiled>> {
    // A panic while holding the lock cannot leave the map inconsistent (each operation is one map call).
    cache().lock().unwrap_or_else(|p| p.into_inner())
}

/// Changes the cache bound (0 disables it); returns the previous bound.
pub fn set_cache_capacity(capacity: usize) -> usize {
    let mut c = lock_cache();
    let old = c.capacity();
    c.set_capacity(capacity);
    old
}

/// (hits, misses, entries) of the compiled-code cache since the process started.
pub fn cache_stats() -> (u64, u64, usize) {
    let c = lock_cache();
    (c.hits, c.misses, c.len())
}

/// A JIT-compiled formula behind the [`Evaluator`] interface.
#[derive(Clone)]
pub struct JitKernel {
    /// Copy of `code.scalar`, saving a dependent load per call (valid while `code` lives).
    scalar: ScalarFn,
    code: Arc<Compiled>,
    /// Parameter slots the caller must supply: max(declared, read by the code).
    n_params: usize,
    /// Whether this kernel came from the cache.
    pub cached: bool,
}

/// Compiles a simplified formula (through the cache) with the builtins of math mode `mode`.
pub fn jit_kernel(f: &Formula, mode: Mode) -> Result<JitKernel, JitError> {
    let (ir, root) = f.ir.compact(f.root);
    let key = cache::Key::new(&ir, root, mode);
    let hit = lock_cache().get(&key);
    let (code, cached) = match hit {
        Some(c) => (c, true),
        None => {
            let c = Arc::new(with_jit(|j| j.translate(&ir, root, mode))?);
            lock_cache().insert(key, c.clone());
            (c, false)
        }
    };
    Ok(JitKernel { n_params: f.params.len().max(code.params_read), scalar: code.scalar, code, cached })
}

/// The machine code (Cranelift's listing) of the scalar and the batched kernel, for `lobe` reports and for
/// checking what the code generator emits (e.g. that the scalar kernel has no stack traffic).
pub fn disassemble(f: &Formula, mode: Mode) -> Result<(String, String), JitError> {
    let (ir, root) = f.ir.compact(f.root);
    let mut j = Jit::new();
    j.disasm = true;
    let c = j.translate(&ir, root, mode)?;
    let w = codegen::Build { ir: &c.ir, plan: &c.plan, imports: &c.imports, mode: c.mode, fma: host_fma(), outline: codegen::outlines(&c.ir) };
    c.code.with_module(|module| j.define_batch(module, &w))?;
    // The listings are in definition order: scalar, prepare (when the formula has a prepared block), batch.
    let l = std::mem::take(&mut j.listing);
    Ok((l.first().cloned().unwrap_or_default(), l.last().cloned().unwrap_or_default()))
}

/// The machine code (Cranelift's listing) of a multi-output program's loop, for checking what it compiles to.
pub fn disassemble_program(p: &crate::backend::program::Program, mode: Mode) -> Result<String, JitError> {
    let mut j = Jit::new();
    j.disasm = true;
    j.translate_program(p, mode)?;
    Ok(j.listing.into_iter().next().unwrap_or_default())
}

/// Compiles without consulting or filling the cache (for compile-time measurements and tests).
pub fn jit_kernel_uncached(f: &Formula, mode: Mode) -> Result<JitKernel, JitError> {
    let (ir, root) = f.ir.compact(f.root);
    let code = Arc::new(with_jit(|j| j.translate(&ir, root, mode))?);
    Ok(JitKernel { n_params: f.params.len().max(code.params_read), scalar: code.scalar, code, cached: false })
}

impl JitKernel {
    /// Whether two kernels share the same machine code (a cache hit).
    pub fn same_code(&self, other: &JitKernel) -> bool {
        Arc::ptr_eq(&self.code, &other.code)
    }

    /// Number of live IR nodes compiled.
    pub fn nodes(&self) -> usize {
        self.code.nodes
    }

    /// `params` padded with NaN to the declared count: a missing parameter is NaN, as in the interpreter.
    fn padded(&self, params: &[f64]) -> Vec<f64> {
        let mut p = params.to_vec();
        p.resize(self.n_params, f64::NAN);
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

    /// Batch call with all lengths already checked.
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

/// A JIT kernel bound to one parameter vector: the parameters padded and the prepared block computed once, so a
/// call is the generated code and nothing else. Borrows the kernel, which keeps the code alive.
pub struct PreparedJit<'a> {
    /// Copy of `kernel.code.scalar`.
    scalar: ScalarFn,
    /// At least `kernel.n_params` slots (missing ones NaN, as in `eval`).
    params: Vec<f64>,
    /// `kernel.code.block_len` slots, computed from `params`.
    block: Vec<f64>,
    /// Holds the borrow that keeps the code alive while this is used.
    _kernel: &'a JitKernel,
}

impl PreparedJit<'_> {
    #[inline(always)]
    pub(crate) fn eval(&self, x: &[f64; N_INPUTS]) -> f64 {
        // Safety: `x` has the inputs the code may read; `params` has every slot it reads (padded to `n_params`
        // in `prepare`); `block` was computed from these `params` by this code's prepare function and has its
        // `block_len` slots; `scalar` is `kernel.code.scalar`, alive while `kernel` (borrowed by `self`) lives.
        unsafe { (self.scalar)(x.as_ptr(), self.params.as_ptr(), self.block.as_ptr()) }
    }
}

impl Evaluator for JitKernel {
    fn prepare(&self, params: &[f64]) -> Prepared<'_> {
        let params = if params.len() >= self.n_params { params.to_vec() } else { self.padded(params) };
        let mut block = vec![0.0; self.code.block_len];
        self.code.prepare_into(&params, &mut block);
        Prepared::Jit(PreparedJit { scalar: self.scalar, params, block, _kernel: self })
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

/// A compiled program's loop: `(cols, params, block, outs, len)`, the ABI both JIT tiers emit.
pub(crate) type ProgramFn = unsafe extern "C" fn(*const *const f64, *const f64, *const f64, *const *mut f64, usize);

/// A compiled multi-output program ([`crate::backend::program`]), by either JIT tier: the loop function, the
/// prepare function of its parameter-only work, and what owns their machine code (a Cranelift module or an
/// LLVM execution engine).
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
    pub compile_time: std::time::Duration,
    /// The tier that compiled it ([`crate::Backend::Jit`] or [`crate::Backend::Llvm`]).
    pub backend: crate::backend::Backend,
    /// The memory `run` and `prepare` point into, freed when this is dropped.
    _owner: Box<dyn Send + Sync>,
}

fn shade_cache() -> &'static Mutex<cache::Lru<ShadeCode>> {
    static CACHE: OnceLock<Mutex<cache::Lru<ShadeCode>>> = OnceLock::new();
    CACHE.get_or_init(|| Mutex::new(cache::Lru::new(DEFAULT_CACHE_CAPACITY)))
}

/// Compiles a multi-output program (through a cache keyed like the kernels': the IR's structure, its roots and
/// the math mode), so a frame whose parameters changed reuses the code.
pub(crate) fn shade_code(p: &crate::backend::program::Program, mode: Mode) -> Result<Arc<ShadeCode>, JitError> {
    let key = cache::Key::of_program(p, mode);
    let lock = || shade_cache().lock().unwrap_or_else(|e| e.into_inner());
    let hit = lock().get(&key);
    if let Some(c) = hit {
        return Ok(c);
    }
    let t = std::time::Instant::now();
    let mut c = with_jit(|j| j.translate_program(p, mode))?;
    c.compile_time = t.elapsed();
    let c = Arc::new(c);
    lock().insert(key, c.clone());
    Ok(c)
}

impl Jit {
    /// Compiles a multi-output program into a fresh module: its loop and (when something is carried) its
    /// prepare function.
    fn translate_program(&mut self, p: &crate::backend::program::Program, mode: Mode) -> Result<ShadeCode, JitError> {
        let outline = codegen::shade::outlines(p);
        // On an error below, `code` is dropped (its memory freed) before any pointer into it escapes.
        let mut code = Code::for_ir(&p.ir, mode, outline)?;
        let module = code.module_mut()?;
        let plan = codegen::shade::plan(p)?;
        let imports = codegen::declare_imports(module, &p.ir, mode, outline)?;
        let w = codegen::Build { ir: &p.ir, plan: &plan, imports: &imports, mode, fma: host_fma(), outline };
        let sig = codegen::shade::signature(module);
        let run = self.define(module, &sig, |m, c, f| codegen::shade::build(m, c, f, &w, p))?;
        let prepare = if plan.carried.is_empty() {
            None
        } else {
            let sig = codegen::prepare_signature(module);
            Some(self.define(module, &sig, |m, c, f| codegen::build_prepare(m, c, f, &w))?)
        };
        module.finalize_definitions()?;
        let run = Self::address(module, run)?;
        let prepare = prepare.map(|id| Self::address(module, id)).transpose()?;
        let block_len = plan.carried.len();
        // Safety: each address is the entry of a function just compiled with exactly the signature of the type
        // it becomes (the host's C calling convention); it stays valid while `module` lives, which the returned
        // `ShadeCode` owns. The loop reads `p.columns` columns, the parameters and `block_len` block slots, and
        // writes each output, `len` elements (codegen::shade).
        unsafe {
            let (run, prepare) = (std::mem::transmute::<*const u8, ProgramFn>(run), prepare.map(|q| std::mem::transmute::<*const u8, PrepareFn>(q)));
            Ok(ShadeCode::from_parts(run, prepare, block_len, p, crate::backend::Backend::Jit, Box::new(code)))
        }
    }
}

impl ShadeCode {
    /// The code of program `p` ([`crate::backend::program::Program`]), compiled by `backend`.
    ///
    /// # Safety
    /// `run` and `prepare` must be entries of functions with exactly the C signatures of their types, valid
    /// while `owner` lives; `run` reads at most `p.columns` columns, `Program::params_read` parameters and `block_len`
    /// block slots, and writes `p.outputs.len()` outputs, `len` elements of each; `prepare` reads the
    /// parameters and writes exactly `block_len` slots.
    pub(crate) unsafe fn from_parts(
        run: ProgramFn,
        prepare: Option<PrepareFn>,
        block_len: usize,
        p: &crate::backend::program::Program,
        backend: crate::backend::Backend,
        owner: Box<dyn Send + Sync>,
    ) -> ShadeCode {
        ShadeCode {
            run,
            prepare,
            block_len,
            columns: p.columns,
            outputs: p.outputs.len(),
            params_read: p.params_read(),
            compile_time: std::time::Duration::ZERO,
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
        // each of the `outputs` outputs the code writes has `len` elements and is exclusively borrowed (distinct `&mut` slices), `params` has
        // every slot the code reads and `block` the `block_len` slots; the code lives as long as `self`.
        unsafe { (self.run)(ptrs.as_ptr(), params.as_ptr(), block.as_ptr(), out_ptrs.as_ptr(), len) };
        Ok(())
    }
}

/// Compiles `f` with the JIT and reports failure as a diagnostic on the formula's file.
pub(crate) fn kernel_evaluator(f: &Formula, mode: Mode) -> Result<Arc<dyn Evaluator>, Diagnostic> {
    jit_kernel(f, mode).map(|k| Arc::new(k) as Arc<dyn Evaluator>).map_err(|e| e.to_diagnostic())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::span::Span;
    use crate::ir::Input;

    #[test]
    fn bad_root_is_an_error_not_a_panic() {
        let mut ir = Ir::new();
        ir.input(Input::NH, Span::default());
        let e = Jit::new().translate(&ir, NodeId(7), Mode::Precise).err().map(|e| e.to_string());
        assert_eq!(e.as_deref(), Some("internal JIT error: root outside the arena"));
    }

    #[test]
    fn errors_become_diagnostics_with_a_fallback_hint() {
        let d = JitError::Module("out of memory".into()).to_diagnostic();
        assert!(d.message.contains("out of memory"));
        assert!(d.hints.contains(&crate::base::diag::Hint::UseInterpreter));
    }

    /// On a host without FMA (simulated: the host ISA with `has_fma` off), Cranelift lowers `fma` to a call
    /// of the `fma` symbol, per lane for F64X2; [`runtime_symbols`] resolves it to a correctly rounded fma.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn fma_without_the_instruction_is_still_correctly_rounded() {
        use cranelift_codegen::ir::{types, AbiParam, InstBuilder};
        use cranelift_frontend::FunctionBuilder;
        let mut fb = settings::builder();
        for (k, v) in [("opt_level", "speed"), ("use_colocated_libcalls", "false"), ("is_pic", "false")] {
            fb.set(k, v).expect("flag");
        }
        let mut ib = cranelift_native::builder().expect("host supported");
        ib.set("has_fma", "false").expect("x86-64 has the setting");
        let isa = ib.finish(settings::Flags::new(fb)).expect("isa");
        assert!(!isa.has_native_fma());
        let mut builder = JITBuilder::with_isa(isa, default_libcall_names());
        runtime_symbols(&mut builder);
        let mut code = Code::owning(JITModule::new(builder));
        let module = code.module_mut().expect("fresh module");
        let mut ctx = module.make_context();
        let mut fctx = FunctionBuilderContext::new();
        let mut ids = vec![];
        for (i, vector) in [false, true].into_iter().enumerate() {
            module.clear_context(&mut ctx);
            for _ in 0..3 {
                ctx.func.signature.params.push(AbiParam::new(types::F64));
            }
            ctx.func.signature.returns.push(AbiParam::new(types::F64));
            let mut b = FunctionBuilder::new(&mut ctx.func, &mut fctx);
            let block = b.create_block();
            b.append_block_params_for_function_params(block);
            b.switch_to_block(block);
            b.seal_block(block);
            let p = b.block_params(block).to_vec();
            let r = if vector {
                let v: Vec<_> = p.iter().map(|&x| b.ins().splat(types::F64X2, x)).collect();
                let f = b.ins().fma(v[0], v[1], v[2]);
                b.ins().extractlane(f, 1)
            } else {
                b.ins().fma(p[0], p[1], p[2])
            };
            b.ins().return_(&[r]);
            b.finalize(module.target_config());
            let id = module.declare_function(&format!("f{i}"), cranelift_module::Linkage::Local, &ctx.func.signature).expect("declare");
            module.define_function(id, &mut ctx).expect("define");
            ids.push(id);
        }
        module.finalize_definitions().expect("every symbol resolves");
        let (a, b, c) = (1.0 + 2f64.powi(-30), 1.0 - 2f64.powi(-30), -1.0);
        assert_eq!(a * b + c, 0.0, "the unfused result differs");
        for id in ids {
            let f = module.get_finalized_function(id);
            // Safety: `f` was just compiled with signature (f64, f64, f64) -> f64 and `code` outlives the call.
            let call = unsafe { std::mem::transmute::<*const u8, extern "C" fn(f64, f64, f64) -> f64>(f) };
            assert_eq!(call(a, b, c), -(2f64.powi(-60)));
            assert_eq!(call(0.1, 10.0, -1.0).to_bits(), 0.1f64.mul_add(10.0, -1.0).to_bits());
        }
        // Dropping `code` frees the module; no pointer into it is used after this point.
        drop(code);
    }

    #[test]
    fn host_isa_is_built_once() {
        let isa = host_isa().expect("host supported");
        assert_eq!(isa.pointer_bytes(), 8);
        assert!(Arc::ptr_eq(&isa, &host_isa().expect("host supported")));
    }
}
