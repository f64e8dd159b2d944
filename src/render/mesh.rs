//! Triangle meshes: the papers' UV sphere, a torus, and OBJ files (via tobj), plus affine transforms.
//!
//! A [`Mesh`] holds per-vertex positions and unit normals and counter-clockwise (seen from outside)
//! triangles. The renderer interpolates the vertex normals per pixel (Phong shading), so the tessellation
//! level shows only in the silhouette and in how the normal field bends, exactly as in the papers' program.
//!
//! Tangent frames: every mesh also carries a unit tangent per vertex, orthogonal to its normal, for formulas
//! that read directions in the local frame (anisotropic models; the bitangent is always N × T). The sphere
//! and the torus take ∂P/∂u of their parametrisation (the direction of growing longitude; the ring direction);
//! OBJ meshes with texture coordinates take the per-triangle tangent of the UV map (∂P/∂u from the UV
//! derivatives, summed over the triangles at a vertex); anything else gets [`onb_tangent`], a stable frame
//! from the normal alone. Every tangent is Gram–Schmidt orthonormalised against its vertex normal; the
//! shader interpolates and orthonormalises again per pixel. Cost: O(vertices + triangles) once per mesh.

use glam::{DMat3, DMat4, DVec3};
use std::f64::consts::PI;

/// An indexed triangle mesh with per-vertex normals.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    pub positions: Vec<DVec3>,
    pub normals: Vec<DVec3>,
    /// Unit tangent per vertex, orthogonal to its normal (see the module docs). An empty list (hand-built
    /// meshes) means [`onb_tangent`] of each normal.
    pub tangents: Vec<DVec3>,
    /// Counter-clockwise seen from the side the normals point to.
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    /// A UV sphere with `stacks` latitude bands (Δθ = π/stacks) and `slices` longitude segments
    /// (Δφ = 2π/slices). The papers' sphere is `sphere(1, 20, 40)`: Δ = π/20 in both angles.
    /// Pole triangles of zero area are not emitted.
    pub fn sphere(radius: f64, stacks: u32, slices: u32) -> Mesh {
        let (stacks, slices) = (stacks.max(2), slices.max(3));
        let mut m = Mesh::default();
        for i in 0..=stacks {
            let theta = PI * i as f64 / stacks as f64;
            for j in 0..=slices {
                let phi = 2.0 * PI * j as f64 / slices as f64;
                // y is up; the sphere's poles are at ±y, φ = 0 faces +z (the viewer in the papers' scene).
                let n = DVec3::new(theta.sin() * phi.sin(), theta.cos(), theta.sin() * phi.cos());
                m.positions.push(n * radius);
                m.normals.push(n);
                // ∂P/∂φ / (r·sin θ): defined at the poles too, orthogonal to n by construction.
                m.tangents.push(DVec3::new(phi.cos(), 0.0, -phi.sin()));
            }
        }
        let row = slices + 1;
        for i in 0..stacks {
            for j in 0..slices {
                let a = i * row + j; // (θ_i, φ_j)
                let b = a + row; // (θ_i+1, φ_j)
                let c = b + 1; // (θ_i+1, φ_j+1)
                let d = a + 1; // (θ_i, φ_j+1)
                if i != 0 {
                    m.triangles.push([a, b, d]);
                }
                if i != stacks - 1 {
                    m.triangles.push([d, b, c]);
                }
            }
        }
        m
    }

    /// A torus around the y axis: ring radius `major`, tube radius `minor`, `segments` around the ring and
    /// `sides` around the tube.
    pub(crate) fn torus(major: f64, minor: f64, segments: u32, sides: u32) -> Mesh {
        let (segments, sides) = (segments.max(3), sides.max(3));
        let mut m = Mesh::default();
        for i in 0..=segments {
            let u = 2.0 * PI * i as f64 / segments as f64;
            let centre = DVec3::new(u.cos(), 0.0, -u.sin()) * major;
            let radial = DVec3::new(u.cos(), 0.0, -u.sin());
            for j in 0..=sides {
                let v = 2.0 * PI * j as f64 / sides as f64;
                let n = radial * v.cos() + DVec3::Y * v.sin();
                m.positions.push(centre + n * minor);
                m.normals.push(n);
                // ∂P/∂u normalised: along the ring, orthogonal to both the radial and the y direction.
                m.tangents.push(DVec3::new(-u.sin(), 0.0, -u.cos()));
            }
        }
        let row = sides + 1;
        for i in 0..segments {
            for j in 0..sides {
                let a = i * row + j;
                let b = a + row;
                m.triangles.push([a, b, a + 1]);
                m.triangles.push([a + 1, b, b + 1]);
            }
        }
        m
    }

    /// Builds a mesh from raw positions and triangles, computing smooth area-weighted vertex normals (for OBJ
    /// files without `vn` lines).
    pub(crate) fn with_smooth_normals(positions: Vec<DVec3>, triangles: Vec<[u32; 3]>) -> Mesh {
        let mut normals = vec![DVec3::ZERO; positions.len()];
        for t in &triangles {
            let [a, b, c] = t.map(|i| positions[i as usize]);
            let n = (b - a).cross(c - a); // length = 2·area: larger faces weigh more
            for &i in t {
                normals[i as usize] += n;
            }
        }
        let normals: Vec<DVec3> = normals.into_iter().map(|n| n.try_normalize().unwrap_or(DVec3::Y)).collect();
        let tangents = normals.iter().map(|n| onb_tangent(*n)).collect();
        Mesh { positions, normals, tangents, triangles }
    }

    /// Replaces the tangents by those of a UV map (`uv[i]` per vertex): per triangle T = (e1·Δv2 − e2·Δv1)/det
    /// (the direction of growing u), summed at each vertex, then orthonormalised against its normal; a vertex
    /// whose triangles all have degenerate UVs gets [`onb_tangent`].
    pub(crate) fn set_uv_tangents(&mut self, uv: &[[f64; 2]]) {
        let mut acc = vec![DVec3::ZERO; self.positions.len()];
        for t in &self.triangles {
            let [a, b, c] = t.map(|i| i as usize);
            let (e1, e2) = (self.positions[b] - self.positions[a], self.positions[c] - self.positions[a]);
            let (du1, dv1) = (uv[b][0] - uv[a][0], uv[b][1] - uv[a][1]);
            let (du2, dv2) = (uv[c][0] - uv[a][0], uv[c][1] - uv[a][1]);
            let det = du1 * dv2 - du2 * dv1;
            if det.abs() < 1e-300 || !det.is_finite() {
                continue;
            }
            // Dividing by |det| would weigh triangles by their UV density; the sign keeps u's direction.
            let tang = (e1 * dv2 - e2 * dv1) * det.signum();
            for i in [a, b, c] {
                acc[i] += tang;
            }
        }
        self.tangents = acc.iter().zip(&self.normals).map(|(t, n)| orthonormal_tangent(*t, *n)).collect();
    }

    /// The tangent of vertex `i` ([`onb_tangent`] of its normal when the mesh has none).
    pub(crate) fn tangent(&self, i: usize) -> DVec3 {
        self.tangents.get(i).copied().unwrap_or_else(|| onb_tangent(self.normals[i]))
    }

    /// Applies an affine transform: positions by `m`, normals by its inverse transpose (renormalised).
    pub fn transform(&mut self, m: &DMat4) {
        let nm = DMat3::from_mat4(*m).inverse().transpose();
        for p in &mut self.positions {
            *p = m.transform_point3(*p);
        }
        for n in &mut self.normals {
            *n = (nm * *n).try_normalize().unwrap_or(DVec3::Y);
        }
        // Tangents are surface directions: they transform by the linear part itself, then are made orthogonal
        // to the transformed normal again (a non-uniform scale tilts them).
        let lin = DMat3::from_mat4(*m);
        for (t, n) in self.tangents.iter_mut().zip(&self.normals) {
            *t = orthonormal_tangent(lin * *t, *n);
        }
        // A mirroring transform flips the winding; keep triangles counter-clockwise from outside.
        if m.determinant() < 0.0 {
            for t in &mut self.triangles {
                t.swap(1, 2);
            }
        }
    }
}

