//! Scene files: TOML → a resolved [`Scene`] (meshes in world space, compiled materials).
//!
//! ```toml
//! width = 512                    # image size, 1..=4096 each (default 512×512)
//! height = 512
//! background = [0, 0, 0]         # linear RGB, 0..1
//! ambient = [1, 0, 0]            # Ia
//!
//! [camera]
//! position = [0, 0, 6]
//! look_at = [0, 0, 0]            # default origin
//! up = [0, 1, 0]                 # default +y
//! fov = 30                       # vertical, degrees (default 45)
//!
//! [[light]]
//! kind = "point"                 # or "directional" with `direction = [x, y, z]` (the way the light travels)
//! position = [10, 0, 10]
//! color = [1, 1, 1]
//!
//! [materials.shiny]
//! brdf = "../brdfs/phong.brdf"   # relative to this file; or `formula = "VR^n"` inline
//! params = { n = 50 }            # baked into the kernel; `--set` overrides
//! ka = 0.4                       # defaults: the papers' ka 0.4, kd 0.5, ks 0.5
//! kd = 0.5
//! ks = 0.5
//! color = [1, 1, 1]              # multiplies the ambient and diffuse terms
//! specular = [1, 1, 1]           # multiplies the specular term
//! normalize = false              # multiply F by the energy coefficient 1/(2π·Int(n))
//!
//! [[object]]
//! shape = "sphere"               # "sphere" (radius, tessellation, slices), "torus" (major_radius,
//! material = "shiny"             #  minor_radius, segments = [ring, tube]), "mesh" (path = "x.obj")
//! tessellation = 20              # stacks: Δθ = π/20; slices default to 2·stacks (Δφ = π/20 too)
//! translate = [0, 0, 0]
//! rotate = [0, 0, 0]             # degrees about x, then y, then z
//! scale = 1                      # or [sx, sy, sz]
//! ```
//!
//! Every table denies unknown keys. Errors are [`Diagnostics`] on the scene file (file:line:col, carets, the
//! key, a hint); a formula that fails to compile reports its own diagnostics plus a note naming the scene key
//! that referenced it. Formulas are compiled through a [`BrdfCompiler`] — [`LobeCompiler`], the real front
//! end and backends; the trait lets embedders supply kernels of their own.

use super::camera::Camera;
use super::mesh::{self, Mesh};
use super::{Light, LightKind, Material, Object, Scene, MAX_SIZE};
use crate::base::diag::{Diagnostic, Diagnostics};
use crate::base::span::Span;
use crate::ir::{InputSet, ParamDecl};
use crate::backend::{Backend, Evaluator};
use glam::DVec3;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use toml::Spanned;

/// Turns formula source into an evaluator. `declare` lists the parameters (to check scene values against);
/// `build` bakes `values` (all parameters, by name) into the kernel.
pub trait BrdfCompiler: Sync {
    fn declare(&self, file: &str, src: &str) -> Result<Vec<ParamDecl>, Diagnostics>;
    fn build(&self, file: &str, src: &str, values: &[(String, f64)]) -> Result<CompiledBrdf, Diagnostics>;
}

/// A compiled material formula.
#[derive(Clone)]
pub struct CompiledBrdf {
    pub evaluator: Arc<dyn Evaluator>,
    pub used: InputSet,
}

/// The real pipeline: `lobe::compile_source` with the chosen backend.
pub struct LobeCompiler {
    pub backend: Backend,
}

impl BrdfCompiler for LobeCompiler {
    fn declare(&self, file: &str, src: &str) -> Result<Vec<ParamDecl>, Diagnostics> {
        Ok(crate::front::parse(file, src)?.params)
    }
    fn build(&self, file: &str, src: &str, values: &[(String, f64)]) -> Result<CompiledBrdf, Diagnostics> {
        let opts = crate::Options { backend: self.backend, bake: values.to_vec(), ..crate::Options::default() };
        let k = crate::compile_source(file, src, &opts)?;
        Ok(CompiledBrdf { used: k.used_inputs(), evaluator: Arc::new(k) })
    }
}


