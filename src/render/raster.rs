//! Triangle setup, binning into screen tiles, and per-tile rasterisation into a small G-buffer.
//!
//! Design:
//! - Setup (serial, once per frame): every triangle is projected, clipped in homogeneous space against the
//!   near plane and a guard band only when a vertex lies outside them (rare), snapped to a fixed-point grid
//!   of 1/256 pixel, and appended to the bin of every tile its bounding box touches, in scene order.
//! - Raster (one tile at a time, tiles in parallel): integer edge functions (exact, so two triangles sharing
//!   an edge never both cover, nor both miss, a pixel centre), the top-left fill rule, and a depth test on
//!   1/w, which is affine in screen space. The G-buffer stores only the winning triangle and its
//!   perspective-correct barycentrics; attributes are interpolated once per visible pixel when shading
//!   (deferred), so overdraw costs no normal interpolation.
//!
//! Determinism: a tile's result depends only on its bin, which is in scene order, and ties in depth keep the
//! earlier triangle, so any thread count produces the same bytes.

use super::camera::ClipTransform;
use super::mesh::Mesh;
use glam::{DVec3, DVec4};

/// Sub-pixel precision: coordinates are snapped to 1/`SUB` pixel.
pub(crate) const SUB: i64 = 256;
/// Screen coordinates stay within ±`GUARD_PX` pixels, so every edge-function product fits an i64 easily.
const GUARD_PX: f64 = 32768.0;
/// Near plane in clip w (world units along the view axis).
const NEAR_W: f64 = 1e-6;
/// Marks a pixel no triangle covers.
pub(crate) const EMPTY: u32 = u32::MAX;

/// A triangle ready for rasterisation: fixed-point screen vertices (counter-clockwise with y down, i.e.
/// positive area) and the world-space attributes shading interpolates.
#[derive(Clone, Debug)]
pub(crate) struct ScreenTri {
    pub x: [i64; 3],
    pub y: [i64; 3],
    pub inv_w: [f64; 3],
    pub pos: [DVec3; 3],
    pub normal: [DVec3; 3],
    /// Vertex tangents (interpolated like the normal, read only by formulas that read directions).
    pub tangent: [DVec3; 3],
    pub material: u32,
    /// The object is drawn from both sides: shading turns the normal towards the viewer.
    pub two_sided: bool,
    pub area: i64,
    /// Pixel bounding box, clamped to the image: `x0..x1`, `y0..y1`.
    pub bbox: [i32; 4],
}

/// The binned frame: triangles and, for each tile in row-major order, the indices of those touching it.
#[derive(Debug, Default)]
pub(crate) struct Setup {
    pub tris: Vec<ScreenTri>,
    pub bins: Vec<Vec<u32>>,
    pub tile: usize,
    pub tiles_x: usize,
    pub width: usize,
    pub height: usize,
    /// Where each pixel is sampled, in pixels from its centre (supersampling moves it; 0, 0 otherwise).
    pub offset: [f64; 2],
}

/// One object to draw.
pub(crate) struct DrawItem<'a> {
    pub mesh: &'a Mesh,
    pub material: u32,
    /// Drop triangles facing away from the camera (closed meshes).
    pub cull_backfaces: bool,
}

#[derive(Clone, Copy, Debug)]
struct ClipVert {
    c: DVec4,
    pos: DVec3,
    normal: DVec3,
    tangent: DVec3,
}

impl ClipVert {
    fn lerp(&self, o: &ClipVert, t: f64) -> ClipVert {
        ClipVert { c: self.c.lerp(o.c, t), pos: self.pos.lerp(o.pos, t), normal: self.normal.lerp(o.normal, t), tangent: self.tangent.lerp(o.tangent, t) }
    }
}

