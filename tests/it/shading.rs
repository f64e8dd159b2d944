//! Shading programs (`lobe::render::program` over `lobe::backend::program`): the interpreted program and every
//! JIT tier's (Cranelift; LLVM with the feature `llvm`) agree bit for bit on every example scene in both math
//! modes, on random formulas, and in whole renders; the program agrees with
//! the lighting sum written out in Rust around the formula's own kernel (`Evaluator::eval`) on every example
//! scene; the `Column` leaf runs through every backend.

use lobe::backend::program::{self, Program};
use lobe::ir::Input;
use lobe::render::program::{self as rp, ProgramCode as Compiled, COLUMNS, N_OUTPUTS};
use lobe::render::scene::{self, LoadOptions, LobeCompiler};
use lobe::render::{self as r, RenderOptions};
use lobe::{Backend, Evaluator, Mode};
use std::path::{Path, PathBuf};

fn scenes() -> Vec<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("examples/scenes");
    let mut v: Vec<PathBuf> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().path()).filter(|p| p.extension().is_some_and(|e| e == "toml")).collect();
    v.sort();
    assert!(v.len() >= 9, "{v:?}");
    v
}

fn load(path: &Path, size: usize, backend: Backend, math: Mode) -> r::Scene {
    let opts = LoadOptions { size: Some((size, size)), ..LoadOptions::default() };
    scene::load_scene(path, &opts, &LobeCompiler::plain(backend, math)).unwrap_or_else(|d| panic!("{}", d.render(false)))
}

/// Pseudo-random data columns: positions near the origin, normals and tangents of any direction (some
/// degenerate: zero normals, tangents parallel to the normal), so the special cases run too.
fn columns(n: usize) -> Vec<Vec<f64>> {
    let mut seed = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    let mut cols: Vec<Vec<f64>> = (0..COLUMNS).map(|_| (0..n).map(|_| next()).collect()).collect();
    for i in (0..n).step_by(37) {
        for c in &mut cols[3..6] {
            c[i] = 0.0;
        }
    }
    for i in (5..n).step_by(41) {
        for c in 0..3 {
            cols[6 + c][i] = cols[3 + c][i];
        }
    }
    cols
}

fn run(c: &Compiled, cols: &[Vec<f64>], params: &[f64]) -> Vec<Vec<f64>> {
    let n = cols[0].len();
    let refs: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
    let mut outs = vec![vec![f64::NAN; n]; N_OUTPUTS];
    {
        let mut o: Vec<&mut [f64]> = outs.iter_mut().map(|v| v.as_mut_slice()).collect();
        let block = c.prepare(params);
        c.run(&refs, params, &block, &mut o, n);
    }
    outs
}

/// `b` has `a`'s bits in every output and element (NaN payloads included: the tiers run the same operations).
fn same_outputs(a: &[Vec<f64>], b: &[Vec<f64>]) -> Result<(), String> {
    for (k, (x, y)) in a.iter().zip(b).enumerate() {
        for (e, (u, v)) in x.iter().zip(y).enumerate() {
            if u.to_bits() != v.to_bits() {
                return Err(format!("output {k} element {e}: interp {u} vs compiled {v}"));
            }
        }
    }
    Ok(())
}

#[test]
fn interpreted_and_compiled_programs_agree_bit_for_bit_on_every_scene() {
    let cols = columns(301);
    for path in scenes() {
        for math in [Mode::Precise, Mode::Fast] {
            let s = load(&path, 32, Backend::Jit, math);
            for m in &s.materials {
                for cutoff in [false, true] {
                    let plan = r::plan::ShadingPlan::new(m, s.ambient, cutoff);
                    let p = build(&s, m, &plan);
                    let i = Compiled::new(&p, Backend::Interp, math).unwrap();
                    let a = run(&i, &cols, &m.params);
                    for tier in crate::differential::jit_backends() {
                        let j = Compiled::new(&p, tier, math).unwrap();
                        if let Err(e) = same_outputs(&a, &run(&j, &cols, &m.params)) {
                            panic!("{} ({}, {math:?}, cut-off {cutoff}): {e}", path.display(), tier.name());
                        }
                    }
                    // Something was shaded (the colour columns are not all ambient) where the scene has lights for
                    // the program (a scene lit only by an environment map is the ray tracer's).
                    assert!(a[4].iter().sum::<f64>() > 0.0 || !plan.specular || s.lights.is_empty(), "{}: no evaluation", path.display());
                }
            }
        }
    }
}

