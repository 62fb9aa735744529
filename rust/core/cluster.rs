//! Motion-based clustering kernels (paper §5.2-5.3).
//!
//! * [`fit_clusters`]: per cluster and per frame, the weighted absolute orientation (Kabsch,
//!   Eq. 14) from the rest points of the cluster to the same points in frame `t`.
//! * [`cluster_residuals`]: for each point `m` and each candidate bone `k`, the residual summed
//!   over frames `sum_t |y_m^t - (R_k^t q_m + T_k^t)|^2` (step (ii) of §5.2).
//! * [`swap_residuals`]: the two halves of the bone-graph edge weight of Eq. 15 (residual of one
//!   cluster's points under the other cluster's transforms, averaged over the cluster).
//!
//! Layouts (all flat, row-major, metres): `rest` is `(M, 3)`, `points` is `(F, M, 3)`,
//! rotations are `(F, K, 3, 3)` and translations `(F, K, 3)`, i.e. the transform of bone `k` at
//! frame `t` is `x = R[t, k] q + T[t, k]` (`T_frame_rest`). Labels are `i64` in `[0, K)`;
//! a negative label means "unassigned" (the point is ignored by the fits).

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use crate::core::error::{check_size, CoreError, CoreResult};
use crate::core::rotation::rotation_maximizing_trace;

/// Per-frame rigid transforms of `K` clusters.
#[derive(Debug, Clone)]
pub struct ClusterFits {
    /// `(F, K, 3, 3)` rotations, row-major.
    pub r: Vec<f64>,
    /// `(F, K, 3)` translations, metres.
    pub t: Vec<f64>,
    /// `(K,)` number of points with a positive weight in each cluster.
    pub counts: Vec<usize>,
}

#[inline]
fn v3(s: &[f64], i: usize) -> Vector3<f64> {
    Vector3::new(s[3 * i], s[3 * i + 1], s[3 * i + 2])
}

#[inline]
fn m3(s: &[f64], i: usize) -> Matrix3<f64> {
    let o = 9 * i;
    Matrix3::new(
        s[o],
        s[o + 1],
        s[o + 2],
        s[o + 3],
        s[o + 4],
        s[o + 5],
        s[o + 6],
        s[o + 7],
        s[o + 8],
    )
}

/// Check `rest (M,3)` / `points (F,M,3)` and return `(M, F)`.
fn dims(rest: &[f64], points: &[f64]) -> CoreResult<(usize, usize)> {
    if rest.is_empty() || !rest.len().is_multiple_of(3) {
        return Err(CoreError::InvalidInput(
            "rest points must be a non-empty (M, 3) array".into(),
        ));
    }
    let m = rest.len() / 3;
    if points.is_empty() || !points.len().is_multiple_of(3 * m) {
        return Err(CoreError::InvalidInput(format!(
            "points must be (F, {m}, 3), got {} values",
            points.len()
        )));
    }
    Ok((m, points.len() / (3 * m)))
}

/// Check transforms `(F, K, 3, 3)` / `(F, K, 3)` and return `K`.
fn n_bones(r: &[f64], t: &[f64], f: usize) -> CoreResult<usize> {
    if !r.len().is_multiple_of(9 * f)
        || !t.len().is_multiple_of(3 * f)
        || r.len() / 9 != t.len() / 3
    {
        return Err(CoreError::InvalidInput(format!(
            "rotations must be (F={f}, K, 3, 3) and translations (F={f}, K, 3); got {} and {} values",
            r.len(),
            t.len()
        )));
    }
    Ok(r.len() / (9 * f))
}