/// Projects, clips and bins every triangle of `items`, for pixels sampled `offset` pixels from their centres
/// (the geometry moves by −`offset`; [0, 0] samples the centres).
pub(crate) fn setup(items: &[DrawItem], xf: &ClipTransform, width: usize, height: usize, tile: usize, offset: [f64; 2]) -> Setup {
    let tiles_x = width.div_ceil(tile);
    let tiles_y = height.div_ceil(tile);
    let mut s = Setup { tris: vec![], bins: vec![vec![]; tiles_x * tiles_y], tile, tiles_x, width, height, offset };
    // Guard band in NDC units per axis.
    let gx = GUARD_PX * 2.0 / width as f64;
    let gy = GUARD_PX * 2.0 / height as f64;
    let planes = [
        DVec4::new(0.0, 0.0, 0.0, 1.0),  // w ≥ NEAR (offset applied below)
        DVec4::new(-1.0, 0.0, 0.0, gx),  // x ≤ gx·w
        DVec4::new(1.0, 0.0, 0.0, gx),   // x ≥ −gx·w
        DVec4::new(0.0, -1.0, 0.0, gy),  // y ≤ gy·w
        DVec4::new(0.0, 1.0, 0.0, gy),   // y ≥ −gy·w
    ];
    let dist = |p: usize, c: DVec4| if p == 0 { c.w - NEAR_W } else { planes[p].dot(c) };
    let mut poly: Vec<ClipVert> = Vec::with_capacity(9);
    let mut next: Vec<ClipVert> = Vec::with_capacity(9);
    for item in items {
        let clip: Vec<DVec4> = item.mesh.positions.iter().map(|p| xf.apply(*p)).collect();
        let inside = |c: DVec4| (0..planes.len()).all(|p| dist(p, c) >= 0.0);
        for t in &item.mesh.triangles {
            let v = t.map(|i| ClipVert {
                c: clip[i as usize],
                pos: item.mesh.positions[i as usize],
                normal: item.mesh.normals[i as usize],
                tangent: item.mesh.tangent(i as usize),
            });
            if v.iter().all(|cv| inside(cv.c)) {
                emit(&mut s, &v, item);
                continue;
            }
            // Sutherland–Hodgman in homogeneous space; attributes are linear there, so lerp is exact.
            poly.clear();
            poly.extend_from_slice(&v);
            for p in 0..planes.len() {
                next.clear();
                for i in 0..poly.len() {
                    let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
                    let (da, db) = (dist(p, a.c), dist(p, b.c));
                    if da >= 0.0 {
                        next.push(a);
                    }
                    if (da >= 0.0) != (db >= 0.0) {
                        next.push(a.lerp(&b, da / (da - db)));
                    }
                }
                std::mem::swap(&mut poly, &mut next);
                if poly.len() < 3 {
                    break;
                }
            }
            for i in 1..poly.len().saturating_sub(1) {
                emit(&mut s, &[poly[0], poly[i], poly[i + 1]], item);
            }
        }
    }
    s
}

fn emit(s: &mut Setup, v: &[ClipVert; 3], item: &DrawItem) {
    let (w, h) = (s.width as f64, s.height as f64);
    let mut x = [0i64; 3];
    let mut y = [0i64; 3];
    let mut inv_w = [0f64; 3];
    for i in 0..3 {
        let c = v[i].c;
        inv_w[i] = 1.0 / c.w;
        // Subtracting a zero offset leaves every value as it was (bit for bit).
        x[i] = (((c.x * inv_w[i] + 1.0) * 0.5 * w - s.offset[0]) * SUB as f64).round() as i64;
        y[i] = (((1.0 - c.y * inv_w[i]) * 0.5 * h - s.offset[1]) * SUB as f64).round() as i64;
    }
    let mut area = (x[1] - x[0]) * (y[2] - y[0]) - (y[1] - y[0]) * (x[2] - x[0]);
    // Counter-clockwise in the world (front-facing) is clockwise on a y-down screen: negative area.
    if area == 0 || (item.cull_backfaces && area > 0) {
        return;
    }
    let mut order = [0usize, 1, 2];
    if area < 0 {
        order = [0, 2, 1];
        area = -area;
    }
    let x = order.map(|i| x[i]);
    let y = order.map(|i| y[i]);
    let px_floor = |v: i64| v.div_euclid(SUB) as i32;
    let x0 = px_floor(*x.iter().min().unwrap_or(&0)).max(0);
    let y0 = px_floor(*y.iter().min().unwrap_or(&0)).max(0);
    let x1 = (px_floor(*x.iter().max().unwrap_or(&0)) + 1).min(s.width as i32);
    let y1 = (px_floor(*y.iter().max().unwrap_or(&0)) + 1).min(s.height as i32);
    if x0 >= x1 || y0 >= y1 {
        return;
    }
    let idx = s.tris.len() as u32;
    s.tris.push(ScreenTri {
        x,
        y,
        inv_w: order.map(|i| inv_w[i]),
        pos: order.map(|i| v[i].pos),
        normal: order.map(|i| v[i].normal),
        tangent: order.map(|i| v[i].tangent),
        material: item.material,
        two_sided: !item.cull_backfaces,
        area,
        bbox: [x0, x1, y0, y1],
    });
    let t = s.tile as i32;
    for ty in (y0 / t)..=((y1 - 1) / t) {
        for tx in (x0 / t)..=((x1 - 1) / t) {
            s.bins[ty as usize * s.tiles_x + tx as usize].push(idx);
        }
    }
}

