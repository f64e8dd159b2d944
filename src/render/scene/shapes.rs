//! `[[object]]` tables → meshes in world space: the sphere and torus generators, OBJ files, and the
//! translate/rotate/scale transform. Shape-specific keys on the wrong shape are errors (a `radius` on a torus
//! is a typo, not something to ignore). This is the part of loading that costs time for big meshes, which is
//! why [`super::Geometry`] does it once and shares the result.

use super::schema::{ObjectDef, Scale, Shape};
use crate::render::mesh::{self, Mesh};
use glam::DVec3;
use std::path::Path;

/// A rejected object: the scene span to underline, the message, and the label.
pub(super) type MeshErr = (std::ops::Range<usize>, String, String);

/// Builds object number `i`; relative mesh paths are resolved against `base`.
pub(super) fn build_mesh(base: &Path, files: &crate::base::source::Files, i: usize, d: &ObjectDef) -> Result<Mesh, MeshErr> {
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
            mesh::load_obj_through(&full, files).map_err(|e| {
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

/// Whether back faces are dropped: the object's `cull`, else on for the closed generated shapes and off for
/// OBJ meshes (which may be open or mis-wound).
pub(super) fn culls(d: &ObjectDef) -> bool {
    d.cull.unwrap_or(*d.shape.get_ref() != Shape::Mesh)
}
