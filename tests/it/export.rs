//! Shader export: every catalogue and explorer formula exports to GLSL 3.30, 4.50 and ES 3.00 that a real
//! validator accepts (glslangValidator from Debian's glslang-tools, installed by .ci/run, which sets
//! `LOBE_REQUIRE_GLSLANG=1` so a missing validator fails there), to WGSL and GLSL 4.50 that naga's front ends
//! and validator accept, with no constant outside f32's range; the text of a few exports is pinned by golden
//! files (tests/golden/export/, `LOBE_BLESS=1` rewrites them).

use lobe::backend::glsl::{self, Dialect, GlslVersion};
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
    let out = Command::new("glslangValidator").arg("--version").output().ok();
    let found = out.is_some_and(|o| o.status.success());
    if !found && std::env::var_os("LOBE_REQUIRE_GLSLANG").is_some_and(|v| v == "1") {
        panic!("glslangValidator is not installed and LOBE_REQUIRE_GLSLANG=1: apt-get install glslang-tools");
    }
    found.then(|| PathBuf::from("glslangValidator"))
}

/// naga's WGSL front end and validator on `text`: the error as text.
fn naga_wgsl(text: &str) -> Result<(), String> {
    let module = naga::front::wgsl::parse_str(text).map_err(|e| e.emit_to_string(text))?;
    naga_validate(&module)
}

/// naga's GLSL front end (4.50, fragment stage) and validator on a complete shader.
fn naga_glsl(shader: &str) -> Result<(), String> {
    let opts = naga::front::glsl::Options::from(naga::ShaderStage::Fragment);
    let module = naga::front::glsl::Frontend::default().parse(&opts, shader).map_err(|e| e.emit_to_string(shader))?;
    naga_validate(&module)
}

fn naga_validate(module: &naga::Module) -> Result<(), String> {
    let mut v = naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::all());
    v.validate(module).map(|_| ()).map_err(|e| format!("{e:?}"))
}

/// Every number written in the code lines of a shader (comments skipped): none may lie outside f32's normal
/// range, and no NaN/∞ may be spelled as a bit pattern.
fn literals_fit_f32(text: &str) -> Result<(), String> {
    for line in text.lines().map(str::trim_start).filter(|l| !l.starts_with("//") && !l.starts_with('#')) {
        if line.contains("BitsToFloat") || line.contains("bitcast") {
            return Err(format!("a bit-pattern constant: `{line}`"));
        }
        let mut rest = line;
        while let Some(i) = rest.find(|c: char| c.is_ascii_digit()) {
            let before = rest[..i].chars().next_back();
            let tail = &rest[i..];
            let len = tail
                .char_indices()
                .find(|&(k, c)| !(c.is_ascii_digit() || c == '.' || c == 'e' || ((c == '-' || c == '+') && tail[..k].ends_with('e'))))
                .map_or(tail.len(), |(k, _)| k);
            let word = before.is_some_and(|c| c.is_ascii_alphanumeric() || c == '_');
            if !word {
                let v: f64 = tail[..len].trim_end_matches(['e', '.']).parse().map_err(|e| format!("`{}` in `{line}`: {e}", &tail[..len]))?;
                if v != 0.0 && !(f32::MIN_POSITIVE as f64..=f32::MAX as f64).contains(&v) {
                    return Err(format!("the literal {} is outside f32's normal range: `{line}`", &tail[..len]));
                }
            }
            rest = &tail[len.max(1)..];
        }
    }
    Ok(())
}

fn examples() -> Vec<PathBuf> {
    let explorer = std::fs::read_dir(root().join("examples/explorer")).unwrap().map(|e| e.unwrap().path());
    let mut files: Vec<PathBuf> = catalogue().into_iter().chain(explorer.filter(|p| p.extension().is_some_and(|x| x == "brdf"))).collect();
    files.sort();
    assert!(files.len() >= 20, "{} example files", files.len());
    files
}

