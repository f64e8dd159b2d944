//! The library on a caller's ordinary thread: formulas as large as the 1 MiB source cap allows go through every
//! pass (parse, simplify, the accuracy pass, the truth, the JIT, the printers, the renderer) on a thread with
//! the default 2 MiB stack, as Python, a server's worker or any embedding program calls them — not only on the
//! CLI's big-stack command thread.

use lobe::numerics::robust::PassOptions;

/// A 300 000-term sum (600 000 nodes as written) and a 10⁶-deep unary minus.
fn huge() -> Vec<(&'static str, String, f64)> {
    vec![("sum.brdf", format!("{}NH\n", "NH+".repeat(300_000)), 150_000.5), ("neg.brdf", format!("{}NH\n", "-".repeat(1_000_000)), 0.5)]
}

/// Runs `f` on a new thread with `stack` bytes of stack (2 MiB: Rust's default for spawned threads).
fn on_stack<T: Send>(stack: usize, f: impl FnOnce() -> T + Send) -> T {
    std::thread::scope(|s| std::thread::Builder::new().stack_size(stack).spawn_scoped(s, f).expect("thread").join().expect("no panic"))
}

#[test]
fn huge_formulas_need_no_big_stack_from_the_caller() {
    for (name, src, at_half) in huge() {
        on_stack(2 << 20, || {
            let f = lobe::front::parse(name, &src).unwrap_or_else(|d| panic!("{d}"));
            // The accuracy pass as every command compiles (no cache), then a value.
            let pass = PassOptions { points: 500, ..Default::default() };
            let opts = lobe::numerics::robust::with_pass(lobe::Options::default(), pass);
            let k = lobe::compile_formula(f.clone(), &opts).unwrap_or_else(|d| panic!("{d}"));
            let mut x = [0.0; lobe::N_INPUTS];
            x[lobe::Input::NH as usize] = 0.5;
            assert_eq!(k.evaluator().eval(&x, &k.default_params()), at_half, "{name}");
            // `lobe check`'s report.
            lobe::numerics::check::check(&f, &[], &pass, pass.points, None, &|_| {}).unwrap_or_else(|d| panic!("{d}"));
            // The exports and the printer.
            let plain = lobe::simplified(&f, &lobe::Options::default()).unwrap();
            assert!(lobe::backend::glsl::export(&plain, lobe::backend::glsl::Dialect::Wgsl).unwrap().contains("fn lobe_"));
            assert!(lobe::backend::glsl::export(&plain, lobe::backend::glsl::Dialect::Glsl(Default::default())).unwrap().contains("float lobe_"));
            assert!(plain.to_program_text().len() > 2);
        });
    }
}

#[test]
fn huge_formulas_render_on_a_small_stack() {
    let dir = std::env::temp_dir().join(format!("lobe-deep-render-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let scene = std::fs::read_to_string(root.join("examples/scenes/paper_sphere.toml")).unwrap();
    for (name, src, _) in huge() {
        std::fs::write(dir.join(name), src).unwrap();
        let path = dir.join(format!("{name}.toml"));
        std::fs::write(&path, scene.replace("\"../brdfs/modified_schlick_vr.brdf\"", &format!("\"{name}\"")).replace("params = { n = 50 }", "params = { }")).unwrap();
        on_stack(2 << 20, || {
            // The shading programs, their JIT and the tiles (rayon's workers: the test binary's default pool).
            let compiler = lobe::render::scene::LobeCompiler::plain(lobe::Backend::Jit, lobe::Mode::Precise);
            let opts = lobe::render::scene::LoadOptions { size: Some((48, 48)), ..Default::default() };
            let sc = lobe::render::scene::load_scene(&path, &opts, &compiler).unwrap_or_else(|d| panic!("{}", d.render(false)));
            let (_, stats) = lobe::render::render(&sc, &lobe::render::RenderOptions::default()).unwrap();
            assert!(stats.visible_pixels > 100 && stats.nan == 0, "{name}: {stats:?}");
        });
    }
    let _ = std::fs::remove_dir_all(&dir);
}
