//! Step 3's tracker: one frame's fit of a rigid-bone skeleton to the raw points (the
//! `init = "track"` start of step 3, docs/joints.md).
//!
//! Every rest point moves rigidly with its bone (one-hot weights), bones meet at fixed rest
//! joints, and the frame's pose is fitted by EM: the truncated posteriors of Eq. 4 (optionally
//! weighed by normal agreement), the joint-constrained bone rotations of
//! [`crate::core::lbs::sweep_articulated`], then the root translation as the weighted mean
//! offset of the targets. `tau` starts at 4/3 of the mean squared nearest-point distance of
//! the starting pose (clipped to `[tau0, tau_max]`), is annealed by `anneal` towards `tau0`
//! for as many iterations as it takes to get there, then follows the form of Eq. 12.
//!
//! Layouts as in [`crate::core::lbs`]: rest points `q (M*3)`, `labels (M)`, rotations
//! `r (B*9)` row-major, translations `(B*3)`, `parent (B)` with -1 at the root, joints
//! `c (B*3)` (joint b = head of bone b), observed points `v (N*3)`, metres.

use crate::core::error::{CoreError, CoreResult};
use crate::core::gmm::Precision;
use crate::core::lbs::{self, Dims, SparseWeights};
use crate::core::nearest::capped_nn_distances;

/// The tracker's settings for one frame.
#[derive(Clone, Copy, Debug)]
pub struct TrackSettings {
    /// EM iterations.
    pub iterations: usize,
    /// Articulated sweeps (each followed by the root shift) per E-step, at least 1.
    pub sweeps: usize,
    /// Lower bound of the start and the annealing target of `tau`, m^2.
    pub tau0: f64,
    /// Upper bound of the start `tau`, m^2.
    pub tau_max: f64,
    /// Floor of the Eq. 12 `tau`, m^2.
    pub floor: f64,
    /// Annealing factor of `tau` per iteration, in (0, 1) (otherwise no annealing).
    pub anneal: f64,
    /// Outlier weight of Eq. 4.
    pub omega: f64,
    /// E-step truncation in units of `sqrt(tau)` (`None` = dense).
    pub cutoff: Option<f64>,
    /// Small-motion weight of the rotations.
    pub gamma: f64,
    /// Factor on the data weights `P1 / tau` (`M / N` for density normalisation, else 1).
    pub density: f64,
}

/// The frame's inputs other than the pose.
#[derive(Clone, Copy, Debug)]
pub struct TrackModel<'a> {
    /// `(M*3)` rest points.
    pub q: &'a [f64],
    /// `(M)` bone of each rest point.
    pub labels: &'a [usize],
    /// `(B)` parent bone, -1 at the root.
    pub parent: &'a [i64],
    /// `(B*3)` rest joints.
    pub joints: &'a [f64],
    /// `(M*3)` unit rest normals and `(N*3)` unit normals of the observed points, with the
    /// concentration `kappa > 0` of the normal agreement factor; `None` = positions only.
    pub normals: Option<(&'a [f64], &'a [f64], f64)>,
}

/// Translations `(B*3)` of every bone with the root's at zero, bones meeting at their joints:
/// `T_k = T_p + (R_p - R_k) c_k`.
fn chain_translations(r: &[f64], joints: &[f64], parent: &[i64], order: &[usize]) -> Vec<f64> {
    let mut t = vec![0.0; joints.len()];
    for &k in order {
        let p = parent[k];
        if p < 0 {
            continue;
        }
        let p = p as usize;
        for i in 0..3 {
            let mut acc = 0.0;
            for j in 0..3 {
                acc += (r[9 * p + 3 * i + j] - r[9 * k + 3 * i + j]) * joints[3 * k + j];
            }
            t[3 * k + i] = t[3 * p + i] + acc;
        }
    }
    t
}