/// A unit tangent orthogonal to the unit normal `n`, continuous in `n` except across n.z = 0: the first
/// vector of Duff et al. 2017's branchless orthonormal basis ("Building an Orthonormal Basis, Revisited").
pub(crate) fn onb_tangent(n: DVec3) -> DVec3 {
    let sign = 1f64.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x)
}

/// Gram–Schmidt: `t` minus its component along the unit normal `n`, normalised; [`onb_tangent`] when `t` is
/// (nearly) parallel to `n`, zero or not finite.
pub(crate) fn orthonormal_tangent(t: DVec3, n: DVec3) -> DVec3 {
    (t - n * n.dot(t)).try_normalize().filter(|u| u.dot(n).abs() < 1e-6).unwrap_or_else(|| onb_tangent(n))
}

/// translate · rotate (Z·Y·X, degrees) · scale — the order a scene author expects: scale the object, turn
/// it, then move it.
pub fn transform_matrix(translate: DVec3, rotate_deg: DVec3, scale: DVec3) -> DMat4 {
    let r = DMat4::from_rotation_z(rotate_deg.z.to_radians())
        * DMat4::from_rotation_y(rotate_deg.y.to_radians())
        * DMat4::from_rotation_x(rotate_deg.x.to_radians());
    DMat4::from_translation(translate) * r * DMat4::from_scale(scale)
}

