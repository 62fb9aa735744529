//! Tiny simplex-constrained quadratic programs for the point weights of Eq. (22).
//!
//! Each point's weights solve
//!
//! ```text
//! minimise 0.5 w^T H w - g^T w   s.t.  w_j >= 0,  sum_j w_j = 1        (Eq. 21b)
//! ```
//!
//! over the k <= 8 bones selected for it (k = 4 in the paper). The problem is convex (H is a
//! Gram matrix, PSD); we add a relative ridge of `RIDGE` times the mean diagonal so that it is
//! strictly convex and every face's equality-constrained minimiser is unique. The global
//! minimiser lies in the relative interior of exactly one face of the simplex and equals that
//! face's affine-hull minimiser, so enumerating the `2^k - 1` faces, keeping the feasible
//! affine-hull minimisers and taking the one with the smallest objective is exact (no
//! iteration, no tolerance on convergence). See docs/joints.md.

use crate::core::error::{CoreError, CoreResult};

/// Largest number of bones per point the enumeration accepts (2^8 - 1 = 255 faces).
pub const MAX_K: usize = 8;
/// Relative ridge added to the diagonal (times the mean diagonal of H).
const RIDGE: f64 = 1e-12;
/// Feasibility slack on `w_j >= 0` before clamping (relative to 1).
const FEAS_TOL: f64 = 1e-10;

/// Solve the `n x n` system `a x = b` in place by Gaussian elimination with partial pivoting.
/// `a` is row-major with stride `MAX_K + 1`. Returns false when singular.
#[allow(clippy::needless_range_loop)]
fn solve_small(a: &mut [[f64; MAX_K + 1]; MAX_K + 1], b: &mut [f64; MAX_K + 1], n: usize) -> bool {
    for col in 0..n {
        let mut piv = col;
        let mut best = a[col][col].abs();
        for (row, a_row) in a.iter().enumerate().take(n).skip(col + 1) {
            if a_row[col].abs() > best {
                best = a_row[col].abs();
                piv = row;
            }
        }
        if best <= f64::MIN_POSITIVE || !best.is_finite() {
            return false;
        }
        if piv != col {
            a.swap(piv, col);
            b.swap(piv, col);
        }
        let d = a[col][col];
        for row in (col + 1)..n {
            let f = a[row][col] / d;
            if f != 0.0 {
                for c in col..n {
                    a[row][c] -= f * a[col][c];
                }
                b[row] -= f * b[col];
            }
        }
    }
    for row in (0..n).rev() {
        let mut s = b[row];
        for c in (row + 1)..n {
            s -= a[row][c] * b[c];
        }
        b[row] = s / a[row][row];
    }
    b.iter().take(n).all(|v| v.is_finite())
}

/// Exact minimiser of `0.5 w^T H w - g^T w` on the probability simplex (Eq. 22 / 21b).
///
/// `h` is the row-major `k x k` symmetric PSD matrix, `g` has length `k`, `1 <= k <= 8`.
/// Returns `w` with `w >= 0` and `sum w = 1` exactly (up to rounding).
pub fn simplex_qp(h: &[f64], g: &[f64], k: usize) -> CoreResult<Vec<f64>> {
    if k == 0 || k > MAX_K {
        return Err(CoreError::InvalidInput(format!(
            "simplex_qp: k must be in 1..={MAX_K}, got {k}"
        )));
    }
    if h.len() != k * k || g.len() != k {
        return Err(CoreError::InvalidInput(format!(
            "simplex_qp: expected H of length {} and g of length {k}, got {} and {}",
            k * k,
            h.len(),
            g.len()
        )));
    }
    if h.iter().chain(g.iter()).any(|v| !v.is_finite()) {
        return Err(CoreError::NonFinite("simplex_qp: H or g".into()));
    }
    let mut w = [0.0; MAX_K];
    simplex_qp_into(h, g, k, &mut w);
    Ok(w[..k].to_vec())
}

