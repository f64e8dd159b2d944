//! Per-tile shading in structure-of-arrays columns: I = ka·Ia·C + Σ_lights Il·(kd·NL·C + ks·coef·F·Cs).
//!
//! Design: one scan of the tile's G-buffer cuts its pixels into runs covered by one triangle (empty pixels get
//! the background there), grouped by material; each material's runs fill spans of up to [`SPAN`] pixels. In a
//! span every quantity is a column of f64 with one entry per pixel. Position and normal (and the tangent, for
//! formulas that read directions) are interpolated run by run straight from the G-buffer's barycentrics (the
//! triangle's attributes are loop constants there); two-sided triangles turn the normal to the viewer. The
//! colours go back to the tile run by run (contiguous pixels), so no per-pixel index list is built.
//!
//! Then one call of the material's shading program ([`ProgramRun`]: [`super::program`], compiled once per
//! render) takes those columns to the colour and the counters — the JIT's batched function or the interpreter
//! running the same program — and the span ends in the 8-bit conversion. Nothing here allocates in the steady
//! state ([`Scratch`] is per thread).
//!
//! The per-pixel loops here ([`surface`], [`encode`]) are also compiled for AVX-512 and AVX2 and chosen at run
//! time: at the release build's baseline (SSE2, two lanes) they cost more than the shading program itself.
//! Same operations, no contraction into FMA, so the same bytes on every host.
//!
//! Cost model: see [`super::plan`] and [`super::program`]; measured numbers: BENCHMARKS.md.

use super::image::Transfer;
use super::program::{ProgramRun, COLUMNS, N_OUTPUTS};
use super::raster::{GBuffer, ScreenTri, Setup, EMPTY};
use super::Scene;
use std::time::Instant;

/// Pixels shaded together: a span's columns (~18 of them, 2 KiB each) stay in the L1 cache between
/// interpolation, the program and the 8-bit conversion, and the program call per span is well amortised.
pub const SPAN: usize = 256;

/// Reusable per-thread buffers, so shading a tile allocates nothing in the steady state.
#[derive(Default)]
pub(crate) struct Scratch {
    pub gb: GBuffer,
    /// The tile's runs of pixels covered by one triangle, in pixel order (by material, then pixel, in a tile
    /// of several materials).
    runs: Vec<Run>,
    g: Group,
    /// The tile's 8-bit pixels (row-major, `tw × th × 3`).
    pub rgb: Vec<u8>,
}

/// Consecutive tile pixels (row-major, possibly across rows) covered by one triangle: its attributes are
/// loop constants for the whole run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
struct Run {
    material: u32,
    start: u32,
    len: u32,
    tri: u32,
}

/// The columns of one span of one material's pixels. The surface columns (p, n, t) are [`SPAN`] long and
/// filled run by run; the others are resized to the span's size.
#[derive(Default)]
struct Group {
    /// Pixels in the span.
    len: usize,
    /// Where the span's pixels go: (span position, tile pixel, count) per piece of a run.
    segs: Vec<(u32, u32, u32)>,
    p: [Vec<f64>; 3],
    n: [Vec<f64>; 3],
    /// The interpolated tangent (formulas that read directions only).
    t: [Vec<f64>; 3],
    /// The program's colour outputs per pixel.
    acc: [Vec<f64>; 3],
    /// Each pixel's 8-bit colour, packed (r | g << 8 | b << 16).
    levels: Vec<u32>,
    /// The shading program's counters per pixel (non-finite F, evaluations, cut-off skips).
    cnt: [Vec<f64>; 3],
}

/// Counters for one tile, summed over tiles (integers, so the sum is independent of thread count).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct ShadeCounts {
    pub visible: u64,
    pub evals: u64,
    pub kernel_calls: u64,
    pub nan: u64,
    /// Lit pixel × light pairs whose kernel evaluation the cut-off skipped.
    pub cut: u64,
}

impl std::ops::AddAssign for ShadeCounts {
    fn add_assign(&mut self, o: ShadeCounts) {
        self.visible += o.visible;
        self.evals += o.evals;
        self.kernel_calls += o.kernel_calls;
        self.nan += o.nan;
        self.cut += o.cut;
    }
}

