//! Shader export: every catalogue formula exports to GLSL that a real validator accepts (glslangValidator from
//! Debian's glslang-tools, installed by .ci/run when possible), and the text of a few exports is pinned by
//! golden files (tests/golden/export/, `LOBE_BLESS=1` rewrites them).

use lobe::backend::glsl::{self, Dialect};
use lobe::{Backend, Options};
use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn catalogue() -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(root().join("examples/brdfs"))
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "brdf"))
        .collect();
    v.sort();
    v
}

fn formula(path: &Path, bake: &[(&str, f64)]) -> lobe::Formula {
    let src = std::fs::read_to_string(path).unwrap();
    let opts = Options {
        backend: Backend::Interp,
        bake: bake.iter().map(|(k, v)| (k.to_string(), *v)).collect(),
        ..Options::default()
    };
    let k = lobe::compile_source(&path.display().to_string(), &src, &opts).unwrap_or_else(|d| panic!("{}", d.render(false)));
    (*k.formula).clone()
}

fn validator() -> Option<PathBuf> {
    let out = Command::new("glslangValidator").arg("--version").output().ok()?;
    out.status.success().then(|| PathBuf::from("glslangValidator"))
}

#[test]
fn every_catalogue_formula_exports_valid_glsl() {
    let Some(v) = validator() else {
        eprintln!("glslangValidator not installed: GLSL validity checked by golden files only");
        return;
    };
    let dir = std::env::temp_dir().join(format!("lobe-glsl-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for path in catalogue() {
        for bake in [&[][..], &[("n", 50.0)][..]] {
            let f = formula(&path, bake);
            let shader = glsl::glsl_test_shader(&f);
            let file = dir.join(format!("{}.frag", glsl::function_name(&f)));
            std::fs::write(&file, &shader).unwrap();
            let out = Command::new(&v).arg(&file).output().unwrap();
            assert!(
                out.status.success(),
                "{} (bake {bake:?}) is not valid GLSL:\n{}\n{}",
                path.display(),
                String::from_utf8_lossy(&out.stdout),
                shader
            );
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn exports_match_golden_files() {
    let bless = std::env::var_os("LOBE_BLESS").is_some();
    let gdir = root().join("tests/golden/export");
    for (name, bake, d, ext) in [
        ("modified_schlick", &[("n", 50.0)][..], Dialect::Glsl, "glsl"),
        ("modified_schlick", &[][..], Dialect::Glsl, "live.glsl"),
        ("cook_torrance", &[][..], Dialect::Glsl, "glsl"),
        ("kutlog", &[("n", 100.0)][..], Dialect::Wgsl, "wgsl"),
    ] {
        let f = formula(&root().join(format!("examples/brdfs/{name}.brdf")), bake);
        let text = glsl::export(&f, d).replace(env!("CARGO_PKG_VERSION"), "VERSION");
        let golden = gdir.join(format!("{name}.{ext}"));
        if bless {
            std::fs::create_dir_all(&gdir).unwrap();
            std::fs::write(&golden, &text).unwrap();
        } else {
            let want = std::fs::read_to_string(&golden).unwrap_or_else(|_| panic!("missing {}", golden.display()));
            assert_eq!(text, want, "{} changed; LOBE_BLESS=1 to accept", golden.display());
        }
    }
}

#[test]
fn export_takes_only_used_inputs_and_live_params() {
    let f = formula(&root().join("examples/brdfs/modified_schlick.brdf"), &[]);
    let text = glsl::export(&f, Dialect::Glsl);
    assert!(text.contains("float lobe_modified_schlick(float NH, float n)"), "{text}");
    let baked = formula(&root().join("examples/brdfs/modified_schlick.brdf"), &[("n", 50.0)]);
    let text = glsl::export(&baked, Dialect::Glsl);
    assert!(text.contains("float lobe_modified_schlick(float NH)"), "{text}");
}

#[test]
fn hostile_parameter_names_export_valid_glsl() {
    let Some(v) = validator() else {
        eprintln!("glslangValidator not installed: hostile names checked by the unit test only");
        return;
    };
    let src = "@name \"x\r#define pow(a,b) 0.0\"\nparam t0 = 1\nparam float = 2\nparam gl_Position = 3\nparam output = 4\n\
               param alias = 5\nparam var = 6\nparam loop = 7\nparam f32 = 8\nparam main = 9\nparam __x = 1\n\
               let a = pow(NH, n)\nlet b = a * a + t0\nb * b * float * gl_Position * output * alias * var * loop * f32 * main * __x\n";
    let f = lobe::front::parse("hostile.brdf", src).unwrap_or_else(|d| panic!("{}", d.render(false)));
    let dir = std::env::temp_dir().join(format!("lobe-glsl-hostile-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("hostile.frag");
    let shader = glsl::glsl_test_shader(&f);
    std::fs::write(&file, &shader).unwrap();
    let out = Command::new(&v).arg(&file).output().unwrap();
    assert!(out.status.success(), "not valid GLSL:\n{}\n{shader}", String::from_utf8_lossy(&out.stdout));
    let _ = std::fs::remove_dir_all(&dir);
}
