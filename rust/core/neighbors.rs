//! Uniform spatial grid for fixed-radius neighbour queries (the truncated E-step, §4.2).
//!
//! The grid buckets `(n, 3)` points into cubic cells of side `h >= radius` with a counting
//! sort, so every point within `radius` of a query lies in the 3 x 3 x 3 block of cells
//! around the query's cell. Along x the three cells of a block row are consecutive in the
//! sorted order, so a query visits at most 9 contiguous index ranges.

use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use rayon::prelude::*;

use crate::core::error::{CoreError, CoreResult};

/// Cap on the number of cells; the cell side grows when the bounding box would need more.
const MAX_CELLS: usize = 1 << 22;

/// Points bucketed by cell. `order[start[c]..start[c + 1]]` are the indices of the points in
/// cell `c = (iz * ny + iy) * nx + ix`.
#[derive(Debug, Clone)]
pub struct Grid {
    origin: [f64; 3],
    inv_h: f64,
    dims: [usize; 3],
    start: Vec<u32>,
    order: Vec<u32>,
}

/// Per-axis minimum and maximum `(lo, hi)` of flat `(n, 3)` points (`+inf` / `-inf` when
/// `n = 0`).
pub(crate) fn bounding_box(points: &[f64]) -> ([f64; 3], [f64; 3]) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in points.chunks_exact(3) {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    (lo, hi)
}

impl Grid {
    /// Bucket `points` (flat row-major `(n, 3)`, finite) into cells of side at least `h`.
    ///
    /// `h` must be positive and finite; it is enlarged when the bounding box would need more
    /// than `MAX_CELLS` cells (queries stay exact, only slower). A bounding box whose extent is
    /// not a finite number (coordinates near the limits of `f64`) is an `InvalidInput` error.
    pub fn new(points: &[f64], h: f64) -> CoreResult<Grid> {
        let n = points.len() / 3;
        let (mut lo, mut hi) = bounding_box(points);
        if n == 0 {
            lo = [0.0; 3];
            hi = [0.0; 3];
        }
        if let Some(a) = (0..3).find(|&a| !(hi[a] - lo[a]).is_finite()) {
            return Err(CoreError::InvalidInput(format!(
                "points span {:e} .. {:e} along axis {a}, too far apart for a grid",
                lo[a], hi[a]
            )));
        }
        let mut h = if h.is_finite() && h > 0.0 { h } else { 1.0 };
        // each axis clamped to MAX_CELLS before the cast, so a huge extent cannot wrap it
        let dims_for = |h: f64| -> [usize; 3] {
            let mut d = [1usize; 3];
            for a in 0..3 {
                d[a] = ((hi[a] - lo[a]) / h).floor().min(MAX_CELLS as f64) as usize + 1;
            }
            d
        };
        let mut dims = dims_for(h);
        while dims[0].saturating_mul(dims[1]).saturating_mul(dims[2]) > MAX_CELLS {
            h *= 2.0;
            dims = dims_for(h);
        }
        let inv_h = 1.0 / h;
        let ncell = dims[0] * dims[1] * dims[2];
        let cell_of = |p: &[f64]| -> usize {
            let mut c = [0usize; 3];
            for a in 0..3 {
                let v = ((p[a] - lo[a]) * inv_h).floor();
                c[a] = (v.max(0.0) as usize).min(dims[a] - 1);
            }
            (c[2] * dims[1] + c[1]) * dims[0] + c[0]
        };
        let cells: Vec<usize> = points.chunks_exact(3).map(cell_of).collect();
        let mut start = vec![0u32; ncell + 1];
        for &c in &cells {
            start[c + 1] += 1;
        }
        for c in 0..ncell {
            start[c + 1] += start[c];
        }
        let mut fill = start.clone();
        let mut order = vec![0u32; n];
        for (i, &c) in cells.iter().enumerate() {
            order[fill[c] as usize] = i as u32;
            fill[c] += 1;
        }
        Ok(Grid {
            origin: lo,
            inv_h,
            dims,
            start,
            order,
        })
    }

    /// Point indices in sorted (cell) order; ranges from [`Grid::ranges`] index into this.
    pub fn order(&self) -> &[u32] {
        &self.order
    }