#[test]
fn jit_and_interpreted_program_renders_are_byte_identical() {
    for path in scenes() {
        let (i, si) = r::render(&load(&path, 48, Backend::Interp, Mode::Precise), &RenderOptions { threads: 1, tile: 16, ..RenderOptions::default() }).unwrap();
        for tier in crate::differential::jit_backends() {
            let (j, sj) = r::render(&load(&path, 48, tier, Mode::Precise), &RenderOptions { threads: 2, tile: 16, ..RenderOptions::default() }).unwrap();
            assert!(j.image == i.image, "{} ({})", path.display(), tier.name());
            assert_eq!((sj.evals, sj.nan, sj.cut), (si.evals, si.nan, si.cut), "{} ({})", path.display(), tier.name());
        }
    }
}

/// Random formulas (the differential test's generator: every builtin, special constants, raw and clamped
/// inputs, directions) as the specular term of a lighting program with a point and a directional light,
/// random colours and, for some, a cut-off: every tier gives the interpreter's bits on odd-length columns (the
/// tails of every lane count), whatever the formula computes (NaN and infinities included).
#[test]
fn random_formulas_shade_alike_on_every_tier() {
    use proptest::prelude::*;
    use proptest::test_runner::{Config, TestCaseError, TestRunner};
    let cols = columns(37);
    let cases = if cfg!(feature = "llvm") { 150 } else { 400 };
    let mut runner = TestRunner::new(Config { cases, failure_persistence: None, ..Config::default() });
    let colour = || prop::array::uniform3(0.0..2.0f64);
    let strategy = (crate::differential::expr(), any::<bool>(), prop::sample::select(Mode::ALL.to_vec()), (colour(), colour(), colour()), any::<bool>(), -0.5..1.0f64);
    let result = runner.run(&strategy, |(e, policy, math, (ambient, diffuse, spec_c), cut, cos)| {
        let f = crate::differential::formula(&e, policy);
        let reads = f.used_inputs();
        let spec = rp::Spec {
            eye: [0.3, -0.2, 4.0],
            lights: vec![
                rp::Light { point: true, at: [2.0, 3.0, 5.0], color: [1.0, 0.9, 0.8] },
                rp::Light { point: false, at: [0.0, 0.6, 0.8], color: [0.5, 0.5, 0.7] },
            ],
            ambient,
            diffuse,
            spec: spec_c,
            specular: true,
            times_nl: policy,
            tangent_rotation: reads.reads_directions().then_some([0.8, 0.6]),
            cutoff: (cut && reads.contains(Input::NH)).then_some((Input::NH, cos)),
        };
        let p = rp::build(&spec, &[&f]).map_err(TestCaseError::fail)?;
        let params = [1.5, -0.25, 7.0];
        let want = run(&Compiled::new(&p, Backend::Interp, math).map_err(|e| TestCaseError::fail(e.to_string()))?, &cols, &params);
        for tier in crate::differential::jit_backends() {
            let c = Compiled::new(&p, tier, math).map_err(|e| TestCaseError::fail(format!("{}: {e}", tier.name())))?;
            same_outputs(&want, &run(&c, &cols, &params)).map_err(|e| TestCaseError::fail(format!("{} ({math:?}): {e}", tier.name())))?;
        }
        Ok(())
    });
    if let Err(e) = result {
        panic!("{e}");
    }
}

fn build(s: &r::Scene, m: &r::Material, plan: &r::plan::ShadingPlan) -> Program {
    let ch: Vec<&lobe::ir::Formula> = m.program.channels.iter().map(|f| f.as_ref()).collect();
    rp::build(&rp::spec(s, plan), &ch).unwrap()
}

