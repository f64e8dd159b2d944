//! Triangle meshes: the papers' UV sphere, a torus, and OBJ files (via tobj), plus affine transforms.
//!
//! A [`Mesh`] holds per-vertex positions and unit normals and counter-clockwise (seen from outside)
//! triangles. The renderer interpolates the vertex normals per pixel (Phong shading), so the tessellation
//! level shows only in the silhouette and in how the normal field bends, exactly as in the papers' program.

use glam::{DMat3, DMat4, DVec3};
use std::f64::consts::PI;

/// An indexed triangle mesh with per-vertex normals.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    pub positions: Vec<DVec3>,
    pub normals: Vec<DVec3>,
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
    pub fn torus(major: f64, minor: f64, segments: u32, sides: u32) -> Mesh {
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
    pub fn with_smooth_normals(positions: Vec<DVec3>, triangles: Vec<[u32; 3]>) -> Mesh {
        let mut normals = vec![DVec3::ZERO; positions.len()];
        for t in &triangles {
            let [a, b, c] = t.map(|i| positions[i as usize]);
            let n = (b - a).cross(c - a); // length = 2·area: larger faces weigh more
            for &i in t {
                normals[i as usize] += n;
            }
        }
        let normals = normals.into_iter().map(|n| n.try_normalize().unwrap_or(DVec3::Y)).collect();
        Mesh { positions, normals, triangles }
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
        // A mirroring transform flips the winding; keep triangles counter-clockwise from outside.
        if m.determinant() < 0.0 {
            for t in &mut self.triangles {
                t.swap(1, 2);
            }
        }
    }

    /// Axis-aligned bounds (min, max); `None` for an empty mesh.
    pub fn bounds(&self) -> Option<(DVec3, DVec3)> {
        let first = *self.positions.first()?;
        Some(self.positions.iter().fold((first, first), |(lo, hi), p| (lo.min(*p), hi.max(*p))))
    }
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

/// Loads every model of an OBJ file into one mesh (triangulated; smooth normals computed when absent).
///
/// tobj reports only an error kind, so on failure the file is scanned once more by [`locate_obj_fault`] to
/// name the offending line.
pub fn load_obj(path: &std::path::Path) -> Result<Mesh, ObjError> {
    let text = std::fs::read(path).map_err(|e| ObjError { message: format!("cannot read: {e}"), line: None })?;
    let opts = tobj::LoadOptions { single_index: true, triangulate: true, ignore_points: true, ignore_lines: true };
    let mut reader = std::io::BufReader::new(&text[..]);
    let loaded = tobj::load_obj_buf(&mut reader, &opts, |_| Err(tobj::LoadError::OpenFileFailed));
    let models = match loaded {
        Ok((models, _materials)) => models,
        Err(e) => {
            let src = String::from_utf8_lossy(&text);
            let line = locate_obj_fault(&src);
            return Err(ObjError { message: format!("not a valid OBJ file ({e})"), line });
        }
    };
    let mut positions = Vec::new();
    let mut normals = Vec::new();
    let mut triangles = Vec::new();
    let mut all_have_normals = true;
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
        for t in mesh.indices.chunks_exact(3) {
            if t.iter().any(|&i| i as usize >= nv) {
                return Err(ObjError { message: "a face refers to a vertex that does not exist".into(), line: None });
            }
            triangles.push([base + t[0], base + t[1], base + t[2]]);
        }
    }
    if triangles.is_empty() {
        return Err(ObjError { message: "the file has no faces".into(), line: locate_obj_fault(&String::from_utf8_lossy(&text)) });
    }
    if positions.iter().any(|p| !p.is_finite()) {
        return Err(ObjError { message: "a vertex coordinate is not a finite number".into(), line: None });
    }
    Ok(if all_have_normals {
        let normals = normals.into_iter().map(|n: DVec3| n.try_normalize().unwrap_or(DVec3::Y)).collect();
        Mesh { positions, normals, triangles }
    } else {
        Mesh::with_smooth_normals(positions, triangles)
    })
}

/// Finds the first line a strict reading of the OBJ subset we use (`v`, `vn`, `vt`, `f`) rejects: a vertex
/// without three numbers, or a face with fewer than three corners or an index out of range.
pub fn locate_obj_fault(src: &str) -> Option<usize> {
    let (mut nv, mut nvt, mut nvn) = (0i64, 0i64, 0i64);
    for (i, line) in src.lines().enumerate() {
        let mut it = line.split_whitespace();
        let Some(kw) = it.next() else { continue };
        let rest: Vec<&str> = it.collect();
        let numbers_ok = |k: usize| rest.len() >= k && rest.iter().all(|s| s.parse::<f64>().map(|v| v.is_finite()).unwrap_or(false));
        let ok = match kw {
            "v" => {
                nv += 1;
                numbers_ok(3)
            }
            "vn" => {
                nvn += 1;
                numbers_ok(3)
            }
            "vt" => {
                nvt += 1;
                numbers_ok(1)
            }
            "f" => {
                rest.len() >= 3
                    && rest.iter().all(|corner| {
                        corner.split('/').enumerate().all(|(k, s)| {
                            if s.is_empty() {
                                return k > 0; // `1//2`: the texture index may be missing
                            }
                            let count = [nv, nvt, nvn][k.min(2)];
                            match s.parse::<i64>() {
                                Ok(idx) if idx > 0 => idx <= count,
                                Ok(idx) if idx < 0 => -idx <= count,
                                _ => false,
                            }
                        })
                    })
            }
            _ => true,
        };
        if !ok {
            return Some(i + 1);
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

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

    #[test]
    fn obj_faults_are_located() {
        assert_eq!(locate_obj_fault("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"), None);
        assert_eq!(locate_obj_fault("v 0 0 0\nv 1 x 0\n"), Some(2));
        assert_eq!(locate_obj_fault("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n"), Some(4));
        assert_eq!(locate_obj_fault("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1//1 2 3\n"), Some(4));
    }
}