/// Allocation-free core of [`simplex_qp`]; inputs must be validated (finite, right sizes).
#[allow(clippy::needless_range_loop)]
pub(crate) fn simplex_qp_into(h: &[f64], g: &[f64], k: usize, out: &mut [f64; MAX_K]) {
    let mean_diag = (0..k).map(|i| h[i * k + i].abs()).sum::<f64>() / k as f64;
    let ridge = RIDGE * mean_diag.max(f64::MIN_POSITIVE);
    let hr = |i: usize, j: usize| h[i * k + j] + if i == j { ridge } else { 0.0 };
    let objective = |w: &[f64; MAX_K]| {
        let mut v = 0.0;
        for i in 0..k {
            if w[i] == 0.0 {
                continue;
            }
            let mut hw = 0.0;
            for j in 0..k {
                hw += hr(i, j) * w[j];
            }
            v += w[i] * (0.5 * hw - g[i]);
        }
        v
    };

    let mut best_val = f64::INFINITY;
    let mut best = [0.0; MAX_K];
    let mut supp = [0usize; MAX_K];
    for mask in 1u32..(1u32 << k) {
        let mut s = 0;
        for (j, slot) in (0..k).filter(|j| mask & (1 << j) != 0).zip(0..) {
            supp[slot] = j;
            s = slot + 1;
        }
        // KKT of the face: [H_SS 1; 1^T 0] [w_S; nu] = [g_S; 1]
        let mut a = [[0.0; MAX_K + 1]; MAX_K + 1];
        let mut rhs = [0.0; MAX_K + 1];
        for r in 0..s {
            for c in 0..s {
                a[r][c] = hr(supp[r], supp[c]);
            }
            a[r][s] = 1.0;
            a[s][r] = 1.0;
            rhs[r] = g[supp[r]];
        }
        rhs[s] = 1.0;
        if !solve_small(&mut a, &mut rhs, s + 1) {
            continue;
        }
        if rhs[..s].iter().any(|&v| v < -FEAS_TOL) {
            continue;
        }
        let mut w = [0.0; MAX_K];
        let mut tot = 0.0;
        for r in 0..s {
            let v = rhs[r].max(0.0);
            w[supp[r]] = v;
            tot += v;
        }
        if tot <= 0.0 {
            continue;
        }
        for v in w.iter_mut().take(k) {
            *v /= tot;
        }
        let val = objective(&w);
        if val < best_val {
            best_val = val;
            best = w;
        }
    }
    if !best_val.is_finite() {
        // Cannot happen for finite input (every vertex is feasible and solvable); fall back to
        // the best vertex to stay total.
        let mut bj = 0;
        let mut bv = f64::INFINITY;
        for j in 0..k {
            let v = 0.5 * hr(j, j) - g[j];
            if v < bv {
                bv = v;
                bj = j;
            }
        }
        best = [0.0; MAX_K];
        best[bj] = 1.0;
    }
    *out = best;
}

#[cfg(test)]
mod tests {
    use super::*;

    fn obj(h: &[f64], g: &[f64], w: &[f64]) -> f64 {
        let k = g.len();
        let mut v = 0.0;
        for i in 0..k {
            for j in 0..k {
                v += 0.5 * w[i] * h[i * k + j] * w[j];
            }
            v -= g[i] * w[i];
        }
        v
    }

    #[test]
    fn interior_solution_matches_closed_form() {
        // H = I, g = 0: the minimiser is the barycentre.
        let h = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        let w = simplex_qp(&h, &[0.0; 3], 3).unwrap();
        for v in w {
            assert!((v - 1.0 / 3.0).abs() < 1e-9);
        }
    }

    #[test]
    fn vertex_solution() {
        // strongly prefers bone 2
        let h = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        let w = simplex_qp(&h, &[0.0, 0.0, 10.0], 3).unwrap();
        assert!((w[2] - 1.0).abs() < 1e-12 && w[0] == 0.0 && w[1] == 0.0);
    }

    #[test]
    fn never_worse_than_random_feasible_points() {
        let mut state = 12345u64;
        let mut rnd = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 11) as f64) / ((1u64 << 53) as f64) - 0.5
        };
        for _ in 0..200 {
            let k = 4;
            let gm: Vec<f64> = (0..k * 6).map(|_| rnd()).collect();
            let mut h = vec![0.0; k * k];
            for i in 0..k {
                for j in 0..k {
                    h[i * k + j] = (0..6).map(|r| gm[i * 6 + r] * gm[j * 6 + r]).sum();
                }
            }
            let g: Vec<f64> = (0..k).map(|_| rnd()).collect();
            let w = simplex_qp(&h, &g, k).unwrap();
            assert!(w.iter().all(|&v| v >= 0.0));
            assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
            let best = obj(&h, &g, &w);
            for _ in 0..50 {
                let mut p: Vec<f64> = (0..k).map(|_| rnd() + 0.5).collect();
                let s: f64 = p.iter().sum();
                p.iter_mut().for_each(|v| *v /= s);
                assert!(best <= obj(&h, &g, &p) + 1e-12);
            }
        }
    }

    #[test]
    fn rejects_bad_sizes() {
        assert!(simplex_qp(&[1.0], &[0.0, 0.0], 2).is_err());
        assert!(simplex_qp(&[], &[], 0).is_err());
    }
}
