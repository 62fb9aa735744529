//! Exact nearest and `k`-th nearest distances, capped, on a uniform grid; the symmetric
//! truncated chamfer misfit built on them (step 1's prediction check and rest-frame choice,
//! step 3's choice between a frame's tracked hypotheses); farthest-point sampling.
//!
//! The points are bucketed into cubic cells of side `h` (a counting sort). A query searches
//! the cells ring by ring in Chebyshev index distance from its own cell: every point in a
//! cell of ring `r + 1` or beyond lies at least `r h` from the query, so the search stops
//! after ring `r` once the best distance found is at most `r h`, or once `r h` reaches the
//! cap (farther points do not matter), or once the rings have covered the whole grid. The
//! result is the exact distance to the nearest point, capped, the same as a k-d tree's.
//! Stray points far outside the bulk of the points are searched in a level of their own
//! ([`Nearest`]), so they cannot make the cells of the bulk large.

use rayon::prelude::*;

use crate::core::error::{CoreError, CoreResult};
use crate::core::neighbors::bounding_box;

/// Rows of cells (one per `(iy, iz)`) per point at most: the cell side grows when the box
/// would need more (a flat or sparse level, such as a far level of a few scattered points),
/// so that the row table stays linear in the points. Cells along x cost nothing: each row holds only its points, sorted by cell.
const ROWS_PER_POINT: usize = 16;

/// Queries per rayon task.
const CHUNK: usize = 512;

/// Points bucketed by cell, sparse along x: row `r = iz * ny + iy` holds its points in
/// `sorted[row_start[r]..row_start[r + 1]]` (flat `(n, 3)`, ordered by their x cell
/// `xcell`), so the cells `x0..=x1` of a row are one contiguous slice found by two binary
/// searches in a short row.
struct NnGrid {
    origin: [f64; 3],
    h: f64,
    dims: [i64; 3],
    row_start: Vec<u32>,
    xcell: Vec<i64>,
    sorted: Vec<f64>,
}

/// The per-axis 1-99 % bounds `(lo, hi)` of flat `(n, 3)` points (`n >= 1`), read on at
/// most 2048 of them (every `n / 2048`-th): a box and a scale that a few outliers do not set.
fn robust_box(points: &[f64]) -> ([f64; 3], [f64; 3]) {
    let n = points.len() / 3;
    let step = n.div_ceil(2048).max(1);
    let mut lo = [0.0f64; 3];
    let mut hi = [0.0f64; 3];
    for a in 0..3 {
        let mut v: Vec<f64> = points.chunks_exact(3).step_by(step).map(|p| p[a]).collect();
        let k_lo = ((v.len() - 1) as f64 * 0.01).round() as usize;
        let k_hi = ((v.len() - 1) as f64 * 0.99).round() as usize;
        lo[a] = *v.select_nth_unstable_by(k_lo, |x, y| x.total_cmp(y)).1;
        hi[a] = *v.select_nth_unstable_by(k_hi, |x, y| x.total_cmp(y)).1;
    }
    (lo, hi)
}

