//! Rays against the scene's triangles: a bounding volume hierarchy of our own (binned SAH, 12 bins per axis,
//! leaves of at most [`LEAF`] triangles), flattened depth-first; Möller–Trumbore intersection in f64.
//!
//! Used by the ray-traced renderer ([`super::trace`]) for camera rays and for occlusion (so a torus shadows
//! itself). Built once per render from the objects' world-space meshes; cost O(n log n) for n triangles (the
//! papers' sphere, 1 520 triangles, builds in well under a millisecond; measured in BENCHMARKS.md).

use super::Object;
use glam::DVec3;

/// Most triangles in a leaf.
pub const LEAF: usize = 4;
const BINS: usize = 12;

#[derive(Clone, Copy, Debug)]
struct Aabb {
    lo: DVec3,
    hi: DVec3,
}

impl Aabb {
    const EMPTY: Aabb = Aabb { lo: DVec3::splat(f64::INFINITY), hi: DVec3::splat(f64::NEG_INFINITY) };
    fn grow(&mut self, p: DVec3) {
        self.lo = self.lo.min(p);
        self.hi = self.hi.max(p);
    }
    fn join(&mut self, o: &Aabb) {
        self.lo = self.lo.min(o.lo);
        self.hi = self.hi.max(o.hi);
    }
    fn area(&self) -> f64 {
        let d = (self.hi - self.lo).max(DVec3::ZERO);
        2.0 * (d.x * d.y + d.y * d.z + d.z * d.x)
    }
    /// Entry distance of the ray into the box, if it enters before `tmax`.
    #[inline]
    fn hit(&self, o: DVec3, inv: DVec3, tmax: f64) -> Option<f64> {
        let t0 = (self.lo - o) * inv;
        let t1 = (self.hi - o) * inv;
        let near = t0.min(t1).max_element().max(0.0);
        let far = t0.max(t1).min_element().min(tmax);
        (near <= far).then_some(near)
    }
}

#[derive(Clone, Copy, Debug)]
struct Node {
    bounds: Aabb,
    /// Leaf: first triangle index into `order`; inner: index of the second child (the first follows the node).
    start: u32,
    /// Triangles in a leaf; 0 for an inner node.
    count: u32,
}

/// One triangle of the scene: its object and index in the object's mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TriRef {
    pub object: u32,
    pub tri: u32,
}

/// A ray's nearest hit: distance, triangle, and barycentrics of the second and third vertex.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    pub t: f64,
    pub tri: TriRef,
    pub b1: f64,
    pub b2: f64,
}

/// The hierarchy over every triangle of a scene.
#[derive(Clone, Debug, Default)]
pub struct Bvh {
    nodes: Vec<Node>,
    /// Triangle vertices, in leaf order.
    verts: Vec<[DVec3; 3]>,
    refs: Vec<TriRef>,
    /// The scene's bounding-box diagonal (for ray offsets).
    pub extent: f64,
}

impl Bvh {
    /// Builds the hierarchy over the objects' triangles.
    pub fn build(objects: &[Object]) -> Bvh {
        let mut verts = vec![];
        let mut refs = vec![];
        for (oi, o) in objects.iter().enumerate() {
            for (ti, t) in o.mesh.triangles.iter().enumerate() {
                verts.push(t.map(|i| o.mesh.positions[i as usize]));
                refs.push(TriRef { object: oi as u32, tri: ti as u32 });
            }
        }
        let n = verts.len();
        let mut all = Aabb::EMPTY;
        for v in &verts {
            v.iter().for_each(|p| all.grow(*p));
        }
        let extent = if n == 0 { 0.0 } else { (all.hi - all.lo).length() };
        let centroids: Vec<DVec3> = verts.iter().map(|v| (v[0] + v[1] + v[2]) / 3.0).collect();
        let boxes: Vec<Aabb> = verts
            .iter()
            .map(|v| {
                let mut b = Aabb::EMPTY;
                v.iter().for_each(|p| b.grow(*p));
                b
            })
            .collect();
        let mut order: Vec<u32> = (0..n as u32).collect();
        let mut nodes = Vec::with_capacity(2 * n / LEAF + 1);
        if n > 0 {
            build_node(&mut nodes, &mut order, 0, &centroids, &boxes);
        }
        Bvh { nodes, verts: order.iter().map(|&i| verts[i as usize]).collect(), refs: order.iter().map(|&i| refs[i as usize]).collect(), extent }
    }