/// Why an OBJ file could not be used; `line` is 1-based when the fault could be located.
#[derive(Debug, Clone, PartialEq)]
pub struct ObjError {
    pub message: String,
    pub line: Option<usize>,
}

/// Largest OBJ file read (a bound on time and memory for a wrong path such as /dev/zero; ~4 M triangles).
pub(crate) const MAX_OBJ_BYTES: u64 = 256 << 20;

/// Loads every model of an OBJ file into one mesh (triangulated; smooth normals computed when the file has
/// none). The text is first checked line by line by [`obj_fault`] — tobj reports only an error kind, and
/// accepts values the renderer cannot use (`vn 0 0 0`, coordinates beyond f32) — so every fault is named with
/// its line.
pub fn load_obj(path: &std::path::Path) -> Result<Mesh, ObjError> {
    load_obj_through(path, &crate::base::source::Files::any())
}

/// [`load_obj`], the file read through `files` (a scene's file-access policy).
pub(crate) fn load_obj_through(path: &std::path::Path, files: &crate::base::source::Files) -> Result<Mesh, ObjError> {
    use crate::base::source::ReadError;
    let text = files.read(path, MAX_OBJ_BYTES).map_err(|e| ObjError {
        message: match e {
            ReadError::Io(e) => format!("cannot read: {e}"),
            ReadError::NotRegular => "not a regular file".into(),
            ReadError::TooLarge => format!("larger than {} MiB; is this the right file?", MAX_OBJ_BYTES >> 20),
            ReadError::Refused(why) => why,
        },
        line: None,
    })?;
    // A byte-order mark (editors on Windows write one) is not part of the first line: tobj would read `\u{feff}v`
    // as an unknown keyword and drop the first vertex, shifting every face.
    let text = text.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(&text);
    if let Some((line, message)) = obj_fault(&String::from_utf8_lossy(text)) {
        return Err(ObjError { message, line: Some(line) });
    }
    let opts = tobj::LoadOptions { single_index: true, triangulate: true, ignore_points: true, ignore_lines: true };
    let mut reader = std::io::BufReader::new(text);
    let loaded = tobj::load_obj_buf(&mut reader, &opts, |_| Err(tobj::LoadError::OpenFileFailed));
    let models = match loaded {
        Ok((models, _materials)) => models,
        Err(e) => return Err(ObjError { message: format!("not a valid OBJ file ({e})"), line: None }),
    };
    let mut positions = Vec::new();
    let mut normals = Vec::new();
    let mut uvs: Vec<[f64; 2]> = Vec::new();
    let mut triangles = Vec::new();
    let mut all_have_normals = true;
    let mut all_have_uvs = true;
    for m in &models {
        let mesh = &m.mesh;
        let base = positions.len() as u32;
        let nv = mesh.positions.len() / 3;
        positions.extend(mesh.positions.chunks_exact(3).map(|p| DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)));
        if mesh.normals.len() == mesh.positions.len() {
            normals.extend(mesh.normals.chunks_exact(3).map(|n| DVec3::new(n[0] as f64, n[1] as f64, n[2] as f64)));
        } else {
            all_have_normals = false;
        }
        if mesh.texcoords.len() == nv * 2 && nv > 0 {
            uvs.extend(mesh.texcoords.chunks_exact(2).map(|t| [t[0] as f64, t[1] as f64]));
        } else {
            all_have_uvs = false;
        }
        for t in mesh.indices.chunks_exact(3) {
            if t.iter().any(|&i| i as usize >= nv) {
                return Err(ObjError { message: "a face refers to a vertex that does not exist".into(), line: None });
            }
            triangles.push([base + t[0], base + t[1], base + t[2]]);
        }
    }
    if triangles.is_empty() {
        return Err(ObjError { message: "the file has no faces".into(), line: None });
    }
    let mut mesh = if all_have_normals {
        let normals: Vec<DVec3> = normals.into_iter().map(|n: DVec3| n.try_normalize().unwrap_or(DVec3::Y)).collect();
        let tangents = normals.iter().map(|n| onb_tangent(*n)).collect();
        Mesh { positions, normals, tangents, triangles }
    } else {
        Mesh::with_smooth_normals(positions, triangles)
    };
    if all_have_uvs {
        mesh.set_uv_tangents(&uvs);
    }
    Ok(mesh)
}