/// What to override when loading.
#[derive(Clone, Debug, Default)]
pub struct LoadOptions {
    /// Image size instead of the file's.
    pub size: Option<(usize, usize)>,
    /// `--set` values: applied to every material whose formula declares the name; an error if none does.
    pub set: Vec<(String, f64)>,
    /// Replace every material's formula by this (file name, source); ka/kd/ks, colours and `normalize` stay.
    /// Scene `params` the replacement does not declare are ignored. Used by `lobe compare`.
    pub formula_override: Option<(String, String)>,
}

type V3 = [f64; 3];

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    width: Option<Spanned<i64>>,
    height: Option<Spanned<i64>>,
    #[serde(default)]
    background: V3,
    #[serde(default)]
    ambient: V3,
    camera: Spanned<CameraDef>,
    #[serde(default, rename = "light")]
    lights: Vec<Spanned<LightDef>>,
    #[serde(default)]
    materials: BTreeMap<String, Spanned<MaterialDef>>,
    #[serde(default, rename = "object")]
    objects: Vec<Spanned<ObjectDef>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraDef {
    position: V3,
    #[serde(default)]
    look_at: V3,
    #[serde(default = "default_up")]
    up: V3,
    #[serde(default = "default_fov")]
    fov: f64,
}

fn default_up() -> V3 {
    [0.0, 1.0, 0.0]
}
fn default_fov() -> f64 {
    45.0
}
fn white() -> V3 {
    [1.0; 3]
}