impl NnGrid {
    /// Bucket `points` (flat `(n, 3)`, finite, `n >= 1`) over their bounding box. The cell
    /// side is `scale L / sqrt(n)` with `L = ext` the largest extent of [`robust_box`], about one
    /// spacing of `n` points spread over a surface of size `L`; it grows when the box would
    /// need more than `ROWS_PER_POINT` rows per point.
    fn new(points: &[f64], ext: f64, scale: f64) -> NnGrid {
        let n = points.len() / 3;
        let (lo, hi) = bounding_box(points);
        let mut h = scale * ext / (n as f64).sqrt();
        if !(h.is_finite() && h > 0.0) {
            h = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
            if !(h.is_finite() && h > 0.0) {
                h = 1.0;
            }
        }
        let dims_for = |h: f64| -> [i64; 3] {
            let mut d = [1i64; 3];
            for a in 0..3 {
                // bounded so that far outliers cannot overflow the cell arithmetic
                d[a] = ((hi[a] - lo[a]) / h).floor().min(1e9) as i64 + 1;
            }
            d
        };
        let max_rows = (ROWS_PER_POINT * n).max(1024);
        let mut dims = dims_for(h);
        while (dims[1] as usize).saturating_mul(dims[2] as usize) > max_rows {
            h *= 1.25;
            dims = dims_for(h);
        }
        let nrows = (dims[1] * dims[2]) as usize;
        let cell = |p: &[f64], a: usize| -> i64 {
            let v = ((p[a] - lo[a]) / h).floor();
            (v.max(0.0) as i64).min(dims[a] - 1)
        };
        let keys: Vec<(usize, i64)> = points
            .chunks_exact(3)
            .map(|p| ((cell(p, 2) * dims[1] + cell(p, 1)) as usize, cell(p, 0)))
            .collect();
        let mut row_start = vec![0u32; nrows + 1];
        for &(r, _) in &keys {
            row_start[r + 1] += 1;
        }
        for r in 0..nrows {
            row_start[r + 1] += row_start[r];
        }
        // counting sort by row, then each row by x cell (stable: ties keep input order)
        let mut fill = row_start.clone();
        let mut order = vec![0u32; n];
        for (i, &(r, _)) in keys.iter().enumerate() {
            order[fill[r] as usize] = i as u32;
            fill[r] += 1;
        }
        for r in 0..nrows {
            let (s, e) = (row_start[r] as usize, row_start[r + 1] as usize);
            if e - s > 1 {
                order[s..e].sort_by_key(|&i| keys[i as usize].1);
            }
        }
        let mut sorted = vec![0.0f64; 3 * n];
        let mut xcell = vec![0i64; n];
        for (k, &i) in order.iter().enumerate() {
            let i = i as usize;
            sorted[3 * k..3 * k + 3].copy_from_slice(&points[3 * i..3 * i + 3]);
            xcell[k] = keys[i].1;
        }
        NnGrid {
            origin: lo,
            h,
            dims,
            row_start,
            xcell,
            sorted,
        }
    }

    /// Visit the points ring by ring in Chebyshev cell distance from `q`'s cell: `visit`
    /// sees every point (a `[x, y, z]` slice) of ring `r`, then `done(state, reach2)` is asked
    /// with `reach2 = (r h)^2`, the squared distance below which rings beyond hold no point.
    /// Returns `true` when `done` said so or the rings covered the whole grid, `false` after
    /// ring `max_ring` otherwise. The query's cell index is not clamped to the box (a query
    /// outside it starts from a virtual cell), so the ring bound holds for every query.
    fn walk_rings<S: ?Sized>(
        &self,
        q: [f64; 3],
        max_ring: i64,
        state: &mut S,
        visit: impl Fn(&mut S, &[f64]),
        done: impl Fn(&S, f64) -> bool,
    ) -> bool {
        let mut c = [0i64; 3];
        for a in 0..3 {
            // finite queries; the clamp keeps far ones from overflowing
            let v = ((q[a] - self.origin[a]) / self.h).floor().clamp(-1e9, 1e9);
            c[a] = v as i64;
        }
        let [nx, ny, nz] = self.dims;
        // the points of row (z, y) in x cells x0..=x1
        let scan = |z: i64, y: i64, x0: i64, x1: i64, state: &mut S| {
            let r = (z * ny + y) as usize;
            let (s, e) = (self.row_start[r] as usize, self.row_start[r + 1] as usize);
            if s == e {
                return;
            }
            let xs = &self.xcell[s..e];
            let a = s + xs.partition_point(|&x| x < x0);
            let b = s + xs.partition_point(|&x| x <= x1);
            for p in self.sorted[3 * a..3 * b].chunks_exact(3) {
                visit(state, p);
            }
        };
        // rings nearer than the box hold no cell of it: start at the first that does (a
        // query far outside the box would otherwise walk one empty ring per cell)
        let gap = |c: i64, n: i64| (-c).max(c - (n - 1)).max(0);
        let mut r = gap(c[0], nx).max(gap(c[1], ny)).max(gap(c[2], nz));
        if r > 0 {
            // the checks of ring r - 1, the last one walked through
            if done(state, ((r - 1) as f64 * self.h).powi(2)) {
                return true;
            }
            if r > max_ring {
                return false;
            }
        }
        loop {
            let z0 = (c[2] - r).max(0);
            let z1 = (c[2] + r).min(nz - 1);
            let y0 = (c[1] - r).max(0);
            let y1 = (c[1] + r).min(ny - 1);
            let x0 = (c[0] - r).max(0);
            let x1 = (c[0] + r).min(nx - 1);
            if z0 <= z1 && y0 <= y1 && x0 <= x1 {
                for z in z0..=z1 {
                    for y in y0..=y1 {
                        if (z - c[2]).abs() == r || (y - c[1]).abs() == r {
                            scan(z, y, x0, x1, state);
                        } else {
                            for x in [c[0] - r, c[0] + r] {
                                if (0..nx).contains(&x) {
                                    scan(z, y, x, x, state);
                                }
                            }
                        }
                    }
                }
            }
            // cells of ring r + 1 and beyond lie at least r h away
            let reach = r as f64 * self.h;
            let covered = c[0] - r <= 0
                && c[0] + r >= nx - 1
                && c[1] - r <= 0
                && c[1] + r >= ny - 1
                && c[2] - r <= 0
                && c[2] + r >= nz - 1;
            if covered || done(state, reach * reach) {
                return true;
            }
            if r >= max_ring {
                return false;
            }
            r += 1;
        }
    }

