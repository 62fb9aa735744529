//! Linear blend skinning kernels for step 3, LBS-based joint learning (§6.4, Eqs. 13, 22-26).
//!
//! All M-step updates work on the *reduced* data term: with the E-step sufficient statistics
//! (P1, PX) of frame t, the GMM term (Eq. 18) plus the registration term (Eq. 19) equal, up to
//! a constant, `sum_m a_m^t / 2 |x_m^t - z_m^t|^2` with `a = P1/tau + zeta` and
//! `z = (PX/tau + zeta y) / a` (docs/joints.md). So every kernel takes per-point, per-frame
//! weights `a (F, M)` and targets `z (F, M, 3)`.
//!
//! Layouts (row-major, flat): rest points `q (M*3)`; sparse weights `idx, w (M*K)` (slot s of
//! point m holds bone `idx[m*K+s]` with weight `w[m*K+s]`, unused slots have weight 0);
//! rotations `r (F*B*9)`, translations `t (F*B*3)` (`x = R q + T`, T_frame_rest);
//! `a (F*M)`, `z (F*M*3)`; bone tree `parent (B)` with -1 at the root; joints `c (B*3)`
//! (joint b = head of bone b, rest pose).
//!
//! Kernels:
//! * [`skin`]: Eq. 13 for every frame.
//! * [`fit_weights`]: Eq. 22, pick the k bones with the smallest single-bone residual, then the
//!   exact simplex QP of `qp.rs`.
//! * [`sweep_paper`]: Eqs. 23-26, one bone at a time in every frame, with the registration
//!   (inside `a, z`), joint (alpha) and small-motion (gamma) terms.
//! * [`sweep_articulated`]: the joint-constrained variant (our deviation, docs/joints.md): the
//!   bone rotates about its head joint and carries its subtree along; [`sweep_with_plan`] is
//!   the same with its [`SweepPlan`] (order, subtrees, their points) built once by the caller.
//!
//! Every frame is independent given W and the joints, so the sweeps run in parallel over
//! frames (rayon); `fit_weights` runs in parallel over points.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use crate::core::error::{CoreError, CoreResult};
use crate::core::qp::{simplex_qp_into, MAX_K};
use crate::core::rotation::rotation_maximizing_trace;

/// E-step sufficient statistics of every frame (Eq. 4 in the form of §6.2), see [`estep_frames`].
#[derive(Debug, Clone, Default)]
pub struct FramesEStep {
    /// `(F*M)` `P1^t_m = sum_i p^t_mi`.
    pub p1: Vec<f64>,
    /// `(F*M*3)` `PX^t_m = sum_i p^t_mi v^t_i`, metres.
    pub px: Vec<f64>,
    /// `(F)` `N_p^t = sum_mi p^t_mi`.
    pub n_p: Vec<f64>,
    /// `(F)` `sum_i (sum_m p^t_mi) |v^t_i|^2`, m^2.
    pub sum_x2: Vec<f64>,
}

/// Truncated E-step of every frame at once: centroids `x (F*M*3)` (the deformed rest points
/// `x^t_m`), observed points `v` (all frames concatenated, frame t = rows
/// `offsets[t]..offsets[t+1]`), variances `tau (F)`. Frames run in parallel (rayon), each with
/// [`crate::core::gmm::estep`] (`cutoff` in units of `sqrt(tau^t)`, `None` = dense).
///
/// `normals = Some((xn, vn, kappa))` (unit normals of the centroids, `F*M*3`, and of the
/// observed points, like `v`) weighs each pair by normal agreement
/// ([`crate::core::gmm::estep_normals`]).
#[allow(clippy::too_many_arguments)]
pub fn estep_frames(
    x: &[f64],
    v: &[f64],
    offsets: &[usize],
    tau: &[f64],
    omega: f64,
    cutoff: Option<f64>,
    precision: crate::core::gmm::Precision,
    normals: Option<(&[f64], &[f64], f64)>,
) -> CoreResult<FramesEStep> {
    let f = tau.len();
    if f == 0 || offsets.len() != f + 1 || !x.len().is_multiple_of(3 * f) {
        return Err(CoreError::InvalidInput(format!(
            "estep_frames: {} variances, {} offsets, {} centroid values",
            f,
            offsets.len(),
            x.len()
        )));
    }
    let m = x.len() / (3 * f);
    if offsets.windows(2).any(|w| w[1] <= w[0]) || offsets[f] * 3 != v.len() || offsets[0] != 0 {
        return Err(CoreError::InvalidInput(
            "estep_frames: offsets must increase strictly from 0 to the number of points".into(),
        ));
    }
    if let Some((xn, vn, _)) = normals {
        if xn.len() != x.len() || vn.len() != v.len() {
            return Err(CoreError::InvalidInput(
                "estep_frames: normals must match the centroids and the observed points".into(),
            ));
        }
    }
    let per: Vec<CoreResult<crate::core::gmm::EStep>> = (0..f)
        .into_par_iter()
        .map(|t| {
            let (xs, vs) = (
                3 * m * t..3 * m * (t + 1),
                3 * offsets[t]..3 * offsets[t + 1],
            );
            match normals {
                Some((xn, vn, kappa)) => crate::core::gmm::estep_normals(
                    &x[xs.clone()],
                    &v[vs.clone()],
                    None,
                    crate::core::gmm::Normals {
                        y: &xn[xs],
                        x: &vn[vs],
                        kappa,
                    },
                    tau[t],
                    omega,
                    cutoff,
                    precision,
                ),
                None => crate::core::gmm::estep(&x[xs], &v[vs], tau[t], omega, cutoff, precision),
            }
        })
        .collect();
    let mut out = FramesEStep {
        p1: Vec::with_capacity(f * m),
        px: Vec::with_capacity(3 * f * m),
        n_p: Vec::with_capacity(f),
        sum_x2: Vec::with_capacity(f),
    };
    for r in per {
        let r = r?;
        out.p1.extend_from_slice(&r.p1);
        out.px.extend_from_slice(&r.px);
        out.n_p.push(r.stats.n_p);
        out.sum_x2.push(r.stats.sum_x2);
    }
    Ok(out)
}

/// One frame's `(S0, d0, S1, S2, d1)` of [`joint_normal_sums`].
type FrameSums = (f64, [f64; 3], Vec<f64>, Vec<f64>, Vec<f64>);