#[derive(Deserialize, Clone, Copy, PartialEq)]
#[serde(rename_all = "lowercase")]
enum LightType {
    Point,
    Directional,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct LightDef {
    kind: LightType,
    position: Option<V3>,
    direction: Option<V3>,
    #[serde(default = "white")]
    color: V3,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MaterialDef {
    brdf: Option<Spanned<String>>,
    formula: Option<Spanned<String>>,
    #[serde(default)]
    params: BTreeMap<Spanned<String>, Spanned<f64>>,
    #[serde(default = "default_ka")]
    ka: f64,
    #[serde(default = "default_kd")]
    kd: f64,
    #[serde(default = "default_ks")]
    ks: f64,
    #[serde(default = "white")]
    color: V3,
    #[serde(default = "white")]
    specular: V3,
    #[serde(default)]
    normalize: bool,
}

fn default_ka() -> f64 {
    0.4
}
fn default_kd() -> f64 {
    0.5
}
fn default_ks() -> f64 {
    0.5
}

#[derive(Deserialize, Clone, Copy, PartialEq, Debug)]
#[serde(rename_all = "lowercase")]
enum Shape {
    Sphere,
    Torus,
    Mesh,
}

#[derive(Deserialize)]
#[serde(untagged)]
enum Scale {
    Uniform(f64),
    Axes(V3),
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ObjectDef {
    shape: Spanned<Shape>,
    material: Spanned<String>,
    radius: Option<f64>,
    tessellation: Option<u32>,
    slices: Option<u32>,
    major_radius: Option<f64>,
    minor_radius: Option<f64>,
    segments: Option<[u32; 2]>,
    path: Option<Spanned<String>>,
    #[serde(default)]
    translate: V3,
    #[serde(default)]
    rotate: V3,
    scale: Option<Scale>,
    /// Drop back faces (default: on for sphere and torus, off for meshes, which may be open or mis-wound).
    cull: Option<bool>,
}

/// The dotted key a byte offset of the TOML text belongs to, for messages: the key on its line (if the
/// offset is at or after `key =`) under the nearest `[table]` / `[[array]]` header above it.
pub fn key_at(src: &str, offset: usize) -> Option<String> {
    let offset = offset.min(src.len());
    let line_start = src[..offset].rfind('\n').map(|i| i + 1).unwrap_or(0);
    let line = src[line_start..].lines().next().unwrap_or("");
    let key = line.split_once('=').map(|(k, _)| k.trim().to_string()).filter(|k| !k.is_empty() && !k.starts_with('#'));
    let table = src[..line_start].lines().rev().map(str::trim).find(|l| l.starts_with('[')).map(|l| {
        let l = l.split('#').next().unwrap_or("").trim();
        l.trim_start_matches('[').trim_end_matches(']').trim().to_string()
    });
    match (table, key) {
        (Some(t), Some(k)) => Some(format!("{t}.{k}")),
        (None, Some(k)) => Some(k),
        (Some(t), None) => Some(t),
        (None, None) => None,
    }
}

fn span_of(r: std::ops::Range<usize>) -> Span {
    Span::new(r.start, r.end)
}

/// Loads a scene file. Paths inside it are relative to its directory.
pub fn load_scene(path: &Path, opts: &LoadOptions, compiler: &dyn BrdfCompiler) -> Result<Scene, Diagnostics> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|e| {
        Diagnostics::single(
            name.clone(),
            Diagnostic::error(format!("cannot read scene `{name}`: {e}")).hint("check the path; examples are in examples/scenes/"),
        )
    })?;
    let src = String::from_utf8(bytes).map_err(|_| {
        Diagnostics::single(name.clone(), Diagnostic::error(format!("scene `{name}` is not UTF-8 text")).hint("a scene is a TOML file"))
    })?;
    let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
    parse_scene(&name, &src, &base, opts, compiler)
}

/// Parses scene text; `base` is the directory relative paths are resolved against.
pub fn parse_scene(name: &str, src: &str, base: &Path, opts: &LoadOptions, compiler: &dyn BrdfCompiler) -> Result<Scene, Diagnostics> {
    let mut ds = Diagnostics::new(name, src);
    let file: SceneFile = match toml::from_str(src) {
        Ok(f) => f,
        Err(e) => {
            let msg = e.message().trim().to_string();
            let key = e.span().and_then(|s| key_at(src, s.start));
            let mut d = match &key {
                Some(k) => Diagnostic::error(format!("`{k}`: {msg}")),
                None => Diagnostic::error(msg),
            };
            if let Some(s) = e.span() {
                d = d.at(span_of(s), key.map(|k| format!("in `{k}`")).unwrap_or_else(|| "here".into()));
            }
            if e.message().contains("unknown field") {
                d = d.hint("the scene format is documented in src/render/scene.rs; examples are in examples/scenes/");
            }
            ds.push(d);
            return Err(ds);
        }
    };
    let err = |ds: &mut Diagnostics, span: std::ops::Range<usize>, msg: String, label: &str| {
        ds.push(Diagnostic::error(msg).at(span_of(span), label.to_string()));
    };

    // Size.
    let dim = |ds: &mut Diagnostics, v: &Option<Spanned<i64>>, key: &str| -> usize {
        match v {
            None => 512,
            Some(s) if (1..=MAX_SIZE as i64).contains(s.get_ref()) => *s.get_ref() as usize,
            Some(s) => {
                err(ds, s.span(), format!("`{key}` = {} is outside 1..={MAX_SIZE}", s.get_ref()), "image size");
                1
            }
        }
    };
    let (mut width, mut height) = (dim(&mut ds, &file.width, "width"), dim(&mut ds, &file.height, "height"));
    if let Some((w, h)) = opts.size {
        (width, height) = (w, h);
    }

    // Camera.
    let c = file.camera.get_ref();
    let camera = Camera { position: c.position.into(), look_at: c.look_at.into(), up: c.up.into(), fov_deg: c.fov };
    if let Err(m) = camera.validate() {
        err(&mut ds, file.camera.span(), format!("[camera]: {m}"), "this camera");
    }

    // Lights.
    let mut lights = vec![];
    for (i, l) in file.lights.iter().enumerate() {
        let d = l.get_ref();
        let kind = match (d.kind, d.position, d.direction) {
            (LightType::Point, Some(p), None) => Some(LightKind::Point(p.into())),
            (LightType::Directional, None, Some(dir)) => match DVec3::from(dir).try_normalize() {
                Some(u) => Some(LightKind::Directional(u)),
                None => {
                    err(&mut ds, l.span(), format!("light[{i}]: `direction` must be a non-zero vector"), "this light");
                    None
                }
            },
            (LightType::Point, _, _) => {
                err(&mut ds, l.span(), format!("light[{i}]: a point light needs `position` (and no `direction`)"), "this light");
                None
            }
            (LightType::Directional, _, _) => {
                err(&mut ds, l.span(), format!("light[{i}]: a directional light needs `direction` (and no `position`)"), "this light");
                None
            }
        };
        if let Some(kind) = kind {
            lights.push(Light { kind, color: d.color.into() });
        }
    }

    // Materials.
    let mat_names: Vec<&String> = file.materials.keys().collect();
    let mut materials = vec![];
    let mut set_used = vec![false; opts.set.len()];
    for (mname, m) in &file.materials {
        match build_material(name, src, base, mname, m, opts, compiler, &mut set_used) {
            Ok(mat) => materials.push(mat),
            Err(e) => match e {
                MatError::Scene(d) => ds.push(d),
                MatError::Formula(fd) => {
                    if ds.has_errors() {
                        return Err(ds);
                    }
                    return Err(fd);
                }
            },
        }
    }
    for (i, (k, _)) in opts.set.iter().enumerate() {
        if !set_used[i] && !file.materials.is_empty() {
            ds.push(Diagnostic::error(format!("--set {k}: no material's formula declares a parameter `{k}`")).hint("every formula has `n`; see each .brdf file's `param` lines"));
        }
    }

    // Objects.
    let mut objects = vec![];
    for (i, o) in file.objects.iter().enumerate() {
        let d = o.get_ref();
        let Some(mi) = mat_names.iter().position(|n| *n == d.material.get_ref()) else {
            let mut diag = Diagnostic::error(format!("object[{i}]: unknown material `{}`", d.material.get_ref())).at(span_of(d.material.span()), "not defined under [materials]");
            diag = match crate::front::suggest(d.material.get_ref(), mat_names.iter().map(|s| s.as_str())) {
                Some(s) => diag.hint(format!("did you mean `{s}`?")),
                None => diag.hint(format!("define it as [materials.{}]", d.material.get_ref())),
            };
            ds.push(diag);
            continue;
        };
        match build_mesh(base, i, d) {
            Ok(mesh) => objects.push(Object { mesh, material: mi, cull_backfaces: d.cull.unwrap_or(*d.shape.get_ref() != Shape::Mesh) }),
            Err((span, msg, label)) => err(&mut ds, span, msg, &label),
        }
    }
    if ds.has_errors() {
        return Err(ds);
    }
    Ok(Scene {
        width,
        height,
        camera,
        background: file.background.into(),
        ambient: file.ambient.into(),
        lights,
        materials,
        objects,
    })
}

enum MatError {
    Scene(Diagnostic),
    Formula(Diagnostics),
}

#[allow(clippy::too_many_arguments)]
fn build_material(
    scene_name: &str,
    scene_src: &str,
    base: &Path,
    mname: &str,
    m: &Spanned<MaterialDef>,
    opts: &LoadOptions,
    compiler: &dyn BrdfCompiler,
    set_used: &mut [bool],
) -> Result<Material, MatError> {
    let d = m.get_ref();
    let here = |s: std::ops::Range<usize>, msg: String, label: &str| MatError::Scene(Diagnostic::error(msg).at(span_of(s), label.to_string()));
    // Where the formula comes from, and the scene span to blame.
    let (file, src, key_span) = if let Some((f, s)) = &opts.formula_override {
        (f.clone(), s.clone(), m.span())
    } else {
        match (&d.brdf, &d.formula) {
            (Some(p), None) => {
                let path: PathBuf = base.join(p.get_ref());
                let file = path.display().to_string();
                let src = match crate::base::source::read_source(&file) {
                    Ok((_, s)) => s,
                    Err(mut d) => {
                        d.message = format!("materials.{mname}.brdf: {}", d.message);
                        return Err(MatError::Scene(d.at(span_of(p.span()), "this path (relative to the scene file)")));
                    }
                };
                (file, src, p.span())
            }
            (None, Some(f)) => (format!("{scene_name} [materials.{mname}.formula]"), f.get_ref().clone(), f.span()),
            (Some(_), Some(f)) => return Err(here(f.span(), format!("materials.{mname}: give `brdf` or `formula`, not both"), "second source")),
            (None, None) => return Err(here(m.span(), format!("materials.{mname}: needs `brdf = \"path.brdf\"` or `formula = \"…\"`"), "this material")),
        }
    };
    let (line, col) = crate::base::span::line_col(scene_src, key_span.start);
    let with_note = |mut fd: Diagnostics| {
        for it in &mut fd.items {
            it.hints.push(format!("used by [materials.{mname}] at {scene_name}:{line}:{col}"));
        }
        MatError::Formula(fd)
    };
    let decls = compiler.declare(&file, &src).map_err(with_note)?;
    let mut values: Vec<(String, f64)> = decls.iter().map(|p| (p.name.clone(), p.default)).collect();
    let mut assign = |name: &str, v: f64| -> Result<bool, String> {
        match decls.iter().position(|p| p.name == name) {
            Some(i) => {
                let p = &decls[i];
                if !p.admits(v) {
                    return Err(format!("value {v} for `{name}` is outside the formula's declared range {}..{}", p.lo, p.hi));
                }
                values[i].1 = v;
                Ok(true)
            }
            None => Ok(false),
        }
    };
    for (k, v) in &d.params {
        match assign(k.get_ref(), *v.get_ref()) {
            Ok(true) => {}
            Ok(false) if opts.formula_override.is_some() => {}
            Ok(false) => {
                let names: Vec<&str> = decls.iter().map(|p| p.name.as_str()).collect();
                let hint = match crate::front::suggest(k.get_ref(), names.iter().copied()) {
                    Some(s) => format!("did you mean `{s}`?"),
                    None => format!("the formula's parameters are: {}", names.join(", ")),
                };
                return Err(MatError::Scene(
                    Diagnostic::error(format!("materials.{mname}.params: the formula has no parameter `{}`", k.get_ref()))
                        .at(span_of(k.span()), "unknown parameter")
                        .hint(hint),
                ));
            }
            Err(msg) => return Err(here(v.span(), format!("materials.{mname}.params.{}: {msg}", k.get_ref()), "out of range")),
        }
    }
    for (i, (k, v)) in opts.set.iter().enumerate() {
        match assign(k, *v) {
            Ok(true) => set_used[i] = true,
            Ok(false) => {}
            Err(msg) => return Err(here(m.span(), format!("--set {k}={v} for material `{mname}`: {msg}"), "this material")),
        }
    }
    let compiled = compiler.build(&file, &src, &values).map_err(with_note)?;
    for (k, val) in [("ka", d.ka), ("kd", d.kd), ("ks", d.ks)] {
        if !(val.is_finite() && val >= 0.0) {
            return Err(here(m.span(), format!("materials.{mname}.{k} = {val} must be a finite number ≥ 0"), "this material"));
        }
    }
    let params: Vec<f64> = values.iter().map(|(_, v)| *v).collect();
    let coef = if d.normalize {
        crate::numerics::normalize::coefficient(compiled.evaluator.as_ref(), compiled.used, &params)
            .map_err(|e| e.to_string())
            .map_err(|msg| here(m.span(), format!("materials.{mname}.normalize: {msg}"), "this material"))?
    } else {
        1.0
    };
    Ok(Material {
        name: mname.to_string(),
        evaluator: compiled.evaluator,
        used: compiled.used,
        params,
        ka: d.ka,
        kd: d.kd,
        ks: d.ks,
        color: d.color.into(),
        specular: d.specular.into(),
        coef,
    })
}

type MeshErr = (std::ops::Range<usize>, String, String);

fn build_mesh(base: &Path, i: usize, d: &ObjectDef) -> Result<Mesh, MeshErr> {
    let shape = *d.shape.get_ref();
    let sspan = d.shape.span();
    let bad = |msg: String| (sspan.clone(), format!("object[{i}]: {msg}"), format!("shape = {shape:?}").to_lowercase());
    let only = |set: bool, key: &str, for_shape: &str| {
        if set {
            Err(bad(format!("`{key}` applies only to shape = \"{for_shape}\"")))
        } else {
            Ok(())
        }
    };
    if shape != Shape::Sphere {
        only(d.radius.is_some(), "radius", "sphere")?;
        only(d.tessellation.is_some(), "tessellation", "sphere")?;
        only(d.slices.is_some(), "slices", "sphere")?;
    }
    if shape != Shape::Torus {
        only(d.major_radius.is_some(), "major_radius", "torus")?;
        only(d.minor_radius.is_some(), "minor_radius", "torus")?;
        only(d.segments.is_some(), "segments", "torus")?;
    }
    if shape != Shape::Mesh {
        only(d.path.is_some(), "path", "mesh")?;
    }
    let positive = |v: f64, key: &str| if v.is_finite() && v > 0.0 { Ok(v) } else { Err(bad(format!("`{key}` = {v} must be > 0"))) };
    let mut mesh = match shape {
        Shape::Sphere => {
            let r = positive(d.radius.unwrap_or(1.0), "radius")?;
            let stacks = d.tessellation.unwrap_or(20);
            let slices = d.slices.unwrap_or(stacks.saturating_mul(2));
            if !(2..=2000).contains(&stacks) || !(3..=4000).contains(&slices) {
                return Err(bad(format!("tessellation {stacks}×{slices} is outside 2..=2000 stacks, 3..=4000 slices")));
            }
            Mesh::sphere(r, stacks, slices)
        }
        Shape::Torus => {
            let big = positive(d.major_radius.unwrap_or(1.0), "major_radius")?;
            let small = positive(d.minor_radius.unwrap_or(0.25), "minor_radius")?;
            let [u, v] = d.segments.unwrap_or([48, 24]);
            if !(3..=4000).contains(&u) || !(3..=4000).contains(&v) {
                return Err(bad(format!("segments [{u}, {v}] must each be in 3..=4000")));
            }
            Mesh::torus(big, small, u, v)
        }
        Shape::Mesh => {
            let Some(p) = &d.path else {
                return Err(bad("a mesh needs `path = \"file.obj\"` (relative to the scene file)".into()));
            };
            let full = base.join(p.get_ref());
            mesh::load_obj(&full).map_err(|e| {
                let at = match e.line {
                    Some(l) => format!("{}:{l}: ", full.display()),
                    None => format!("{}: ", full.display()),
                };
                (p.span(), format!("object[{i}].path: {at}{}", e.message), "this mesh".to_string())
            })?
        }
    };
    let scale: DVec3 = match d.scale {
        None => DVec3::ONE,
        Some(Scale::Uniform(s)) => DVec3::splat(s),
        Some(Scale::Axes(a)) => a.into(),
    };
    let (t, r): (DVec3, DVec3) = (d.translate.into(), d.rotate.into());
    if !(scale.is_finite() && scale.abs().min_element() > 1e-12 && t.is_finite() && r.is_finite()) {
        return Err(bad("`translate`, `rotate` and `scale` must be finite and the scale non-zero".into()));
    }
    mesh.transform(&mesh::transform_matrix(t, r, scale));
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_are_named_from_offsets() {
        let src = "width = 5\n[camera]\nposition = \"x\"\n[[light]]\ncolor = 1\n";
        assert_eq!(key_at(src, 3).as_deref(), Some("width"));
        assert_eq!(key_at(src, src.find("\"x").unwrap()).as_deref(), Some("camera.position"));
        assert_eq!(key_at(src, src.find("1\n").unwrap()).as_deref(), Some("light.color"));
    }

}