/// The frame's translations `(B*3)` and skinned points `(M*3)` with the joints held: the
/// chain from a zero root translation, shifted by `shift`, or, with data weights `a (M)` and
/// targets `z (M*3)` of positive total weight, by `sum_m a_m (z_m - x0_m) / sum_m a_m`.
fn fixed_joint_pose(
    model: &TrackModel<'_>,
    sw: SparseWeights<'_>,
    r: &[f64],
    order: &[usize],
    shift: [f64; 3],
    data: Option<(&[f64], &[f64])>,
) -> CoreResult<(Vec<f64>, Vec<f64>)> {
    let (m, b) = (model.labels.len(), model.parent.len());
    let mut t = chain_translations(r, model.joints, model.parent, order);
    let mut x = lbs::skin(model.q, sw, r, &t, Dims { f: 1, m, b })?;
    let mut s = shift;
    if let Some((a, z)) = data {
        let total: f64 = a.iter().sum();
        if total > 0.0 {
            s = [0.0; 3];
            for (mm, &am) in a.iter().enumerate() {
                for i in 0..3 {
                    s[i] += am * (z[3 * mm + i] - x[3 * mm + i]);
                }
            }
            s.iter_mut().for_each(|v| *v /= total);
        }
    }
    for (i, v) in t.iter_mut().enumerate() {
        *v += s[i % 3];
    }
    for (i, v) in x.iter_mut().enumerate() {
        *v += s[i % 3];
    }
    Ok((t, x))
}

