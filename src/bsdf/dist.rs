//! Piecewise-constant distributions on [0, 1) and [0, 1)²: the tables the samplers draw from.
//!
//! Built from non-negative cell values (the sampler passes each cell's maximum of the target over a sub-grid,
//! as pbrt-v4's `PiecewiseConstant2D::FromFuncLInfinity` does, so a cell is never 0 where the target is positive
//! at one of its sub-grid points). Sampling inverts the cumulative sums (a marginal over the first coordinate, a
//! conditional per row over the second) from a guide table: u's share of n equal parts names the first cell that
//! can hold it, and a step or two forward finds the cell (Chen and Asau's index method) — no binary search, and
//! still the inverse of the cumulative distribution, so u → point is monotone and moves little when the values
//! move little (an image changes smoothly with a parameter). The density is the cell's value over the mean
//! value, read by direct indexing (the grid is uniform), so evaluating it costs no search.

/// A piecewise-constant density on [0, 1) with `n` equal cells.
#[derive(Clone, Debug)]
pub(crate) struct Dist1D {
    /// Cell densities (∫₀¹ = 1).
    pdf: Vec<f64>,
    /// Running sums of the cell values, `cdf[0] = 0`, `cdf[n]` = the total; length n + 1.
    cdf: Vec<f64>,
    /// Entry g: a cell at or before the one holding g/n of the total (n entries).
    guide: Vec<u32>,
    /// 1/(cell value) per cell (∞ for an empty cell, which is never chosen): a draw's fraction within its cell by
    /// a product.
    inv: Vec<f64>,
}

impl Dist1D {
    /// `None` when every value is 0 (nothing to sample). Values must be finite and ≥ 0.
    pub fn new(values: &[f64]) -> Option<Dist1D> {
        let n = values.len();
        let mut cdf = Vec::with_capacity(n + 1);
        cdf.push(0.0);
        let mut s = 0.0;
        for &v in values {
            s += v;
            cdf.push(s);
        }
        if s <= 0.0 || !s.is_finite() {
            return None;
        }
        let scale = n as f64 / s;
        // Each entry's target a hair low, so rounding in `sample_cell`'s own g and target can only make it step.
        let mut guide = Vec::with_capacity(n);
        let mut i = 0;
        for g in 0..n {
            let t = g as f64 / n as f64 * s * (1.0 - 4.0 * f64::EPSILON);
            while i + 1 < n && cdf[i + 1] <= t {
                i += 1;
            }
            guide.push(i as u32);
        }
        let inv = cdf.windows(2).map(|w| 1.0 / (w[1] - w[0])).collect();
        Some(Dist1D { pdf: values.iter().map(|v| v * scale).collect(), cdf, guide, inv })
    }

    /// The total of the cell values it was built from.
    pub fn total(&self) -> f64 {
        self.cdf[self.pdf.len()]
    }

    /// A point of [0, 1) for `u` in [0, 1), and the cell it fell in. Only cells of positive mass are chosen.
    pub fn sample(&self, u: f64) -> (f64, usize) {
        let n = self.pdf.len();
        let (i, frac) = self.sample_cell(u);
        // Kept inside cell i (the rounding of i + frac can reach the next cell's edge).
        (((i as f64 + frac) / n as f64).min(((i + 1) as f64 / n as f64).next_down()), i)
    }

    /// The cell `u` in [0, 1) falls in and where in it, as a fraction in [0, 1] of the cell's mass (the cell's
    /// own coordinate, for a caller that spreads a cell's mass by a measure of its own). Only cells of positive
    /// mass are chosen.
    pub fn sample_cell(&self, u: f64) -> (usize, f64) {
        let n = self.pdf.len();
        let target = u * self.total();
        // The last i with cdf[i] ≤ target (then cdf[i + 1] > target, so cell i has mass): from the guide's entry
        // forward, a step at a time (one or two on average), and by bisection past a few steps (a run of tiny
        // cells inside one guide entry), so no draw costs more than a search.
        let mut i = self.guide[((u * n as f64) as usize).min(n - 1)] as usize;
        let mut steps = 0;
        while i + 1 < n && self.cdf[i + 1] <= target {
            if steps == 4 {
                i += self.cdf[i + 1..n].partition_point(|&c| c <= target);
                break;
            }
            i += 1;
            steps += 1;
        }
        let i = self.skip_empty(i);
        (i, ((target - self.cdf[i]) * self.inv[i]).clamp(0.0, 1.0))
    }