/// Shades the tile whose G-buffer is in `sc.gb` (`tw × th` pixels) with the per-material `programs`; the
/// 8-bit result (background where nothing is visible) is left in `sc.rgb`. Returns the counters and the time
/// spent inside the programs, in nanoseconds.
pub(crate) fn shade_tile(scene: &Scene, programs: &[ProgramRun], s: &Setup, n: usize, sc: &mut Scratch, transfer: Transfer, bg: [u8; 3]) -> (ShadeCounts, u64) {
    let mut counts = ShadeCounts::default();
    let mut kernel_ns = 0;
    sc.rgb.resize(n * 3, 0);
    counts.visible = runs(&sc.gb.tri[..n], s, &mut sc.runs, &mut sc.rgb[..n * 3], bg);
    let eye = scene.camera.position.to_array();
    let g = &mut sc.g;
    for c in 0..3 {
        fit(&mut g.p[c], SPAN);
        fit(&mut g.n[c], SPAN);
        fit(&mut g.t[c], SPAN);
    }
    let mut start = 0;
    while start < sc.runs.len() {
        let m = sc.runs[start].material;
        let end = start + sc.runs[start..].iter().take_while(|r| r.material == m).count();
        let runs = &sc.runs[start..end];
        start = end;
        let pr = &programs[m as usize];
        for_each_span(g, runs, s, &sc.gb, eye, pr.tangent, |g| {
            kernel_ns += run_program(g, pr, &mut counts);
            encode(g, &mut sc.rgb, transfer);
        });
    }
    (counts, kernel_ns)
}

/// Splits the tile's pixels (`tri`: each pixel's triangle or [`EMPTY`]) into runs of one triangle, in pixel
/// order, or sorted by material when the tile has several; empty pixels get the background in `rgb` (so every
/// pixel is written once, by this or by [`encode`]). Returns the number of visible pixels.
fn runs(tri: &[u32], s: &Setup, runs: &mut Vec<Run>, rgb: &mut [u8], bg: [u8; 3]) -> u64 {
    runs.clear();
    let mut visible = 0;
    let mut mixed = false;
    let mut o = 0;
    while o < tri.len() {
        let t = tri[o];
        // Eight pixels per test (one vector compare) while the run lasts, then one by one.
        let mut e = o + 1;
        while tri.get(e..e + 8).is_some_and(|c| c.iter().all(|&x| x == t)) {
            e += 8;
        }
        e += tri[e..].iter().take_while(|&&x| x == t).count();
        if t == EMPTY {
            for p in rgb[o * 3..e * 3].chunks_exact_mut(3) {
                p.copy_from_slice(&bg);
            }
        } else {
            let material = s.tris[t as usize].material;
            mixed |= runs.first().is_some_and(|f: &Run| f.material != material);
            runs.push(Run { material, start: o as u32, len: (e - o) as u32, tri: t });
            visible += (e - o) as u64;
        }
        o = e;
    }
    // Runs are found in pixel order, so one material needs no sort; the order within a material stays the
    // pixel order either way (starts are distinct).
    if mixed {
        runs.sort_unstable();
    }
    visible
}

/// Fills `g`'s surface columns from `runs` (one material's) span by span — each run's pixels interpolated
/// straight from the G-buffer's barycentrics, cut where a span is full — and calls `shade` on each span.
#[allow(clippy::too_many_arguments)]
fn for_each_span(g: &mut Group, runs: &[Run], s: &Setup, gb: &GBuffer, eye: [f64; 3], tangent: bool, mut shade: impl FnMut(&mut Group)) {
    g.segs.clear();
    let mut k = 0;
    for r in runs {
        let tri = &s.tris[r.tri as usize];
        let (mut o, mut left) = (r.start as usize, r.len as usize);
        while left > 0 {
            let take = left.min(SPAN - k);
            let bary = &gb.bary[o..o + take];
            if tangent {
                surface::<true>(g, k, tri, bary, eye);
            } else {
                surface::<false>(g, k, tri, bary, eye);
            }
            g.segs.push((k as u32, o as u32, take as u32));
            (k, o, left) = (k + take, o + take, left - take);
            if k == SPAN {
                g.len = k;
                shade(g);
                g.segs.clear();
                k = 0;
            }
        }
    }
    if k > 0 {
        g.len = k;
        shade(g);
    }
}

