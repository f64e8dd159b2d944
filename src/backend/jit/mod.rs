//! The Cranelift tier: a simplified [`Formula`] → native scalar and batched kernels, and multi-output programs.
//!
//! Design (after bytecodealliance/cranelift-jit-demo, stricter):
//! - a [`Jit`] owns the reusable Cranelift contexts; one per thread (compiles run in parallel);
//! - `codegen` has one translator, generic over the lane type (`F64` for the scalar kernel and the batch tail,
//!   `F64X2` for the batch loop), implementing the native layer's `Lower` and the math library's `Emit`: the
//!   node dispatch and inline builtins are [`crate::backend::native::lower`]'s, written once for both tiers;
//!   `Lowering::Math` builtins are the math library's code (`builtins::math`) emitted inline in the kernel's
//!   lanes — the definition the interpreter runs on `f64`, so the backends agree bit for bit in each math mode;
//!   the only calls are the trigonometric fallbacks to libm for huge arguments, outlined library functions
//!   ([`crate::backend::native::OUTLINE_AT`]) and, on a host without FMA, Cranelift's `fma` libcall (a
//!   correctly rounded fma: same bits), registered with `JITBuilder::symbol` before anything is finalized (an
//!   unresolved import would panic inside Cranelift);
//! - the native layer's plan: parameter-only work is computed once per parameter set by a prepare function
//!   into a block the kernels load;
//! - one `JITModule` per compiled formula: the scalar kernel and the prepare function are compiled at once,
//!   the batched kernel is added to the same module on the first batch call ([`KernelCode::batch`]); its
//!   memory is freed when the last kernel using it is dropped;
//! - the native layer's bounded LRU cache ([`crate::backend::native::cache`]) keyed by the simplified IR's
//!   structure, so compiling a formula twice is free;
//! - live parameters are loads from the `params` slice, so changing them needs no recompilation; baked ones
//!   are already constants in the IR.
//!
//! `unsafe` here: turning finalized addresses into the native layer's function-pointer types, and freeing the
//! module; calling the code is [`crate::backend::native::abi`]'s (each block has its `# Safety` note).
//!
//! Cost model. Compiling is Cranelift's work: a fixed per-module cost plus roughly linear in the nodes; the
//! batched kernel (a loop and two copies of the body) costs more than the scalar one, hence built lazily. A
//! plain scalar call pays a fixed dispatch (`Kernel` → `dyn Evaluator` → length check → per-thread block
//! lookup → generated code) on top of the body, which dominates short arithmetic formulas; a prepared call
//! (`Prepared::Native`) pays only a `match` and the indirect call; the batched kernel pays it once per batch,
//! runs two lanes per instruction, and does each clamp against a constant as one `maxpd`/`minpd`. A
//! transcendental builtin is 20–200 vector instructions (pow the most: double-double in precise mode),
//! straight-line except for rarely taken special-case blocks; scalar code runs the same instructions one lane
//! at a time, where its selects become branches. Measured compile times and ns/eval against the interpreter
//! and hand-written Rust: BENCHMARKS.md.

// Turning addresses into function pointers and freeing generated code (each block has its `# Safety` note).
#![allow(unsafe_code)]

mod codegen;

use crate::backend::native::abi::{BatchFn, KernelCode, NativeCode, PrepareFn, ProgramFn, ScalarFn, Shape};
use crate::backend::native::cache::{Cache, Key};
use crate::backend::native::{outlines, NativeError, NativeKernel, Plan, ShadeCode};
use crate::backend::program::Program;
use crate::backend::Backend;
use crate::builtins::Mode;
use crate::ir::{Formula, Ir, NodeId};
use cranelift_codegen::ir::UserFuncName;
use cranelift_codegen::isa::OwnedTargetIsa;
use cranelift_codegen::settings::{self, Configurable};
use cranelift_codegen::Context;
use cranelift_frontend::FunctionBuilderContext;
use cranelift_jit::{JITBuilder, JITModule};
use cranelift_module::{default_libcall_names, FuncId, Module, ModuleError};
use std::cell::RefCell;
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Instant;

impl From<ModuleError> for NativeError {
    fn from(e: ModuleError) -> NativeError {
        NativeError::Module(e.to_string())
    }
}