    /// Number of cells.
    pub fn n_cells(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    /// The side of a cell (at least the `h` asked for).
    pub fn cell_size(&self) -> f64 {
        1.0 / self.inv_h
    }

    /// The contiguous ranges `order[lo..hi]` of points in the 3 x 3 x 3 cells around `q` (a
    /// superset of the points within one cell size of `q`): `(ranges, count)`.
    #[inline(always)]
    pub fn block(&self, q: [f64; 3]) -> ([(u32, u32); 9], usize) {
        let mut out = [(0u32, 0u32); 9];
        let mut cnt = 0;
        let Some(c) = self.query_cell(q) else {
            return (out, 0);
        };
        let (nx, ny, nz) = (
            self.dims[0] as i64,
            self.dims[1] as i64,
            self.dims[2] as i64,
        );
        let x0 = (c[0] - 1).max(0);
        let x1 = (c[0] + 1).min(nx - 1);
        if x0 > x1 {
            return (out, 0);
        }
        for z in (c[2] - 1).max(0)..=(c[2] + 1).min(nz - 1) {
            for y in (c[1] - 1).max(0)..=(c[1] + 1).min(ny - 1) {
                let row = (z * ny + y) * nx;
                let lo = self.start[(row + x0) as usize];
                let hi = self.start[(row + x1 + 1) as usize];
                if hi > lo {
                    out[cnt] = (lo, hi);
                    cnt += 1;
                }
            }
        }
        (out, cnt)
    }

    /// Mean number of points in the 3 x 3 x 3 block of a query placed at one of the bucketed
    /// points (the work per query of a radius search whose queries follow the points).
    pub fn mean_block(&self) -> f64 {
        let n = self.order.len();
        if n == 0 {
            return 0.0;
        }
        let (nx, ny) = (self.dims[0], self.dims[1]);
        let mut total = 0.0;
        for c in 0..self.n_cells() {
            let cnt = self.start[c + 1] - self.start[c];
            if cnt == 0 {
                continue;
            }
            let (ix, iy, iz) = (c % nx, (c / nx) % ny, c / (nx * ny));
            // The centre of cell c.
            let q = [
                self.origin[0] + (ix as f64 + 0.5) / self.inv_h,
                self.origin[1] + (iy as f64 + 0.5) / self.inv_h,
                self.origin[2] + (iz as f64 + 0.5) / self.inv_h,
            ];
            let (r, k) = self.block(q);
            let b: u32 = r[..k].iter().map(|&(lo, hi)| hi - lo).sum();
            total += cnt as f64 * b as f64;
        }
        total / n as f64
    }

    /// A key shared by exactly the queries whose [`Grid::block`] is the same: the query's
    /// cell, extended by one cell of margin on every side; `u64::MAX` for queries with no
    /// cell within reach (their block is empty). Sorting queries by key groups them so that
    /// one gather of the block serves the whole group.
    #[inline(always)]
    pub fn key(&self, q: [f64; 3]) -> u64 {
        let Some(c) = self.query_cell(q) else {
            return u64::MAX;
        };
        // shift by one cell so that the margin cells -1 are non-negative
        let c = c.map(|v| (v + 1) as u64);
        let (nx, ny) = (self.dims[0] as u64 + 2, self.dims[1] as u64 + 2);
        (c[2] * ny + c[1]) * nx + c[0]
    }

    /// The cell of a query, `-1..=dims` per axis (one cell of margin around the box), or
    /// `None` when no cell is within reach (far outside the box, or a NaN coordinate). The one
    /// place [`Grid::block`] and [`Grid::key`] locate a query, so equal keys mean equal blocks.
    #[inline(always)]
    fn query_cell(&self, q: [f64; 3]) -> Option<[i64; 3]> {
        let mut c = [0i64; 3];
        for a in 0..3 {
            let v = ((q[a] - self.origin[a]) * self.inv_h).floor();
            if !(v >= -1.0 && v <= self.dims[a] as f64) {
                return None;
            }
            c[a] = v as i64;
        }
        Some(c)
    }

    /// Call `f(lo, hi)` for each range of [`Grid::block`].
    #[inline(always)]
    pub fn ranges(&self, q: [f64; 3], mut f: impl FnMut(usize, usize)) {
        let (r, n) = self.block(q);
        for &(lo, hi) in &r[..n] {
            f(lo as usize, hi as usize);
        }
    }
}

/// Unit surface normals at `query` points (flat `(n, 3)`) from the `source` points (flat
/// `(N, 3)`) within `radius` (metres): the direction of least spread of those neighbours
/// (the least-squares plane's normal), flipped to face `camera`. The source is first reduced
/// to count-weighted voxel centroids of side `radius / 4` (a plane at that scale needs no
/// more, and a dense frame would otherwise cost thousands of neighbours per query). A query
/// with fewer than 3 neighbouring centroids, or a degenerate (collinear) neighbourhood, gets
/// a zero normal. Each query is independent, so the result does not depend on the thread
/// count.
pub fn surface_normals(
    query: &[f64],
    source: &[f64],
    radius: f64,
    camera: [f64; 3],
) -> CoreResult<Vec<f64>> {
    if !query.len().is_multiple_of(3) || !source.len().is_multiple_of(3) {
        return Err(CoreError::InvalidInput(
            "points must have shape (n, 3)".into(),
        ));
    }
    if !(radius.is_finite() && radius > 0.0) {
        return Err(CoreError::InvalidInput(format!(
            "normal radius must be positive and finite, got {radius}"
        )));
    }
    if !query
        .iter()
        .chain(source)
        .chain(&camera)
        .all(|v| v.is_finite())
    {
        return Err(CoreError::NonFinite("points or camera".into()));
    }
    if source.is_empty() {
        return Ok(vec![0.0; query.len()]);
    }
    let (cent, cnt) = voxel_downsample(source, 0.25 * radius);
    let grid = Grid::new(&cent, radius)?;
    let order = grid.order();
    let r2 = radius * radius;
    let out: Vec<[f64; 3]> = query
        .par_chunks_exact(3)
        .map(|q| {
            let mut n = 0usize;
            let mut wsum = 0.0;
            let mut s = Vector3::zeros();
            let mut ss = Matrix3::zeros();
            grid.ranges([q[0], q[1], q[2]], |lo, hi| {
                for &k in &order[lo..hi] {
                    let k = k as usize;
                    // relative to the query: better conditioned sums
                    let d = Vector3::new(
                        cent[3 * k] - q[0],
                        cent[3 * k + 1] - q[1],
                        cent[3 * k + 2] - q[2],
                    );
                    if d.norm_squared() <= r2 {
                        let w = cnt[k];
                        n += 1;
                        wsum += w;
                        s += w * d;
                        ss += w * (d * d.transpose());
                    }
                }
            });
            if n < 3 {
                return [0.0; 3];
            }
            let m = s / wsum;
            let cov = ss / wsum - m * m.transpose();
            let eig = SymmetricEigen::new(cov);
            // eigenvalues in increasing order: the plane's normal is the first axis
            let mut ix = [0, 1, 2];
            ix.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
            // collinear neighbours (a line of points) span no plane
            if eig.eigenvalues[ix[1]].is_nan() || eig.eigenvalues[ix[1]] <= 0.0 {
                return [0.0; 3];
            }
            let mut v = eig.eigenvectors.column(ix[0]).normalize();
            let to_cam = Vector3::new(camera[0] - q[0], camera[1] - q[1], camera[2] - q[2]);
            if v.dot(&to_cam) < 0.0 {
                v = -v;
            }
            [v.x, v.y, v.z]
        })
        .collect();
    Ok(out.into_iter().flatten().collect())
}

/// Voxel-grid subsampling: the centroid of the points of each occupied cubic cell of side
/// `h` and the number of points it stands for, `(centroids (K, 3) flat, counts (K,))`.
///
/// Cells are keyed relative to the bounding-box minimum and emitted in key order, so the
/// result is deterministic. `h` must be positive and finite (otherwise the input is returned
/// with unit counts).
pub fn voxel_downsample(points: &[f64], h: f64) -> (Vec<f64>, Vec<f64>) {
    let (c, w, _) = voxel_downsample_with(points, None, h);
    (c, w)
}

/// [`voxel_downsample`] that also averages a per-point 3-vector `attr` (flat `(N, 3)`, e.g.
/// surface normals) over each cell; the third result is the per-cell means (empty without
/// `attr`).
pub fn voxel_downsample_with(
    points: &[f64],
    attr: Option<&[f64]>,
    h: f64,
) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let n = points.len() / 3;
    if n == 0 || !(h.is_finite() && h > 0.0) {
        return (
            points.to_vec(),
            vec![1.0; n],
            attr.map_or(Vec::new(), |a| a.to_vec()),
        );
    }
    let mut lo = [f64::INFINITY; 3];
    for p in points.chunks_exact(3) {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
        }
    }
    let inv = 1.0 / h;
    // 21 bits per axis: 2^21 cells of side h per axis (clamped; far points share the last cell).
    const MAXC: f64 = ((1u64 << 21) - 1) as f64;
    let mut keyed: Vec<(u64, u32)> = points
        .chunks_exact(3)
        .enumerate()
        .map(|(i, p)| {
            let mut k = 0u64;
            for a in 0..3 {
                let c = ((p[a] - lo[a]) * inv).floor().clamp(0.0, MAXC) as u64;
                k = (k << 21) | c;
            }
            (k, i as u32)
        })
        .collect();
    keyed.sort_unstable();
    let mut cent = Vec::new();
    let mut cnt = Vec::new();
    let mut means = Vec::new();
    let mut i = 0;
    while i < keyed.len() {
        let mut j = i;
        let mut s = [0.0f64; 3];
        let mut sa = [0.0f64; 3];
        while j < keyed.len() && keyed[j].0 == keyed[i].0 {
            let q = keyed[j].1 as usize;
            for a in 0..3 {
                s[a] += points[3 * q + a];
            }
            if let Some(v) = attr {
                for a in 0..3 {
                    sa[a] += v[3 * q + a];
                }
            }
            j += 1;
        }
        let c = (j - i) as f64;
        cent.extend_from_slice(&[s[0] / c, s[1] / c, s[2] / c]);
        if attr.is_some() {
            means.extend_from_slice(&[sa[0] / c, sa[1] / c, sa[2] / c]);
        }
        cnt.push(c);
        i = j;
    }
    (cent, cnt, means)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn far_apart_points_keep_a_bounded_grid_or_fail_cleanly() {
        // an extent of 1e18 or 1e300 cells of 0.1: the cell side grows, nothing wraps
        for far in [1e18, 1e300] {
            let pts = [0.0, 0.0, 0.0, 0.05, 0.0, 0.0, far, far, far];
            let g = Grid::new(&pts, 0.1).unwrap();
            assert!(g.n_cells() <= MAX_CELLS);
            let mut found = Vec::new();
            g.ranges([0.0, 0.0, 0.0], |lo, hi| {
                found.extend_from_slice(&g.order()[lo..hi])
            });
            assert!(found.contains(&0) && found.contains(&1));
        }
        // an extent that is not a finite number
        let pts = [-1e308, 0.0, 0.0, 1e308, 0.0, 0.0];
        assert!(matches!(
            Grid::new(&pts, 0.1),
            Err(CoreError::InvalidInput(_))
        ));
    }

    #[test]
    fn radius_query_matches_brute_force() {
        let pts: Vec<f64> = (0..3000)
            .map(|i| ((i as f64) * 0.618_033_988_7).fract() * 2.0 - 1.0)
            .collect();
        let r = 0.2;
        let g = Grid::new(&pts, r).unwrap();
        for q in pts.chunks_exact(3).take(50) {
            let q = [q[0] + 0.05, q[1], q[2] - 0.03];
            let mut found = vec![];
            g.ranges(q, |lo, hi| {
                for k in lo..hi {
                    let i = g.order()[k] as usize;
                    let d2: f64 = (0..3).map(|a| (pts[3 * i + a] - q[a]).powi(2)).sum();
                    if d2 < r * r {
                        found.push(i);
                    }
                }
            });
            found.sort();
            let brute: Vec<usize> = (0..pts.len() / 3)
                .filter(|&i| (0..3).map(|a| (pts[3 * i + a] - q[a]).powi(2)).sum::<f64>() < r * r)
                .collect();
            assert_eq!(found, brute);
        }
    }

    #[test]
    fn mean_block_is_the_average_block_of_the_points() {
        let pts: Vec<f64> = (0..900)
            .map(|i| (i * 7919 % 1009) as f64 / 1009.0)
            .collect();
        let g = Grid::new(&pts, 0.15).unwrap();
        let brute: f64 = pts
            .chunks_exact(3)
            .map(|p| {
                let (r, n) = g.block([p[0], p[1], p[2]]);
                r[..n].iter().map(|&(lo, hi)| (hi - lo) as f64).sum::<f64>()
            })
            .sum::<f64>()
            / 300.0;
        assert!(
            (g.mean_block() - brute).abs() < 1e-9,
            "{} {}",
            g.mean_block(),
            brute
        );
    }

    #[test]
    fn equal_keys_mean_equal_blocks() {
        let pts: Vec<f64> = (0..600)
            .map(|i| ((i * 7919 % 1000) as f64 / 1000.0) * if i % 3 == 2 { 0.3 } else { 1.0 })
            .collect();
        let g = Grid::new(&pts, 0.1).unwrap();
        let mut seen = std::collections::HashMap::new();
        for i in 0..3000 {
            let q = [
                -0.25 + 1.5 * ((i * 31 % 997) as f64 / 997.0),
                -0.25 + 1.5 * ((i * 17 % 991) as f64 / 991.0),
                -0.25 + 0.8 * ((i * 13 % 983) as f64 / 983.0),
            ];
            let (r, n) = g.block(q);
            let k = g.key(q);
            if k == u64::MAX {
                assert_eq!(n, 0);
                continue;
            }
            let b = r[..n].to_vec();
            if let Some(prev) = seen.insert(k, b.clone()) {
                assert_eq!(prev, b, "same key, different block");
            }
        }
        assert!(seen.len() > 50);
    }

    #[test]
    fn voxel_downsample_preserves_mass_and_centroid() {
        let mut pts = Vec::new();
        let mut state = 12345u64;
        for _ in 0..3000 {
            for _ in 0..3 {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                pts.push((state >> 11) as f64 / (1u64 << 53) as f64);
            }
        }
        let (c, w) = voxel_downsample(&pts, 0.25);
        assert!(w.len() <= 64 && w.len() >= 60);
        assert_eq!(w.iter().sum::<f64>(), 3000.0);
        for a in 0..3 {
            let m0: f64 = pts.iter().skip(a).step_by(3).sum::<f64>() / 3000.0;
            let m1: f64 = c
                .iter()
                .skip(a)
                .step_by(3)
                .zip(&w)
                .map(|(v, k)| v * k)
                .sum::<f64>()
                / 3000.0;
            assert!((m0 - m1).abs() < 1e-12);
        }
        // every centroid lies inside its cell
        for p in c.chunks_exact(3) {
            assert!(p.iter().all(|v| (0.0..=1.0).contains(v)));
        }
    }

    #[test]
    fn surface_normals_match_a_sphere_and_face_the_camera() {
        // the camera-facing half of a sphere of radius 0.3 m centred 2 m in front of it
        let c = [0.1, -0.05, 2.0];
        let mut pts = Vec::new();
        let mut dirs = Vec::new();
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        let n = 8000;
        for i in 0..n {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let d = [
                r * (golden * i as f64).cos(),
                r * (golden * i as f64).sin(),
                z,
            ];
            if d[2] < -0.2 {
                pts.extend_from_slice(&[c[0] + 0.3 * d[0], c[1] + 0.3 * d[1], c[2] + 0.3 * d[2]]);
                dirs.push(d);
            }
        }
        let nr = surface_normals(&pts, &pts, 0.03, [0.0; 3]).unwrap();
        for (v, d) in nr.chunks_exact(3).zip(&dirs) {
            let cos = v[0] * d[0] + v[1] * d[1] + v[2] * d[2];
            assert!(cos > 0.995, "{cos}");
        }
        // a camera behind the sphere flips them; an isolated query gets zero
        let back = surface_normals(&pts, &pts, 0.03, [0.0, 0.0, 5.0]).unwrap();
        assert!(back
            .chunks_exact(3)
            .zip(&dirs)
            .all(|(v, d)| v[0] * d[0] + v[1] * d[1] + v[2] * d[2] < 0.0));
        let far = surface_normals(&[9.0, 9.0, 9.0], &pts, 0.03, [0.0; 3]).unwrap();
        assert_eq!(far, vec![0.0; 3]);
        assert!(surface_normals(&pts, &pts, 0.0, [0.0; 3]).is_err());
    }
}