/// Per-tile raster output: for each pixel the nearest triangle (or [`EMPTY`]) and the perspective-correct
/// barycentric weights of its first two vertices.
#[derive(Clone, Debug, Default)]
pub(crate) struct GBuffer {
    pub depth: Vec<f64>,
    pub tri: Vec<u32>,
    pub bary: Vec<[f64; 2]>,
}

impl GBuffer {
    fn reset(&mut self, n: usize) {
        self.depth.clear();
        self.depth.resize(n, 0.0);
        self.tri.clear();
        self.tri.resize(n, EMPTY);
        self.bary.clear();
        self.bary.resize(n, [0.0; 2]);
    }
}

/// The pixel rectangle of tile `t`: (x0, y0, width, height).
pub(crate) fn tile_rect(s: &Setup, t: usize) -> (usize, usize, usize, usize) {
    let (tx, ty) = (t % s.tiles_x, t / s.tiles_x);
    let (x0, y0) = (tx * s.tile, ty * s.tile);
    (x0, y0, s.tile.min(s.width - x0), s.tile.min(s.height - y0))
}

/// Rasterises tile `t` into `gb` (row-major, `tw × th`). Returns the number of pixel coverage tests.
pub(crate) fn raster_tile(s: &Setup, t: usize, gb: &mut GBuffer) -> u64 {
    let (tx0, ty0, tw, th) = tile_rect(s, t);
    gb.reset(tw * th);
    let mut tests = 0u64;
    for &ti in &s.bins[t] {
        let tri = &s.tris[ti as usize];
        let bx0 = (tri.bbox[0] as usize).max(tx0);
        let bx1 = (tri.bbox[1] as usize).min(tx0 + tw);
        let by0 = (tri.bbox[2] as usize).max(ty0);
        let by1 = (tri.bbox[3] as usize).min(ty0 + th);
        if bx0 >= bx1 || by0 >= by1 {
            continue;
        }
        // Edge k is opposite vertex k: from vertex k+1 to k+2; its value over the area is vertex k's weight.
        let mut a = [0i64; 3];
        let mut b = [0i64; 3];
        let mut bias = [0i64; 3];
        for k in 0..3 {
            let (i, j) = ((k + 1) % 3, (k + 2) % 3);
            a[k] = tri.y[i] - tri.y[j];
            b[k] = tri.x[j] - tri.x[i];
            // Top-left rule: pixel centres exactly on a top or left edge belong to this triangle, others not.
            let top_left = a[k] > 0 || (a[k] == 0 && b[k] > 0);
            bias[k] = if top_left { 0 } else { -1 };
        }
        let edge = |k: usize, px: i64, py: i64| {
            let (i, j) = ((k + 1) % 3, (k + 2) % 3);
            (tri.x[j] - tri.x[i]) * (py - tri.y[i]) - (tri.y[j] - tri.y[i]) * (px - tri.x[i])
        };
        let inv_area = 1.0 / tri.area as f64;
        let step = [a[0] * SUB, a[1] * SUB, a[2] * SUB];
        for py in by0..by1 {
            let cy = py as i64 * SUB + SUB / 2;
            let cx = bx0 as i64 * SUB + SUB / 2;
            let mut e = [edge(0, cx, cy) + bias[0], edge(1, cx, cy) + bias[1], edge(2, cx, cy) + bias[2]];
            let row = (py - ty0) * tw;
            tests += (bx1 - bx0) as u64;
            for px in bx0..bx1 {
                if (e[0] | e[1] | e[2]) >= 0 {
                    // Undo the bias for the weights (it only decides ties).
                    let l0 = (e[0] - bias[0]) as f64 * inv_area;
                    let l1 = (e[1] - bias[1]) as f64 * inv_area;
                    let l2 = 1.0 - l0 - l1;
                    let q = [l0 * tri.inv_w[0], l1 * tri.inv_w[1], l2 * tri.inv_w[2]];
                    let iw = q[0] + q[1] + q[2];
                    let o = row + (px - tx0);
                    if iw > gb.depth[o] {
                        gb.depth[o] = iw;
                        gb.tri[o] = ti;
                        gb.bary[o] = [q[0] / iw, q[1] / iw];
                    }
                }
                e[0] += step[0];
                e[1] += step[1];
                e[2] += step[2];
            }
        }
    }
    tests
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::camera::Camera;

    fn quad_setup(w: usize, h: usize) -> Setup {
        // Two triangles sharing a diagonal, covering a square at distance 2 exactly filling a 90° view.
        let mesh = Mesh {
            positions: vec![
                DVec3::new(-2.0, -2.0, 0.0),
                DVec3::new(2.0, -2.0, 0.0),
                DVec3::new(2.0, 2.0, 0.0),
                DVec3::new(-2.0, 2.0, 0.0),
            ],
            normals: vec![DVec3::Z; 4],
            tangents: vec![],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
        };
        let cam = Camera { position: DVec3::new(0.0, 0.0, 2.0), look_at: DVec3::ZERO, up: DVec3::Y, fov_deg: 90.0 };
        let items = [DrawItem { mesh: &mesh, material: 0, cull_backfaces: true }];
        setup(&items, &cam.clip_transform(w as f64 / h as f64), w, h, 8, [0.0; 2])
    }

    #[test]
    fn shared_edges_cover_every_pixel_exactly_once() {
        // The quad fills a square view exactly; the shared diagonal crosses many pixel centres' rows.
        let s = quad_setup(37, 37);
        assert_eq!(s.tris.len(), 2);
        let mut count = vec![0u32; 37 * 37];
        for t in 0..s.bins.len() {
            let mut gb = GBuffer::default();
            raster_tile(&s, t, &mut gb);
            let (x0, y0, tw, th) = tile_rect(&s, t);
            for y in 0..th {
                for x in 0..tw {
                    if gb.tri[y * tw + x] != EMPTY {
                        count[(y0 + y) * 37 + x0 + x] += 1;
                    }
                }
            }
        }
        let bad: Vec<usize> = (0..count.len()).filter(|&i| count[i] != 1).collect();
        assert!(bad.is_empty(), "pixels covered ≠ once: {bad:?}");
    }

    #[test]
    fn backfaces_are_culled_and_triangles_behind_the_camera_clipped() {
        let mesh = Mesh {
            positions: vec![DVec3::new(-1.0, -1.0, 0.0), DVec3::new(1.0, -1.0, 0.0), DVec3::new(0.0, 1.0, 0.0)],
            normals: vec![DVec3::Z; 3],
            tangents: vec![],
            triangles: vec![[0, 2, 1]], // clockwise from +z: a back face
        };
        let cam = Camera { position: DVec3::new(0.0, 0.0, 2.0), look_at: DVec3::ZERO, up: DVec3::Y, fov_deg: 60.0 };
        let xf = cam.clip_transform(1.0);
        assert!(setup(&[DrawItem { mesh: &mesh, material: 0, cull_backfaces: true }], &xf, 16, 16, 8, [0.0; 2]).tris.is_empty());
        assert_eq!(setup(&[DrawItem { mesh: &mesh, material: 0, cull_backfaces: false }], &xf, 16, 16, 8, [0.0; 2]).tris.len(), 1);
        // A huge triangle through the camera plane: clipped, never NaN or overflowing coordinates.
        let big = Mesh {
            positions: vec![DVec3::new(-100.0, -1.0, 10.0), DVec3::new(100.0, -1.0, 10.0), DVec3::new(0.0, -1.0, -100.0)],
            normals: vec![DVec3::Y; 3],
            tangents: vec![],
            triangles: vec![[0, 1, 2]],
        };
        let s = setup(&[DrawItem { mesh: &big, material: 0, cull_backfaces: false }], &xf, 16, 16, 8, [0.0; 2]);
        assert!(!s.tris.is_empty());
        for t in &s.tris {
            assert!(t.inv_w.iter().all(|w| w.is_finite() && *w > 0.0));
            assert!(t.x.iter().chain(&t.y).all(|v| v.abs() <= (GUARD_PX as i64 + 16) * SUB));
        }
    }
}