    /// Rounding can leave `target` on a cell of zero mass at the end; step back to the last cell with mass.
    fn skip_empty(&self, mut i: usize) -> usize {
        while i > 0 && self.cdf[i + 1] <= self.cdf[i] {
            i -= 1;
        }
        while self.cdf[i + 1] <= self.cdf[i] {
            i += 1;
        }
        i
    }

    /// The cell densities (∫₀¹ = 1), for exports that rebuild the distribution.
    pub fn densities(&self) -> &[f64] {
        &self.pdf
    }

    /// The density at `x` (0 outside [0, 1)).
    #[cfg(test)]
    pub fn pdf(&self, x: f64) -> f64 {
        if !(0.0..1.0).contains(&x) {
            return 0.0;
        }
        let n = self.pdf.len();
        self.pdf[((x * n as f64) as usize).min(n - 1)]
    }

    /// The density of cell `i`.
    #[inline]
    pub fn cell_pdf(&self, i: usize) -> f64 {
        self.pdf[i]
    }
}

/// A piecewise-constant density on [0, 1)² with `n` rows (first coordinate) × `m` columns (second).
#[derive(Clone, Debug)]
pub(crate) struct Dist2D {
    n: usize,
    m: usize,
    /// Cell densities, row-major (∫∫ = 1).
    pdf: Vec<f64>,
    /// The marginal over rows.
    rows: Dist1D,
    /// Each row's conditional over columns (`None` for a row of zero mass, never chosen).
    cols: Vec<Option<Dist1D>>,
}

impl Dist2D {
    /// `None` when every value is 0. `values` row-major, n × m, finite and ≥ 0.
    pub fn new(values: &[f64], n: usize, m: usize) -> Option<Dist2D> {
        debug_assert_eq!(values.len(), n * m);
        let sums: Vec<f64> = values.chunks(m).map(|r| r.iter().sum()).collect();
        let rows = Dist1D::new(&sums)?;
        let scale = (n * m) as f64 / rows.total();
        let cols = values.chunks(m).map(Dist1D::new).collect();
        Some(Dist2D { n, m, pdf: values.iter().map(|v| v * scale).collect(), rows, cols })
    }

    /// A point of [0, 1)² for `u` in [0, 1)².
    pub fn sample(&self, u1: f64, u2: f64) -> (f64, f64) {
        let (x1, i) = self.rows.sample(u1);
        // The row was chosen for its mass, so its conditional exists.
        match &self.cols[i] {
            Some(c) => (x1, c.sample(u2).0),
            None => (x1, u2),
        }
    }

    /// The cell (row i, column j) for `u` in [0, 1)², and the fractions of the cell's mass below the point along
    /// each coordinate: (i, f₁, j, f₂) ([`Dist1D::sample_cell`]).
    pub fn sample_cell(&self, u1: f64, u2: f64) -> (usize, f64, usize, f64) {
        let (i, f1) = self.rows.sample_cell(u1);
        // The row was chosen for its mass, so its conditional exists.
        match &self.cols[i] {
            Some(c) => {
                let (j, f2) = c.sample_cell(u2);
                (i, f1, j, f2)
            }
            None => (i, f1, ((u2 * self.m as f64) as usize).min(self.m - 1), 0.5),
        }
    }

    /// The cell densities, row-major (∫∫ = 1), for exports that rebuild the distribution.
    pub fn densities(&self) -> &[f64] {
        &self.pdf
    }