    /// Smallest squared distance from `q` to a point, or `cap2` when none is nearer; `None`
    /// when the search reaches ring `max_ring` without an answer that rings beyond could not
    /// beat.
    fn nearest_sq(&self, q: [f64; 3], cap2: f64, max_ring: i64) -> Option<f64> {
        let mut best = cap2;
        let found = self.walk_rings(
            q,
            max_ring,
            &mut best,
            |best, p| {
                let d = sq_dist(p, q);
                if d < *best {
                    *best = d;
                }
            },
            |best, reach2| *best <= reach2 || reach2 >= cap2,
        );
        found.then_some(best)
    }

    /// The `k` smallest squared distances from `q` (ascending, into `best`, which holds
    /// `k` slots initialised to infinity), searching rings up to `max_ring`; `false` when
    /// rings beyond could still hold a nearer point than the `k`-th found.
    fn k_nearest_sq(&self, q: [f64; 3], best: &mut [f64], max_ring: i64) -> bool {
        let k = best.len();
        self.walk_rings(
            q,
            max_ring,
            best,
            |best, p| {
                let d = sq_dist(p, q);
                if d < best[k - 1] {
                    // insertion into the ascending list
                    let mut i = k - 1;
                    while i > 0 && best[i - 1] > d {
                        best[i] = best[i - 1];
                        i -= 1;
                    }
                    best[i] = d;
                }
            },
            |best, reach2| best[k - 1] <= reach2,
        )
    }
}

/// Squared distance of a point (an `[x, y, z]` slice) and `q`.
#[inline]
fn sq_dist(p: &[f64], q: [f64; 3]) -> f64 {
    (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)
}

/// A fine grid (about one point spacing per cell) for the queries near the points and a
/// coarse one (`COARSE` times the side) for the far ones, which the fine grid would search
/// through many empty rings. Points farther than [`FAR_MARGIN`] robust extents outside the
/// points' 1-99 % box (a stray point kilometres away) are left out of both and searched in a
/// level of their own (`far`, built the same way): in the grids they would set a box so large
/// that the whole subject fell into one cell.
struct Nearest {
    fine: NnGrid,
    coarse: NnGrid,
    far: Option<Box<Nearest>>,
}

/// Fine rings searched before a query moves to the coarse grid.
const FINE_RINGS: i64 = 2;
/// Fine rings searched by a `k`-nearest query before it moves to the coarse grid.
const FINE_RINGS_K: i64 = 5;
/// Cell side of the coarse grid over the fine one.
const COARSE: f64 = 8.0;
/// Margin round the 1-99 % box, in units of its largest extent, beyond which points go to the
/// far level.
const FAR_MARGIN: f64 = 1.0;