    /// Triangles in the hierarchy.
    pub fn len(&self) -> usize {
        self.verts.len()
    }

    pub fn is_empty(&self) -> bool {
        self.verts.is_empty()
    }

    /// The nearest hit along `o + t·d` with `t` in (0, `tmax`), both faces.
    pub fn intersect(&self, o: DVec3, d: DVec3, tmax: f64) -> Option<Hit> {
        self.walk(o, d, tmax, false)
    }

    /// Whether anything lies along `o + t·d`, `t` in (0, `tmax`).
    pub fn occluded(&self, o: DVec3, d: DVec3, tmax: f64) -> bool {
        self.walk(o, d, tmax, true).is_some()
    }

    fn walk(&self, o: DVec3, d: DVec3, mut tmax: f64, any: bool) -> Option<Hit> {
        if self.nodes.is_empty() {
            return None;
        }
        let inv = d.recip();
        let mut best: Option<Hit> = None;
        let mut stack: smallvec::SmallVec<[u32; 64]> = smallvec::smallvec![0];
        while let Some(ni) = stack.pop() {
            let ni = ni as usize;
            let node = &self.nodes[ni];
            if node.bounds.hit(o, inv, tmax).is_none() {
                continue;
            }
            if node.count > 0 {
                for k in node.start as usize..(node.start + node.count) as usize {
                    if let Some((t, b1, b2)) = tri_hit(&self.verts[k], o, d, tmax) {
                        tmax = t;
                        best = Some(Hit { t, tri: self.refs[k], b1, b2 });
                        if any {
                            return best;
                        }
                    }
                }
            } else {
                // Visit the nearer child first.
                let (a, b) = (ni + 1, node.start as usize);
                let ta = self.nodes[a].bounds.hit(o, inv, tmax);
                let tb = self.nodes[b].bounds.hit(o, inv, tmax);
                let (first, second) = match (ta, tb) {
                    (Some(x), Some(y)) if y < x => (Some(b), Some(a)),
                    (Some(_), Some(_)) => (Some(a), Some(b)),
                    (Some(_), None) => (Some(a), None),
                    (None, Some(_)) => (Some(b), None),
                    (None, None) => (None, None),
                };
                stack.extend([second, first].into_iter().flatten().map(|c| c as u32));
            }
        }
        best
    }
}