    /// The density at (x1, x2) (0 outside [0, 1)²).
    #[inline]
    pub fn pdf(&self, x1: f64, x2: f64) -> f64 {
        if !(0.0..1.0).contains(&x1) || !(0.0..1.0).contains(&x2) {
            return 0.0;
        }
        let i = ((x1 * self.n as f64) as usize).min(self.n - 1);
        let j = ((x2 * self.m as f64) as usize).min(self.m - 1);
        self.pdf[i * self.m + j]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_dimension_samples_its_cells_and_integrates_to_one() {
        let d = Dist1D::new(&[0.0, 1.0, 3.0, 0.0]).unwrap();
        assert_eq!(d.pdf(0.1), 0.0);
        assert_eq!(d.pdf(0.3), 1.0);
        assert_eq!(d.pdf(0.6), 3.0);
        // u below a quarter of the mass lands in cell 1, the rest in cell 2; the end points map into the cells.
        assert_eq!(d.sample(0.0), (0.25, 1));
        assert_eq!(d.sample(0.125).1, 1);
        assert!((d.sample(0.125).0 - 0.375).abs() < 1e-15);
        assert_eq!(d.sample(0.5).1, 2);
        let (x, i) = d.sample(1.0f64.next_down());
        assert_eq!(i, 2);
        assert!(x < 0.75);
        assert!(Dist1D::new(&[0.0, 0.0]).is_none());
    }

    #[test]
    fn the_guide_finds_the_cell_the_binary_search_finds() {
        // The search it replaces, on random tables with runs of zeros and spans of many orders of magnitude, at
        // random u, at u on the guide's own boundaries and at the cells' edges.
        let binary = |d: &Dist1D, u: f64| {
            let n = d.pdf.len();
            let target = u * d.total();
            let i = (d.cdf.partition_point(|&c| c <= target).max(1) - 1).min(n - 1);
            let i = d.skip_empty(i);
            (i, ((target - d.cdf[i]) / (d.cdf[i + 1] - d.cdf[i])).clamp(0.0, 1.0))
        };
        let mut rng = crate::base::rng::Rng(0x6E1DE);
        for _ in 0..300 {
            let n = 1 + (rng.unit() * 700.0) as usize;
            let vals: Vec<f64> = (0..n)
                .map(|_| match (rng.unit() * 4.0) as u32 {
                    0 => 0.0,
                    1 => 10f64.powf(40.0 * rng.unit() - 20.0),
                    _ => rng.unit(),
                })
                .collect();
            let Some(d) = Dist1D::new(&vals) else { continue };
            let mut us: Vec<f64> = (0..200).map(|_| rng.unit()).collect();
            us.extend((0..n).flat_map(|g| {
                let u = g as f64 / n as f64;
                [u, u.next_up(), u.next_down().max(0.0)]
            }));
            us.extend(d.cdf.iter().map(|c| (c / d.total()).min(1.0f64.next_down())));
            us.push(1.0f64.next_down());
            for u in us {
                let (got, want) = (d.sample_cell(u), binary(&d, u));
                // The same cell; the fraction by a product with the reciprocal, within a few ulps of the quotient.
                assert_eq!(got.0, want.0, "u {u}");
                assert!((got.1 - want.1).abs() <= 4.0 * f64::EPSILON, "u {u}: {} against {}", got.1, want.1);
                assert!(vals[got.0] > 0.0);
            }
        }
    }

    #[test]
    fn two_dimensions_match_their_density() {
        let vals = [1.0, 0.0, 2.0, 5.0, 0.0, 0.0];
        let d = Dist2D::new(&vals, 3, 2).unwrap();
        // Mean value 8/6: cell (0,0) has density 0.75.
        assert!((d.pdf(0.1, 0.2) - 0.75).abs() < 1e-15);
        assert_eq!(d.pdf(0.9, 0.2), 0.0);
        let mut hits = [0usize; 6];
        let n = 64;
        for a in 0..n {
            for b in 0..n {
                let (i, f1, j, f2) = d.sample_cell((a as f64 + 0.5) / n as f64, (b as f64 + 0.5) / n as f64);
                assert!((0.0..=1.0).contains(&f1) && (0.0..=1.0).contains(&f2));
                hits[i * 2 + j] += 1;
            }
        }
        let total = (n * n) as f64;
        for (h, v) in hits.iter().zip(vals) {
            assert!((*h as f64 / total - v / 8.0).abs() < 0.01, "{hits:?}");
        }
    }
}