impl Nearest {
    /// The levels for flat `(n, 3)` finite points, `n >= 1`.
    fn new(points: &[f64]) -> Nearest {
        let (lo, hi) = robust_box(points);
        let ext = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
        let margin = FAR_MARGIN * ext;
        let near = |p: &[f64]| (0..3).all(|a| p[a] >= lo[a] - margin && p[a] <= hi[a] + margin);
        let n_near = points.chunks_exact(3).filter(|p| near(p)).count();
        // every point in the grids when none is far, or when none is near (no progress)
        if n_near == points.len() / 3 || n_near == 0 {
            return Nearest {
                fine: NnGrid::new(points, ext, 1.0),
                coarse: NnGrid::new(points, ext, COARSE),
                far: None,
            };
        }
        let (mut inner, mut outer) = (Vec::with_capacity(3 * n_near), Vec::new());
        for p in points.chunks_exact(3) {
            if near(p) {
                inner.extend_from_slice(p);
            } else {
                outer.extend_from_slice(p);
            }
        }
        Nearest {
            fine: NnGrid::new(&inner, ext, 1.0),
            coarse: NnGrid::new(&inner, ext, COARSE),
            far: Some(Box::new(Nearest::new(&outer))),
        }
    }

    /// Exact smallest squared distance from `q` to a point, capped at `cap2`.
    fn nearest_sq(&self, q: [f64; 3], cap2: f64) -> f64 {
        let best = match self.fine.nearest_sq(q, cap2, FINE_RINGS) {
            Some(d) => d,
            // the coarse search has no ring limit, so it always answers
            None => self.coarse.nearest_sq(q, cap2, i64::MAX).unwrap_or(cap2),
        };
        // a far point counts only when nearer than the best so far
        match &self.far {
            Some(far) => far.nearest_sq(q, best),
            None => best,
        }
    }

    /// The `k` smallest squared distances from `q` merged into `best` (ascending, `k` slots,
    /// infinity where none yet); `scratch` is a buffer of the same length.
    fn k_nearest_sq(&self, q: [f64; 3], best: &mut [f64], scratch: &mut [f64]) {
        // the fine search scans a prefix of the rings; when it cannot answer, the coarse one
        // starts again from what `best` held (it would count the fine search's points twice)
        scratch.copy_from_slice(best);
        if !self.fine.k_nearest_sq(q, best, FINE_RINGS_K) {
            best.copy_from_slice(scratch);
            self.coarse.k_nearest_sq(q, best, i64::MAX);
        }
        if let Some(far) = &self.far {
            far.k_nearest_sq(q, best, scratch);
        }
    }
}

fn check(name: &str, pts: &[f64]) -> CoreResult<()> {
    if !pts.len().is_multiple_of(3) {
        return Err(CoreError::InvalidInput(format!(
            "{name} must have shape (n, 3)"
        )));
    }
    if let Some(i) = pts.iter().position(|v| !v.is_finite()) {
        return Err(CoreError::NonFinite(format!(
            "{name}: row {} is not finite",
            i / 3
        )));
    }
    Ok(())
}

/// For each query (flat `(n, 3)`), the distance to its nearest point of `points` (flat
/// `(N, 3)`), capped at `cap` (metres, positive and finite): `min(d, cap)`. With no points
/// every distance is `cap`. Each query is independent, so the result does not depend on the
/// thread count.
pub fn capped_nn_distances(queries: &[f64], points: &[f64], cap: f64) -> CoreResult<Vec<f64>> {
    check("queries", queries)?;
    check("points", points)?;
    if !(cap.is_finite() && cap > 0.0) {
        return Err(CoreError::InvalidInput(format!(
            "distance cap must be positive and finite, got {cap}"
        )));
    }
    let nq = queries.len() / 3;
    if points.is_empty() {
        return Ok(vec![cap; nq]);
    }
    let grid = Nearest::new(points);
    let cap2 = cap * cap;
    let mut out = vec![0.0f64; nq];
    out.par_chunks_mut(CHUNK)
        .zip(queries.par_chunks(3 * CHUNK))
        .for_each(|(o, qs)| {
            for (d, q) in o.iter_mut().zip(qs.chunks_exact(3)) {
                *d = grid.nearest_sq([q[0], q[1], q[2]], cap2).sqrt().min(cap);
            }
        });
    Ok(out)
}

