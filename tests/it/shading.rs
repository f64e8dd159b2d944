//! Shading programs (`lobe::backend::shading`): the interpreted and the JIT-compiled program agree bit for bit
//! on every example scene in both math modes; renders through the program stay within one level of the Rust
//! span loops (the previous path) on every example scene; the `Column` leaf runs through every backend.

use lobe::backend::shading::{self, Program, N_OUTPUTS};
use lobe::render::shade::ProgramCode as Compiled;
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
    scene::load_scene(path, &opts, &LobeCompiler { backend, math }).unwrap_or_else(|d| panic!("{}", d.render(false)))
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
    let mut cols: Vec<Vec<f64>> = (0..shading::MAX_COLUMNS).map(|_| (0..n).map(|_| next()).collect()).collect();
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
        let [a, b, c2, d, e, f] = &mut outs[..] else { unreachable!() };
        let mut o: [&mut [f64]; N_OUTPUTS] = [a, b, c2, d, e, f];
        let block = c.prepare(params);
        c.run(&refs, params, &block, &mut o, n);
    }
    outs
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
                    let spec = r::shade::spec(&s, &plan);
                    let src = m.program.as_ref().expect("lobe formulas have a program source");
                    let ch: Vec<&lobe::ir::Formula> = src.channels.iter().map(|f| f.as_ref()).collect();
                    let p = Program::new(&spec, &ch).unwrap();
                    let i = Compiled::new(&p, Backend::Interp, math).unwrap();
                    let j = Compiled::new(&p, Backend::Jit, math).unwrap();
                    let (a, b) = (run(&i, &cols, &m.params), run(&j, &cols, &m.params));
                    for (k, (x, y)) in a.iter().zip(&b).enumerate() {
                        for (e, (u, v)) in x.iter().zip(y).enumerate() {
                            assert!(u.to_bits() == v.to_bits(), "{}: {math:?} output {k} element {e}: interp {u} vs jit {v}", path.display());
                        }
                    }
                    // Something was shaded (the colour columns are not all ambient).
                    assert!(a[4].iter().sum::<f64>() > 0.0 || !plan.specular, "{}: no evaluation", path.display());
                }
            }
        }
    }
}

#[test]
fn jit_and_interpreted_program_renders_are_byte_identical() {
    for path in scenes() {
        let (j, sj) = r::render(&load(&path, 48, Backend::Jit, Mode::Precise), &RenderOptions { threads: 2, tile: 16, ..RenderOptions::default() }).unwrap();
        let (i, si) = r::render(&load(&path, 48, Backend::Interp, Mode::Precise), &RenderOptions { threads: 1, tile: 16, ..RenderOptions::default() }).unwrap();
        assert!(j.image == i.image, "{}", path.display());
        assert_eq!((sj.evals, sj.nan, sj.cut), (si.evals, si.nan, si.cut), "{}", path.display());
    }
}

/// The previous path (Rust span loops, approximate inverse square roots) against the program (exact ones):
/// within one level per channel on every example scene, and the same counts.
#[test]
fn program_and_span_loop_renders_are_within_one_level() {
    for path in scenes() {
        let s = load(&path, 96, Backend::Jit, Mode::Precise);
        let (a, sa) = r::render(&s, &RenderOptions { threads: 2, tile: 32, ..RenderOptions::default() }).unwrap();
        let (b, sb) = r::render(&s, &RenderOptions { threads: 2, tile: 32, program: false, ..RenderOptions::default() }).unwrap();
        let mut moved = 0;
        for (p, q) in a.image.rgb.chunks_exact(3).zip(b.image.rgb.chunks_exact(3)) {
            let d = p.iter().zip(q).map(|(x, y)| x.abs_diff(*y)).max().unwrap_or(0);
            assert!(d <= 1, "{}: a channel differs by {d}", path.display());
            moved += usize::from(d > 0);
        }
        assert!(moved * 100 <= sa.visible_pixels as usize, "{}: {moved} pixels moved", path.display());
        println!("{}: {moved} of {} visible pixels differ by one level", path.file_name().unwrap_or_default().display(), sa.visible_pixels);
        assert_eq!(sa.visible_pixels, sb.visible_pixels);
        // Evaluations: the same lit pixels up to rounding at the terminator (NL ≈ 0).
        let (ea, eb) = (sa.evals as f64, sb.evals as f64);
        assert!((ea - eb).abs() <= 0.002 * eb + 8.0, "{}: {ea} vs {eb} evaluations", path.display());
    }
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
    let spec = shading::Spec {
        eye: [0.0, 0.0, 5.0],
        lights: vec![shading::Light { point: false, at: [0.0, 0.0, 1.0], color: [1.0; 3] }],
        ambient: [0.0; 3],
        diffuse: [1.0; 3],
        spec: [0.0; 3],
        specular: false,
        times_nl: false,
        tangent_rotation: None,
        cutoff: None,
    };
    let one = lobe::front::parse("one", "1").unwrap();
    let p = Program::new(&spec, &[&one]).unwrap();
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
    let f = m.program.as_ref().unwrap().channels[0].clone();
    let p = Program::new(&r::shade::spec(&s, &plan), &[&f]).unwrap();
    assert_eq!(p.regions.len(), 3, "three lights, three guarded regions");
    let sqrt = |n: &Node| matches!(n, Node::Call(Builtin::Sqrt, _));
    let varying_roots = p.ir.nodes().iter().zip(&p.class).filter(|(n, c)| sqrt(n) && **c != shading::Class::Invariant).count();
    let (fir, _) = f.ir.compact(f.root);
    assert_eq!(fir.nodes().iter().filter(|n| sqrt(n)).count(), 0, "F_kutlog's square roots are all the library's");
    let (_, batch) = lobe::backend::jit::disassemble(&f, Mode::Precise).unwrap();
    let listing = lobe::backend::jit::disassemble_program(&p, Mode::Precise).unwrap();
    let count = |s: &str| s.matches("sqrtpd").count();
    assert!(count(&batch) >= 1);
    let vectors = 5;
    assert_eq!(count(&listing), vectors * (varying_roots + p.regions.len() * count(&batch)), "{listing}");
}