/// Weighted absolute orientation (Eq. 14) of every cluster in every frame.
///
/// `labels (M,)` in `[0, k)` (negative = unassigned); `weights (M,)` optional non-negative point
/// weights (`None` = all 1). A cluster with zero total weight gets the identity transform.
/// Parallel over `(cluster, frame)` pairs.
pub fn fit_clusters(
    rest: &[f64],
    points: &[f64],
    labels: &[i64],
    k: usize,
    weights: Option<&[f64]>,
) -> CoreResult<ClusterFits> {
    let (m, f) = dims(rest, points)?;
    if labels.len() != m {
        return Err(CoreError::InvalidInput(format!(
            "labels must have one entry per rest point ({m}), got {}",
            labels.len()
        )));
    }
    if let Some(w) = weights {
        if w.len() != m {
            return Err(CoreError::InvalidInput(format!(
                "weights must have one entry per rest point ({m}), got {}",
                w.len()
            )));
        }
        if w.iter().any(|&x| x.is_nan() || x < 0.0 || !x.is_finite()) {
            return Err(CoreError::InvalidInput(
                "weights must be finite and non-negative".into(),
            ));
        }
    }
    if k > m {
        return Err(CoreError::InvalidInput(format!(
            "{k} clusters for {m} points: at most one cluster per point"
        )));
    }
    check_size(
        "cluster fits",
        f.checked_mul(k).and_then(|c| c.checked_mul(12)),
    )?;
    if let Some(&bad) = labels.iter().find(|&&l| l >= k as i64) {
        return Err(CoreError::InvalidInput(format!(
            "label {bad} out of range for {k} clusters"
        )));
    }
    // members and weighted rest centroids per cluster (frame independent)
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); k];
    for (i, &l) in labels.iter().enumerate() {
        let w = weights.map_or(1.0, |w| w[i]);
        if l >= 0 && w > 0.0 {
            members[l as usize].push(i);
        }
    }
    let wt = |i: usize| weights.map_or(1.0, |w| w[i]);
    let rest_stats: Vec<(f64, Vector3<f64>)> = members
        .iter()
        .map(|idx| {
            let mut ws = 0.0;
            let mut c = Vector3::zeros();
            for &i in idx {
                ws += wt(i);
                c += v3(rest, i) * wt(i);
            }
            (ws, if ws > 0.0 { c / ws } else { c })
        })
        .collect();
    // centred rest points (frame independent), then per frame one sequential pass over the
    // points accumulating, per cluster, sum w y and A = sum w y (q - cs)^T, which equals
    // sum w (y - cd)(q - cs)^T because sum w (q - cs) = 0. Parallel over frames.
    let centred: Vec<Vector3<f64>> = (0..m)
        .map(|i| match labels[i] {
            l if l >= 0 => v3(rest, i) - rest_stats[l as usize].1,
            _ => Vector3::zeros(),
        })
        .collect();
    let fits: Vec<(Matrix3<f64>, Vector3<f64>)> = (0..f)
        .into_par_iter()
        .flat_map_iter(|t| {
            let frame = &points[t * 3 * m..(t + 1) * 3 * m];
            let mut sy = vec![Vector3::<f64>::zeros(); k];
            let mut a = vec![Matrix3::<f64>::zeros(); k];
            for (i, &l) in labels.iter().enumerate() {
                let w = wt(i);
                if l < 0 || w <= 0.0 {
                    continue;
                }
                let wy = v3(frame, i) * w;
                sy[l as usize] += wy;
                a[l as usize] += wy * centred[i].transpose();
            }
            (0..k)
                .map(|c| {
                    let (ws, cs) = rest_stats[c];
                    if ws <= 0.0 {
                        return (Matrix3::identity(), Vector3::zeros());
                    }
                    let cd = sy[c] / ws;
                    let r = rotation_maximizing_trace(&a[c]);
                    (r, cd - r * cs)
                })
                .collect::<Vec<_>>()
        })
        .collect();
    let mut r = Vec::with_capacity(9 * f * k);
    let mut tr = Vec::with_capacity(3 * f * k);
    for (rot, tv) in &fits {
        for i in 0..3 {
            for j in 0..3 {
                r.push(rot[(i, j)]);
            }
        }
        tr.extend_from_slice(&[tv.x, tv.y, tv.z]);
    }
    Ok(ClusterFits {
        r,
        t: tr,
        counts: members.iter().map(Vec::len).collect(),
    })
}