/// Every catalogue and explorer file, live and with n = 50 baked: GLSL 3.30, 4.50 and ES 3.00 test shaders
/// compile in glslangValidator, 4.50 also in naga's GLSL front end, WGSL in naga's, and no export writes a
/// constant f32 cannot hold.
#[test]
fn every_example_exports_for_every_target_and_validates() {
    let v = validator();
    if v.is_none() {
        eprintln!("glslangValidator not installed: GLSL checked by naga (4.50) and golden files only");
    }
    let dir = crate::scratch_dir("export", "targets");
    let mut checked = 0;
    for path in examples() {
        let src = std::fs::read_to_string(&path).unwrap();
        let rel = path.strip_prefix(root()).unwrap().display().to_string();
        let f = lobe::front::parse(&rel, &src).unwrap_or_else(|d| panic!("{}", d.render(false)));
        for bake in [&[][..], &[("n", 50.0)][..]] {
            let f = simplified(&f, bake);
            let stem = format!("{}-{}", glsl::function_name(&f), bake.len());
            for version in GlslVersion::ALL {
                let text = glsl::export(&f, Dialect::Glsl(version)).unwrap_or_else(|e| panic!("{rel} {bake:?} {}: {e}", version.name()));
                literals_fit_f32(&text).unwrap_or_else(|e| panic!("{rel} {bake:?} {}: {e}\n{text}", version.name()));
                let shader = glsl::glsl_test_shader(&f, version).unwrap();
                if let Some(v) = &v {
                    validate(v, &dir, &format!("{stem}-{}", version.name()), &shader);
                }
                if version == GlslVersion::V450 {
                    naga_glsl(&shader).unwrap_or_else(|e| panic!("{rel} {bake:?}: naga refuses the GLSL:\n{e}\n{shader}"));
                }
            }
            let wgsl = glsl::export(&f, Dialect::Wgsl).unwrap();
            literals_fit_f32(&wgsl).unwrap_or_else(|e| panic!("{rel} {bake:?} WGSL: {e}\n{wgsl}"));
            naga_wgsl(&wgsl).unwrap_or_else(|e| panic!("{rel} {bake:?}: naga refuses the WGSL:\n{e}\n{wgsl}"));
            let be = glsl::brdf_explorer(&f).unwrap();
            literals_fit_f32(be.split("::begin shader").nth(1).unwrap()).unwrap_or_else(|e| panic!("{rel} {bake:?} BRDF Explorer: {e}"));
            checked += 1;
        }
    }
    assert!(checked >= 40, "{checked}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The checks above can fail: a bit-pattern or an out-of-range literal is caught, a broken shader is refused by
/// naga.
#[test]
fn the_export_checks_catch_what_they_look_for() {
    assert!(literals_fit_f32("    float t0 = (NH * 1e39);").is_err());
    assert!(literals_fit_f32("    float t0 = (NH * 1e-39);").is_err());
    assert!(literals_fit_f32("    float t0 = uintBitsToFloat(0x7f800000u);").is_err());
    assert!(literals_fit_f32("// 1e400 in a comment\n    float t1 = (t0 * 2.5e-3) + 0.0 + 3.4e38;").is_ok());
    assert!(naga_wgsl("fn f(x: f32) -> f32 { return x * y; }").is_err());
    assert!(naga_wgsl("fn f(x: f32) -> f32 { return x * 2.0; }").is_ok());
    assert!(naga_glsl("#version 450\nlayout(location = 0) out vec4 c;\nvoid main() { c = vec4(q); }\n").is_err());
}

/// `lobe export --glsl-version`: each version's text is the library's, an unknown version is refused naming
/// the three, and a formula with a constant f32 cannot hold fails with file:line:col and a hint.
#[test]
fn export_command_takes_a_glsl_version_and_refuses_what_f32_cannot_hold() {
    let lobe = env!("CARGO_BIN_EXE_lobe");
    let path = root().join("examples/brdfs/cook_torrance.brdf");
    let f = simplified(&lobe::front::parse(&path.display().to_string(), &std::fs::read_to_string(&path).unwrap()).unwrap(), &[]);
    for version in GlslVersion::ALL {
        let out = Command::new(lobe).args(["export", "--glsl-version", version.name()]).arg(&path).output().unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let want = glsl::export(&f, Dialect::Glsl(version)).unwrap();
        assert_eq!(String::from_utf8(out.stdout).unwrap(), want, "--glsl-version {}", version.name());
    }
    let out = Command::new(lobe).args(["export", "--glsl-version", "310"]).arg(&path).output().unwrap();
    assert_eq!(out.status.code(), Some(2), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stderr).contains("`330`, `450` or `es300`"));
    let dir = crate::scratch_dir("export", "range");
    let bad = dir.join("huge.brdf");
    std::fs::write(&bad, "# a constant for f64\nNH * 1e300\n").unwrap();
    for flag in ["--glsl", "--wgsl", "--brdf-explorer"] {
        let out = Command::new(lobe).args(["export", flag]).arg(&bad).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{flag}: {err}");
        assert!(err.contains("huge.brdf:2:") && err.contains("beyond f32's range") && err.contains("help:"), "{flag}: {err}");
        assert!(!err.contains("panicked"), "{err}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn exports_match_golden_files() {
    let bless = std::env::var_os("LOBE_BLESS").is_some();
    let gdir = root().join("tests/golden/export");
    for (name, bake, d, ext) in [
        ("modified_schlick", &[("n", 50.0)][..], Dialect::Glsl(GlslVersion::V450), "glsl"),
        ("modified_schlick", &[][..], Dialect::Glsl(GlslVersion::V450), "live.glsl"),
        ("cook_torrance", &[][..], Dialect::Glsl(GlslVersion::V450), "glsl"),
        ("kutlog", &[("n", 100.0)][..], Dialect::Wgsl, "wgsl"),
    ] {
        let f = formula(&root().join(format!("examples/brdfs/{name}.brdf")), bake);
        let text = glsl::export(&f, d).unwrap().replace(env!("CARGO_PKG_VERSION"), "VERSION");
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
    let text = glsl::export(&f, Dialect::Glsl(GlslVersion::V450)).unwrap();
    assert!(text.contains("float lobe_modified_schlick(float NH, float n)"), "{text}");
    let baked = formula(&root().join("examples/brdfs/modified_schlick.brdf"), &[("n", 50.0)]);
    let text = glsl::export(&baked, Dialect::Glsl(GlslVersion::V450)).unwrap();
    assert!(text.contains("float lobe_modified_schlick(float NH)"), "{text}");
}

#[test]
fn hostile_parameter_names_export_valid_glsl() {
    let Some(v) = validator() else {
        eprintln!("glslangValidator not installed: hostile names checked by the unit test only");
        return;
    };
    // A line separator in the name (a CR would end the string): the export must not let it start a directive.
    let src = "@name \"x\u{2028}#define pow(a,b) 0.0\"\nparam t0 = 1\nparam float = 2\nparam gl_Position = 3\nparam output = 4\n\
               param alias = 5\nparam var = 6\nparam loop = 7\nparam f32 = 8\nparam main = 9\nparam __x = 1\n\
               let a = pow(NH, n)\nlet b = a * a + t0\nb * b * float * gl_Position * output * alias * var * loop * f32 * main * __x\n";
    let f = lobe::front::parse("hostile.brdf", src).unwrap_or_else(|d| panic!("{}", d.render(false)));
    let dir = std::env::temp_dir().join(format!("lobe-glsl-hostile-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("hostile.frag");
    let shader = glsl::glsl_test_shader(&f, GlslVersion::V450).unwrap();
    std::fs::write(&file, &shader).unwrap();
    let out = Command::new(&v).arg(&file).output().unwrap();
    assert!(out.status.success(), "not valid GLSL:\n{}\n{shader}", String::from_utf8_lossy(&out.stdout));
    let _ = std::fs::remove_dir_all(&dir);
}

/// A colour formula that reads directions, a bool and a colour parameter: an anisotropic Ward lobe over a
/// diffuse colour, `base / π + spec`, with `iso ? ax : ay` (built with `front::values`, as both front ends
/// lower). Its red channel alone is a scalar direction formula.
pub fn aniso_colour() -> lobe::Formula {
    use lobe::base::span::Span;
    use lobe::builtins::Builtin;
    use lobe::front::values::{Val, Values};
    use lobe::ir::{BinOp, Ir, Meta, ParamDecl, ParamKind};
    let s = Span::default();
    let decl = |name: &str, default: f64, kind: ParamKind| ParamDecl { name: name.into(), default, lo: 0.0, hi: 1.0, span: None, kind };
    let params = vec![
        ParamDecl::float("ax", 0.2, 0.01, 1.0),
        ParamDecl::float("ay", 0.5, 0.01, 1.0),
        decl("iso", 0.0, ParamKind::Bool),
        decl("base.r", 0.8, ParamKind::Color(0)),
        decl("base.g", 0.6, ParamKind::Color(1)),
        decl("base.b", 0.2, ParamKind::Color(2)),
        ParamDecl::float("gain", 1.0, 0.0, f64::INFINITY),
    ];
    let mut ir = Ir::new();
    let mut b = Values::new(&mut ir, s);
    let p = |b: &mut Values, i: u16| b.ir.param(i, s);
    let (ax, ay, iso) = (Val::F(p(&mut b, 0)), Val::F(p(&mut b, 1)), Val::B(p(&mut b, 2)));
    let gain = Val::F(p(&mut b, 6));
    let [l, v, n, x, y] = ["L", "V", "N", "X", "Y"].map(|k| b.frame(k).unwrap());
    let sum = b.arith(BinOp::Add, l, v).unwrap();
    let h = b.normalize(sum).unwrap();
    let ay = b.select(iso, ax, ay).unwrap();
    let hx = b.dot(h, x).unwrap();
    let hy = b.dot(h, y).unwrap();
    let nh = b.dot(n, h).unwrap();
    let sq = |b: &mut Values, a: Val| b.arith(BinOp::Mul, a, a).unwrap();
    let (qx, qy) = (b.arith(BinOp::Div, hx, ax).unwrap(), b.arith(BinOp::Div, hy, ay).unwrap());
    let (qx, qy, nh2) = (sq(&mut b, qx), sq(&mut b, qy), sq(&mut b, nh));
    let e = b.arith(BinOp::Add, qx, qy).unwrap();
    let e = b.neg(e).unwrap();
    let e = b.arith(BinOp::Div, e, nh2).unwrap();
    let e = b.builtin(Builtin::Exp, &[e]).unwrap();
    let (nl, nv) = (b.dot(n, l).unwrap(), b.dot(n, v).unwrap());
    let nlv = b.arith(BinOp::Mul, nl, nv).unwrap();
    let root = b.builtin(Builtin::Sqrt, &[nlv]).unwrap();
    let k = b.num(4.0 * std::f64::consts::PI);
    let d = b.arith(BinOp::Mul, k, ax).unwrap();
    let d = b.arith(BinOp::Mul, d, ay).unwrap();
    let d = b.arith(BinOp::Mul, d, root).unwrap();
    let spec = b.arith(BinOp::Div, e, d).unwrap();
    let spec = b.arith(BinOp::Mul, spec, gain).unwrap();
    let pi = b.num(std::f64::consts::PI);
    let mut roots = [lobe::ir::NodeId(0); 3];
    for (c, slot) in roots.iter_mut().enumerate() {
        let base = Val::F(p(&mut b, 3 + c as u16));
        let diffuse = b.arith(BinOp::Div, base, pi).unwrap();
        let Val::F(r) = b.arith(BinOp::Add, diffuse, spec).unwrap() else { unreachable!() };
        *slot = r;
    }
    lobe::Formula::from_channels(Meta::default(), params, &ir, roots, "aniso_colour.brdf".into(), String::new())
}

/// A fragment shader the way BRDF Explorer builds one from `file`: its reader (first line `analytic`, blank
/// and `#` lines skipped everywhere, `::begin`/`::end` sections), one `uniform float|bool|vec3` per parameter
/// line, the shader section pasted in, and a main that calls `BRDF` on a tangent frame.
fn brdf_explorer_shader(file: &str) -> String {
    let mut lines = file.lines();
    assert_eq!(lines.next().map(str::trim), Some("analytic"), "{file}");
    let (mut section, mut uniforms, mut shader) = (String::new(), String::new(), String::new());
    for line in lines {
        let t = line.trim();
        if t.is_empty() || t.starts_with('#') {
            continue;
        }
        let mut words = t.split_whitespace();
        match words.next().unwrap() {
            "::begin" => section = words.next().unwrap().to_string(),
            "::end" => {
                assert_eq!(words.next(), Some(section.as_str()), "{file}");
                section.clear();
            }
            ty if section == "parameters" => {
                let name = words.next().unwrap();
                let nums: Vec<f64> = words.map(|w| w.parse().unwrap_or_else(|_| panic!("`{w}` in `{t}`"))).collect();
                let (glsl_ty, count) = match ty {
                    "float" => ("float", 3),
                    "bool" => ("bool", 1),
                    "color" => ("vec3", 3),
                    _ => panic!("unknown parameter type in `{t}`"),
                };
                assert_eq!(nums.len(), count, "`{t}`");
                if ty == "float" {
                    assert!(nums.iter().all(|v| v.is_finite()) && nums[0] <= nums[2] && nums[2] <= nums[1], "`{t}`: finite min ≤ default ≤ max");
                }
                uniforms.push_str(&format!("uniform {glsl_ty} {name};\n"));
            }
            _ if section == "shader" => {
                shader.push_str(line);
                shader.push('\n');
            }
            _ => panic!("a line outside any section: `{t}`"),
        }
    }
    format!(
        "#version 410\nuniform vec3 incidentVector;\nuniform float brightness;\nout vec4 fragColor;\n{uniforms}\n{shader}\n\
         void main(void)\n{{\n    vec3 N = vec3(0.0, 0.0, 1.0);\n    vec3 X = normalize(cross(vec3(0.0, 1.0, 0.0), N));\n    \
         vec3 Y = normalize(cross(N, X));\n    vec3 V = normalize(vec3(0.3, -0.2, 0.9));\n    \
         vec3 b = max(BRDF(incidentVector, V, N, X, Y), vec3(0.0)) * brightness;\n    fragColor = vec4(b, 1.0);\n}}\n"
    )
}

/// Runs glslangValidator on `shader` (named `name` in messages); false when it is not installed.
fn validate(v: &Path, dir: &Path, name: &str, shader: &str) {
    let file = dir.join(format!("{name}.frag"));
    std::fs::write(&file, shader).unwrap();
    let out = Command::new(v).arg(&file).output().unwrap();
    assert!(out.status.success(), "{name} is not valid GLSL:\n{}\n{shader}", String::from_utf8_lossy(&out.stdout));
}

fn simplified(f: &lobe::Formula, bake: &[(&str, f64)]) -> lobe::Formula {
    let opts = Options { bake: bake.iter().map(|(k, v)| (k.to_string(), *v)).collect(), ..Options::default() };
    lobe::simplified(f, &opts).unwrap_or_else(|d| panic!("{}", d.render(false)))
}

#[test]
fn every_catalogue_file_exports_to_brdf_explorer_and_validates_in_its_template() {
    let Some(v) = validator() else {
        eprintln!("glslangValidator not installed: BRDF Explorer export not validated");
        return;
    };
    let dir = crate::scratch_dir("export", "brdf-explorer");
    let mut checked = 0;
    for path in catalogue() {
        for bake in [&[][..], &[("n", 50.0)][..]] {
            let f = formula(&path, bake);
            let text = glsl::brdf_explorer(&f).unwrap();
            assert!(text.contains("vec3 BRDF(vec3 L, vec3 V, vec3 N, vec3 X, vec3 Y)"), "{text}");
            // `n` is declared only when the formula reads it.
            assert_eq!(text.contains("\nfloat n "), bake.is_empty() && f.ir.used_params(f.root).contains(&0), "{text}");
            validate(&v, &dir, &format!("{}-{}", glsl::function_name(&f), bake.len()), &brdf_explorer_shader(&text));
            checked += 1;
        }
    }
    assert_eq!(checked, 2 * catalogue().len());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn direction_bool_and_colour_formulas_export_everywhere() {
    let colour = simplified(&aniso_colour(), &[]);
    let red = colour.channels().remove(0);
    let baked = simplified(&aniso_colour(), &[("iso", 1.0), ("base.g", 0.5)]);
    let be = glsl::brdf_explorer(&colour).unwrap();
    for want in [
        "float ax 0.01 1 0.2",
        "bool iso 0",
        "color base 0.8 0.6 0.2",
        "float gain 0 11 1",
        "# gain: declared range 0..inf",
        "float Lx = dot(L, X);",
        "float(iso)",
        "base.g",
        "return vec3(",
    ] {
        assert!(be.contains(want), "missing `{want}`:\n{be}");
    }
    assert!(!be.contains("float n ") && !be.contains("NH"), "{be}");
    let red_be = glsl::brdf_explorer(&red).unwrap();
    let shader = red_be.split("::begin shader").nth(1).unwrap();
    assert!(red_be.contains("color base 0.8 0.6 0.2") && shader.contains("base.r") && !shader.contains("base.g"), "{red_be}");
    // --glsl / --wgsl: directions are arguments, a colour is one vec3 argument, the result a vec3.
    let g = glsl::export(&colour, Dialect::Glsl(GlslVersion::V450)).unwrap();
    assert!(g.contains("vec3 lobe_aniso_colour(float Lx, float Ly, float Lz, float Vx, float Vy, float Vz, float ax, float ay, float iso, vec3 base, float gain)"), "{g}");
    assert!(g.contains("return vec3("), "{g}");
    let w = glsl::export(&colour, Dialect::Wgsl).unwrap();
    assert!(w.contains("base: vec3<f32>, gain: f32) -> vec3<f32> {") && w.contains("return vec3<f32>("), "{w}");
    let wr = glsl::export(&red, Dialect::Wgsl).unwrap();
    assert!(wr.contains("Lx: f32") && wr.contains("base: vec3<f32>") && wr.contains(") -> f32 {"), "{wr}");
    let gb = glsl::export(&baked, Dialect::Glsl(GlslVersion::V450)).unwrap();
    assert!(!gb.contains("float iso") && gb.contains("vec3 base"), "{gb}");
    let Some(v) = validator() else {
        eprintln!("glslangValidator not installed: direction and colour exports not validated");
        return;
    };
    let dir = crate::scratch_dir("export", "directions");
    for (name, f) in [("colour", &colour), ("red", &red), ("baked", &baked)] {
        validate(&v, &dir, &format!("be-{name}"), &brdf_explorer_shader(&glsl::brdf_explorer(f).unwrap()));
        for version in GlslVersion::ALL {
            validate(&v, &dir, &format!("glsl-{name}-{}", version.name()), &glsl::glsl_test_shader(f, version).unwrap());
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Import → export → import: a catalogue file exported for BRDF Explorer and read back evaluates as the
/// original (to f64 rounding of the exported literals), and exporting the import again changes nothing.
#[test]
fn brdf_explorer_export_round_trips_through_the_importer() {
    let dir = crate::scratch_dir("export", "round-trip");
    let lobe = env!("CARGO_BIN_EXE_lobe");
    let run = |args: &[&str]| {
        let out = Command::new(lobe).args(args).output().unwrap();
        assert!(out.status.success(), "lobe {args:?}: {}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8(out.stdout).unwrap()
    };
    let points = dir.join("points.csv");
    let mut csv = String::from("Lx,Ly,Lz,Vx,Vy,Vz\n");
    for (tl, pl, tv, pv) in [(0.1, 0.0, 0.5, 2.0), (0.7, 1.0, 0.3, -1.0), (1.2, 0.4, 1.0, 2.5), (0.0, 0.0, 0.0, 0.0), (1.5, 3.0, 0.9, 0.1)] {
        let (l, v) = (lobe::numerics::dir(tl, pl), lobe::numerics::dir(tv, pv));
        csv.push_str(&format!("{},{},{},{},{},{}\n", l[0], l[1], l[2], v[0], v[1], v[2]));
    }
    std::fs::write(&points, csv).unwrap();
    let values = |file: &Path| -> Vec<f64> {
        // One number per row, or `[r, g, b]` for a colour formula (explorer principled).
        let out = run(&["eval", file.to_str().unwrap(), "--points", points.to_str().unwrap()]);
        out.lines().flat_map(|l| l.trim_matches(['[', ']']).split(", ").map(|x| x.parse::<f64>().unwrap()).collect::<Vec<_>>()).collect()
    };
    // The explorer examples too: their accuracy-pass forms carry constants beyond f32's range (scaled-norm).
    let explorer = std::fs::read_dir(root().join("examples/explorer")).unwrap().map(|e| e.unwrap().path());
    for path in catalogue().into_iter().chain(explorer.filter(|p| p.extension().is_some_and(|x| x == "brdf"))) {
        let once = dir.join("once.brdf");
        let twice = dir.join("twice.brdf");
        run(&["export", "--brdf-explorer", path.to_str().unwrap(), "-o", once.to_str().unwrap(), "--force"]);
        run(&["export", "--brdf-explorer", once.to_str().unwrap(), "-o", twice.to_str().unwrap(), "--force"]);
        let (a, b, c) = (values(&path), values(&once), values(&twice));
        let close = |x: f64, y: f64, rel: f64| x == y || (x - y).abs() <= rel * x.abs() || (x.is_nan() && y.is_nan());
        assert!(a.len() >= 5 && (b.len(), c.len()) == (a.len(), a.len()), "{}: {a:?} {b:?} {c:?}", path.display());
        for ((x, y), z) in a.iter().zip(&b).zip(&c) {
            assert!(close(*x, *y, 1e-9), "{}: {x} vs {y} after export and import", path.display());
            assert!(close(*y, *z, 1e-12), "{}: a second round trip changed {y} to {z}", path.display());
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn export_command_writes_brdf_explorer_files() {
    let lobe = env!("CARGO_BIN_EXE_lobe");
    let blinn = root().join("examples/brdfs/blinn.brdf");
    let out = Command::new(lobe).args(["export", "--brdf-explorer"]).arg(&blinn).args(["--set", "n=20"]).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success() && text.starts_with("analytic\n") && text.contains("float NH = dot(N, H);"), "{text}");
    assert!(!text.contains("float n "), "n is baked:\n{text}");
    let both = Command::new(lobe).args(["export", "--glsl", "--brdf-explorer"]).arg(&blinn).output().unwrap();
    assert!(!both.status.success() && String::from_utf8_lossy(&both.stderr).contains("cannot be used with"));
}

/// What an export must never contain: the accuracy pass's internal builtins (no shader has them) and its
/// 2^600 scaling (∞ in a GPU's f32).
const NOT_IN_EXPORTS: [&str; 4] = ["acoslo", "powlo", "expmuldiv", "4.149515568880993e180"];

/// `lobe export --glsl|--wgsl|--brdf-explorer` writes the plain simplification with the `--set` values baked,
/// not the accuracy pass's form: for every catalogue and BRDF Explorer example the text is the library's export
/// of `lobe::simplified` (no pass), holds no internal builtin nor the pass's 2^600 scaling, and validates
/// (glslangValidator for GLSL, naga for WGSL).
#[test]
fn exports_are_the_plain_simplification_without_internal_builtins() {
    let lobe = env!("CARGO_BIN_EXE_lobe");
    let run = |args: &[&str]| {
        let out = Command::new(lobe).args(args).current_dir(root()).output().unwrap();
        assert!(out.status.success(), "lobe {args:?}: {}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8(out.stdout).unwrap()
    };
    let glslang = validator();
    let dir = crate::scratch_dir("export", "plain");
    for path in &examples() {
        let rel = path.strip_prefix(root()).unwrap().to_str().unwrap().to_string();
        let src = std::fs::read_to_string(path).unwrap();
        let f = lobe::front::parse(&rel, &src).unwrap_or_else(|d| panic!("{}", d.render(false)));
        for set in [None, Some("n=50")] {
            let mut args = vec![rel.as_str()];
            let mut bake = vec![];
            if let Some(s) = set {
                args.extend(["--set", s]);
                bake.push(("n", 50.0));
            }
            let plain = simplified(&f, &bake);
            for (flag, want) in [
                ("--glsl", glsl::export(&plain, Dialect::Glsl(GlslVersion::V450)).unwrap()),
                ("--wgsl", glsl::export(&plain, Dialect::Wgsl).unwrap()),
                ("--brdf-explorer", glsl::brdf_explorer(&plain).unwrap()),
            ] {
                let text = run(&[&["export", flag][..], &args].concat());
                assert_eq!(text, want, "{rel} {flag} {set:?}: not the plain simplification's export");
                for bad in NOT_IN_EXPORTS {
                    assert!(!text.contains(bad), "{rel} {flag} {set:?} contains `{bad}`:\n{text}");
                }
                let stem = format!("{}-{}", glsl::function_name(&plain), set.map_or(0, |_| 1));
                match flag {
                    "--glsl" => {
                        if let Some(v) = &glslang {
                            validate(v, &dir, &stem, &format!("#version 450\n{text}\nvoid main() {{}}\n"));
                        }
                    }
                    "--wgsl" => naga_wgsl(&text).unwrap_or_else(|e| panic!("{rel}: naga refuses the WGSL:\n{e}\n{text}")),
                    _ => {}
                }
            }
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}