/// The first line of `src` that the OBJ subset lobe reads (`v`, `vn`, `vt`, `f`) rejects, with the reason:
/// a vertex without three numbers finite in f32 (what tobj stores), a zero or non-finite normal, a face
/// with fewer than three corners or an index out of range, or a face corner without a normal index in a file
/// that has normals (half the faces would silently get computed normals).
pub(crate) fn obj_fault(src: &str) -> Option<(usize, String)> {
    let (mut nv, mut nvt, mut nvn) = (0i64, 0i64, 0i64);
    let has_normals = src.lines().any(|l| l.split_whitespace().next() == Some("vn"));
    for (i, line) in src.lines().enumerate() {
        let mut it = line.split_whitespace();
        let Some(kw) = it.next() else { continue };
        let rest: Vec<&str> = it.collect();
        let numbers = |k: usize| -> Option<Vec<f32>> {
            let v: Vec<f32> = rest.iter().map(|s| s.parse::<f32>().ok().filter(|v| v.is_finite())).collect::<Option<_>>()?;
            (v.len() >= k).then_some(v)
        };
        let fault = match kw {
            "v" => {
                nv += 1;
                numbers(3).is_none().then(|| "a vertex needs three numbers, each finite in single precision (|x| < 3.4e38)".to_string())
            }
            "vn" => {
                nvn += 1;
                match numbers(3) {
                    None => Some("a normal needs three finite numbers".to_string()),
                    Some(n) if n[..3].iter().all(|c| *c == 0.0) => Some("a normal of zero length has no direction".to_string()),
                    Some(_) => None,
                }
            }
            "vt" => {
                nvt += 1;
                numbers(1).is_none().then(|| "a texture coordinate needs finite numbers".to_string())
            }
            "f" => {
                let index_ok = |k: usize, s: &str| {
                    let count = [nv, nvt, nvn][k.min(2)];
                    match s.parse::<i64>() {
                        Ok(idx) if idx > 0 => idx <= count,
                        Ok(idx) if idx < 0 => -idx <= count,
                        _ => false,
                    }
                };
                if rest.len() < 3 {
                    Some("a face needs at least three corners".to_string())
                } else if !rest.iter().all(|c| c.split('/').enumerate().all(|(k, s)| (s.is_empty() && k == 1) || index_ok(k, s))) {
                    Some("a face index is missing, malformed or out of range".to_string())
                } else if has_normals && rest.iter().any(|c| c.split('/').nth(2).is_none_or(str::is_empty)) {
                    Some("this face has a corner without a normal index (v//vn) although the file has normals; give every corner one, or remove the `vn` lines to have smooth normals computed".to_string())
                } else {
                    None
                }
            }
            _ => None,
        };
        if let Some(m) = fault {
            return Some((i + 1, m));
        }
    }
    None
}