/// Runs the span's shading program: columns p, n (and t) in, colours into `acc`, counters summed. Returns
/// the nanoseconds spent in the program.
fn run_program(g: &mut Group, pr: &ProgramRun, counts: &mut ShadeCounts) -> u64 {
    let m = g.len;
    let ([px, py, pz], [nx, ny, nz], [tx, ty, tz]) = (&g.p, &g.n, &g.t);
    let tk = if pr.tangent { m } else { 0 };
    let cols: [&[f64]; COLUMNS] = [&px[..m], &py[..m], &pz[..m], &nx[..m], &ny[..m], &nz[..m], &tx[..tk], &ty[..tk], &tz[..tk]];
    let [r, gg, b] = &mut g.acc;
    let [c0, c1, c2] = &mut g.cnt;
    let mut outs: [&mut [f64]; N_OUTPUTS] = [fit(r, m), fit(gg, m), fit(b, m), fit(c0, m), fit(c1, m), fit(c2, m)];
    let t = Instant::now();
    pr.code.run(&cols, &pr.params, &pr.block, &mut outs, m);
    let ns = t.elapsed().as_nanos() as u64;
    counts.kernel_calls += 1;
    let [nan, evals, cut] = sum_counters([&g.cnt[0][..m], &g.cnt[1][..m], &g.cnt[2][..m]]);
    counts.nan += nan;
    counts.evals += evals;
    counts.cut += cut;
    ns
}

/// The three counter columns' sums. Small non-negative integers in f64, so the f64 sums are exact (two
/// partial sums per counter, one pass: LLVM vectorises it); a NaN, from a failed call, counts 0.
fn sum_counters(c: [&[f64]; 3]) -> [u64; 3] {
    let m = c[0].len();
    let mut acc = [[0.0f64; 2]; 3];
    let pairs = m / 2;
    for i in 0..pairs {
        for (a, c) in acc.iter_mut().zip(c) {
            a[0] += c[2 * i];
            a[1] += c[2 * i + 1];
        }
    }
    std::array::from_fn(|k| (acc[k][0] + acc[k][1] + c[k][2 * pairs..].iter().sum::<f64>()) as u64)
}

fn fit<T: Copy + Default>(v: &mut Vec<T>, m: usize) -> &mut [T] {
    v.resize(m, T::default());
    &mut v[..m]
}

/// The surface step for one piece of a run of triangle `tri`: p and n (and with `TAN` the tangent) at span
/// positions `k..`, interpolated from the pixels' barycentrics with the triangle's vertices as loop constants:
/// a = v2 + b0·(v0 − v2) + b1·(v1 − v2). Two-sided triangles turn n towards the viewer.
#[multiversion::multiversion(targets("x86_64+avx512f+avx512dq+avx2+fma", "x86_64+avx2+fma"))]
fn surface<const TAN: bool>(g: &mut Group, k: usize, tri: &ScreenTri, bary: &[[f64; 2]], eye: [f64; 3]) {
    let e = k + bary.len();
    let (a, d0, d1) = (tri.pos[2], tri.pos[0] - tri.pos[2], tri.pos[1] - tri.pos[2]);
    let (na, n0, n1) = (tri.normal[2], tri.normal[0] - tri.normal[2], tri.normal[1] - tri.normal[2]);
    let [px, py, pz] = &mut g.p;
    let [nx, ny, nz] = &mut g.n;
    let (px, py, pz, nx, ny, nz) = (&mut px[k..e], &mut py[k..e], &mut pz[k..e], &mut nx[k..e], &mut ny[k..e], &mut nz[k..e]);
    for (i, &[u, w]) in bary.iter().enumerate() {
        px[i] = a.x + u * d0.x + w * d1.x;
        py[i] = a.y + u * d0.y + w * d1.y;
        pz[i] = a.z + u * d0.z + w * d1.z;
        nx[i] = na.x + u * n0.x + w * n1.x;
        ny[i] = na.y + u * n0.y + w * n1.y;
        nz[i] = na.z + u * n0.z + w * n1.z;
    }
    if TAN {
        let (ta, t0, t1) = (tri.tangent[2], tri.tangent[0] - tri.tangent[2], tri.tangent[1] - tri.tangent[2]);
        let [tx, ty, tz] = &mut g.t;
        let (tx, ty, tz) = (&mut tx[k..e], &mut ty[k..e], &mut tz[k..e]);
        for (i, &[u, w]) in bary.iter().enumerate() {
            tx[i] = ta.x + u * t0.x + w * t1.x;
            ty[i] = ta.y + u * t0.y + w * t1.y;
            tz[i] = ta.z + u * t0.z + w * t1.z;
        }
    }
    if tri.two_sided {
        for i in 0..bary.len() {
            if nx[i] * (eye[0] - px[i]) + ny[i] * (eye[1] - py[i]) + nz[i] * (eye[2] - pz[i]) < 0.0 {
                nx[i] = -nx[i];
                ny[i] = -ny[i];
                nz[i] = -nz[i];
            }
        }
    }
}