/// Residuals summed over frames for candidate bones (step (ii) of §5.2).
///
/// `candidates (M, C)` holds bone indices in `[0, K)` per point, `-1` for "no candidate";
/// the result `(M, C)` is `sum_t |y_m^t - (R_k^t q_m + T_k^t)|^2` in m^2 (`+inf` where the
/// candidate is `-1`). Pass every bone as a candidate for the full `M x K` matrix.
/// Parallel over points.
pub fn cluster_residuals(
    rest: &[f64],
    points: &[f64],
    r: &[f64],
    t: &[f64],
    candidates: &[i64],
    c: usize,
) -> CoreResult<Vec<f64>> {
    let (m, f) = dims(rest, points)?;
    let k = n_bones(r, t, f)?;
    if c == 0 || candidates.len() != m * c {
        return Err(CoreError::InvalidInput(format!(
            "candidates must be (M={m}, C>0), got {} values for C={c}",
            candidates.len()
        )));
    }
    if let Some(&bad) = candidates.iter().find(|&&x| x >= k as i64) {
        return Err(CoreError::InvalidInput(format!(
            "candidate bone {bad} out of range for {k} bones"
        )));
    }
    // transforms unpacked once (F * K small matrices), then one pass per point
    let mats: Vec<(Matrix3<f64>, Vector3<f64>)> =
        (0..f * k).map(|idx| (m3(r, idx), v3(t, idx))).collect();
    let mut out = vec![0.0; m * c];
    out.par_chunks_mut(c).enumerate().for_each(|(i, row)| {
        let q = v3(rest, i);
        let cand = &candidates[i * c..(i + 1) * c];
        for (slot, &b) in row.iter_mut().zip(cand) {
            if b < 0 {
                *slot = f64::INFINITY;
            }
        }
        for tt in 0..f {
            let y = v3(points, tt * m + i);
            let fr = &mats[tt * k..(tt + 1) * k];
            for (slot, &b) in row.iter_mut().zip(cand) {
                if b >= 0 {
                    let (rot, tr) = &fr[b as usize];
                    *slot += (y - rot * q - tr).norm_squared();
                }
            }
        }
    });
    Ok(out)
}