type V3 = [f64; 3];
fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// The lighting sum of `render::program` written out in Rust for one pixel (position `p`, normal `n`, tangent
/// `t`), F from the material's kernels through `Evaluator::eval`: the colour, and the counters (non-finite F,
/// evaluations, cut-off skips).
fn reference(m: &r::Material, spec: &rp::Spec, p: V3, n: V3, t: V3) -> ([f64; 3], [f64; 3]) {
    let v = sub(spec.eye, p);
    let inv_n = 1.0 / dot(n, n).sqrt();
    let inv_v = 1.0 / dot(v, v).sqrt();
    let nv = dot(n, v) * inv_n * inv_v;
    let frame = spec.tangent_rotation.map(|[c, sn]| {
        let nh = n.map(|x| x * inv_n);
        let k = dot(nh, t);
        let u = sub(t, nh.map(|x| x * k));
        let l2 = dot(u, u);
        let ok = 1e-20 < l2;
        let sign = if nh[2] < 0.0 { -1.0 } else { 1.0 };
        let q = -1.0 / (sign + nh[2]);
        let sa = sign * nh[0];
        let o = [1.0 + sa * nh[0] * q, sa * nh[1] * q, -sa];
        let il = if ok { 1.0 / l2.sqrt() } else { 1.0 };
        let u = if ok { u.map(|x| x * il) } else { o };
        let w = [nh[1] * u[2] - nh[2] * u[1], nh[2] * u[0] - nh[0] * u[2], nh[0] * u[1] - nh[1] * u[0]];
        let tt: V3 = std::array::from_fn(|i| c * u[i] + sn * w[i]);
        let bb: V3 = std::array::from_fn(|i| c * w[i] - sn * u[i]);
        (tt, bb, dot(v, tt) * inv_v, dot(v, bb) * inv_v)
    });
    let kernels: Vec<&dyn Evaluator> = m.kernels().collect();
    let mut acc = spec.ambient;
    let mut counts = [0.0; 3];
    for light in &spec.lights {
        let (l, il) = if light.point {
            let l = sub(light.at, p);
            (l, 1.0 / dot(l, l).sqrt())
        } else {
            (light.at, 1.0)
        };
        let nl = dot(n, l) * inv_n * il;
        let mut x = [0.0; lobe::N_INPUTS];
        x[Input::NL.index()] = nl;
        x[Input::Lz.index()] = nl;
        x[Input::NV.index()] = nv;
        x[Input::Vz.index()] = nv;
        let vl = dot(v, l) * inv_v * il;
        let h2 = 2.0 + 2.0 * vl;
        let ih = if 1e-300 < h2 { 1.0 / h2.sqrt() } else { 0.0 };
        x[Input::NH.index()] = (nl + nv) * ih;
        x[Input::VH.index()] = (1.0 + vl) * ih;
        x[Input::VR.index()] = 2.0 * nl * nv - vl;
        if let Some((tt, bb, vx, vy)) = frame {
            x[Input::Vx.index()] = vx;
            x[Input::Vy.index()] = vy;
            x[Input::Lx.index()] = dot(l, tt) * il;
            x[Input::Ly.index()] = dot(l, bb) * il;
        }
        let lit_nl = 0.0 < nl;
        let lit = lit_nl && spec.cutoff.is_none_or(|(i, cos)| cos <= x[i.index()]);
        // F (0 where non-finite) times NL where lit, 0 elsewhere (even where NL is NaN).
        let mut f = [0.0; 3];
        if spec.specular {
            for (c, k) in kernels.iter().enumerate() {
                if lit {
                    let raw = k.eval(&x, &m.params);
                    let finite = raw.abs() < f64::INFINITY;
                    let g = if finite { raw } else { 0.0 };
                    counts[0] += if finite { 0.0 } else { 1.0 };
                    f[c] = if spec.times_nl { g * nl } else { g };
                }
            }
            counts[1] += if lit { kernels.len() as f64 } else { 0.0 };
            if kernels.len() == 1 {
                f = [f[0]; 3];
            }
        }
        if spec.specular && lit_nl && !lit {
            counts[2] += 1.0;
        }
        let n_pos = if lit_nl { nl } else { 0.0 };
        for c in 0..3 {
            let term = if spec.specular { spec.diffuse[c] * n_pos + spec.spec[c] * f[c] } else { spec.diffuse[c] * n_pos };
            acc[c] += light.color[c] * term;
        }
    }
    (acc, counts)
}