/// Per-frame sums of the articulated joint solve (docs/joints.md, deviation 1):
/// `S0 = sum_m a`, `d0 = sum_m a r`, `S1_e = sum_m a ws_me`, `S2_eg = sum_m a ws_me ws_mg`,
/// `d1_e = sum_m a ws_me r_m` for every frame, with `ws (M*E)` (subtree weight sums),
/// `a (F*M)`, `r (F*M*3)`. Returns flat `(S0 (F), d0 (F*3), S1 (F*E), S2 (F*E*E), d1 (F*E*3))`.
/// Parallel over frames; only the non-zero entries of each `ws` row are visited.
pub fn joint_normal_sums(ws: &[f64], e: usize, a: &[f64], r: &[f64]) -> CoreResult<[Vec<f64>; 5]> {
    if e == 0 || !ws.len().is_multiple_of(e) {
        return Err(CoreError::InvalidInput(
            "joint_normal_sums: ws must be (M, E), E > 0".into(),
        ));
    }
    let m = ws.len() / e;
    if m == 0 || !a.len().is_multiple_of(m) || r.len() != 3 * a.len() {
        return Err(CoreError::InvalidInput(format!(
            "joint_normal_sums: a has {} values, r {}, M = {m}",
            a.len(),
            r.len()
        )));
    }
    let f = a.len() / m;
    // sparse rows of ws (frame independent)
    let rows: Vec<Vec<(usize, f64)>> = ws
        .chunks_exact(e)
        .map(|row| {
            row.iter()
                .copied()
                .enumerate()
                .filter(|&(_, v)| v != 0.0)
                .collect()
        })
        .collect();
    let per: Vec<FrameSums> = (0..f)
        .into_par_iter()
        .map(|t| {
            let mut s0 = 0.0;
            let mut d0 = [0.0; 3];
            let mut s1 = vec![0.0; e];
            let mut s2 = vec![0.0; e * e];
            let mut d1 = vec![0.0; 3 * e];
            for (k, row) in rows.iter().enumerate() {
                let am = a[t * m + k];
                if am == 0.0 {
                    continue;
                }
                let rm = &r[3 * (t * m + k)..3 * (t * m + k) + 3];
                s0 += am;
                for i in 0..3 {
                    d0[i] += am * rm[i];
                }
                for &(ei, wi) in row {
                    let aw = am * wi;
                    s1[ei] += aw;
                    for i in 0..3 {
                        d1[3 * ei + i] += aw * rm[i];
                    }
                    for &(gi, wg) in row {
                        s2[ei * e + gi] += aw * wg;
                    }
                }
            }
            (s0, d0, s1, s2, d1)
        })
        .collect();
    let mut out: [Vec<f64>; 5] = Default::default();
    for (s0, d0, s1, s2, d1) in per {
        out[0].push(s0);
        out[1].extend_from_slice(&d0);
        out[2].extend_from_slice(&s1);
        out[3].extend_from_slice(&s2);
        out[4].extend_from_slice(&d1);
    }
    Ok(out)
}

/// Sparse LBS weights of the rest points.
#[derive(Clone, Copy)]
pub struct SparseWeights<'a> {
    /// `(M*K)` bone index per slot.
    pub idx: &'a [usize],
    /// `(M*K)` weight per slot (0 for unused slots).
    pub w: &'a [f64],
    /// Slots per point.
    pub k: usize,
}

/// Problem sizes.
#[derive(Clone, Copy, Debug)]
pub struct Dims {
    /// Frames.
    pub f: usize,
    /// Rest points.
    pub m: usize,
    /// Bones.
    pub b: usize,
}

#[inline]
fn v3(s: &[f64], i: usize) -> Vector3<f64> {
    Vector3::new(s[3 * i], s[3 * i + 1], s[3 * i + 2])
}

fn check_len(name: &str, got: usize, want: usize) -> CoreResult<()> {
    if got != want {
        return Err(CoreError::InvalidInput(format!(
            "{name}: expected {want} values, got {got}"
        )));
    }
    Ok(())
}

fn check_common(q: &[f64], r: &[f64], t: &[f64], d: Dims) -> CoreResult<()> {
    if d.b == 0 || d.m == 0 {
        return Err(CoreError::InvalidInput(
            "need at least one bone and one point".into(),
        ));
    }
    check_len("rest points", q.len(), d.m * 3)?;
    check_len("R", r.len(), d.f * d.b * 9)?;
    check_len("T", t.len(), d.f * d.b * 3)?;
    Ok(())
}

fn check_weights(sw: &SparseWeights<'_>, d: Dims) -> CoreResult<()> {
    if sw.k == 0 {
        return Err(CoreError::InvalidInput(
            "weights need at least one slot".into(),
        ));
    }
    check_len("weight indices", sw.idx.len(), d.m * sw.k)?;
    check_len("weights", sw.w.len(), d.m * sw.k)?;
    if let Some(&bad) = sw.idx.iter().find(|&&j| j >= d.b) {
        return Err(CoreError::InvalidInput(format!(
            "weight index {bad} out of range for {} bones",
            d.b
        )));
    }
    if sw.w.iter().any(|&v| v < 0.0) {
        return Err(CoreError::InvalidInput(
            "weights must be non-negative".into(),
        ));
    }
    Ok(())
}

fn check_data(a: &[f64], z: &[f64], d: Dims) -> CoreResult<()> {
    check_len("a (data weights)", a.len(), d.f * d.m)?;
    check_len("z (targets)", z.len(), d.f * d.m * 3)?;
    if a.iter().any(|&v| v < 0.0) {
        return Err(CoreError::InvalidInput(
            "data weights a must be non-negative".into(),
        ));
    }
    Ok(())
}

/// Validate the bone tree and return a topological order (parents before children).
pub fn topological_order(parent: &[i64], b: usize) -> CoreResult<Vec<usize>> {
    check_len("bone_parent", parent.len(), b)?;
    let mut children = vec![Vec::new(); b];
    let mut roots = Vec::new();
    for (j, &p) in parent.iter().enumerate() {
        if p < 0 {
            roots.push(j);
        } else if (p as usize) < b && p as usize != j {
            children[p as usize].push(j);
        } else {
            return Err(CoreError::InvalidInput(format!(
                "bone_parent[{j}] = {p} is invalid"
            )));
        }
    }
    let mut order = Vec::with_capacity(b);
    let mut stack = roots;
    while let Some(j) = stack.pop() {
        order.push(j);
        stack.extend(children[j].iter().rev().copied());
    }
    if order.len() != b {
        return Err(CoreError::InvalidInput(
            "bone_parent contains a cycle".into(),
        ));
    }
    Ok(order)
}

