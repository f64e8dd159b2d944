//! Label placement for the scatter: a pure function of the label boxes (tested without rendering).

use super::*;

/// Where a label went: its text box and, when it sits away from its point, a leader line (point → box).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct PlacedLabel {
    pub rect: Rect,
    pub leader: Option<[(f64, f64); 2]>,
}

/// What [`place_labels`] places: one label of `sizes[i]` (width, height) per point `anchors[i]`, whose
/// marker covers a square of half-side `marker`; every box stays inside `bounds`, off `obstacles`, and off
/// the `avoid` segments (e.g. the Pareto line) when some other position allows.
pub(crate) struct LabelProblem<'a> {
    pub anchors: &'a [(f64, f64)],
    pub sizes: &'a [(f64, f64)],
    pub marker: f64,
    pub bounds: Rect,
    pub obstacles: &'a [Rect],
    pub avoid: &'a [[(f64, f64); 2]],
}

/// Clear space kept around each label box, and the farthest a label may sit from its point.
pub(super) const LABEL_PAD: f64 = 1.5;
pub(super) const MAX_LEADER: f64 = 400.0;

/// Greedy, deterministic label placement. Points are taken most crowded first; each tries candidate boxes on
/// square rings of growing distance around its point (the 8 touching positions first, then rings with a leader
/// line), right/left before up/down, and takes the first box that leaves the bounds, the obstacles, every
/// marker, every placed box and every placed leader alone (its own leader crossing none of them) — preferring,
/// within two rings, one that also stays off the `avoid` segments and, if beside its point, is nearer to it
/// than to any other point. `None` only when no ring up to `MAX_LEADER` has room.
/// Cost: O(n² · candidates) box tests; 33 bench labels take milliseconds, far less than drawing them.
pub(crate) fn place_labels(p: &LabelProblem) -> Vec<Option<PlacedLabel>> {
    let n = p.anchors.len();
    let markers: Vec<Rect> = p.anchors.iter().map(|&a| Rect::around(a, p.marker + 1.0)).collect();
    let crowd = |i: usize| {
        let r = 3.0 * p.sizes[i].1.max(p.marker * 2.0);
        p.anchors.iter().filter(|a| (a.0 - p.anchors[i].0).hypot(a.1 - p.anchors[i].1) < r).count()
    };
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by_key(|&i| (std::cmp::Reverse(crowd(i)), i));
    let mut placed: Vec<Option<PlacedLabel>> = vec![None; n];
    for &i in &order {
        placed[i] = best_spot(p, i, &markers, &placed);
    }
    placed
}

/// Candidate directions of one ring, preferred first: near-horizontal (beside the point) before vertical.
pub(super) fn ring_dirs(ring: usize) -> Vec<(f64, f64)> {
    if ring == 0 {
        return vec![(1.0, 0.0), (-1.0, 0.0), (1.0, -1.0), (1.0, 1.0), (-1.0, -1.0), (-1.0, 1.0), (0.0, -1.0), (0.0, 1.0)];
    }
    let k = if ring < 4 { 16 } else { 32 };
    let mut dirs: Vec<(usize, f64, f64)> = (0..k)
        .map(|j| {
            let a = j as f64 * std::f64::consts::TAU / k as f64;
            // Rank by distance from the horizontal; j breaks ties so the order is fixed.
            let rank = (a.sin().abs() * 1000.0) as usize * k + j;
            (rank, a.cos(), -a.sin())
        })
        .collect();
    dirs.sort_by_key(|d| d.0);
    dirs.into_iter().map(|d| (d.1, d.2)).collect()
}

pub(super) fn best_spot(p: &LabelProblem, i: usize, markers: &[Rect], placed: &[Option<PlacedLabel>]) -> Option<PlacedLabel> {
    let (ax, ay) = p.anchors[i];
    let (w, h) = p.sizes[i];
    let gap = p.marker + 1.0 + LABEL_PAD + 1.0;
    let step = (h * 0.75).max(4.0);
    let others: Vec<&PlacedLabel> = placed.iter().flatten().collect();
    let mut fallback: Option<(usize, PlacedLabel)> = None;
    for ring in 0.. {
        let d = gap + ring as f64 * step;
        if d > MAX_LEADER {
            break;
        }
        if let Some((r, f)) = fallback {
            if ring > r + 2 {
                return Some(f);
            }
        }
        for (cx, cy) in ring_dirs(ring) {
            // Attach point on the square of half-side d; the box hangs off it away from the point.
            let s = d / cx.abs().max(cy.abs());
            let (tx, ty) = (ax + cx * s, ay + cy * s);
            let x0 = if cx > 0.38 { tx } else if cx < -0.38 { tx - w } else { tx - w / 2.0 };
            let y0 = if cy > 0.38 { ty } else if cy < -0.38 { ty - h } else { ty - h / 2.0 };
            let rect = Rect { x0, y0, x1: x0 + w, y1: y0 + h };
            let padded = rect.grow(LABEL_PAD);
            if !p.bounds.contains(&padded)
                || p.obstacles.iter().any(|o| o.intersects(&padded))
                || markers.iter().any(|m| m.intersects(&padded))
                || others.iter().any(|o| o.rect.grow(LABEL_PAD).intersects(&padded) || o.leader.is_some_and(|l| padded.hit_by(l[0], l[1])))
            {
                continue;
            }
            let leader = (ring > 0).then(|| {
                let q = rect.nearest((ax, ay));
                let len = (q.0 - ax).hypot(q.1 - ay).max(1e-9);
                let r = p.marker + 1.5;
                [(ax + (q.0 - ax) * r / len, ay + (q.1 - ay) * r / len), q]
            });
            if let Some(l) = leader {
                let blocked = others.iter().any(|o| o.rect.grow(LABEL_PAD).hit_by(l[0], l[1]) || o.leader.is_some_and(|m| segments_cross(l, m)))
                    || markers.iter().enumerate().any(|(j, m)| {
                        // A marker overlapping this one cannot be cleared; any other is passed with 2 px to spare.
                        let m = m.grow(2.0);
                        j != i && !m.contains(&Rect::around(l[0], 0.0)) && m.hit_by(l[0], l[1])
                    });
                if blocked {
                    continue;
                }
            }
            let spot = PlacedLabel { rect, leader };
            // Soft: off the avoided segments, and closer to its own point than to any other (no misreading).
            let dist = |a: (f64, f64)| {
                let q = rect.nearest(a);
                (q.0 - a.0).hypot(q.1 - a.1)
            };
            let own = if leader.is_some() { f64::INFINITY } else { dist((ax, ay)) };
            let soft_clear = !p.avoid.iter().any(|s| padded.hit_by(s[0], s[1]) || leader.is_some_and(|l| segments_cross(l, *s)))
                && !p.anchors.iter().enumerate().any(|(j, &a)| j != i && dist(a) < own + 2.0 && leader.is_none());
            if soft_clear {
                return Some(spot);
            }
            if fallback.is_none() {
                fallback = Some((ring, spot));
            }
        }
    }
    fallback.map(|f| f.1)
}