/// The program against the lighting sum written out in Rust around the formula's own kernels (the same
/// arithmetic in the same order, so a wrong program — a missing light, a wrong cosine, F where it should be
/// cut — shows): every colour within 1e-9 relative (or both NaN), every counter equal, on every example
/// scene's materials, with and without their cut-offs, interpreted and compiled.
#[test]
fn programs_agree_with_the_formula_evaluated_per_pixel() {
    let cols = columns(211);
    for path in scenes() {
        let s = load(&path, 32, Backend::Jit, Mode::Precise);
        for m in &s.materials {
            for cutoff in [false, true] {
                let plan = r::plan::ShadingPlan::new(m, s.ambient, cutoff);
                let spec = rp::spec(&s, &plan);
                let p = build(&s, m, &plan);
                for backend in [Backend::Interp, Backend::Jit] {
                    let out = run(&Compiled::new(&p, backend, Mode::Precise).unwrap(), &cols, &m.params);
                    for e in 0..cols[0].len() {
                        let at = |k: usize| [cols[k][e], cols[k + 1][e], cols[k + 2][e]];
                        let (want, counts) = reference(m, &spec, at(0), at(3), at(6));
                        for c in 0..3 {
                            let (got, w) = (out[c][e], want[c]);
                            let close = (got - w).abs() <= 1e-9 * (1.0 + w.abs()) || (got.is_nan() && w.is_nan()) || got == w;
                            assert!(close, "{} {backend:?} cutoff {cutoff} pixel {e} channel {c}: program {got} vs per-pixel {w}", path.display());
                            assert_eq!(out[3 + c][e], counts[c], "{} {backend:?} pixel {e} counter {c}", path.display());
                        }
                    }
                }
            }
        }
    }
}

/// The Rust-side shader (what a measured material renders with) computes what the program computes: the same
/// frame definitions on f64 and the same sums, so with the material's own formula as its channels its colours
/// have the compiled program's bits on every example scene's colour materials (without cut-offs, which it
/// refuses), and its counters match.
#[test]
fn the_rust_shader_is_the_program_on_f64() {
    let cols = columns(211);
    let mut tried = 0;
    for path in scenes() {
        let s = load(&path, 32, Backend::Jit, Mode::Precise);
        for m in &s.materials {
            let plan = r::plan::ShadingPlan::new(m, s.ambient, false);
            let spec = rp::spec(&s, &plan);
            let p = build(&s, m, &plan);
            let program = run(&Compiled::new(&p, Backend::Interp, Mode::Precise).unwrap(), &cols, &m.params);
            let ch = &m.program.channels;
            let evs: Vec<std::sync::Arc<dyn Evaluator>> = ch.iter().map(|f| std::sync::Arc::new(lobe::backend::interp::Interp::with_mode(f, Mode::Precise)) as _).collect();
            let shader = Compiled::Evaluated(std::sync::Arc::new(rp::EvalShader::new(spec, evs).unwrap()));
            let rust = run(&shader, &cols, &m.params);
            for e in 0..cols[0].len() {
                for c in 0..3 {
                    let (a, b) = (program[c][e], rust[c][e]);
                    assert!(a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()), "{} pixel {e} channel {c}: program {a} vs Rust {b}", path.display());
                    assert_eq!(program[3 + c][e], rust[3 + c][e], "{} pixel {e} counter {c}", path.display());
                }
            }
            tried += 1;
        }
    }
    assert!(tried >= 9, "{tried} materials");
}

