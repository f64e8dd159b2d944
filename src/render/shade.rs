//! Per-tile shading: I = ka·Ia·C + Σ_lights Il·(kd·NL·C + ks·coef·F·Cs), with F the material's BRDF kernel.
//!
//! Design: the visible pixels of a tile are gathered once (interpolated unit normal, position, view vector),
//! grouped by material; then, for each light and material, the lit pixels (NL > 0) are packed into
//! structure-of-arrays columns and the kernel's `eval_batch` is called once. Only the inputs the formula
//! reads are computed: no reflected vector unless VR is read, no half vector unless NH or VH is read. The
//! cosines are passed raw; clamping them to [0, 1] is the formula's own domain policy (written into its IR).
//! A NaN from the kernel contributes 0 and is counted.

use super::raster::{GBuffer, Setup, EMPTY};
use super::{LightKind, Scene};
use crate::ir::Input;
use crate::backend::Columns;
use glam::DVec3;

/// Reusable per-thread buffers, so shading a tile allocates nothing in the steady state.
#[derive(Default)]
pub struct Scratch {
    pub gb: GBuffer,
    /// (material, tile-local pixel index) of the visible pixels, sorted.
    vis: Vec<(u32, u32)>,
    n: Vec<DVec3>,
    p: Vec<DVec3>,
    v: Vec<DVec3>,
    /// Colour accumulated per tile pixel (linear).
    pub accum: Vec<DVec3>,
    cols: [Vec<f64>; 5],
    lit: Vec<u32>,
    out: Vec<f64>,
}

/// Counters for one tile, summed over tiles (integers, so the sum is independent of thread count).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ShadeCounts {
    pub visible: u64,
    pub evals: u64,
    pub kernel_calls: u64,
    pub nan: u64,
}

impl std::ops::AddAssign for ShadeCounts {
    fn add_assign(&mut self, o: ShadeCounts) {
        self.visible += o.visible;
        self.evals += o.evals;
        self.kernel_calls += o.kernel_calls;
        self.nan += o.nan;
    }
}

/// Shades the tile whose G-buffer is in `sc.gb` (`n` pixels); the result is left in `sc.accum`.
pub fn shade_tile(scene: &Scene, s: &Setup, n: usize, sc: &mut Scratch) -> ShadeCounts {
    let mut counts = ShadeCounts::default();
    let eye = scene.camera.position;
    sc.vis.clear();
    for (o, &t) in sc.gb.tri.iter().enumerate() {
        if t != EMPTY {
            sc.vis.push((s.tris[t as usize].material, o as u32));
        }
    }
    sc.vis.sort_unstable();
    counts.visible = sc.vis.len() as u64;
    sc.accum.clear();
    sc.accum.resize(n, scene.background);
    sc.n.clear();
    sc.p.clear();
    sc.v.clear();
    for &(m, o) in &sc.vis {
        let tri = &s.tris[sc.gb.tri[o as usize] as usize];
        let [b0, b1] = sc.gb.bary[o as usize];
        let b2 = 1.0 - b0 - b1;
        let p = tri.pos[0] * b0 + tri.pos[1] * b1 + tri.pos[2] * b2;
        let v = (eye - p).normalize_or_zero();
        let mut nrm = (tri.normal[0] * b0 + tri.normal[1] * b1 + tri.normal[2] * b2).normalize_or_zero();
        if tri.two_sided && nrm.dot(v) < 0.0 {
            nrm = -nrm;
        }
        sc.n.push(nrm);
        sc.p.push(p);
        sc.v.push(v);
        let mat = &scene.materials[m as usize];
        sc.accum[o as usize] = scene.ambient * mat.color * mat.ka;
    }
    // Material groups: contiguous runs of `vis`.
    let mut start = 0;
    while start < sc.vis.len() {
        let m = sc.vis[start].0;
        let end = start + sc.vis[start..].iter().take_while(|(mm, _)| *mm == m).count();
        let mat = &scene.materials[m as usize];
        let used = mat.used;
        let need_h = used.contains(Input::NH) || used.contains(Input::VH);
        for light in &scene.lights {
            sc.lit.clear();
            for c in &mut sc.cols {
                c.clear();
            }
            for k in start..end {
                let (nrm, p, v) = (sc.n[k], sc.p[k], sc.v[k]);
                let l = match light.kind {
                    LightKind::Point(pos) => (pos - p).normalize_or_zero(),
                    LightKind::Directional(dir) => -dir,
                };
                let nl = nrm.dot(l);
                if nl <= 0.0 || nl.is_nan() {
                    continue;
                }
                sc.lit.push(k as u32);
                sc.cols[0].push(nl);
                if used.contains(Input::NV) {
                    sc.cols[1].push(nrm.dot(v));
                }
                if need_h {
                    let h = (l + v).normalize_or_zero();
                    if used.contains(Input::NH) {
                        sc.cols[2].push(nrm.dot(h));
                    }
                    if used.contains(Input::VH) {
                        sc.cols[4].push(v.dot(h));
                    }
                }
                if used.contains(Input::VR) {
                    let r = nrm * (2.0 * nl) - l;
                    sc.cols[3].push(v.dot(r));
                }
            }
            let count = sc.lit.len();
            if count == 0 {
                continue;
            }
            sc.out.clear();
            sc.out.resize(count, 0.0);
            let specular = mat.ks != 0.0;
            if specular {
                let cols = Columns::new([&sc.cols[0], &sc.cols[1], &sc.cols[2], &sc.cols[3], &sc.cols[4]]);
                mat.evaluator.eval_batch(&cols, &mat.params, &mut sc.out);
                counts.kernel_calls += 1;
                counts.evals += count as u64;
            }
            let diffuse = mat.color * mat.kd;
            let spec = mat.specular * (mat.ks * mat.coef);
            for i in 0..count {
                let k = sc.lit[i] as usize;
                let mut f = sc.out[i];
                // NaN and ±inf are no light, and counted: an infinite lobe is a defect, not a highlight.
                if !f.is_finite() {
                    counts.nan += 1;
                    f = 0.0;
                }
                let o = sc.vis[k].1 as usize;
                sc.accum[o] += light.color * (diffuse * sc.cols[0][i] + spec * f);
            }
        }
        start = end;
    }
    counts
}