/// [`capped_nn_distances`] of `G` groups in one call: group `g`'s queries, rows
/// `query_offsets[g]..query_offsets[g + 1]` of `queries` (flat `(n, 3)`), against its points,
/// rows `point_offsets[g]..point_offsets[g + 1]` of `points` (flat `(N, 3)`); the distances in
/// the queries' order. Both offset lists have `G + 1` entries, start at 0, do not decrease and
/// end at their array's row count. The groups run side by side, one thread each; every
/// distance is exact, so the result does not depend on the thread count.
pub fn capped_nn_distances_grouped(
    queries: &[f64],
    query_offsets: &[usize],
    points: &[f64],
    point_offsets: &[usize],
    cap: f64,
) -> CoreResult<Vec<f64>> {
    check("queries", queries)?;
    check("points", points)?;
    if !(cap.is_finite() && cap > 0.0) {
        return Err(CoreError::InvalidInput(format!(
            "distance cap must be positive and finite, got {cap}"
        )));
    }
    for (name, offs, rows) in [
        ("query_offsets", query_offsets, queries.len() / 3),
        ("point_offsets", point_offsets, points.len() / 3),
    ] {
        if offs.first() != Some(&0)
            || offs.last() != Some(&rows)
            || offs.windows(2).any(|w| w[1] < w[0])
        {
            return Err(CoreError::InvalidInput(format!(
                "{name}: must rise from 0 to the {rows} rows without decreasing"
            )));
        }
    }
    if query_offsets.len() != point_offsets.len() {
        return Err(CoreError::InvalidInput(format!(
            "{} query groups but {} point groups",
            query_offsets.len() - 1,
            point_offsets.len() - 1
        )));
    }
    let cap2 = cap * cap;
    let mut out = vec![cap; queries.len() / 3];
    let mut parts = Vec::with_capacity(query_offsets.len() - 1);
    let mut rest = out.as_mut_slice();
    for g in 0..query_offsets.len() - 1 {
        let (head, tail) = rest.split_at_mut(query_offsets[g + 1] - query_offsets[g]);
        parts.push((g, head));
        rest = tail;
    }
    parts.into_par_iter().for_each(|(g, o)| {
        let p = &points[3 * point_offsets[g]..3 * point_offsets[g + 1]];
        if o.is_empty() || p.is_empty() {
            return; // no queries, or every distance the cap
        }
        let grid = Nearest::new(p);
        let q = &queries[3 * query_offsets[g]..3 * query_offsets[g + 1]];
        for (d, q) in o.iter_mut().zip(q.chunks_exact(3)) {
            *d = grid.nearest_sq([q[0], q[1], q[2]], cap2).sqrt().min(cap);
        }
    });
    Ok(out)
}

/// For each query (flat `(n, 3)`), the distance to its `k`-th nearest point of `points`
/// (flat `(N, 3)`, `1 <= k <= N`; a query that is itself one of the points counts itself
/// as its first nearest, as a k-d tree's `query(points, k)` does). Exact; each query is
/// independent, so the result does not depend on the thread count.
pub fn kth_nn_distances(queries: &[f64], points: &[f64], k: usize) -> CoreResult<Vec<f64>> {
    check("queries", queries)?;
    check("points", points)?;
    let np = points.len() / 3;
    if k == 0 || k > np {
        return Err(CoreError::InvalidInput(format!(
            "neighbour rank k must be in 1..={np}, got {k}"
        )));
    }
    let grid = Nearest::new(points);
    let nq = queries.len() / 3;
    let mut out = vec![0.0f64; nq];
    out.par_chunks_mut(CHUNK)
        .zip(queries.par_chunks(3 * CHUNK))
        .for_each(|(o, qs)| {
            let mut best = vec![f64::INFINITY; k];
            let mut scratch = vec![f64::INFINITY; k];
            for (d, q) in o.iter_mut().zip(qs.chunks_exact(3)) {
                best.fill(f64::INFINITY);
                grid.k_nearest_sq([q[0], q[1], q[2]], &mut best, &mut scratch);
                *d = best[k - 1].sqrt();
            }
        });
    Ok(out)
}