/// One frame's bone transforms as nalgebra values.
fn load_frame(r: &[f64], t: &[f64], b: usize) -> (Vec<Matrix3<f64>>, Vec<Vector3<f64>>) {
    let rs = (0..b)
        .map(|j| Matrix3::from_row_slice(&r[9 * j..9 * j + 9]))
        .collect();
    let ts = (0..b).map(|j| v3(t, j)).collect();
    (rs, ts)
}

fn store_frame(r: &mut [f64], t: &mut [f64], rs: &[Matrix3<f64>], ts: &[Vector3<f64>]) {
    for (j, (rj, tj)) in rs.iter().zip(ts).enumerate() {
        for a in 0..3 {
            for c in 0..3 {
                r[9 * j + 3 * a + c] = rj[(a, c)];
            }
            t[3 * j + a] = tj[a];
        }
    }
}

fn skin_frame(
    q: &[f64],
    sw: &SparseWeights<'_>,
    rs: &[Matrix3<f64>],
    ts: &[Vector3<f64>],
    out: &mut [f64],
) {
    let k = sw.k;
    for (m, o) in out.chunks_exact_mut(3).enumerate() {
        let qm = v3(q, m);
        let mut x = Vector3::zeros();
        for s in 0..k {
            let wv = sw.w[m * k + s];
            if wv != 0.0 {
                let j = sw.idx[m * k + s];
                x += (rs[j] * qm + ts[j]) * wv;
            }
        }
        o.copy_from_slice(x.as_slice());
    }
}

/// Linear blend skinning (Eq. 13) of the rest points into every frame: `(F*M*3)`, metres.
pub fn skin(
    q: &[f64],
    sw: SparseWeights<'_>,
    r: &[f64],
    t: &[f64],
    d: Dims,
) -> CoreResult<Vec<f64>> {
    check_common(q, r, t, d)?;
    check_weights(&sw, d)?;
    let mut out = vec![0.0; d.f * d.m * 3];
    out.par_chunks_mut(d.m * 3).enumerate().for_each(|(f, o)| {
        let (rs, ts) = load_frame(
            &r[f * d.b * 9..(f + 1) * d.b * 9],
            &t[f * d.b * 3..(f + 1) * d.b * 3],
            d.b,
        );
        skin_frame(q, &sw, &rs, &ts, o);
    });
    Ok(out)
}

/// Point weights by Eq. (22) on the reduced data term.
///
/// For point m, with `p_j^t = R_j^t q_m + T_j^t` and `d_j^t = p_j^t - z_m^t`, the objective
/// `sum_t a_m^t |sum_j w_j p_j^t - z_m^t|^2` equals `w^T H w` with
/// `H_ij = sum_t a_m^t d_i^t . d_j^t` on the simplex (because `sum_j w_j = 1`). The `k` bones
/// with the smallest single-bone residuals `H_jj` are selected among the allowed ones
/// (`allowed (M*B)`, all when `None`), then the k-variable simplex QP is solved exactly.
///
/// Returns `(idx (M*k), w (M*k), residual (M))` where `residual` is the optimal objective.
#[allow(clippy::too_many_arguments)]
pub fn fit_weights(
    q: &[f64],
    r: &[f64],
    t: &[f64],
    a: &[f64],
    z: &[f64],
    d: Dims,
    k: usize,
    allowed: Option<&[bool]>,
) -> CoreResult<(Vec<usize>, Vec<f64>, Vec<f64>)> {
    check_common(q, r, t, d)?;
    check_data(a, z, d)?;
    if k == 0 || k > MAX_K {
        return Err(CoreError::InvalidInput(format!(
            "bones per point must be in 1..={MAX_K}, got {k}"
        )));
    }
    if let Some(al) = allowed {
        check_len("allowed bones mask", al.len(), d.m * d.b)?;
    }
    let kk = k.min(d.b);
    let rs: Vec<Matrix3<f64>> = (0..d.f * d.b)
        .map(|i| Matrix3::from_row_slice(&r[9 * i..9 * i + 9]))
        .collect();
    let ts: Vec<Vector3<f64>> = (0..d.f * d.b).map(|i| v3(t, i)).collect();

    let per_point: Vec<(Vec<usize>, Vec<f64>, f64)> = (0..d.m)
        .into_par_iter()
        .map(|m| {
            let qm = v3(q, m);
            let mut resid = vec![0.0; d.b];
            for f in 0..d.f {
                let am = a[f * d.m + m];
                if am == 0.0 {
                    continue;
                }
                let zm = v3(z, f * d.m + m);
                for (j, rj) in resid.iter_mut().enumerate() {
                    let i = f * d.b + j;
                    *rj += am * (rs[i] * qm + ts[i] - zm).norm_squared();
                }
            }
            let mut cand: Vec<usize> = (0..d.b)
                .filter(|&j| allowed.is_none_or(|al| al[m * d.b + j]))
                .collect();
            if cand.is_empty() {
                cand = (0..d.b).collect();
            }
            cand.sort_by(|&x, &y| resid[x].total_cmp(&resid[y]).then(x.cmp(&y)));
            cand.truncate(kk);
            let n = cand.len();
            let mut h = vec![0.0; n * n];
            let mut dv = vec![Vector3::zeros(); n];
            for f in 0..d.f {
                let am = a[f * d.m + m];
                if am == 0.0 {
                    continue;
                }
                let zm = v3(z, f * d.m + m);
                for (s, &j) in cand.iter().enumerate() {
                    let i = f * d.b + j;
                    dv[s] = rs[i] * qm + ts[i] - zm;
                }
                for s in 0..n {
                    for u in s..n {
                        h[s * n + u] += am * dv[s].dot(&dv[u]);
                    }
                }
            }
            for s in 0..n {
                for u in 0..s {
                    h[s * n + u] = h[u * n + s];
                }
            }
            let g = vec![0.0; n];
            let mut wbuf = [0.0; MAX_K];
            let finite = h.iter().all(|v| v.is_finite());
            if finite {
                simplex_qp_into(&h, &g, n, &mut wbuf);
            } else {
                wbuf[0] = 1.0;
            }
            let mut obj = 0.0;
            for s in 0..n {
                for u in 0..n {
                    obj += wbuf[s] * h[s * n + u] * wbuf[u];
                }
            }
            (cand, wbuf[..n].to_vec(), obj)
        })
        .collect();

    let mut idx = vec![0usize; d.m * k];
    let mut w = vec![0.0; d.m * k];
    let mut res = vec![0.0; d.m];
    for (m, (cand, wv, obj)) in per_point.into_iter().enumerate() {
        for (s, (&j, &v)) in cand.iter().zip(&wv).enumerate() {
            idx[m * k + s] = j;
            w[m * k + s] = v;
        }
        // pad unused slots with the first bone and weight 0
        for s in cand.len()..k {
            idx[m * k + s] = cand[0];
        }
        res[m] = obj;
    }
    Ok((idx, w, res))
}