/// Converts the span's colours to 8 bits into the tile: first every pixel's three levels packed in a u32
/// (one branch-free pass over the columns, which LLVM vectorises for the linear transfer; sRGB through
/// [`Transfer::encode`]), then each piece of a run stored to its contiguous pixels.
#[multiversion::multiversion(targets("x86_64+avx512f+avx512dq+avx2+fma", "x86_64+avx2+fma"))]
fn encode(g: &mut Group, rgb: &mut [u8], transfer: Transfer) {
    let m = g.len;
    let [r, gg, b] = &g.acc;
    let (r, gg, b) = (&r[..m], &gg[..m], &b[..m]);
    let lv = fit(&mut g.levels, m);
    let pack = |r: u8, g: u8, b: u8| u32::from(r) | u32::from(g) << 8 | u32::from(b) << 16;
    match transfer {
        Transfer::Linear => {
            for i in 0..m {
                lv[i] = linear_pixel(r[i], gg[i], b[i]);
            }
        }
        Transfer::Srgb => {
            for i in 0..m {
                lv[i] = pack(transfer.encode(r[i]), transfer.encode(gg[i]), transfer.encode(b[i]));
            }
        }
    }
    // Each pixel but the last is one 4-byte store whose high byte (0) the next pixel's store overwrites.
    for &(k, o, len) in &g.segs {
        let (k, o, len) = (k as usize, o as usize, len as usize);
        let (px, lv) = (&mut rgb[o * 3..(o + len) * 3], &lv[k..k + len]);
        let Some((last, head)) = lv.split_last() else { continue };
        for (i, v) in head.iter().enumerate() {
            px[3 * i..3 * i + 4].copy_from_slice(&v.to_le_bytes());
        }
        px[3 * head.len()..].copy_from_slice(&last.to_le_bytes()[..3]);
    }
}

/// A pixel's three linear levels packed: each level sits in the low byte of its [`linear_bits`], so shifted
/// and added in 64-bit lanes the low 32 bits are the packed pixel (no shuffle per channel).
#[inline(always)]
fn linear_pixel(r: f64, g: f64, b: f64) -> u32 {
    linear_bits(r).wrapping_add(linear_bits(g) << 8).wrapping_add(linear_bits(b) << 16) as u32
}

/// [`Transfer::encode`]'s linear branch, bit for bit, without branches or a float-to-int conversion, as the
/// low byte of the result (the bits above it are junk to discard): the comparisons turn NaN into 0, and
/// floor(y) comes from adding 1.5·2^52 (which rounds y to an integer in the low mantissa bits) and stepping
/// down where that rounded up.
#[inline(always)]
fn linear_bits(x: f64) -> u64 {
    const M: f64 = 6_755_399_441_055_744.0;
    let c = if x > 0.0 { x } else { 0.0 };
    let c = if c < 1.0 { c } else { 1.0 };
    let y = c * 255.0 + 0.5;
    let t = y + M;
    t.to_bits().wrapping_sub(u64::from(t - M > y))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vectorised_linear_encoding_is_transfer_encode_bit_for_bit() {
        let mut vals: Vec<f64> = (0..=5100).map(|k| k as f64 / 5100.0).collect();
        // Exact half levels, values just around them, out of range, NaN, ±inf.
        for k in 0..=255 {
            let h = (k as f64 + 0.5) / 255.0;
            vals.extend([h, h.next_up(), h.next_down()]);
        }
        vals.extend([-1.0, -0.0, 1.0 + 1e-12, 7.0, f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 1e-300]);
        // Each channel its own order of the values, so a level packed into the wrong byte shows.
        let n = vals.len();
        let chans: [Vec<f64>; 3] = [vals.clone(), vals.iter().rev().copied().collect(), (0..n).map(|i| vals[(i * 7 + 3) % n]).collect()];
        let mut g = Group { len: n, segs: vec![(0, 0, n as u32)], acc: chans.clone(), ..Group::default() };
        let mut rgb = vec![0u8; n * 3];
        encode(&mut g, &mut rgb, Transfer::Linear);
        for i in 0..n {
            for (c, ch) in chans.iter().enumerate() {
                assert_eq!(rgb[i * 3 + c], Transfer::Linear.encode(ch[i]), "channel {c}: {}", ch[i]);
            }
        }
    }
}