/// The two directed halves of the Eq. 15 edge weight for each requested bone pair.
///
/// For pair `(i, j)` returns `(a, b)` with
/// `a = 1/|clu(i)| sum_t sum_{m in clu(i)} |y_m^t - (R_j^t q_m + T_j^t)|^2` and `b` the same
/// with `i` and `j` exchanged; `e_ij = a + b` (m^2). An empty cluster gives `+inf`.
/// Parallel over pairs.
pub fn swap_residuals(
    rest: &[f64],
    points: &[f64],
    labels: &[i64],
    r: &[f64],
    t: &[f64],
    pairs: &[i64],
) -> CoreResult<Vec<f64>> {
    let (m, f) = dims(rest, points)?;
    let k = n_bones(r, t, f)?;
    if labels.len() != m {
        return Err(CoreError::InvalidInput(format!(
            "labels must have one entry per rest point ({m}), got {}",
            labels.len()
        )));
    }
    if !pairs.len().is_multiple_of(2) || pairs.iter().any(|&p| p < 0 || p >= k as i64) {
        return Err(CoreError::InvalidInput(format!(
            "pairs must be (P, 2) bone indices in [0, {k})"
        )));
    }
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); k];
    for (i, &l) in labels.iter().enumerate() {
        if l >= 0 && (l as usize) < k {
            members[l as usize].push(i);
        }
    }
    let directed = |src: usize, bone: usize| -> f64 {
        let idx = &members[src];
        if idx.is_empty() {
            return f64::INFINITY;
        }
        let mut s = 0.0;
        for tt in 0..f {
            let rot = m3(r, tt * k + bone);
            let tr = v3(t, tt * k + bone);
            for &i in idx {
                s += (v3(points, tt * m + i) - rot * v3(rest, i) - tr).norm_squared();
            }
        }
        s / idx.len() as f64
    };
    let out: Vec<[f64; 2]> = pairs
        .par_chunks(2)
        .map(|p| {
            let (i, j) = (p[0] as usize, p[1] as usize);
            [directed(i, j), directed(j, i)]
        })
        .collect();
    Ok(out.into_iter().flatten().collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    type Motions = Vec<(Matrix3<f64>, Vector3<f64>)>;

    /// Two rigid clusters with known per-frame motions.
    fn two_parts(f: usize) -> (Vec<f64>, Vec<f64>, Vec<i64>, Motions) {
        let m = 40;
        let mut rest = Vec::new();
        let mut labels = Vec::new();
        for i in 0..m {
            let x = i as f64;
            rest.extend_from_slice(&[(x * 0.37).sin(), (x * 1.1).cos(), 0.05 * x]);
            labels.push(if i < m / 2 { 0 } else { 1 });
        }
        let mut truth = Vec::new();
        let mut pts = Vec::new();
        for tt in 0..f {
            let a = tt as f64 * 0.2;
            let motions = [
                (
                    Rotation3::from_euler_angles(a, 0.1, -a).into_inner(),
                    Vector3::new(a, 0.0, 1.0),
                ),
                (
                    Rotation3::from_euler_angles(-0.5 * a, a, 0.3).into_inner(),
                    Vector3::new(0.0, -a, 0.2),
                ),
            ];
            for i in 0..m {
                let (rr, tv) = motions[labels[i] as usize];
                let y = rr * v3(&rest, i) + tv;
                pts.extend_from_slice(&[y.x, y.y, y.z]);
            }
            truth.extend_from_slice(&motions);
        }
        (rest, pts, labels, truth)
    }

    #[test]
    fn fits_recover_known_motions() {
        let f = 5;
        let (rest, pts, labels, truth) = two_parts(f);
        let fits = fit_clusters(&rest, &pts, &labels, 2, None).unwrap();
        assert_eq!(fits.counts, vec![20, 20]);
        for tt in 0..f {
            for c in 0..2 {
                let (rr, tv) = truth[tt * 2 + c];
                assert!((m3(&fits.r, tt * 2 + c) - rr).norm() < 1e-9);
                assert!((v3(&fits.t, tt * 2 + c) - tv).norm() < 1e-9);
            }
        }
    }

    #[test]
    fn residuals_zero_on_own_bone_and_swap_matches_brute_force() {
        let f = 4;
        let (rest, pts, labels, _) = two_parts(f);
        let fits = fit_clusters(&rest, &pts, &labels, 2, None).unwrap();
        let m = labels.len();
        let cand: Vec<i64> = (0..m).flat_map(|_| [0i64, 1, -1]).collect();
        let res = cluster_residuals(&rest, &pts, &fits.r, &fits.t, &cand, 3).unwrap();
        let mut s = [[0.0; 2]; 2];
        for i in 0..m {
            let l = labels[i] as usize;
            assert!(res[i * 3 + l] < 1e-16);
            assert!(res[i * 3 + 2].is_infinite());
            for b in 0..2 {
                s[l][b] += res[i * 3 + b];
            }
        }
        let sw = swap_residuals(&rest, &pts, &labels, &fits.r, &fits.t, &[0, 1]).unwrap();
        assert!((sw[0] - s[0][1] / 20.0).abs() < 1e-9 * (1.0 + sw[0]));
        assert!((sw[1] - s[1][0] / 20.0).abs() < 1e-9 * (1.0 + sw[1]));
        assert!(sw[0] > 1e-3 && sw[1] > 1e-3);
    }

    #[test]
    fn empty_cluster_and_bad_input() {
        let (rest, pts, labels, _) = two_parts(2);
        let fits = fit_clusters(&rest, &pts, &labels, 3, None).unwrap();
        assert_eq!(fits.counts[2], 0);
        assert!((m3(&fits.r, 2) - Matrix3::identity()).norm() < 1e-15);
        assert!(fit_clusters(&rest, &pts, &labels, 1, None).is_err());
        assert!(fit_clusters(&rest, &pts[..10], &labels, 2, None).is_err());
        assert!(cluster_residuals(&rest, &pts, &fits.r, &fits.t, &[5], 1).is_err());
        assert!(swap_residuals(&rest, &pts, &labels, &fits.r, &fits.t, &[0, 7]).is_err());
    }

    #[test]
    fn weights_select_points() {
        let (rest, pts, labels, truth) = two_parts(3);
        // put every point in cluster 0 but give cluster-1 points zero weight
        let all0 = vec![0i64; labels.len()];
        let w: Vec<f64> = labels
            .iter()
            .map(|&l| if l == 0 { 1.0 } else { 0.0 })
            .collect();
        let fits = fit_clusters(&rest, &pts, &all0, 1, Some(&w)).unwrap();
        assert_eq!(fits.counts[0], 20);
        assert!((m3(&fits.r, 2) - truth[2 * 2].0).norm() < 1e-9);
    }
}