/// For each bone, the `(point, slot)` pairs with a positive weight on it.
fn bone_points(sw: &SparseWeights<'_>, d: Dims) -> Vec<Vec<(usize, usize)>> {
    let mut out = vec![Vec::new(); d.b];
    for m in 0..d.m {
        for s in 0..sw.k {
            if sw.w[m * sw.k + s] > 0.0 {
                out[sw.idx[m * sw.k + s]].push((m, s));
            }
        }
    }
    out
}

/// Weighted-moment accumulator for a rigid fit `d ~ R s + T` (Eqs. 24-25).
struct Moments {
    sw: f64,
    ss: Vector3<f64>,
    sd: Vector3<f64>,
    sds: Matrix3<f64>,
}

impl Moments {
    fn new() -> Self {
        Moments {
            sw: 0.0,
            ss: Vector3::zeros(),
            sd: Vector3::zeros(),
            sds: Matrix3::zeros(),
        }
    }
    /// Add a correspondence `src -> dst` with weight `om`, given `om * dst` directly.
    #[inline]
    fn add_scaled(&mut self, om: f64, src: &Vector3<f64>, om_dst: &Vector3<f64>) {
        self.sw += om;
        self.ss += src * om;
        self.sd += om_dst;
        self.sds += om_dst * src.transpose();
    }
    /// `mu_q = ss / sw`, `mu_u = sd / sw`, `Z = sum om (d - mu_u)(s - mu_q)^T`.
    fn centred(&self) -> (Vector3<f64>, Vector3<f64>, Matrix3<f64>) {
        let mu_q = self.ss / self.sw;
        let mu_u = self.sd / self.sw;
        let z = self.sds - self.sd * mu_q.transpose();
        (mu_q, mu_u, z)
    }
}

/// The paper's bone update (Eqs. 23-26), one bone at a time, in every frame (in place).
///
/// For bone `j` at frame `t`, with the other bones fixed (`u_mj = x_m - w_mj (R_j q_m + T_j)`),
/// minimises
/// `sum_m a_m/2 |z_m - u_mj - w_mj (R q_m + T)|^2`
/// `+ alpha/2 sum_{edges (j,k)} |R c_jk + T - (R_k c_jk + T_k)|^2`
/// `+ gamma/2 (|R - R_pre|_F^2 + |T - T_pre|^2)` in closed form: `T = mu_u - R mu_q` (Eq. 24),
/// `R` from the SVD of `Z = sum om (d - mu_u)(s - mu_q)^T + gamma R_pre` (Eqs. 25-26, Lemma 1).
/// Bones are visited in `order` (parents first); `r_pre, t_pre` are the transforms of the
/// previous iteration.
#[allow(clippy::too_many_arguments)]
pub fn sweep_paper(
    q: &[f64],
    sw: SparseWeights<'_>,
    r: &mut [f64],
    t: &mut [f64],
    a: &[f64],
    z: &[f64],
    r_pre: &[f64],
    t_pre: &[f64],
    parent: &[i64],
    joints: &[f64],
    alpha: f64,
    gamma: f64,
    d: Dims,
) -> CoreResult<()> {
    check_common(q, r, t, d)?;
    check_weights(&sw, d)?;
    check_data(a, z, d)?;
    check_len("R_pre", r_pre.len(), r.len())?;
    check_len("T_pre", t_pre.len(), t.len())?;
    check_len("joints", joints.len(), d.b * 3)?;
    if !(alpha >= 0.0 && gamma >= 0.0) {
        return Err(CoreError::InvalidInput(
            "alpha and gamma must be >= 0".into(),
        ));
    }
    let order = topological_order(parent, d.b)?;
    let bp = bone_points(&sw, d);
    let mut children = vec![Vec::new(); d.b];
    for (j, &p) in parent.iter().enumerate() {
        if p >= 0 {
            children[p as usize].push(j);
        }
    }
    let (b, m) = (d.b, d.m);
    r.par_chunks_mut(9 * b)
        .zip(t.par_chunks_mut(3 * b))
        .enumerate()
        .for_each(|(f, (rf, tf))| {
            let (mut rs, mut ts) = load_frame(rf, tf, b);
            let (rp, tp) = load_frame(
                &r_pre[f * 9 * b..(f + 1) * 9 * b],
                &t_pre[f * 3 * b..(f + 1) * 3 * b],
                b,
            );
            let mut x = vec![0.0; m * 3];
            skin_frame(q, &sw, &rs, &ts, &mut x);
            let af = &a[f * m..(f + 1) * m];
            let zf = &z[f * m * 3..(f + 1) * m * 3];
            for &j in &order {
                let mut mo = Moments::new();
                for &(pm, s) in &bp[j] {
                    let wj = sw.w[pm * sw.k + s];
                    let am = af[pm];
                    if am == 0.0 {
                        continue;
                    }
                    let qm = v3(q, pm);
                    let u = v3(&x, pm) - (rs[j] * qm + ts[j]) * wj;
                    // om = a w^2, om * dst = a w (z - u)
                    let om_dst = (v3(zf, pm) - u) * (am * wj);
                    mo.add_scaled(am * wj * wj, &qm, &om_dst);
                }
                if alpha > 0.0 {
                    let pj = parent[j];
                    if pj >= 0 {
                        let c = v3(joints, j);
                        let p = pj as usize;
                        let dst = rs[p] * c + ts[p];
                        mo.add_scaled(alpha, &c, &(dst * alpha));
                    }
                    for &k in &children[j] {
                        let c = v3(joints, k);
                        let dst = rs[k] * c + ts[k];
                        mo.add_scaled(alpha, &c, &(dst * alpha));
                    }
                }
                if gamma > 0.0 {
                    mo.add_scaled(gamma, &Vector3::zeros(), &(tp[j] * gamma));
                }
                if mo.sw <= 0.0 {
                    continue;
                }
                let (mu_q, mu_u, zmat) = mo.centred();
                let rn = rotation_maximizing_trace(&(zmat + rp[j] * gamma));
                let tn = mu_u - rn * mu_q;
                let (dr, dt) = (rn - rs[j], tn - ts[j]);
                for &(pm, s) in &bp[j] {
                    let wj = sw.w[pm * sw.k + s];
                    let dx = (dr * v3(q, pm) + dt) * wj;
                    for c in 0..3 {
                        x[3 * pm + c] += dx[c];
                    }
                }
                rs[j] = rn;
                ts[j] = tn;
            }
            store_frame(rf, tf, &rs, &ts);
        });
    Ok(())
}