#[test]
fn the_column_leaf_runs_through_every_backend() {
    use lobe::ir::{BinOp, Formula, Ir, Meta, Node};
    let mut ir = Ir::new();
    let s = lobe::base::span::Span::default();
    let c = ir.column(2, s);
    let two = ir.konst(2.0, s);
    let root = ir.bin(BinOp::Mul, c, two, s);
    let f = Formula { meta: Meta::default(), params: vec![], ir, root, file: "c".into(), source: String::new(), rgb: None };
    assert_eq!(*f.ir.node(c), Node::Column(2));
    // Printing and GLSL name it; formulas never contain it, so the formula interpreter reads it as NaN.
    assert!(f.to_program_text().contains("column2"), "{}", f.to_program_text());
    assert!(lobe::backend::interp::Interp::new(&f).eval(&[0.5; lobe::N_INPUTS], &[]).is_nan());
    // The simplifier keeps it (a varying leaf of unknown range).
    let simplified = lobe::simplify::simplify(&f, &[]);
    assert!(simplified.ir.nodes().contains(&Node::Column(2)));
    // Programs read it: the interpreted and compiled program give the column's values through the pipeline.
    let spec = rp::Spec {
        eye: [0.0, 0.0, 5.0],
        lights: vec![rp::Light { point: false, at: [0.0, 0.0, 1.0], color: [1.0; 3] }],
        ambient: [0.0; 3],
        diffuse: [1.0; 3],
        spec: [0.0; 3],
        specular: false,
        times_nl: false,
        tangent_rotation: None,
        cutoff: None,
    };
    let one = lobe::front::parse("one", "1").unwrap();
    let p = rp::build(&spec, &[&one]).unwrap();
    let cols = columns(9);
    for backend in [Backend::Interp, Backend::Jit] {
        let out = run(&Compiled::new(&p, backend, Mode::Precise).unwrap(), &cols, &[]);
        for e in 0..9 {
            // Directional light along +z: the colour is max(n̂·z, 0).
            let n = [cols[3][e], cols[4][e], cols[5][e]];
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            let want = if n[2] / len > 0.0 { n[2] / len } else { 0.0 };
            assert!((out[0][e] - want).abs() < 1e-12 || (want == 0.0 && out[0][e] == 0.0), "{backend:?} {e}: {} vs {want}", out[0][e]);
        }
    }
}

/// Values several light regions read (NV, 1/|v|) are computed once per pixel, before the first region, not
/// again inside each: each vector the program's code handles (four per step of the main loop, one in the loop
/// after it, as F calls the math library) has one `sqrtpd` per varying square root of the program, plus the
/// math library's own in each region's copy of the formula (as many as the formula's batched kernel has).
#[test]
fn values_regions_share_are_computed_once_per_pixel() {
    use lobe::builtins::Builtin;
    use lobe::ir::Node;
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("examples/scenes/fill_kutlog.toml");
    let s = load(&path, 32, Backend::Jit, Mode::Precise);
    let m = &s.materials[0];
    let plan = r::plan::ShadingPlan::new(m, s.ambient, false);
    let f = m.program.channels[0].clone();
    let p = rp::build(&rp::spec(&s, &plan), &[&f]).unwrap();
    assert_eq!(p.regions.len(), 3, "three lights, three guarded regions");
    let sqrt = |n: &Node| matches!(n, Node::Call(Builtin::Sqrt, _));
    let varying_roots = p.ir.nodes().iter().zip(&p.class).filter(|(n, c)| sqrt(n) && **c != program::Class::Invariant).count();
    let (fir, _) = f.ir.compact(f.root);
    assert_eq!(fir.nodes().iter().filter(|n| sqrt(n)).count(), 0, "F_kutlog's square roots are all the library's");
    let (_, batch) = lobe::backend::jit::disassemble(&f, Mode::Precise).unwrap();
    let listing = lobe::backend::jit::disassemble_program(&p, Mode::Precise).unwrap();
    let count = |s: &str| s.matches("sqrtpd").count();
    assert!(count(&batch) >= 1);
    let vectors = 5;
    assert_eq!(count(&listing), vectors * (varying_roots + p.regions.len() * count(&batch)), "{listing}");
}
