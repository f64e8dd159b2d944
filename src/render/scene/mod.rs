//! Scene files: TOML → a resolved [`Scene`] (meshes in world space, compiled materials). The format:
//!
//! ```toml
//! width = 512                    # image size, 1..=4096 each (default 512×512)
//! height = 512
//! aa = 1                         # supersampling: aa×aa samples per pixel, averaged, 1..=8 (default 1: none)
//! background = [0, 0, 0]         # linear RGB, 0..1
//! ambient = [1, 0, 0]            # Ia
//! spp = 16                       # samples per pixel of the ray tracer, 1..=65536 (default 16)
//! shadows = false                # shadow rays for the lights (renders through the ray tracer)
//!
//! [environment]                  # optional: environment light, rendered by the ray tracer (`super::trace`)
//! path = "sky.exr"               # a latitude-longitude .exr or .hdr, relative to this file; or
//! # color = [1, 1, 1]            #  a constant sky (exactly one of the two)
//! rotate = 0                     # degrees about +y (the map's centre looks along +z; `super::envmap`)
//! intensity = 1                  # multiplies the map
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
//! params = { n = 50 }            # baked into the kernel; a run's values override
//! ka = 0.4                       # defaults: the papers' ka 0.4, kd 0.5, ks 0.5
//! kd = 0.5
//! ks = 0.5
//! color = [1, 1, 1]              # multiplies the ambient and diffuse terms
//! specular = [1, 1, 1]           # multiplies the specular term
//! normalize = false              # multiply F by the energy coefficient 1/(2π·Int(n))
//! cutoff = 8                     # optional: skip F where the lobe is below 2^-q (formulas of NH or VR only)
//! tangent_angle_deg = 0          # turns the tangent X (and bitangent Y) about the normal, for formulas that
//!                                #  read directions; the shapes' tangents: sphere ∂P/∂longitude (around +y),
//!                                #  torus along the ring, OBJ from its UVs (else a frame from the normal)
//! times_nl = false               # multiply F by NL: for BRDFs proper (BRDF Explorer's), whose f has no cosine
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
//! that referenced it.
//!
//! # Loading, in two stages
//! 1. **Geometry** ([`load_geometry`], [`parse_geometry`]): read and parse the TOML (`schema.rs`), check size,
//!    camera and lights, resolve each object's material name and build its mesh (`shapes.rs`). The result, a
//!    [`Geometry`], keeps the material tables uncompiled.
//! 2. **Materials** ([`Geometry::with_materials`]): compile each table's formula with the parameter values of
//!    this call (the run's values, or a formula that replaces every material's) and assemble a [`Scene`] (`material.rs`).
//!    Formulas are compiled through a [`BrdfCompiler`] — [`LobeCompiler`], the real front end and backends;
//!    the trait lets embedders supply kernels of their own.
//!
//! [`load_scene`] / [`parse_scene`] run both. The split exists because only stage 2 depends on parameter
//! values: comparing over several n parses the file and tessellates once, then runs stage 2 twice per n (the
//! scenes share the meshes through `Arc`, so a new [`Scene`] copies no vertex data). Diagnostics are the same
//! either way: one load reports geometry errors (size, camera, lights first; objects last) together with the
//! material errors, in that order, exactly as the single pass this replaced did. For that, stage 1 keeps its
//! errors inside the [`Geometry`] for stage 2 to report around the material errors; [`parse_geometry`] on its
//! own reports them at once and hands out only error-free geometry.
//!
//! # Files
//! The scene file and everything it names (meshes, formula files, measured tables) are read through one
//! [`Files`] policy: [`LoadOptions::files`] for a full load, the argument of [`load_geometry`] /
//! [`parse_geometry`] for stage 1, kept in the [`Geometry`] for stage 2. The commands pass the default (any
//! regular file); `lobe serve` passes its served directories, so the loader itself has no server case.

mod material;
mod schema;
mod shapes;

pub use material::{compile_channels, BrdfCompiler, CompiledBrdf, LobeCompiler};