/// Joint-constrained bone update (our deviation from Eq. 23, docs/joints.md), in place.
///
/// Bones are visited parents first. Bone `b` receives a rigid change `G` that also moves its
/// whole subtree: for the root, any rigid motion; for another bone, a rotation `dR` about its
/// head joint `h = R_b c_b + T_b`, so the joint shared with the parent stays where it is. With
/// `W_m = sum_{j in sub(b)} w_mj`, `P_m = sum_{j in sub(b)} w_mj (R_j q_m + T_j)` and
/// `u_m = x_m - P_m`, the moved point is `u_m + W_m G(P_m / W_m)`, so the data term is a
/// weighted Procrustes problem with weights `a W^2`, sources `P/W`, targets `(z - u)/W`, solved
/// exactly by Lemma 1 with `gamma sum_{j in sub(b)} R_pre_j R_j^T` added to the correlation
/// matrix (small-motion term on the rotations of every moved bone). The energy
/// `sum a/2 |x - z|^2 + gamma/2 sum |R - R_pre|^2` never increases.
///
/// `smooth` (empty = off, else one weight `lambda_j >= 0` per bone) adds the temporal term
/// `sum_j lambda_j/2 sum_t |R_j^(t-1) - 2 R_j^t + R_j^(t+1)|_F^2` (our deviation,
/// docs/joints.md): the rotations' second differences, so a bone turning at a
/// steady rate pays nothing. With `|R|_F^2 = 3` the term is linear in each frame's rotation:
/// in the interior, `lambda_j (4 (R^(t-1) + R^(t+1)) - R^(t-2) - R^(t+2)) R_j^T` enters the
/// correlation matrix of each moved bone. The frames `t mod 3 = 0, 1, 2` are updated in turn
/// (each pass in parallel, the other frames held), so each frame's update is an exact block
/// minimisation and the energy with this term still never increases.
#[allow(clippy::too_many_arguments)]
pub fn sweep_articulated(
    q: &[f64],
    sw: SparseWeights<'_>,
    r: &mut [f64],
    t: &mut [f64],
    a: &[f64],
    z: &[f64],
    r_pre: &[f64],
    parent: &[i64],
    joints: &[f64],
    gamma: f64,
    smooth: &[f64],
    d: Dims,
) -> CoreResult<()> {
    let plan = SweepPlan::new(parent, sw, d)?;
    sweep_with_plan(
        &plan, q, sw, r, t, a, z, r_pre, parent, joints, gamma, smooth, d,
    )
}

/// What [`sweep_articulated`] derives from the bone tree and the weights alone: the bones'
/// order, their subtrees and the points each subtree touches. A caller that sweeps many times
/// with the same tree and weights (the tracker) builds it once.
#[derive(Clone, Debug)]
pub struct SweepPlan {
    order: Vec<usize>,
    // in_sub[a * b + j]: bone j is in the subtree of bone a (a itself included)
    in_sub: Vec<bool>,
    subtree: Vec<Vec<usize>>,
    // the points (increasing) with a positive weight on a bone of each subtree
    sub_points: Vec<Vec<usize>>,
    m: usize,
}

impl SweepPlan {
    /// The plan of the tree `parent (B)` and the weights `sw` over `d.m` points.
    pub fn new(parent: &[i64], sw: SparseWeights<'_>, d: Dims) -> CoreResult<Self> {
        check_weights(&sw, d)?;
        let order = topological_order(parent, d.b)?;
        let (b, m, k) = (d.b, d.m, sw.k);
        let mut in_sub = vec![false; b * b];
        for j in 0..b {
            let mut cur = j as i64;
            while cur >= 0 {
                in_sub[cur as usize * b + j] = true;
                cur = parent[cur as usize];
            }
        }
        let subtree: Vec<Vec<usize>> = (0..b)
            .map(|a_| (0..b).filter(|&j| in_sub[a_ * b + j]).collect())
            .collect();
        // every ancestor of every bone a point is weighted on (points in increasing order)
        let mut sub_points: Vec<Vec<usize>> = vec![Vec::new(); b];
        for mm in 0..m {
            for s in 0..k {
                if sw.w[mm * k + s] <= 0.0 {
                    continue;
                }
                let mut cur = sw.idx[mm * k + s] as i64;
                while cur >= 0 {
                    let list = &mut sub_points[cur as usize];
                    if list.last() != Some(&mm) {
                        list.push(mm);
                    }
                    cur = parent[cur as usize];
                }
            }
        }
        Ok(SweepPlan {
            order,
            in_sub,
            subtree,
            sub_points,
            m,
        })
    }
}