/// The line of [`obj_fault`].
#[cfg(test)]
fn locate_obj_fault(src: &str) -> Option<usize> {
    obj_fault(src).map(|(line, _)| line)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    /// Sum over triangles of (a × b)·c / 6: the enclosed volume, positive when every face is counter-clockwise
    /// seen from outside.
    fn signed_volume(m: &Mesh) -> f64 {
        m.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| m.positions[i as usize]);
                a.cross(b).dot(c) / 6.0
            })
            .sum()
    }

    #[test]
    fn sphere_is_closed_outward_and_converges_to_the_ball_volume() {
        let m = Mesh::sphere(1.0, 20, 40);
        assert_eq!(m.triangles.len(), 2 * 20 * 40 - 2 * 40);
        let v = signed_volume(&m);
        // An inscribed polyhedron: a little under 4π/3, and closer with finer tessellation.
        assert!(v > 0.0 && v < 4.0 * PI / 3.0, "{v}");
        let fine = signed_volume(&Mesh::sphere(1.0, 80, 160));
        assert!((4.0 * PI / 3.0 - fine) < (4.0 * PI / 3.0 - v) / 10.0);
        for (p, n) in m.positions.iter().zip(&m.normals) {
            assert!((p.length() - 1.0).abs() < 1e-12 && (n.dot(*p) - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn torus_volume_matches_pappus() {
        let m = Mesh::torus(2.0, 0.5, 96, 48);
        let exact = 2.0 * PI * 2.0 * PI * 0.25; // 2πR · πr²
        let v = signed_volume(&m);
        assert!((v - exact).abs() / exact < 0.01, "{v} vs {exact}");
    }

    #[test]
    fn mirroring_keeps_outward_winding() {
        let mut m = Mesh::sphere(1.0, 8, 16);
        m.transform(&transform_matrix(DVec3::new(1.0, 2.0, 3.0), DVec3::new(10.0, 20.0, 30.0), DVec3::new(-1.0, 2.0, 1.0)));
        let v = signed_volume(&m);
        assert!(v > 0.0, "{v}");
    }

    /// Every vertex frame is orthonormal: unit tangent, orthogonal to the unit normal.
    fn assert_orthonormal(m: &Mesh, what: &str) {
        assert_eq!(m.tangents.len(), m.positions.len(), "{what}");
        for (i, (t, n)) in m.tangents.iter().zip(&m.normals).enumerate() {
            assert!((t.length() - 1.0).abs() < 1e-12 && t.dot(*n).abs() < 1e-12, "{what} vertex {i}: t = {t}, n = {n}");
        }
    }

    #[test]
    fn frames_are_orthonormal_on_every_shape() {
        let sphere = Mesh::sphere(2.0, 20, 40);
        assert_orthonormal(&sphere, "sphere");
        // The sphere's tangent is the direction of growing longitude: horizontal, turning with φ.
        for (t, p) in sphere.tangents.iter().zip(&sphere.positions) {
            assert!(t.y.abs() < 1e-15);
            if p.x.hypot(p.z) > 1e-9 {
                assert!((t.cross(DVec3::new(p.x, 0.0, p.z).normalize()) - DVec3::NEG_Y).length() < 1e-12, "{t} at {p}");
            }
        }
        let torus = Mesh::torus(2.0, 0.5, 24, 12);
        assert_orthonormal(&torus, "torus");
        for (t, p) in torus.tangents.iter().zip(&torus.positions) {
            // Along the ring: orthogonal to the radial direction and to the axis.
            assert!(t.y.abs() < 1e-15 && t.dot(DVec3::new(p.x, 0.0, p.z).normalize()).abs() < 1e-12);
        }
        // A non-uniform, mirroring transform tilts tangents off the new normals; they are re-orthonormalised.
        let mut m = Mesh::torus(2.0, 0.5, 24, 12);
        m.transform(&transform_matrix(DVec3::new(1.0, 2.0, 3.0), DVec3::new(10.0, 20.0, 30.0), DVec3::new(-1.0, 3.0, 0.5)));
        assert_orthonormal(&m, "transformed torus");
        let bumpy = load_obj(&Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/meshes/bumpy.obj")).unwrap();
        assert_orthonormal(&bumpy, "OBJ without UVs");
        // Duff et al.'s frame, including the normal that breaks the classic formula (n = −z).
        for n in [DVec3::Z, DVec3::NEG_Z, DVec3::X, DVec3::new(1e-300, -1e-300, -1.0), DVec3::new(0.3, -0.4, -0.5).normalize()] {
            let t = onb_tangent(n);
            assert!((t.length() - 1.0).abs() < 1e-12 && t.dot(n).abs() < 1e-12, "{n}: {t}");
        }
        // A tangent parallel to the normal, zero or NaN falls back to that frame.
        for bad in [DVec3::Z * 3.0, DVec3::ZERO, DVec3::NAN] {
            assert_eq!(orthonormal_tangent(bad, DVec3::Z), onb_tangent(DVec3::Z));
        }
    }

    #[test]
    fn obj_uv_tangents_follow_the_uv_map() {
        // examples/meshes/uv_roof.obj: a roof with its ridge along x; u runs from y = −1 over the ridge (y = 0,
        // z = 1) to y = 1. So ∂P/∂u is (0, 1, 1)/√2 on one slope, (0, 1, −1)/√2 on the other, and +y on the
        // ridge, where the two slopes' tangents are summed and made orthogonal to the ridge's normal +z (the
        // file gives the normals: +z on the ridge, the slopes' own on the eaves).
        let m = load_obj(&Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/meshes/uv_roof.obj")).unwrap();
        assert_orthonormal(&m, "uv_roof");
        let r = std::f64::consts::FRAC_1_SQRT_2;
        for (p, t) in m.positions.iter().zip(&m.tangents) {
            let want = match p.y {
                y if y < -0.5 => DVec3::new(0.0, r, r),
                y if y > 0.5 => DVec3::new(0.0, r, -r),
                _ => DVec3::Y,
            };
            assert!((*t - want).length() < 1e-6, "at {p}: {t} vs {want}");
        }
        // The same file without its `vt` lines gets the normal-only frame instead.
        let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/meshes/uv_roof.obj")).unwrap();
        let plain: String = text.lines().filter(|l| !l.starts_with("vt")).map(|l| {
            let l = if l.starts_with("f ") {
                l.split_whitespace().map(|c| c.split('/').enumerate().map(|(k, x)| if k == 1 { "" } else { x }).collect::<Vec<_>>().join("/")).collect::<Vec<_>>().join(" ")
            } else {
                l.to_string()
            };
            l + "\n"
        }).collect();
        let dir = std::env::temp_dir().join(format!("lobe-mesh-uv-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("plain.obj");
        std::fs::write(&path, plain).unwrap();
        let p = load_obj(&path).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        assert_orthonormal(&p, "uv_roof without UVs");
        assert!(p.tangents.iter().zip(&p.normals).all(|(t, n)| *t == onb_tangent(*n)));
    }

    #[test]
    fn a_byte_order_mark_does_not_drop_the_first_vertex() {
        let dir = std::env::temp_dir().join(format!("lobe-mesh-bom-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let text = std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/meshes/uv_roof.obj")).unwrap();
        let (plain, bom) = (dir.join("plain.obj"), dir.join("bom.obj"));
        std::fs::write(&plain, &text).unwrap();
        std::fs::write(&bom, [&b"\xEF\xBB\xBF"[..], &text].concat()).unwrap();
        let (a, b) = (load_obj(&plain).unwrap(), load_obj(&bom).unwrap());
        let _ = std::fs::remove_dir_all(&dir);
        assert_eq!(a.positions, b.positions);
        assert_eq!(a.triangles, b.triangles);
        assert_eq!(a.normals, b.normals);
    }

    #[test]
    fn obj_faults_are_located() {
        assert_eq!(locate_obj_fault("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"), None);
        assert_eq!(locate_obj_fault("v 0 0 0\nv 1 x 0\n"), Some(2));
        assert_eq!(locate_obj_fault("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n"), Some(4));
        assert_eq!(locate_obj_fault("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1//1 2 3\n"), Some(4));
    }

    #[test]
    fn obj_values_the_renderer_cannot_use_are_located() {
        let tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
        assert_eq!(locate_obj_fault(&format!("{tri}v 1e39 0 0\n")), Some(4));
        assert!(obj_fault(&format!("{tri}vn 0 0 0\nf 1//1 2//1 3//1\n")).unwrap().1.contains("zero length"));
        assert_eq!(locate_obj_fault(&format!("{tri}vn nan 0 1\nf 1//1 2//1 3//1\n")), Some(4));
        assert!(obj_fault(&format!("{tri}vn 0 0 1\nf 1//1 2//1 3\n")).unwrap().1.contains("normal index"));
        assert_eq!(obj_fault(&format!("{tri}vn 0 0 1\nf 1//1 2//1 3//1\n")), None);
        assert_eq!(obj_fault(&format!("{tri}f 1 2 3\n")), None);
    }
}