use super::camera::Camera;
use super::envmap::EnvMap;
use super::trace::MAX_SPP;
use super::{Light, LightKind, Object, Scene, MAX_AA, MAX_SIZE};
use crate::base::diag::{Diagnostic, Diagnostics};
use crate::base::source::Files;
use crate::base::span::Span;
use glam::DVec3;
use schema::{is_colour, LightType, MaterialDef, SceneFile, V3};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use toml::Spanned;

/// The papers' comparison scene (`examples/scenes/paper_sphere.toml`, compiled in): what `lobe compare` and
/// `lobe serve` use when no scene is given.
pub const PAPER_SCENE: &str = include_str!("../../../examples/scenes/paper_sphere.toml");

/// What to override when loading.
#[derive(Clone, Debug, Default)]
pub struct LoadOptions {
    /// Image size instead of the file's.
    pub size: Option<(usize, usize)>,
    /// Parameter values for this run: applied to every material whose formula declares the name; an error if none does.
    pub set: Vec<(String, f64)>,
    /// Replace every material's formula by this (file name, source); ka/kd/ks, colours and `normalize` stay.
    /// Scene `params` the replacement does not declare are ignored. Used by `lobe compare`.
    pub formula_override: Option<(String, String)>,
    /// What the scene file and every file it names are read through (default: any regular file).
    pub files: Files,
}

/// A scene file parsed and checked, everything but the compiled materials: stage 1 of loading (see the module
/// docs). Make [`Scene`]s from it with [`Geometry::with_materials`], as many as needed.
#[derive(Clone, Debug)]
pub struct Geometry {
    /// Everything but the materials (`materials` is empty). Its objects' meshes are in world space and shared
    /// with every scene made from this geometry; `Object::material` indexes the material tables in name order
    /// (the order of [`Scene::materials`]).
    pub scene: Scene,
    /// The scene file's name and text (for diagnostics) and the directory relative paths start from.
    name: String,
    src: String,
    base: PathBuf,
    materials: BTreeMap<String, Spanned<MaterialDef>>,
    /// The file-access policy the geometry was loaded with; stage 2 reads the formula files through it too.
    files: Files,
    /// Errors found in stage 1 that a full load reports around the material errors: size, camera and lights
    /// before them, objects after. Always empty in a geometry handed out by [`parse_geometry`].
    deferred: [Vec<Diagnostic>; 2],
}

impl Geometry {
    /// The scene file's name, as diagnostics show it.
    pub(crate) fn name(&self) -> &str {
        &self.name
    }

    /// The formula files the materials name (`brdf = "…"`, joined to the scene's directory), in table order.
    pub fn material_files(&self) -> Vec<PathBuf> {
        self.materials.values().filter_map(|m| m.get_ref().brdf.as_ref().map(|p| self.base.join(p.get_ref()))).collect()
    }

    /// Compiles the materials (stage 2) and returns the scene. `set` applies to every material whose formula
    /// declares the name (an error if none does); `formula` = (file name, source) replaces every material's
    /// formula, keeping ka/kd/ks, colours and `normalize` (scene `params` it does not declare are ignored).
    pub fn with_materials(&self, set: &[(String, f64)], formula: Option<(&str, &str)>, compiler: &dyn BrdfCompiler) -> Result<Scene, Diagnostics> {
        let mut ds = Diagnostics::new(self.name.as_str(), self.src.as_str());
        ds.items.extend(self.deferred[0].iter().cloned());
        let at = material::SceneText { name: &self.name, src: &self.src, base: &self.base, files: &self.files };
        let materials = material::build_all(&at, &self.materials, &material::Choice { set, formula }, compiler, &mut ds)?;
        ds.items.extend(self.deferred[1].iter().cloned());
        if ds.has_errors() {
            return Err(ds);
        }
        Ok(Scene { materials, ..self.scene.clone() })
    }
}