/// [`sweep_articulated`] with its [`SweepPlan`] built by the caller from the same `parent`,
/// `sw` and `d`.
#[allow(clippy::too_many_arguments)]
pub fn sweep_with_plan(
    plan: &SweepPlan,
    q: &[f64],
    sw: SparseWeights<'_>,
    r: &mut [f64],
    t: &mut [f64],
    a: &[f64],
    z: &[f64],
    r_pre: &[f64],
    parent: &[i64],
    joints: &[f64],
    gamma: f64,
    smooth: &[f64],
    d: Dims,
) -> CoreResult<()> {
    check_common(q, r, t, d)?;
    check_weights(&sw, d)?;
    check_data(a, z, d)?;
    check_len("R_pre", r_pre.len(), r.len())?;
    check_len("joints", joints.len(), d.b * 3)?;
    check_len("bone_parent", parent.len(), d.b)?;
    if gamma.is_nan() || gamma < 0.0 {
        return Err(CoreError::InvalidInput("gamma must be >= 0".into()));
    }
    if !smooth.is_empty() {
        check_len("smooth", smooth.len(), d.b)?;
        if smooth.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
            return Err(CoreError::InvalidInput(
                "smooth weights must be finite and >= 0".into(),
            ));
        }
    }
    if plan.order.len() != d.b || plan.m != d.m {
        return Err(CoreError::InvalidInput(
            "sweep plan built for another tree or other points".into(),
        ));
    }
    let (b, m, k) = (d.b, d.m, sw.k);
    let (order, in_sub, subtree, sub_points) =
        (&plan.order, &plan.in_sub, &plan.subtree, &plan.sub_points);
    let frame_update = |f: usize, rf: &mut [f64], tf: &mut [f64], snap: &[f64]| {
        let (mut rs, mut ts) = load_frame(rf, tf, b);
        // the temporal term's coefficient of each bone's rotation in this frame: the second
        // differences centred at f - 1, f and f + 1 that exist, each linear in R_f (|R_f|^2 is
        // constant), give 2 (R_(f-1) + R_(f+1)), 2 R_(f-1) - R_(f-2) and 2 R_(f+1) - R_(f+2)
        let nb: Vec<Matrix3<f64>> = if smooth.is_empty() {
            Vec::new()
        } else {
            let fi = f as i64;
            let n = d.f as i64;
            let at = |g: i64, j: usize| {
                let o = (g as usize * b + j) * 9;
                Matrix3::from_row_slice(&snap[o..o + 9])
            };
            (0..b)
                .map(|j| {
                    let mut acc = Matrix3::zeros();
                    if fi >= 1 && fi + 1 < n {
                        acc += (at(fi - 1, j) + at(fi + 1, j)) * 2.0;
                    }
                    if fi >= 2 {
                        acc += at(fi - 1, j) * 2.0 - at(fi - 2, j);
                    }
                    if fi + 2 < n {
                        acc += at(fi + 1, j) * 2.0 - at(fi + 2, j);
                    }
                    acc
                })
                .collect()
        };
        let rp: Vec<Matrix3<f64>> = (0..b)
            .map(|j| Matrix3::from_row_slice(&r_pre[(f * b + j) * 9..(f * b + j) * 9 + 9]))
            .collect();
        let mut x = vec![0.0; m * 3];
        skin_frame(q, &sw, &rs, &ts, &mut x);
        let af = &a[f * m..(f + 1) * m];
        let zf = &z[f * m * 3..(f + 1) * m * 3];
        let mut pbuf: Vec<(f64, Vector3<f64>)> = Vec::with_capacity(m);
        for &bb in order.iter() {
            let is_root = parent[bb] < 0;
            let h = if is_root {
                Vector3::zeros()
            } else {
                rs[bb] * v3(joints, bb) + ts[bb]
            };
            pbuf.clear();
            let mut mo = Moments::new();
            for &pm in &sub_points[bb] {
                let qm = v3(q, pm);
                let mut wsub = 0.0;
                let mut pp = Vector3::zeros();
                for s in 0..k {
                    let wv = sw.w[pm * k + s];
                    let j = sw.idx[pm * k + s];
                    if wv > 0.0 && in_sub[bb * b + j] {
                        wsub += wv;
                        pp += (rs[j] * qm + ts[j]) * wv;
                    }
                }
                pbuf.push((wsub, pp));
                let am = af[pm];
                if am == 0.0 || wsub <= 0.0 {
                    continue;
                }
                let u = v3(&x, pm) - pp;
                // source p = P/W, target (z-u)/W, weight a W^2, all relative to h
                let src = pp / wsub - h;
                let om_dst = (v3(zf, pm) - u - h * wsub) * (am * wsub);
                mo.add_scaled(am * wsub * wsub, &src, &om_dst);
            }
            let mut small = Matrix3::zeros();
            if gamma > 0.0 {
                for &j in &subtree[bb] {
                    small += rp[j] * rs[j].transpose() * gamma;
                }
            }
            let mut prior = false;
            if !nb.is_empty() {
                for &j in &subtree[bb] {
                    if smooth[j] > 0.0 && nb[j] != Matrix3::zeros() {
                        small += nb[j] * rs[j].transpose() * smooth[j];
                        prior = true;
                    }
                }
            }
            // no data: only a non-root bone with the temporal term has anything to fit (an
            // occluded limb takes the rotation between its neighbouring frames)
            if mo.sw <= 0.0 && (is_root || !prior) {
                continue;
            }
            let (dr, dt) = if is_root {
                let (mu_q, mu_u, zmat) = mo.centred();
                let dr = rotation_maximizing_trace(&(zmat + small));
                (dr, mu_u - dr * mu_q)
            } else {
                // rotation about h: maximise tr(dR^T sum om (d)(s)^T)
                let dr = rotation_maximizing_trace(&(mo.sds + small));
                (dr, h - dr * h)
            };
            for &j in &subtree[bb] {
                rs[j] = dr * rs[j];
                ts[j] = dr * ts[j] + dt;
            }
            for (&pm, &(wsub, pp)) in sub_points[bb].iter().zip(&pbuf) {
                let u = v3(&x, pm) - pp;
                let xn = u + dr * pp + dt * wsub;
                for c in 0..3 {
                    x[3 * pm + c] = xn[c];
                }
            }
        }
        store_frame(rf, tf, &rs, &ts);
    };
    if smooth.is_empty() {
        r.par_chunks_mut(9 * b)
            .zip(t.par_chunks_mut(3 * b))
            .enumerate()
            .for_each(|(f, (rf, tf))| frame_update(f, rf, tf, &[]));
    } else {
        // frames t mod 3 = 0, 1, 2 in turn: a second difference couples frames at most two
        // apart, so the frames of one pass are independent given the held others
        for colour in 0..3 {
            let snap = r.to_vec();
            r.par_chunks_mut(9 * b)
                .zip(t.par_chunks_mut(3 * b))
                .enumerate()
                .filter(|(f, _)| f % 3 == colour)
                .for_each(|(f, (rf, tf))| frame_update(f, rf, tf, &snap));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    fn rot(ax: f64, ay: f64, az: f64) -> Matrix3<f64> {
        Rotation3::from_euler_angles(ax, ay, az).into_inner()
    }

    /// Two-bone chain along x, child rotated about joint (0.5, 0, 0).
    #[allow(clippy::type_complexity)]
    fn chain(f: usize) -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<usize>, Vec<f64>, Dims) {
        let m = 40;
        let mut q = Vec::new();
        for i in 0..m {
            let s = i as f64 / (m - 1) as f64;
            q.extend_from_slice(&[
                s,
                0.05 * ((i * 7) as f64).sin(),
                0.05 * ((i * 3) as f64).cos(),
            ]);
        }
        let c = Vector3::new(0.5, 0.0, 0.0);
        let mut r = Vec::new();
        let mut t = Vec::new();
        for fi in 0..f {
            let r0 = rot(0.1 * fi as f64, 0.0, 0.05);
            let t0 = Vector3::new(0.01 * fi as f64, 0.0, 0.0);
            let r1 = r0 * rot(0.0, 0.0, 0.3 + 0.2 * fi as f64);
            let t1 = r0 * c + t0 - r1 * c;
            for rr in [r0, r1] {
                for a in 0..3 {
                    for b in 0..3 {
                        r.push(rr[(a, b)]);
                    }
                }
            }
            t.extend_from_slice(t0.as_slice());
            t.extend_from_slice(t1.as_slice());
        }
        let mut idx = Vec::new();
        let mut w = Vec::new();
        for i in 0..m {
            let s = i as f64 / (m - 1) as f64;
            let w1 = ((s - 0.4) / 0.2).clamp(0.0, 1.0);
            idx.extend_from_slice(&[0, 1]);
            w.extend_from_slice(&[1.0 - w1, w1]);
        }
        (q, r, t, idx, w, Dims { f, m, b: 2 })
    }

    /// The chain's transforms with the child turned by `turn(frame)` (right-multiplied) and
    /// moved so that it still meets the parent at the joint (0.5, 0, 0).
    fn turn_child(
        r: &[f64],
        t: &[f64],
        d: Dims,
        turn: impl Fn(usize) -> Matrix3<f64>,
    ) -> (Vec<f64>, Vec<f64>) {
        let (mut r2, mut t2) = (r.to_vec(), t.to_vec());
        let c = Vector3::new(0.5, 0.0, 0.0);
        for fi in 0..d.f {
            let o = fi * 18 + 9;
            let rr = Matrix3::from_row_slice(&r2[o..o + 9]) * turn(fi);
            r2[o..o + 9].copy_from_slice(rr.transpose().as_slice()); // row-major
            let r0 = Matrix3::from_row_slice(&r2[fi * 18..fi * 18 + 9]);
            let tn = r0 * c + v3(&t2, fi * 2) - rr * c;
            t2[fi * 6 + 3..fi * 6 + 6].copy_from_slice(tn.as_slice());
        }
        (r2, t2)
    }

    fn data_energy(x: &[f64], a: &[f64], z: &[f64]) -> f64 {
        (0..a.len())
            .map(|i| a[i] * (v3(x, i) - v3(z, i)).norm_squared())
            .sum()
    }

    #[test]
    fn weights_recovered_exactly() {
        let (q, r, t, idx, w, d) = chain(5);
        let sw = SparseWeights {
            idx: &idx,
            w: &w,
            k: 2,
        };
        let x = skin(&q, sw, &r, &t, d).unwrap();
        let a = vec![1.0; d.f * d.m];
        let (idx2, w2, res) = fit_weights(&q, &r, &t, &a, &x, d, 2, None).unwrap();
        for mm in 0..d.m {
            for s in 0..2 {
                let j = idx2[mm * 2 + s];
                assert!((w2[mm * 2 + s] - w[mm * 2 + j]).abs() < 1e-6, "point {mm}");
            }
            assert!(res[mm] < 1e-12);
        }
    }

    #[test]
    fn sweeps_do_not_increase_energy_and_recover_truth() {
        let (q, r, t, idx, w, d) = chain(4);
        let sw = SparseWeights {
            idx: &idx,
            w: &w,
            k: 2,
        };
        let z = skin(&q, sw, &r, &t, d).unwrap();
        let a = vec![1.0; d.f * d.m];
        // perturb the child's rotation
        let (r2, t2) = turn_child(&r, &t, d, |_| rot(0.05, -0.04, 0.1));
        let joints = vec![0.0, 0.0, 0.0, 0.5, 0.0, 0.0];
        let parent = vec![-1i64, 0];
        let e0 = data_energy(&skin(&q, sw, &r2, &t2, d).unwrap(), &a, &z);
        let mut prev = e0;
        let (mut ra, mut ta) = (r2.clone(), t2.clone());
        for _ in 0..30 {
            let rp = ra.clone();
            sweep_articulated(
                &q,
                sw,
                &mut ra,
                &mut ta,
                &a,
                &z,
                &rp,
                &parent,
                &joints,
                0.0,
                &[],
                d,
            )
            .unwrap();
            let e = data_energy(&skin(&q, sw, &ra, &ta, d).unwrap(), &a, &z);
            assert!(e <= prev * (1.0 + 1e-12) + 1e-15);
            prev = e;
        }
        assert!(prev < 1e-3 * e0, "articulated energy {prev} from {e0}");
        let (mut rp_, mut tp_) = (r2.clone(), t2.clone());
        let mut prev = f64::INFINITY;
        for _ in 0..10 {
            let (rpre, tpre) = (rp_.clone(), tp_.clone());
            sweep_paper(
                &q, sw, &mut rp_, &mut tp_, &a, &z, &rpre, &tpre, &parent, &joints, 0.0, 0.0, d,
            )
            .unwrap();
            let e = data_energy(&skin(&q, sw, &rp_, &tp_, d).unwrap(), &a, &z);
            assert!(e <= prev * (1.0 + 1e-12) + 1e-15);
            prev = e;
        }
    }

    fn smooth_energy(r: &[f64], d: Dims, lam: &[f64]) -> f64 {
        let at = |fi: usize, j: usize| {
            let o = (fi * d.b + j) * 9;
            Matrix3::from_row_slice(&r[o..o + 9])
        };
        let mut e = 0.0;
        for fi in 1..d.f - 1 {
            for (j, l) in lam.iter().enumerate() {
                let dm = at(fi - 1, j) - at(fi, j) * 2.0 + at(fi + 1, j);
                e += l * dm.norm_squared();
            }
        }
        e
    }

    #[test]
    fn temporal_term_never_increases_energy_and_fills_a_frame_without_data() {
        let (q, r, t, idx, w, d) = chain(8);
        let sw = SparseWeights {
            idx: &idx,
            w: &w,
            k: 2,
        };
        let z = skin(&q, sw, &r, &t, d).unwrap();
        let mut a = vec![1.0; d.f * d.m];
        // frame 5 sees none of the child's points (an occluded limb)
        for mm in 0..d.m {
            if w[mm * 2 + 1] > 0.0 {
                a[5 * d.m + mm] = 0.0;
            }
        }
        // start from a child that spins by a different angle in every frame
        let (mut r2, mut t2) = turn_child(&r, &t, d, |fi| rot(0.3 * fi as f64, 0.2, -0.1));
        let c = Vector3::new(0.5, 0.0, 0.0);
        let joints = vec![0.0, 0.0, 0.0, 0.5, 0.0, 0.0];
        let parent = vec![-1i64, 0];
        let lam = vec![0.3, 0.05];
        let total = |r: &[f64], t: &[f64]| {
            0.5 * data_energy(&skin(&q, sw, r, t, d).unwrap(), &a, &z)
                + 0.5 * smooth_energy(r, d, &lam)
        };
        // one sweep with the temporal weights `l`, R_pre = the current rotations
        let sweep = |r: &mut Vec<f64>, t: &mut Vec<f64>, l: &[f64]| {
            let rp = r.clone();
            sweep_articulated(&q, sw, r, t, &a, &z, &rp, &parent, &joints, 0.0, l, d)
        };
        let mut prev = total(&r2, &t2);
        for _ in 0..20 {
            sweep(&mut r2, &mut t2, &lam).unwrap();
            let e = total(&r2, &t2);
            assert!(e <= prev * (1.0 + 1e-12) + 1e-15, "{e} > {prev}");
            prev = e;
        }
        // the child of frame 5 (no data; 5 mod 3 = 2, the last pass, so against its
        // neighbours' new rotations) is the rotation nearest 4 (R4 + R6) - R3 - R7
        sweep(&mut r2, &mut t2, &lam).unwrap();
        let child = |fi: usize| Matrix3::from_row_slice(&r2[fi * 18 + 9..fi * 18 + 18]);
        let sum = (child(4) + child(6)) * 4.0 - child(3) - child(7);
        let svd = sum.svd(true, true);
        let (u, vt) = (svd.u.unwrap(), svd.v_t.unwrap());
        let polar = u * vt;
        assert!(polar.determinant() > 0.0);
        assert!(
            (child(5) - polar).norm() < 1e-9,
            "{}",
            (child(5) - polar).norm()
        );
        // and still meets its parent at the joint
        let parent5 = Matrix3::from_row_slice(&r2[90..99]);
        let gap = parent5 * c + v3(&t2, 10) - (child(5) * c + v3(&t2, 11));
        assert!(gap.norm() < 1e-12);
        // the bad weights are refused
        assert!(sweep(&mut r2, &mut t2, &[0.1]).is_err());
        assert!(sweep(&mut r2, &mut t2, &[0.1, -1.0]).is_err());
    }

    #[test]
    fn rejects_cycles_and_bad_indices() {
        assert!(topological_order(&[1, 0], 2).is_err());
        assert!(topological_order(&[-1, 5], 2).is_err());
        let q = [0.0; 3];
        let sw = SparseWeights {
            idx: &[3],
            w: &[1.0],
            k: 1,
        };
        let d = Dims { f: 1, m: 1, b: 1 };
        assert!(skin(
            &q,
            sw,
            &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            &[0.0; 3],
            d
        )
        .is_err());
    }

    /// The plan's subtree point lists against the direct definition (a point is listed for
    /// bone `a` when a positive weight sits on a bone of `a`'s subtree), on a branched tree
    /// with two weights a point, some zero.
    #[test]
    fn sweep_plan_lists_the_points_of_every_subtree() {
        let parent = [-1i64, 0, 1, 0, 3, 3];
        let (b, m, k) = (6usize, 50usize, 2usize);
        let mut idx = Vec::new();
        let mut w = Vec::new();
        for mm in 0..m {
            idx.extend_from_slice(&[(mm * 7) % b, (mm * 3 + 1) % b]);
            w.extend_from_slice(&[if mm % 5 == 0 { 0.0 } else { 0.6 }, 0.4]);
        }
        let sw = SparseWeights {
            idx: &idx,
            w: &w,
            k,
        };
        let plan = SweepPlan::new(&parent, sw, Dims { f: 1, m, b }).unwrap();
        let ancestor = |a_: usize, j: usize| {
            let mut cur = j as i64;
            while cur >= 0 {
                if cur as usize == a_ {
                    return true;
                }
                cur = parent[cur as usize];
            }
            false
        };
        for a_ in 0..b {
            let direct: Vec<usize> = (0..m)
                .filter(|&mm| (0..k).any(|s| w[mm * k + s] > 0.0 && ancestor(a_, idx[mm * k + s])))
                .collect();
            assert_eq!(plan.sub_points[a_], direct, "bone {a_}");
        }
        // a plan for other points is refused, not misread
        let (q, mut r, mut t, idx2, w2, d) = chain(1);
        let sw2 = SparseWeights {
            idx: &idx2,
            w: &w2,
            k: 2,
        };
        let a = vec![1.0; d.m];
        let z = skin(&q, sw2, &r, &t, d).unwrap();
        let rp = r.clone();
        let other = SweepPlan::new(&[-1, 0], sw2, d).unwrap();
        let wrong = SweepPlan {
            m: d.m + 1,
            ..other.clone()
        };
        let call = |plan: &SweepPlan, r: &mut [f64], t: &mut [f64]| {
            sweep_with_plan(
                plan,
                &q,
                sw2,
                r,
                t,
                &a,
                &z,
                &rp,
                &[-1, 0],
                &[0.5, 0.0, 0.0, 0.5, 0.0, 0.0],
                0.0,
                &[],
                d,
            )
        };
        assert!(call(&wrong, &mut r, &mut t).is_err());
        assert!(call(&other, &mut r, &mut t).is_ok());
    }
}