/// Fit one frame `v (N*3)` from the start rotations `r (B*9)` and root translation
/// `t_root`: returns the rotations `(B*9)`, translations `(B*3)` and skinned points `(M*3)`.
pub fn track_frame(
    model: &TrackModel<'_>,
    v: &[f64],
    r: &[f64],
    t_root: [f64; 3],
    s: &TrackSettings,
) -> CoreResult<(Vec<f64>, Vec<f64>, Vec<f64>)> {
    let (m, b) = (model.labels.len(), model.parent.len());
    if model.q.len() != 3 * m || model.joints.len() != 3 * b || r.len() != 9 * b {
        return Err(CoreError::InvalidInput(format!(
            "track_frame: {} rest values for {m} labels, {} joint values and {} rotation \
             values for {b} bones",
            model.q.len(),
            model.joints.len(),
            r.len()
        )));
    }
    if m == 0 || v.len() < 3 || !v.len().is_multiple_of(3) {
        return Err(CoreError::InvalidInput(
            "track_frame: needs rest points and at least one observed point".into(),
        ));
    }
    if model.labels.iter().any(|&l| l >= b) {
        return Err(CoreError::InvalidInput(
            "track_frame: a label is not a bone".into(),
        ));
    }
    if let Some((rn, vn, _)) = model.normals {
        if rn.len() != 3 * m || vn.len() != v.len() {
            return Err(CoreError::InvalidInput(
                "track_frame: normals must match the rest and the observed points".into(),
            ));
        }
    }
    let order = lbs::topological_order(model.parent, b)?;
    // the first root, whose translation the root shift moves (topological_order has one)
    let root = model.parent.iter().position(|&p| p < 0).unwrap_or(0);
    // one-hot skinning weights: every rest point moves with its bone
    let ones = vec![1.0; m];
    let sw = SparseWeights {
        idx: model.labels,
        w: &ones,
        k: 1,
    };
    let mut r = r.to_vec();
    let (mut t, mut x) = fixed_joint_pose(model, sw, &r, &order, t_root, None)?;
    let d = capped_nn_distances(&x, v, f64::MAX)?;
    let mean_d2 = d.iter().map(|v| v * v).sum::<f64>() / d.len() as f64;
    let mut tau = (4.0 / 3.0 * mean_d2).max(s.tau0).min(s.tau_max);
    let k_coarse = if tau > s.tau0 && s.anneal > 0.0 && s.anneal < 1.0 {
        ((tau / s.tau0).ln() / (1.0 / s.anneal).ln()).ceil() as usize
    } else {
        0
    };
    let offsets = [0usize, v.len() / 3];
    let dims = Dims { f: 1, m, b };
    let mut xn = vec![0.0; 3 * m];
    let plan = lbs::SweepPlan::new(model.parent, sw, dims)?;
    for it in 0..s.iterations {
        let normals = match model.normals {
            Some((rn, vn, kappa)) => {
                for (mm, &l) in model.labels.iter().enumerate() {
                    for i in 0..3 {
                        xn[3 * mm + i] =
                            (0..3).map(|j| r[9 * l + 3 * i + j] * rn[3 * mm + j]).sum();
                    }
                }
                Some((&xn[..], vn, kappa))
            }
            None => None,
        };
        let es = lbs::estep_frames(
            &x,
            v,
            &offsets,
            &[tau],
            s.omega,
            s.cutoff,
            Precision::Single,
            normals,
        )?;
        let a: Vec<f64> = es.p1.iter().map(|p| p / tau * s.density).collect();
        let total: f64 = a.iter().sum();
        if total.is_nan() || total <= 0.0 {
            break;
        }
        let mut z = vec![0.0; 3 * m];
        for mm in 0..m {
            for i in 0..3 {
                z[3 * mm + i] = if a[mm] > 0.0 {
                    es.px[3 * mm + i] / es.p1[mm].max(1e-300)
                } else {
                    x[3 * mm + i]
                };
            }
        }
        let r_pre = r.clone();
        for _ in 0..s.sweeps.max(1) {
            // the sweep's translations are not used: the joints hold, and the root moves below
            let root_t = [t[3 * root], t[3 * root + 1], t[3 * root + 2]];
            let mut t_sweep = t.clone();
            lbs::sweep_with_plan(
                &plan,
                model.q,
                sw,
                &mut r,
                &mut t_sweep,
                &a,
                &z,
                &r_pre,
                model.parent,
                model.joints,
                s.gamma,
                &[],
                dims,
            )?;
            (t, x) = fixed_joint_pose(model, sw, &r, &order, root_t, Some((&a, &z)))?;
        }
        // the form of Eq. 12 with this E-step's statistics at the new points
        let mut ss = es.sum_x2[0];
        for mm in 0..m {
            for i in 0..3 {
                let xv = x[3 * mm + i];
                ss += -2.0 * es.px[3 * mm + i] * xv + es.p1[mm] * xv * xv;
            }
        }
        let eq12 = (ss / (3.0 * es.n_p[0].max(1e-12))).max(s.floor);
        tau = if it < k_coarse {
            eq12.min((s.anneal * tau).max(s.tau0))
        } else {
            eq12
        };
    }
    Ok((r, t, x))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The observed frame is the rest points bent by 30 degrees at the joint of a two-bone
    /// chain: started from that pose, the fit stays there (the exact pose is a fixed point of
    /// the EM: every point lands on its own observation), and bad input is an error.
    #[test]
    fn the_exact_pose_is_a_fixed_point() {
        let n = 400;
        let mut q = Vec::new();
        let mut labels = Vec::new();
        for i in 0..n {
            // a 2 m x 0.24 m x 0.16 m slab of points, a bone each side of x = 1
            let s = (i as f64 + 0.5) / n as f64 * 2.0;
            let (y, z) = ((i % 7) as f64 * 0.04 - 0.12, (i % 5) as f64 * 0.04 - 0.08);
            q.extend_from_slice(&[s, y, z]);
            labels.push(usize::from(s >= 1.0));
        }
        let parent = [-1i64, 0];
        let joints = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0];
        let (c, sn) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
        let mut v = Vec::new();
        for mm in 0..n {
            let p = [q[3 * mm], q[3 * mm + 1], q[3 * mm + 2]];
            if labels[mm] == 0 {
                v.extend_from_slice(&p);
            } else {
                let d = [p[0] - 1.0, p[1], p[2]];
                v.extend_from_slice(&[1.0 + c * d[0] - sn * d[1], sn * d[0] + c * d[1], d[2]]);
            }
        }
        let eye = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        let bent = [c, -sn, 0.0, sn, c, 0.0, 0.0, 0.0, 1.0];
        let r0: Vec<f64> = eye.iter().chain(bent.iter()).copied().collect();
        let model = TrackModel {
            q: &q,
            labels: &labels,
            parent: &parent,
            joints: &joints,
            normals: None,
        };
        let s = TrackSettings {
            iterations: 10,
            sweeps: 1,
            tau0: 1e-4,
            tau_max: 0.05,
            floor: 1e-8,
            anneal: 0.5,
            omega: 0.01,
            cutoff: Some(3.5),
            gamma: 0.1,
            density: 1.0,
        };
        let (r, t, x) = track_frame(&model, &v, &r0, [0.0; 3], &s).unwrap();
        let worst = x
            .iter()
            .zip(&v)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        // float32 E-step distances: exact to well within a micrometre
        assert!(worst < 1e-6, "worst coordinate error {worst}");
        assert!(r.iter().zip(&r0).all(|(a, b)| (a - b).abs() < 1e-6));
        // the child meets the root at its joint: T_1 = (I - R_1) c_1
        assert!((t[3] - (1.0 - c)).abs() < 1e-6 && (t[4] + sn).abs() < 1e-6);
        assert!(track_frame(&model, &[], &r0, [0.0; 3], &s).is_err());
        let bad = [0usize, 2];
        let wrong = TrackModel {
            labels: &bad[..],
            q: &q[..6],
            ..model
        };
        assert!(track_frame(&wrong, &v, &r0, [0.0; 3], &s).is_err());
    }
}