/// Builds the subtree over `order[start..]`'s slice given by the recursion; returns its node index.
fn build_node(nodes: &mut Vec<Node>, order: &mut [u32], start: usize, cen: &[DVec3], boxes: &[Aabb]) -> usize {
    let mut bounds = Aabb::EMPTY;
    let mut cb = Aabb::EMPTY;
    for &i in order.iter() {
        bounds.join(&boxes[i as usize]);
        cb.grow(cen[i as usize]);
    }
    let me = nodes.len();
    nodes.push(Node { bounds, start: start as u32, count: order.len() as u32 });
    if order.len() <= LEAF {
        return me;
    }
    // Binned SAH over the three axes of the centroids' box.
    let mut best: Option<(f64, usize, f64)> = None;
    let ext = cb.hi - cb.lo;
    for axis in 0..3 {
        if ext[axis] <= 0.0 {
            continue;
        }
        let bin_of = |c: DVec3| (((c[axis] - cb.lo[axis]) / ext[axis] * BINS as f64) as usize).min(BINS - 1);
        let mut bb = [Aabb::EMPTY; BINS];
        let mut cnt = [0usize; BINS];
        for &i in order.iter() {
            let b = bin_of(cen[i as usize]);
            bb[b].join(&boxes[i as usize]);
            cnt[b] += 1;
        }
        for split in 1..BINS {
            let (mut l, mut r) = (Aabb::EMPTY, Aabb::EMPTY);
            let (mut nl, mut nr) = (0, 0);
            for b in 0..split {
                l.join(&bb[b]);
                nl += cnt[b];
            }
            for b in split..BINS {
                r.join(&bb[b]);
                nr += cnt[b];
            }
            if nl == 0 || nr == 0 {
                continue;
            }
            let cost = l.area() * nl as f64 + r.area() * nr as f64;
            if best.is_none_or(|(c, _, _)| cost < c) {
                best = Some((cost, axis, cb.lo[axis] + ext[axis] * split as f64 / BINS as f64));
            }
        }
    }
    let mid = match best {
        Some((_, axis, at)) => {
            let mut i = 0;
            for j in 0..order.len() {
                if cen[order[j] as usize][axis] < at {
                    order.swap(i, j);
                    i += 1;
                }
            }
            i
        }
        None => 0,
    };
    // No useful split (coincident centroids): halve by position.
    let mid = if mid == 0 || mid == order.len() { order.len() / 2 } else { mid };
    let (left, right) = order.split_at_mut(mid);
    build_node(nodes, left, start, cen, boxes);
    let r = build_node(nodes, right, start + mid, cen, boxes);
    nodes[me].count = 0;
    nodes[me].start = r as u32;
    me
}

/// Möller–Trumbore: (t, b1, b2) of a hit with `t` in (0, tmax).
#[inline]
fn tri_hit(v: &[DVec3; 3], o: DVec3, d: DVec3, tmax: f64) -> Option<(f64, f64, f64)> {
    let e1 = v[1] - v[0];
    let e2 = v[2] - v[0];
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-300 {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - v[0];
    let b1 = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&b1) {
        return None;
    }
    let q = s.cross(e1);
    let b2 = d.dot(q) * inv;
    if b2 < 0.0 || b1 + b2 > 1.0 {
        return None;
    }
    let t = e2.dot(q) * inv;
    (t > 0.0 && t < tmax).then_some((t, b1, b2))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::mesh::Mesh;
    use std::sync::Arc;

    #[test]
    fn bvh_agrees_with_brute_force_on_a_torus() {
        let mesh = Arc::new(Mesh::torus(1.0, 0.4, 48, 24));
        let objects = vec![Object { mesh: mesh.clone(), material: 0, cull_backfaces: true }];
        let bvh = Bvh::build(&objects);
        assert_eq!(bvh.len(), mesh.triangles.len());
        let mut rng = crate::base::rng::Rng(5);
        let mut hits = 0;
        for _ in 0..2000 {
            let o = DVec3::new(rng.unit() * 6.0 - 3.0, rng.unit() * 6.0 - 3.0, rng.unit() * 6.0 - 3.0);
            let d = DVec3::new(rng.unit() - 0.5, rng.unit() - 0.5, rng.unit() - 0.5).normalize();
            let brute = mesh
                .triangles
                .iter()
                .filter_map(|t| tri_hit(&t.map(|i| mesh.positions[i as usize]), o, d, f64::INFINITY))
                .map(|h| h.0)
                .fold(f64::INFINITY, f64::min);
            let got = bvh.intersect(o, d, f64::INFINITY).map_or(f64::INFINITY, |h| h.t);
            assert_eq!(got, brute, "ray {o} {d}");
            assert_eq!(bvh.occluded(o, d, f64::INFINITY), brute.is_finite());
            hits += usize::from(brute.is_finite());
        }
        assert!(hits > 100, "{hits} rays hit");
        // The torus shadows itself: from the inner side of the ring, across the hole, the far side is in the way.
        assert!(bvh.occluded(DVec3::new(-0.6, 0.0, 0.0), DVec3::X, f64::INFINITY));
        assert!(!bvh.occluded(DVec3::new(0.0, 2.0, 0.0), DVec3::Y, f64::INFINITY));
    }
}
