//! The scene file format as serde structs: they mirror the TOML of the format documented in [`super`] one to
//! one, with its defaults (docs/scenes.md shows the same example; keep the three in step).
//!
//! Every table denies unknown keys. Values that need a location in messages are [`Spanned`]; nothing here
//! checks ranges or cross-references — that is `mod.rs` (size, camera, lights, objects), `shapes.rs` and
//! `material.rs`.

use serde::Deserialize;
use std::collections::BTreeMap;
use toml::Spanned;

pub(super) type V3 = [f64; 3];

/// A usable linear-RGB colour: three finite numbers ≥ 0 (a NaN would blank a whole channel).
pub(super) fn is_colour(c: &V3) -> bool {
    c.iter().all(|v| v.is_finite() && *v >= 0.0)
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct SceneFile {
    pub width: Option<Spanned<i64>>,
    pub height: Option<Spanned<i64>>,
    /// Supersampling: `aa`×`aa` samples per pixel.
    pub aa: Option<Spanned<i64>>,
    pub background: Option<Spanned<V3>>,
    pub ambient: Option<Spanned<V3>>,
    pub camera: Spanned<CameraDef>,
    #[serde(default, rename = "light")]
    pub lights: Vec<Spanned<LightDef>>,
    /// By name; the map's (sorted) order is the order of [`crate::render::Scene::materials`].
    #[serde(default)]
    pub materials: BTreeMap<String, Spanned<MaterialDef>>,
    #[serde(default, rename = "object")]
    pub objects: Vec<Spanned<ObjectDef>>,
    /// Environment light (the scene then renders through the ray tracer).
    pub environment: Option<Spanned<EnvironmentDef>>,
    /// Samples per pixel of the ray tracer.
    pub spp: Option<Spanned<i64>>,
    /// Shadow rays for the point and directional lights (ray tracer).
    #[serde(default)]
    pub shadows: bool,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct EnvironmentDef {
    /// A latitude–longitude map (.exr or .hdr), relative to the scene file.
    pub path: Option<Spanned<String>>,
    /// A constant sky.
    pub color: Option<Spanned<V3>>,
    /// Degrees about +y.
    #[serde(default = "zero")]
    pub rotate: Spanned<f64>,
    #[serde(default = "one")]
    pub intensity: Spanned<f64>,
}

fn zero() -> Spanned<f64> {
    Spanned::new(0..0, 0.0)
}
fn one() -> Spanned<f64> {
    Spanned::new(0..0, 1.0)
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct CameraDef {
    pub position: V3,
    #[serde(default)]
    pub look_at: V3,
    #[serde(default = "default_up")]
    pub up: V3,
    #[serde(default = "default_fov")]
    pub fov: f64,
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
pub(super) enum LightType {
    Point,
    Directional,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct LightDef {
    pub kind: LightType,
    pub position: Option<V3>,
    pub direction: Option<V3>,
    #[serde(default = "white")]
    pub color: V3,
}

#[derive(Deserialize, Clone, Debug)]
#[serde(deny_unknown_fields)]
pub(super) struct MaterialDef {
    pub brdf: Option<Spanned<String>>,
    pub formula: Option<Spanned<String>>,
    #[serde(default)]
    pub params: BTreeMap<Spanned<String>, Spanned<f64>>,
    #[serde(default = "default_ka")]
    pub ka: f64,
    #[serde(default = "default_kd")]
    pub kd: f64,
    #[serde(default = "default_ks")]
    pub ks: f64,
    #[serde(default = "white")]
    pub color: V3,
    #[serde(default = "white")]
    pub specular: V3,
    #[serde(default)]
    pub normalize: bool,
    /// The papers' cut-off exponent q: F is not evaluated where the lobe is below 2^−q.
    #[serde(default)]
    pub cutoff: Option<Spanned<f64>>,
    /// `math = "fast"` or `"precise"`: this material's math mode (default: the math mode the caller chose).
    #[serde(default)]
    pub math: Option<Spanned<String>>,
    /// Turns the shape's tangent about the normal, degrees (anisotropic formulas; default 0).
    #[serde(default)]
    pub tangent_angle_deg: Option<Spanned<f64>>,
    /// Multiply F by NL (formulas that are a BRDF without the cosine, as BRDF Explorer's).
    #[serde(default)]
    pub times_nl: bool,
    /// `lookup = "linear"` or `"nearest"`: how a measured table is read ([`crate::measured::Lookup`]).
    #[serde(default)]
    pub lookup: Option<Spanned<String>>,
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
pub(super) enum Shape {
    Sphere,
    Torus,
    Mesh,
}

#[derive(Deserialize)]
#[serde(untagged)]
pub(super) enum Scale {
    Uniform(f64),
    Axes(V3),
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ObjectDef {
    pub shape: Spanned<Shape>,
    pub material: Spanned<String>,
    pub radius: Option<f64>,
    pub tessellation: Option<u32>,
    pub slices: Option<u32>,
    pub major_radius: Option<f64>,
    pub minor_radius: Option<f64>,
    pub segments: Option<[u32; 2]>,
    pub path: Option<Spanned<String>>,
    #[serde(default)]
    pub translate: V3,
    #[serde(default)]
    pub rotate: V3,
    pub scale: Option<Scale>,
    /// Drop back faces (default: on for sphere and torus, off for meshes, which may be open or mis-wound).
    pub cull: Option<bool>,
}