/// The target ISA for this host, built once per process (cloning it is an `Arc` clone).
fn host_isa() -> Result<OwnedTargetIsa, NativeError> {
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
    .map_err(NativeError::Host)
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

/// JIT memory: one `JITModule` for the host, its code freed when this is dropped. The one owner of
/// generated code, for kernels ([`KernelModule`]) and multi-output programs ([`ShadeCode`]) alike.
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
    fn for_ir(ir: &Ir, mode: Mode, outline: bool) -> Result<Code, NativeError> {
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
    fn module_mut(&mut self) -> Result<&mut JITModule, NativeError> {
        match self.module.get_mut() {
            Ok(m) => m.as_mut(),
            Err(poisoned) => poisoned.into_inner().as_mut(),
        }
        .ok_or(NativeError::internal("JIT module already freed"))
    }

    /// Runs `f` on the module under its lock (to add a function to shared code).
    fn with_module<R>(&self, f: impl FnOnce(&mut JITModule) -> Result<R, NativeError>) -> Result<R, NativeError> {
        let mut guard = self.module.lock().map_err(|_| NativeError::internal("JIT module lock poisoned"))?;
        f(guard.as_mut().ok_or(NativeError::internal("JIT module already freed"))?)
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
            // (`NativeCode`, `ShadeCode`), or never left a failed compile; that struct is being dropped, and its
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
        build: impl FnOnce(&mut JITModule, &mut Context, &mut FunctionBuilderContext) -> Result<(), NativeError>,
    ) -> Result<FuncId, NativeError> {
        let id = module.declare_anonymous_function(sig)?;
        module.clear_context(&mut self.ctx);
        self.ctx.func.name = UserFuncName::user(0, id.as_u32());
        let built = build(module, &mut self.ctx, &mut self.fctx);
        let defined = built.and_then(|()| {
            self.ctx.set_disasm(self.disasm);
            module.define_function(id, &mut self.ctx).map_err(NativeError::from)
        });
        self.keep_listing();
        module.clear_context(&mut self.ctx);
        defined.map(|()| id)
    }

    /// The finalized address of `id`, checked.
    fn address(module: &JITModule, id: FuncId) -> Result<*const u8, NativeError> {
        let p = module.get_finalized_function(id);
        if p.is_null() {
            return Err(NativeError::internal("finalized function has no address"));
        }
        Ok(p)
    }

    /// Defines the scalar kernel and, when the plan carries nodes, the prepare function; finalizes them.
    fn define_scalar(&mut self, module: &mut JITModule, w: &codegen::Build) -> Result<(ScalarFn, Option<PrepareFn>), NativeError> {
        let scalar = self.define(module, &codegen::scalar_signature(module), |m, c, f| codegen::build_scalar(m, c, f, w))?;
        let prepare = self.define_prepare(module, w)?;
        module.finalize_definitions()?;
        let scalar = Self::address(module, scalar)?;
        let prepare = prepare.map(|id| Self::address(module, id)).transpose()?;
        // Safety: each address is the entry of a function just compiled with exactly the signature of the type it
        // becomes (declared with the host's C calling convention); it stays valid while `module` lives, and the
        // caller's `KernelModule` owns it.
        Ok(unsafe { (std::mem::transmute::<*const u8, ScalarFn>(scalar), prepare.map(|p| std::mem::transmute::<*const u8, PrepareFn>(p))) })
    }

    /// The prepare function, when the plan carries nodes.
    fn define_prepare(&mut self, module: &mut JITModule, w: &codegen::Build) -> Result<Option<FuncId>, NativeError> {
        if w.plan.carried.is_empty() {
            return Ok(None);
        }
        self.define(module, &codegen::prepare_signature(module), |m, c, f| codegen::build_prepare(m, c, f, w)).map(Some)
    }

    /// Adds the batched kernel to an already finalized module (new code goes to new pages; the scalar
    /// kernel's pages are untouched, so it may run concurrently).
    fn define_batch(&mut self, module: &mut JITModule, w: &codegen::Build) -> Result<BatchFn, NativeError> {
        let id = self.define(module, &codegen::batch_signature(module), |m, c, f| codegen::build_batch(m, c, f, w))?;
        module.finalize_definitions()?;
        let p = Self::address(module, id)?;
        // Safety: `p` is the entry of the function just compiled with exactly `BatchFn`'s signature (declared
        // with the host's C calling convention); it stays valid while the module lives, which `KernelModule` owns.
        Ok(unsafe { std::mem::transmute::<*const u8, BatchFn>(p) })
    }

    /// Compiles a compacted IR (every node reachable from `root`, root last) into a fresh module. Only the
    /// scalar kernel (and the prepare function) is built now; the batched one on the first batch call.
    pub(crate) fn translate(&mut self, ir: &Ir, root: NodeId, mode: Mode) -> Result<NativeCode, NativeError> {
        let t = Instant::now();
        // On an error below, `m` is dropped (its memory freed) before any pointer into it escapes.
        let mut m = KernelModule::new(ir, root, mode)?;
        let w = codegen::Build { ir: &m.ir, plan: &m.plan, imports: &m.imports, mode, fma: host_fma(), outline: m.outline };
        let (scalar, prepare) = self.define_scalar(m.code.module_mut()?, &w)?;
        let shape = Shape::of(&m.ir, &m.plan);
        // Safety: `scalar` and `prepare` were just compiled from `ir` and its plan with exactly their types'
        // signatures, into the module `m` holds; `KernelModule::batch` adds the batched kernel of the same IR.
        Ok(unsafe { NativeCode::new(scalar, prepare, shape, (Backend::Jit, 2), t.elapsed(), Box::new(m)) })
    }

    /// Compiles a multi-output program into a fresh module: its loop and (when something is carried) its
    /// prepare function.
    fn translate_program(&mut self, p: &Program, mode: Mode) -> Result<ShadeCode, NativeError> {
        let t = Instant::now();
        let outline = crate::backend::native::plan::program_outlines(p);
        // On an error below, `code` is dropped (its memory freed) before any pointer into it escapes.
        let mut code = Code::for_ir(&p.ir, mode, outline)?;
        let module = code.module_mut()?;
        let plan = Plan::of_program(p)?;
        let imports = codegen::declare_imports(module, &p.ir, mode, outline)?;
        let w = codegen::Build { ir: &p.ir, plan: &plan, imports: &imports, mode, fma: host_fma(), outline };
        let sig = codegen::shade::signature(module);
        let run = self.define(module, &sig, |m, c, f| codegen::shade::build(m, c, f, &w, p))?;
        let prepare = self.define_prepare(module, &w)?;
        module.finalize_definitions()?;
        let run = Self::address(module, run)?;
        let prepare = prepare.map(|id| Self::address(module, id)).transpose()?;
        // Safety: each address is the entry of a function just compiled with exactly the signature of the type
        // it becomes (the host's C calling convention); it stays valid while `module` lives, which the returned
        // `ShadeCode` owns. The loop reads `p.columns` columns, the parameters and the plan's block slots, and
        // writes each output, `len` elements (codegen::shade).
        unsafe {
            let (run, prepare) = (std::mem::transmute::<*const u8, ProgramFn>(run), prepare.map(|q| std::mem::transmute::<*const u8, PrepareFn>(q)));
            Ok(ShadeCode::new(run, prepare, p, &plan, Backend::Jit, t.elapsed(), Box::new(code)))
        }
    }
}

/// A compiled kernel's module, with what it needs to add the batched kernel later.
struct KernelModule {
    code: Code,
    /// The compacted IR, its plan and the imports, kept to build the batched kernel.
    ir: Ir,
    plan: Plan,
    imports: codegen::Imports,
    mode: Mode,
    outline: bool,
}

impl KernelModule {
    /// A fresh module for the compacted `ir` (root `root`) with its imports declared.
    fn new(ir: &Ir, root: NodeId, mode: Mode) -> Result<KernelModule, NativeError> {
        if root.index() >= ir.len() {
            return Err(NativeError::internal("root outside the arena"));
        }
        let outline = outlines(ir);
        let mut code = Code::for_ir(ir, mode, outline)?;
        let imports = codegen::declare_imports(code.module_mut()?, ir, mode, outline)?;
        Ok(KernelModule { code, ir: ir.clone(), plan: Plan::new(ir, root), imports, mode, outline })
    }

    /// The batched kernel added to this module by `j`.
    fn define_batch(&self, j: &mut Jit) -> Result<BatchFn, NativeError> {
        let w = codegen::Build { ir: &self.ir, plan: &self.plan, imports: &self.imports, mode: self.mode, fma: host_fma(), outline: self.outline };
        self.code.with_module(|module| j.define_batch(module, &w))
    }
}

// Safety: `batch` compiles the batched kernel of `ir` with its plan (codegen::build_batch: `BatchFn`'s signature,
// reading `len` elements of the used inputs' columns, the parameters and the block, writing `len` elements of
// `out`) into the module this owns, which keeps it valid while `self` lives.
unsafe impl KernelCode for KernelModule {
    fn batch(&self) -> Result<BatchFn, NativeError> {
        with_jit(|j| self.define_batch(j))
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

/// The compiled kernels and programs, by the IR's structure.
static KERNELS: Cache<NativeCode> = Cache::new();
static PROGRAMS: Cache<ShadeCode> = Cache::new();

/// Changes the kernel cache's bound (0 disables it); returns the previous bound.
pub fn set_cache_capacity(capacity: usize) -> usize {
    KERNELS.set_capacity(capacity)
}

/// (hits, misses, entries) of the kernel cache since the process started.
pub fn cache_stats() -> (u64, u64, usize) {
    KERNELS.stats()
}

/// Compiles a simplified formula (through the cache) with the builtins of math mode `mode`.
pub fn jit_kernel(f: &Formula, mode: Mode) -> Result<NativeKernel, NativeError> {
    let (ir, root) = f.ir.compact(f.root);
    let (code, cached) = KERNELS.get_or_compile(Key::new(&ir, root, mode), || with_jit(|j| j.translate(&ir, root, mode)))?;
    Ok(NativeKernel::new(code, f.params.len(), cached))
}

/// Compiles without consulting or filling the cache (for compile-time measurements and tests).
pub fn jit_kernel_uncached(f: &Formula, mode: Mode) -> Result<NativeKernel, NativeError> {
    let (ir, root) = f.ir.compact(f.root);
    let code = Arc::new(with_jit(|j| j.translate(&ir, root, mode))?);
    Ok(NativeKernel::new(code, f.params.len(), false))
}

/// Compiles a multi-output program (through a cache keyed like the kernels': the IR's structure, its roots and
/// the math mode), so a frame whose parameters changed reuses the code.
pub(crate) fn shade_code(p: &Program, mode: Mode) -> Result<Arc<ShadeCode>, NativeError> {
    PROGRAMS.get_or_compile(Key::of_program(p, mode), || with_jit(|j| j.translate_program(p, mode))).map(|(c, _)| c)
}

/// The machine code (Cranelift's listing) of the scalar and the batched kernel, for `lobe` reports and for
/// checking what the code generator emits (e.g. that the scalar kernel has no stack traffic).
pub fn disassemble(f: &Formula, mode: Mode) -> Result<(String, String), NativeError> {
    let (ir, root) = f.ir.compact(f.root);
    let mut j = Jit::new();
    j.disasm = true;
    let mut m = KernelModule::new(&ir, root, mode)?;
    let w = codegen::Build { ir: &m.ir, plan: &m.plan, imports: &m.imports, mode, fma: host_fma(), outline: m.outline };
    j.define_scalar(m.code.module_mut()?, &w)?;
    m.define_batch(&mut j)?;
    // The listings are in definition order: scalar, prepare (when the formula has a prepared block), batch.
    let l = std::mem::take(&mut j.listing);
    Ok((l.first().cloned().unwrap_or_default(), l.last().cloned().unwrap_or_default()))
}

/// The machine code (Cranelift's listing) of a multi-output program's loop, for checking what it compiles to.
pub fn disassemble_program(p: &Program, mode: Mode) -> Result<String, NativeError> {
    let mut j = Jit::new();
    j.disasm = true;
    j.translate_program(p, mode)?;
    Ok(j.listing.into_iter().next().unwrap_or_default())
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