/// The dotted key a byte offset of the TOML text belongs to, for messages: the key on its line (if the
/// offset is at or after `key =`) under the nearest `[table]` / `[[array]]` header above it.
pub(crate) fn key_at(src: &str, offset: usize) -> Option<String> {
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

/// Loads a scene file (both stages). Paths inside it are relative to its directory.
pub fn load_scene(path: &Path, opts: &LoadOptions, compiler: &dyn BrdfCompiler) -> Result<Scene, Diagnostics> {
    let (name, src, base) = read_scene(path, &opts.files)?;
    parse_scene(&name, &src, &base, opts, compiler)
}

/// Parses scene text (both stages); `base` is the directory relative paths are resolved against.
pub fn parse_scene(name: &str, src: &str, base: &Path, opts: &LoadOptions, compiler: &dyn BrdfCompiler) -> Result<Scene, Diagnostics> {
    let formula = opts.formula_override.as_ref().map(|(f, s)| (f.as_str(), s.as_str()));
    check(name, src, base, opts.size, &opts.files)?.with_materials(&opts.set, formula, compiler)
}

/// Loads a scene file's geometry (stage 1); `size` replaces the file's image size. The scene and every file it
/// names, now or in stage 2, are read through `files`.
pub fn load_geometry(path: &Path, size: Option<(usize, usize)>, files: &Files) -> Result<Geometry, Diagnostics> {
    let (name, src, base) = read_scene(path, files)?;
    parse_geometry(&name, &src, &base, size, files)
}

/// Parses scene text into its geometry (stage 1), reporting every error stage 1 finds.
pub fn parse_geometry(name: &str, src: &str, base: &Path, size: Option<(usize, usize)>, files: &Files) -> Result<Geometry, Diagnostics> {
    let mut g = check(name, src, base, size, files)?;
    if g.deferred.iter().any(|d| !d.is_empty()) {
        let mut ds = Diagnostics::new(name, src);
        ds.items = std::mem::take(&mut g.deferred).concat();
        return Err(ds);
    }
    Ok(g)
}

/// Stage 1 for callers that go on to [`Geometry::with_materials`] whatever happens (`lobe compare`): errors
/// other than unparsable TOML are kept and reported by `with_materials` together with the material errors,
/// so the diagnostics are exactly those of [`parse_scene`].
pub(in crate::render) fn parse_geometry_deferred(name: &str, src: &str, base: &Path, size: Option<(usize, usize)>) -> Result<Geometry, Diagnostics> {
    check(name, src, base, size, &Files::any())
}

/// Samples per pixel of the ray tracer when the scene does not say.
pub const DEFAULT_SPP: usize = 16;

/// Largest scene file read: a scene is a page of TOML (meshes live in their own files).
pub(crate) const MAX_SCENE_BYTES: u64 = 4 << 20;

fn read_scene(path: &Path, files: &Files) -> Result<(String, String, PathBuf), Diagnostics> {
    use crate::base::source::ReadError;
    let name = path.display().to_string();
    let fail = |d: Diagnostic| Diagnostics::single(name.clone(), d);
    let bytes = files.read(path, MAX_SCENE_BYTES).map_err(|e| {
        fail(match e {
            ReadError::Io(e) => {
                Diagnostic::error(format!("cannot read scene `{name}`: {e}")).hint("check the path; examples are in examples/scenes/")
            }
            ReadError::NotRegular => Diagnostic::error(format!("scene `{name}` is not a regular file")).hint("a scene is a TOML file"),
            ReadError::Refused(why) => Diagnostic::error(format!("cannot read scene `{name}`: {why}")),
            ReadError::TooLarge => Diagnostic::error(format!("scene `{name}` is larger than {} MiB", MAX_SCENE_BYTES >> 20))
                .hint("a scene is a page of TOML; put large meshes in .obj files referenced by `path`"),
        })
    })?;
    let src = String::from_utf8(bytes).map_err(|_| {
        Diagnostics::single(name.clone(), Diagnostic::error(format!("scene `{name}` is not UTF-8 text")).hint("a scene is a TOML file"))
    })?;
    let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
    Ok((name, src, base))
}

/// Stage 1. Fails only on TOML that does not fit the schema; every other error is kept in `deferred`.
fn check(name: &str, src: &str, base: &Path, size: Option<(usize, usize)>, files: &Files) -> Result<Geometry, Diagnostics> {
    let file: SceneFile = match toml::from_str(src) {
        Ok(f) => f,
        Err(e) => {
            let msg = e.message().trim().to_string();
            // A missing table or key has no place of its own in the text; do not blame the key at its span.
            let missing = msg.starts_with("missing field");
            let key = e.span().filter(|_| !missing).and_then(|s| key_at(src, s.start));
            let mut d = match &key {
                Some(k) => Diagnostic::error(format!("`{k}`: {msg}")),
                None => Diagnostic::error(msg.clone()),
            };
            if let Some(s) = e.span().filter(|_| !missing) {
                d = d.at(span_of(s), key.map(|k| format!("in `{k}`")).unwrap_or_else(|| "here".into()));
            }
            if msg.contains("missing field `camera`") {
                d = d.hint("add a [camera] table with at least `position = [x, y, z]`");
            }
            if e.message().contains("unknown field") {
                d = d.hint("the scene format is documented in src/render/scene/mod.rs; examples are in examples/scenes/");
            }
            let mut ds = Diagnostics::new(name, src);
            ds.push(d);
            return Err(ds);
        }
    };
    // Errors before the materials (size, camera, lights) and after them (objects).
    let (mut before, mut after) = (vec![], vec![]);
    let err = |ds: &mut Vec<Diagnostic>, span: std::ops::Range<usize>, msg: String, label: &str| {
        ds.push(Diagnostic::error(msg).at(span_of(span), label.to_string()));
    };

    // Size.
    let dim = |ds: &mut Vec<Diagnostic>, v: &Option<Spanned<i64>>, key: &str| -> usize {
        match v {
            None => 512,
            Some(s) if (1..=MAX_SIZE as i64).contains(s.get_ref()) => *s.get_ref() as usize,
            Some(s) => {
                err(ds, s.span(), format!("`{key}` = {} is outside 1..={MAX_SIZE}", s.get_ref()), "image size");
                1
            }
        }
    };
    let (mut width, mut height) = (dim(&mut before, &file.width, "width"), dim(&mut before, &file.height, "height"));
    if let Some((w, h)) = size {
        (width, height) = (w, h);
    }
    let aa = match &file.aa {
        None => 1,
        Some(s) if (1..=MAX_AA as i64).contains(s.get_ref()) => *s.get_ref() as usize,
        Some(s) => {
            err(&mut before, s.span(), format!("`aa` = {} is outside 1..={MAX_AA}", s.get_ref()), "samples per pixel side");
            1
        }
    };

    // Camera.
    let c = file.camera.get_ref();
    let camera = Camera { position: c.position.into(), look_at: c.look_at.into(), up: c.up.into(), fov_deg: c.fov };
    if let Err(m) = camera.validate() {
        err(&mut before, file.camera.span(), format!("[camera]: {m}"), "this camera");
    }

    // Colours and positions: finite, colours not negative (a NaN colour would blank a whole channel).
    let colour = |ds: &mut Vec<Diagnostic>, v: Option<&Spanned<V3>>, key: &str| -> DVec3 {
        let Some(v) = v else { return DVec3::ZERO };
        if !is_colour(v.get_ref()) {
            err(ds, v.span(), format!("`{key}` = {:?} must be three finite numbers ≥ 0", v.get_ref()), "linear RGB");
        }
        DVec3::from(*v.get_ref())
    };
    let background = colour(&mut before, file.background.as_ref(), "background");
    let ambient = colour(&mut before, file.ambient.as_ref(), "ambient");

    // Lights.
    let mut lights = vec![];
    for (i, l) in file.lights.iter().enumerate() {
        let d = l.get_ref();
        let finite = |v: &Option<V3>| v.is_none_or(|v| v.iter().all(|c| c.is_finite()));
        if !(finite(&d.position) && finite(&d.direction)) {
            err(&mut before, l.span(), format!("light[{i}]: `position` and `direction` must be finite"), "this light");
            continue;
        }
        if !is_colour(&d.color) {
            err(&mut before, l.span(), format!("light[{i}]: `color` = {:?} must be three finite numbers ≥ 0", d.color), "this light");
            continue;
        }
        let kind = match (d.kind, d.position, d.direction) {
            (LightType::Point, Some(p), None) => Some(LightKind::Point(p.into())),
            (LightType::Directional, None, Some(dir)) => match DVec3::from(dir).try_normalize() {
                Some(u) => Some(LightKind::Directional(u)),
                None => {
                    err(&mut before, l.span(), format!("light[{i}]: `direction` must be a non-zero vector"), "this light");
                    None
                }
            },
            (LightType::Point, _, _) => {
                err(&mut before, l.span(), format!("light[{i}]: a point light needs `position` (and no `direction`)"), "this light");
                None
            }
            (LightType::Directional, _, _) => {
                err(&mut before, l.span(), format!("light[{i}]: a directional light needs `direction` (and no `position`)"), "this light");
                None
            }
        };
        if let Some(kind) = kind {
            lights.push(Light { kind, color: d.color.into() });
        }
    }

    // Samples per pixel and the environment (read here, so a bad map is reported with the other scene errors).
    let spp = match &file.spp {
        None => DEFAULT_SPP,
        Some(s) if (1..=MAX_SPP as i64).contains(s.get_ref()) => *s.get_ref() as usize,
        Some(s) => {
            before.push(
                Diagnostic::error(format!("`spp` = {} is outside 1..={MAX_SPP}", s.get_ref()))
                    .at(span_of(s.span()), "samples per pixel")
                    .hint("a few hundred samples per pixel give a clean image; a reference a few thousand"),
            );
            1
        }
    };
    let mut environment = None;
    if let Some(e) = &file.environment {
        let d = e.get_ref();
        let (intensity, rotate) = (*d.intensity.get_ref(), *d.rotate.get_ref());
        let at = |s: std::ops::Range<usize>| if s.is_empty() { span_of(e.span()) } else { span_of(s) };
        let made = match (&d.path, &d.color) {
            (Some(p), None) => EnvMap::load(&base.join(p.get_ref()), files, intensity, rotate).map_err(|m| {
                Diagnostic::error(format!("[environment]: {m}"))
                    .at(span_of(p.span()), "this map")
                    .hint("a latitude-longitude OpenEXR (.exr) or Radiance (.hdr) file, relative to the scene file")
            }),
            (None, Some(c)) => EnvMap::constant(DVec3::from(*c.get_ref()), intensity, rotate)
                .map_err(|m| Diagnostic::error(format!("[environment]: {m}")).at(span_of(c.span()), "linear RGB")),
            _ => Err(Diagnostic::error("[environment] needs exactly one of `path` (a map) and `color` (a constant sky)")
                .at(span_of(e.span()), "this environment")),
        };
        let intensity_ok = intensity.is_finite() && intensity >= 0.0;
        match made {
            // A bad intensity or rotation is blamed on its own key when it has one.
            Err(mut diag) if !(intensity_ok && rotate.is_finite()) => {
                let span = if intensity_ok { d.rotate.span() } else { d.intensity.span() };
                diag.primary = Some((at(span), "here".into()));
                before.push(diag)
            }
            Err(diag) => before.push(diag),
            Ok(m) => environment = Some(Arc::new(m)),
        }
    }
    let shadows = file.shadows;

    // Objects: a material by name (an index into the tables, compiled in stage 2), and a mesh.
    let mat_names: Vec<&String> = file.materials.keys().collect();
    let mut objects = vec![];
    for (i, o) in file.objects.iter().enumerate() {
        let d = o.get_ref();
        let Some(mi) = mat_names.iter().position(|n| *n == d.material.get_ref()) else {
            let mut diag = Diagnostic::error(format!("object[{i}]: unknown material `{}`", d.material.get_ref())).at(span_of(d.material.span()), "not defined under [materials]");
            diag = match crate::front::suggest(d.material.get_ref(), mat_names.iter().map(|s| s.as_str())) {
                Some(s) => diag.hint(format!("did you mean `{s}`?")),
                None => diag.hint(format!("define it as [materials.{}]", d.material.get_ref())),
            };
            after.push(diag);
            continue;
        };
        match shapes::build_mesh(base, files, i, d) {
            Ok(mesh) => objects.push(Object { mesh: Arc::new(mesh), material: mi, cull_backfaces: shapes::culls(d) }),
            Err((span, msg, label)) => err(&mut after, span, msg, &label),
        }
    }
    Ok(Geometry {
        scene: Scene { width, height, aa, camera, background, ambient, lights, materials: vec![], objects, environment, spp, shadows },
        name: name.to_string(),
        src: src.to_string(),
        base: base.to_path_buf(),
        materials: file.materials,
        files: files.clone(),
        deferred: [before, after],
    })
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