/// The symmetric truncated chamfer misfit of a posed template (flat `(M, 3)`, `M >= 1`) and
/// a frame (flat `(N, 3)`, `N >= 1`), metres: the mean over template points of the capped
/// distance to the nearest frame point plus the mean over frame points of the capped
/// distance to the nearest template point, each distance capped at `trunc`. The means are
/// summed in point order, so the value does not depend on the thread count.
pub fn chamfer_misfit(template: &[f64], data: &[f64], trunc: f64) -> CoreResult<f64> {
    if template.len() < 3 || data.len() < 3 {
        return Err(CoreError::InvalidInput(
            "chamfer misfit needs at least one template and one data point".into(),
        ));
    }
    let d_td = capped_nn_distances(template, data, trunc)?;
    let d_dt = capped_nn_distances(data, template, trunc)?;
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    Ok(mean(&d_td) + mean(&d_dt))
}

/// Farthest-point sampling: indices of `n` of the points (flat `(m, 3)`), starting at
/// `first`, each next one the point farthest from those chosen (the first such index on a
/// tie). Squared distances are `(dx^2 + dy^2) + dz^2` in that order, the same arithmetic as
/// numpy's `np.sum((p - q) ** 2, axis=1)`, so the choice matches the numpy loop it replaces
/// bit for bit. `n >= m` returns every index in order.
pub fn farthest_point_sampling(points: &[f64], n: usize, first: usize) -> CoreResult<Vec<usize>> {
    check("points", points)?;
    let m = points.len() / 3;
    if n >= m {
        return Ok((0..m).collect());
    }
    if first >= m {
        return Err(CoreError::InvalidInput(format!(
            "first index {first} out of range for {m} points"
        )));
    }
    let sq = |i: usize, j: usize| -> f64 {
        let (a, b) = (&points[3 * i..3 * i + 3], &points[3 * j..3 * j + 3]);
        let (dx, dy, dz) = (a[0] - b[0], a[1] - b[1], a[2] - b[2]);
        (dx * dx + dy * dy) + dz * dz
    };
    let mut idx = Vec::with_capacity(n);
    idx.push(first);
    let mut d: Vec<f64> = (0..m).map(|i| sq(i, first)).collect();
    for _ in 1..n {
        let mut best = 0usize;
        for (i, &v) in d.iter().enumerate() {
            if v > d[best] {
                best = i;
            }
        }
        idx.push(best);
        for (i, v) in d.iter_mut().enumerate() {
            let e = sq(i, best);
            if e < *v {
                *v = e;
            }
        }
    }
    Ok(idx)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lcg(seed: &mut u64) -> f64 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*seed >> 11) as f64) / ((1u64 << 53) as f64)
    }

    /// `n` random points on a sphere shell of radius 0.5 (flat `(n, 3)`).
    fn sphere(seed: &mut u64, n: usize) -> Vec<f64> {
        let mut p = Vec::with_capacity(3 * n);
        for _ in 0..n {
            let (u, v) = (lcg(seed) * 2.0 - 1.0, lcg(seed) * std::f64::consts::TAU);
            let r = (1.0 - u * u).sqrt();
            p.extend_from_slice(&[0.5 * r * v.cos(), 0.5 * r * v.sin(), 0.5 * u]);
        }
        p
    }

    fn brute(q: &[f64], p: &[f64], cap: f64) -> Vec<f64> {
        q.chunks_exact(3)
            .map(|a| {
                p.chunks_exact(3)
                    .map(|b| {
                        ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2))
                            .sqrt()
                    })
                    .fold(cap, f64::min)
            })
            .collect()
    }

    #[test]
    fn matches_brute_force_on_a_surface_with_outliers() {
        let mut s = 7u64;
        // points on a sphere shell of radius 0.5, plus far outliers
        let mut p = sphere(&mut s, 1500);
        for _ in 0..20 {
            p.extend_from_slice(&[
                lcg(&mut s) * 20.0 - 10.0,
                lcg(&mut s) * 20.0 - 10.0,
                lcg(&mut s) * 20.0 - 10.0,
            ]);
        }
        let mut q = Vec::new();
        for _ in 0..800 {
            q.extend_from_slice(&[
                lcg(&mut s) * 3.0 - 1.5,
                lcg(&mut s) * 3.0 - 1.5,
                lcg(&mut s) * 3.0 - 1.5,
            ]);
        }
        q.extend_from_slice(&[100.0, -50.0, 3.0]);
        for cap in [0.01, 0.2, 5.0, 1e3] {
            let got = capped_nn_distances(&q, &p, cap).unwrap();
            let want = brute(&q, &p, cap);
            for (g, w) in got.iter().zip(&want) {
                assert!((g - w).abs() < 1e-12, "cap {cap}: {g} vs {w}");
            }
        }
    }

    #[test]
    fn grouped_distances_equal_one_call_per_group() {
        // three groups: an ordinary one, one with no points (every distance the cap) and one
        // with no queries, then another ordinary one; each equal to its own call bit for bit
        let mut s = 11u64;
        let p1 = sphere(&mut s, 700);
        let p3 = sphere(&mut s, 300);
        let q1 = sphere(&mut s, 250);
        let q2 = sphere(&mut s, 40);
        let q3 = sphere(&mut s, 90);
        let qs = [q1.clone(), q2.clone(), vec![], q3.clone()];
        let ps = [p1.clone(), vec![], p3.clone(), p3.clone()];
        let offs = |v: &[Vec<f64>]| {
            let mut o = vec![0usize];
            for x in v {
                o.push(o.last().unwrap() + x.len() / 3);
            }
            o
        };
        let got =
            capped_nn_distances_grouped(&qs.concat(), &offs(&qs), &ps.concat(), &offs(&ps), 0.3)
                .unwrap();
        let mut want = capped_nn_distances(&q1, &p1, 0.3).unwrap();
        want.extend(vec![0.3; q2.len() / 3]);
        want.extend(capped_nn_distances(&q3, &p3, 0.3).unwrap());
        assert_eq!(got, want);
        // offsets that do not end at the row count are an error, not a panic
        assert!(capped_nn_distances_grouped(&q1, &[0, 10], &p1, &[0, 700], 0.3).is_err());
        assert!(capped_nn_distances_grouped(&q1, &[0, 250], &p1, &[0, 700, 700], 0.3).is_err());
    }

    #[test]
    fn far_points_and_far_queries_are_exact() {
        // a subject with stray points kilometres and a thousand kilometres away along each
        // axis: they go to far levels, and the distances stay exact for queries near the
        // subject, between the strays and beyond them
        let mut s = 5u64;
        let mut p = sphere(&mut s, 2000);
        for (i, far) in [2e3, -5e3, 1e6, -3e6].iter().enumerate() {
            let mut v = [0.1, -0.2, 0.3];
            v[i % 3] += far;
            p.extend_from_slice(&v);
        }
        for _ in 0..60 {
            p.extend_from_slice(&[lcg(&mut s) * 40.0, 0.0, lcg(&mut s) * -40.0]);
        }
        let mut q = sphere(&mut s, 300);
        q.extend_from_slice(&[
            2e3 + 1.0,
            -0.2,
            0.3,
            0.0,
            1e7,
            0.0,
            -4e6,
            3.0,
            1.0,
            20.0,
            0.5,
            -20.0,
        ]);
        for cap in [0.05, 3.0, 1e8] {
            let got = capped_nn_distances(&q, &p, cap).unwrap();
            for (g, w) in got.iter().zip(brute(&q, &p, cap)) {
                assert!((g - w).abs() <= 1e-9 * w.max(1.0), "cap {cap}: {g} vs {w}");
            }
        }
        let np = p.len() / 3;
        for k in [1, 7, np - 2, np] {
            let got = kth_nn_distances(&q, &p, k).unwrap();
            for (i, g) in got.iter().enumerate() {
                let mut d: Vec<f64> = p
                    .chunks_exact(3)
                    .map(|b| sq_dist(b, [q[3 * i], q[3 * i + 1], q[3 * i + 2]]).sqrt())
                    .collect();
                d.sort_by(f64::total_cmp);
                let w = d[k - 1];
                assert!(
                    (g - w).abs() <= 1e-9 * w.max(1.0),
                    "k {k} query {i}: {g} vs {w}"
                );
            }
        }
    }

    #[test]
    fn chamfer_of_a_shifted_copy_is_twice_the_shift() {
        // a grid plane shifted along its normal by 1 cm: every nearest distance is 1 cm
        let mut a = Vec::new();
        for i in 0..30 {
            for j in 0..30 {
                a.extend_from_slice(&[i as f64 * 0.02, j as f64 * 0.02, 0.0]);
            }
        }
        let b: Vec<f64> = a.chunks_exact(3).flat_map(|p| [p[0], p[1], 0.01]).collect();
        let m = chamfer_misfit(&a, &b, 0.1).unwrap();
        assert!((m - 0.02).abs() < 1e-12, "{m}");
        // capped below the shift, each side contributes the cap
        let m = chamfer_misfit(&a, &b, 0.004).unwrap();
        assert!((m - 0.008).abs() < 1e-12, "{m}");
    }

    #[test]
    fn farthest_point_sampling_spreads_and_matches_a_naive_loop() {
        let mut s = 3u64;
        let p: Vec<f64> = (0..900).map(|_| lcg(&mut s)).collect();
        let idx = farthest_point_sampling(&p, 40, 5).unwrap();
        // the naive definition: each next point maximises the distance to the chosen set
        let d = |i: usize, j: usize| -> f64 {
            (0..3)
                .map(|a| (p[3 * i + a] - p[3 * j + a]).powi(2))
                .sum::<f64>()
        };
        assert_eq!(idx[0], 5);
        for k in 1..idx.len() {
            let to_set = |i: usize| idx[..k].iter().map(|&j| d(i, j)).fold(f64::MAX, f64::min);
            let best = (0..300).map(to_set).fold(0.0, f64::max);
            assert!((to_set(idx[k]) - best).abs() < 1e-12);
        }
        assert_eq!(
            farthest_point_sampling(&p, 500, 0).unwrap(),
            (0..300).collect::<Vec<_>>()
        );
        assert!(farthest_point_sampling(&p, 10, 300).is_err());
    }

    #[test]
    fn kth_distances_match_brute_force() {
        let mut s = 11u64;
        let mut p = sphere(&mut s, 1200);
        for _ in 0..30 {
            p.extend_from_slice(&[lcg(&mut s) * 6.0 - 3.0, lcg(&mut s) * 6.0, 0.0]);
        }
        for k in [1, 2, 11, 40] {
            let got = kth_nn_distances(&p, &p, k).unwrap();
            for (i, g) in got.iter().enumerate() {
                let mut d: Vec<f64> = p
                    .chunks_exact(3)
                    .map(|b| {
                        ((p[3 * i] - b[0]).powi(2)
                            + (p[3 * i + 1] - b[1]).powi(2)
                            + (p[3 * i + 2] - b[2]).powi(2))
                        .sqrt()
                    })
                    .collect();
                d.sort_by(f64::total_cmp);
                assert!(
                    (g - d[k - 1]).abs() < 1e-12,
                    "k {k} point {i}: {g} vs {}",
                    d[k - 1]
                );
            }
        }
        assert!(kth_nn_distances(&p[..6], &p[..6], 3).is_err());
        assert!(kth_nn_distances(&p[..6], &p[..6], 0).is_err());
    }

    #[test]
    fn bad_input_is_an_error_not_a_panic() {
        assert!(capped_nn_distances(&[0.0, 0.0], &[0.0; 3], 1.0).is_err());
        assert!(capped_nn_distances(&[0.0; 3], &[f64::NAN, 0.0, 0.0], 1.0).is_err());
        assert!(capped_nn_distances(&[0.0; 3], &[0.0; 3], 0.0).is_err());
        assert!(chamfer_misfit(&[], &[0.0; 3], 1.0).is_err());
        assert_eq!(
            capped_nn_distances(&[0.0; 6], &[], 0.5).unwrap(),
            vec![0.5, 0.5]
        );
    }
}
