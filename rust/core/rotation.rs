//! Closed-form rotations: Lemma 1 of the paper (Myronenko and Song 2009), i.e. Kabsch /
//! orthogonal Procrustes with the determinant correction, and weighted absolute orientation
//! (Eq. 14).

use nalgebra::{Matrix3, Vector3};

/// The rotation `R` in SO(3) that maximises `tr(A^T R)` (Lemma 1).
///
/// With `A = U S V^T`, `R = U C V^T` and `C = diag(1, 1, det(U V^T))`, so `det(R) = +1`
/// always, also for rank-deficient or reflective `A`.
pub fn rotation_maximizing_trace(a: &Matrix3<f64>) -> Matrix3<f64> {
    let svd = a.svd(true, true);
    let (u, v_t) = match (svd.u, svd.v_t) {
        (Some(u), Some(v_t)) => (u, v_t),
        _ => return Matrix3::identity(),
    };
    let d = (u * v_t).determinant();
    let c = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, if d < 0.0 { -1.0 } else { 1.0 }));
    let r = u * c * v_t;
    if r.iter().all(|x| x.is_finite()) {
        r
    } else {
        Matrix3::identity()
    }
}

/// Weighted absolute orientation (Kabsch, Eq. 14): `R, t` minimising
/// `sum_i w_i |dst_i - (R src_i + t)|^2`.
///
/// `src`, `dst`: points in metres; `w`: non-negative weights (`None` means all 1).
/// Returns identity and the centroid difference when the total weight is zero.
pub fn kabsch(
    src: &[Vector3<f64>],
    dst: &[Vector3<f64>],
    w: Option<&[f64]>,
) -> (Matrix3<f64>, Vector3<f64>) {
    let n = src.len().min(dst.len());
    let mut ws = 0.0;
    let mut cs = Vector3::zeros();
    let mut cd = Vector3::zeros();
    for i in 0..n {
        let wi = w.map_or(1.0, |w| w[i]);
        ws += wi;
        cs += src[i] * wi;
        cd += dst[i] * wi;
    }
    if ws <= 0.0 {
        return (Matrix3::identity(), Vector3::zeros());
    }
    cs /= ws;
    cd /= ws;
    // A = sum w (dst - cd)(src - cs)^T ; maximise tr(A^T R)
    let mut a = Matrix3::zeros();
    for i in 0..n {
        let wi = w.map_or(1.0, |w| w[i]);
        a += (dst[i] - cd) * (src[i] - cs).transpose() * wi;
    }
    let r = rotation_maximizing_trace(&a);
    let t = cd - r * cs;
    (r, t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    #[test]
    fn recovers_known_rotation() {
        let r_true = Rotation3::from_euler_angles(0.3, -1.1, 2.0).into_inner();
        let t_true = Vector3::new(0.1, -0.2, 0.3);
        let src: Vec<Vector3<f64>> = (0..20)
            .map(|i| {
                let f = i as f64;
                Vector3::new((f * 0.7).sin(), (f * 1.3).cos(), f * 0.05)
            })
            .collect();
        let dst: Vec<Vector3<f64>> = src.iter().map(|p| r_true * p + t_true).collect();
        let (r, t) = kabsch(&src, &dst, None);
        assert!((r - r_true).norm() < 1e-10);
        assert!((t - t_true).norm() < 1e-10);
    }

    #[test]
    fn reflection_is_corrected() {
        let a = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0));
        let r = rotation_maximizing_trace(&a);
        assert!((r.determinant() - 1.0).abs() < 1e-12);
    }
}
