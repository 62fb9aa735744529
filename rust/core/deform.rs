//! Embedded deformation graph (Sumner et al. 2007, Li et al. 2009) and the M-step of §4.3.
//!
//! Points follow Eq. 2, `y'_m = sum_j w_mj [R_j (y_m - n_j) + n_j + T_j]`. The M-step
//! minimises Eq. 8a, `E = E_GMM + beta_smooth/2 E_smooth + beta_small/2 E_small`, where the
//! E-step sufficient statistics give `E_GMM = sum_m P1_m |y'_m - PX_m/P1_m|^2 / (2 sigma^2)
//! + const`. Two solvers:
//!
//! * [`Graph::node_update`] / [`Graph::sweeps`]: the paper's closed form for one node with the
//!   others fixed (Eq. 9 translation, Eq. 11 rotation by Lemma 1), forward then backward;
//!   `mu_v`, `mu_y`, `H` are derived in `docs/registration.md`.
//! * [`Graph::gauss_newton_step`]: one Gauss-Newton step on all node transforms jointly
//!   (6 unknowns per node: a rotation increment `R_j <- exp([w_j]x) R_j` and `T_j += dT_j`),
//!   block-sparse normal equations solved by block-Jacobi preconditioned conjugate gradients.
//!
//! [`register_frame`] runs Algorithm 1 on one frame. Every loop that runs in parallel writes
//! disjoint outputs and reduces in a fixed order, so results do not depend on the number of
//! threads.

#![allow(clippy::needless_range_loop)]
// `!(x > 0.0)` deliberately also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::nonminimal_bool)]

use nalgebra::{Matrix3, Matrix6, Rotation3, Vector3, Vector6};
use rayon::prelude::*;

use crate::core::error::{CoreError, CoreResult};
use crate::core::gmm::{estep_normals, estep_weighted, Normals, Precision};
use crate::core::neighbors::voxel_downsample_with;
use crate::core::rotation::{kabsch, rotation_maximizing_trace};

/// Node transforms `{R_j, T_j}` (Eq. 2).
#[derive(Debug, Clone, PartialEq)]
pub struct NodeState {
    pub r: Vec<Matrix3<f64>>,
    pub t: Vec<Vector3<f64>>,
}

impl NodeState {
    /// All nodes at the identity.
    pub fn identity(j: usize) -> Self {
        NodeState {
            r: vec![Matrix3::identity(); j],
            t: vec![Vector3::zeros(); j],
        }
    }
}

/// E-step statistics the M-step needs (see `gmm::EStep`).
#[derive(Debug, Clone, Copy)]
pub struct DataTerm<'a> {
    /// `P1 (M,)`.
    pub p1: &'a [f64],
    /// `PX (M, 3)` flat.
    pub px: &'a [f64],
    /// `sum_i Pt1_i |x_i|^2`.
    pub sum_x2: f64,
    /// `N_p`.
    pub n_p: f64,
    /// `sigma^2` of the posteriors (m^2).
    pub sigma2: f64,
}

/// Weights of Eq. 8a.
#[derive(Debug, Clone, Copy)]
pub struct Weights {
    pub beta_smooth: f64,
    pub beta_small: f64,
}

/// The deformation graph: rest points, nodes, point-node weights and node-node edges.
#[derive(Debug, Clone)]
pub struct Graph {
    rest: Vec<Vector3<f64>>,
    nodes: Vec<Vector3<f64>>,
    k: usize,
    pn_idx: Vec<usize>,
    pn_w: Vec<f64>,
    edges: Vec<(usize, usize)>,
    node_points: Vec<Vec<(usize, f64)>>,
    edges_out: Vec<Vec<usize>>,
    edges_in: Vec<Vec<usize>>,
    /// Per node (block row), the sorted nodes it couples with (itself included).
    cols: Vec<Vec<usize>>,
    /// Rest-pose unit surface normals (M) or empty (see [`Graph::set_normals`]).
    normals: Vec<Vector3<f64>>,
}

fn v3(s: &[f64], i: usize) -> Vector3<f64> {
    Vector3::new(s[3 * i], s[3 * i + 1], s[3 * i + 2])
}

fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// `[[a, b], [c, d]]` from 3x3 blocks.
fn block6(a: &Matrix3<f64>, b: &Matrix3<f64>, c: &Matrix3<f64>, d: &Matrix3<f64>) -> Matrix6<f64> {
    let mut m = Matrix6::zeros();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(a);
    m.fixed_view_mut::<3, 3>(0, 3).copy_from(b);
    m.fixed_view_mut::<3, 3>(3, 0).copy_from(c);
    m.fixed_view_mut::<3, 3>(3, 3).copy_from(d);
    m
}

fn add_top(g: &mut Vector6<f64>, v: Vector3<f64>) {
    for a in 0..3 {
        g[a] += v[a];
    }
}

fn add_bottom(g: &mut Vector6<f64>, v: Vector3<f64>) {
    for a in 0..3 {
        g[a + 3] += v[a];
    }
}

impl Graph {
    /// Build the graph. `rest (M,3)`, `nodes (J,3)` flat; `pn_idx`, `pn_w` `(M, k)` flat:
    /// the nodes driving each point and their weights (normalised here to sum 1);
    /// `edges`: directed pairs `(j, k)`, `k in N(n_j)` (Eq. 6), flat `(E, 2)`.
    pub fn new(
        rest: &[f64],
        nodes: &[f64],
        pn_idx: &[i64],
        pn_w: &[f64],
        k: usize,
        edges: &[i64],
    ) -> CoreResult<Graph> {
        let m = rest.len() / 3;
        let j = nodes.len() / 3;
        if m == 0 || j == 0 || k == 0 {
            return Err(CoreError::InvalidInput(
                "graph needs points, nodes and k >= 1".into(),
            ));
        }
        if pn_idx.len() != m * k || pn_w.len() != m * k {
            return Err(CoreError::InvalidInput(format!(
                "point-node arrays must have shape ({m}, {k})"
            )));
        }
        if !edges.len().is_multiple_of(2) {
            return Err(CoreError::InvalidInput(
                "edges must have shape (E, 2)".into(),
            ));
        }
        let in_range = |v: i64| v >= 0 && (v as usize) < j;
        if !pn_idx.iter().all(|&v| in_range(v)) || !edges.iter().all(|&v| in_range(v)) {
            return Err(CoreError::InvalidInput("node index out of range".into()));
        }
        let mut w_norm = vec![0.0; m * k];
        for p in 0..m {
            let row = &pn_w[p * k..(p + 1) * k];
            let s: f64 = row.iter().sum();
            if !(s > 0.0) || row.iter().any(|&w| !(w >= 0.0)) {
                return Err(CoreError::InvalidInput(format!(
                    "point {p}: node weights must be non-negative with a positive sum"
                )));
            }
            for a in 0..k {
                w_norm[p * k + a] = row[a] / s;
            }
        }
        let pn_idx: Vec<usize> = pn_idx.iter().map(|&v| v as usize).collect();
        let edges: Vec<(usize, usize)> = edges
            .chunks_exact(2)
            .map(|e| (e[0] as usize, e[1] as usize))
            .filter(|e| e.0 != e.1)
            .collect();
        let mut node_points = vec![Vec::new(); j];
        let mut cols: Vec<Vec<usize>> = (0..j).map(|a| vec![a]).collect();
        for p in 0..m {
            for a in 0..k {
                let na = pn_idx[p * k + a];
                if w_norm[p * k + a] > 0.0 {
                    node_points[na].push((p, w_norm[p * k + a]));
                }
                for b in 0..k {
                    cols[na].push(pn_idx[p * k + b]);
                }
            }
        }
        let mut edges_out = vec![Vec::new(); j];
        let mut edges_in = vec![Vec::new(); j];
        for (e, &(a, b)) in edges.iter().enumerate() {
            edges_out[a].push(e);
            edges_in[b].push(e);
            cols[a].push(b);
            cols[b].push(a);
        }
        for c in &mut cols {
            c.sort_unstable();
            c.dedup();
        }
        Ok(Graph {
            rest: (0..m).map(|i| v3(rest, i)).collect(),
            nodes: (0..j).map(|i| v3(nodes, i)).collect(),
            k,
            pn_idx,
            pn_w: w_norm,
            edges,
            node_points,
            edges_out,
            edges_in,
            cols,
            normals: Vec::new(),
        })
    }

    /// Attach rest-pose surface normals `(M, 3)` flat (unit length, or zero where unknown);
    /// they ride with the nodes' rotations ([`Graph::deform_normals`]) and let
    /// [`register_frame`] weight its posteriors by normal agreement.
    pub fn set_normals(&mut self, normals: &[f64]) -> CoreResult<()> {
        let m = self.rest.len();
        if normals.len() != 3 * m {
            return Err(CoreError::InvalidInput(format!(
                "normals must have shape ({m}, 3), got {} values",
                normals.len()
            )));
        }
        if !normals.iter().all(|v| v.is_finite()) {
            return Err(CoreError::NonFinite("normals".into()));
        }
        self.normals = (0..m).map(|i| v3(normals, i)).collect();
        Ok(())
    }

    /// Whether rest normals are attached.
    pub fn has_normals(&self) -> bool {
        !self.normals.is_empty()
    }

    /// Deformed unit normals `normalise(sum_j w_pj R_j n_p)` (zero where the rest normal is
    /// zero); empty without rest normals.
    pub fn deform_normals(&self, st: &NodeState) -> Vec<Vector3<f64>> {
        if self.normals.is_empty() {
            return Vec::new();
        }
        let mut v = self.blend(|p, j| st.r[j] * self.normals[p]);
        for n in &mut v {
            let l = n.norm();
            *n = if l > 0.0 { *n / l } else { Vector3::zeros() };
        }
        v
    }

    pub fn n_points(&self) -> usize {
        self.rest.len()
    }
    pub fn n_nodes(&self) -> usize {
        self.nodes.len()
    }
    pub fn n_edges(&self) -> usize {
        self.edges.len()
    }

    /// Check that `st` has one transform per node.
    pub fn check_state(&self, st: &NodeState) -> CoreResult<()> {
        if st.r.len() != self.nodes.len() || st.t.len() != self.nodes.len() {
            return Err(CoreError::InvalidInput(format!(
                "expected {} node transforms",
                self.nodes.len()
            )));
        }
        Ok(())
    }

    /// Deformed points `y'` (Eq. 2).
    pub fn deform(&self, st: &NodeState) -> Vec<Vector3<f64>> {
        self.blend(|p, j| st.r[j] * (self.rest[p] - self.nodes[j]) + self.nodes[j] + st.t[j])
    }

    /// Per point `p`, `sum_a w_pa f(p, j_a)` over the nodes driving it (parallel over points).
    fn blend<F>(&self, f: F) -> Vec<Vector3<f64>>
    where
        F: Fn(usize, usize) -> Vector3<f64> + Sync,
    {
        (0..self.rest.len())
            .into_par_iter()
            .map(|p| {
                let mut y = Vector3::zeros();
                for a in 0..self.k {
                    y += self.pn_w[p * self.k + a] * f(p, self.pn_idx[p * self.k + a]);
                }
                y
            })
            .collect()
    }

    /// `E_smooth` of Eq. 6 (edge weights 1).
    pub fn e_smooth(&self, st: &NodeState) -> f64 {
        (0..self.edges.len())
            .map(|e| self.edge_residual(st, e).norm_squared())
            .sum()
    }

    /// Residual of edge `e` (Eq. 6), `R_j (n_k - n_j) + n_j + T_j - (n_k + T_k)`.
    fn edge_residual(&self, st: &NodeState, e: usize) -> Vector3<f64> {
        let (j, k) = self.edges[e];
        let n = &self.nodes;
        st.r[j] * (n[k] - n[j]) + n[j] + st.t[j] - n[k] - st.t[k]
    }

    /// `E_small` of Eq. 7.
    pub fn e_small(st: &NodeState, pre: &NodeState) -> f64 {
        st.r.iter()
            .zip(&pre.r)
            .map(|(a, b)| (a - b).norm_squared())
            .sum::<f64>()
            + st.t
                .iter()
                .zip(&pre.t)
                .map(|(a, b)| (a - b).norm_squared())
                .sum::<f64>()
    }

    /// `sum_mi p_mi |x_i - y'_m|^2` from the sufficient statistics.
    pub fn data_sq(y: &[Vector3<f64>], d: &DataTerm) -> f64 {
        let mut s = d.sum_x2;
        for (m, ym) in y.iter().enumerate() {
            s += d.p1[m] * ym.norm_squared() - 2.0 * ym.dot(&v3(d.px, m));
        }
        s.max(0.0)
    }

    /// Eq. 8a at the node transforms `st` (posteriors and sigma^2 from `d`; `E_small`
    /// relative to `pre`).
    pub fn energy(&self, st: &NodeState, pre: &NodeState, d: &DataTerm, w: &Weights) -> f64 {
        let y = self.deform(st);
        Self::data_sq(&y, d) / (2.0 * d.sigma2)
            + 1.5 * d.n_p * d.sigma2.ln()
            + 0.5 * w.beta_smooth * self.e_smooth(st)
            + 0.5 * w.beta_small * Self::e_small(st, pre)
    }

    /// The paper's closed-form update of node `j` with all other nodes fixed (Eqs. 9, 11).
    ///
    /// `y` must be the deformed points of `st` (updated in place). `pre` holds
    /// `{R^pre, T^pre}` of Eq. 7.
    pub fn node_update(
        &self,
        st: &mut NodeState,
        pre: &NodeState,
        y: &mut [Vector3<f64>],
        j: usize,
        d: &DataTerm,
        w: &Weights,
    ) {
        let nj = self.nodes[j];
        let (r_old, t_old) = (st.r[j], st.t[j]);
        // Terms c |R p + T - g|^2 (data, smooth as source) and c' |T - f|^2 (smooth as
        // target, small motion); see docs/registration.md.
        let mut cp: Vec<(f64, Vector3<f64>, Vector3<f64>)> = Vec::new();
        let mut cf: Vec<(f64, Vector3<f64>)> = Vec::new();
        for &(m, wm) in &self.node_points[j] {
            let p1 = d.p1[m];
            if p1 <= 0.0 {
                continue;
            }
            let q = self.rest[m] - nj;
            let u = v3(d.px, m) / p1;
            let other = y[m] - wm * (r_old * q + t_old);
            cp.push((p1 * wm * wm / (2.0 * d.sigma2), q, (u - other) / wm));
        }
        let half_b = 0.5 * w.beta_smooth;
        if half_b > 0.0 {
            for &e in &self.edges_out[j] {
                let k = self.edges[e].1;
                let nk = self.nodes[k];
                cp.push((half_b, nk - nj, nk + st.t[k] - nj));
            }
            for &e in &self.edges_in[j] {
                let k = self.edges[e].0;
                let nk = self.nodes[k];
                cf.push((half_b, st.r[k] * (nj - nk) + nk + st.t[k] - nj));
            }
        }
        if w.beta_small > 0.0 {
            cf.push((0.5 * w.beta_small, pre.t[j]));
        }
        let wsum: f64 = cp.iter().map(|c| c.0).sum::<f64>() + cf.iter().map(|c| c.0).sum::<f64>();
        if !(wsum > 0.0) {
            return;
        }
        let mu_y = cp.iter().fold(Vector3::zeros(), |a, c| a + c.0 * c.1) / wsum;
        let mu_v = (cp.iter().fold(Vector3::zeros(), |a, c| a + c.0 * c.2)
            + cf.iter().fold(Vector3::zeros(), |a, c| a + c.0 * c.1))
            / wsum;
        let mut h = Matrix3::zeros();
        for (c, p, g) in &cp {
            h += 2.0 * c * (p - mu_y) * (g - mu_v).transpose();
        }
        let fsum = cf
            .iter()
            .fold(Vector3::zeros(), |a, c| a + c.0 * (mu_v - c.1));
        h += 2.0 * mu_y * fsum.transpose();
        h += w.beta_small * pre.r[j].transpose();
        // E = z - tr(H R): maximise tr((H^T)^T R), Lemma 1 with A = H^T (Eq. 11).
        let r_new = rotation_maximizing_trace(&h.transpose());
        let t_new = mu_v - r_new * mu_y;
        st.r[j] = r_new;
        st.t[j] = t_new;
        for &(m, wm) in &self.node_points[j] {
            let q = self.rest[m] - nj;
            y[m] += wm * ((r_new - r_old) * q + (t_new - t_old));
        }
    }

    /// One forward then one backward sweep of [`Graph::node_update`] (§4.3, Fig. 2c-d).
    pub fn sweeps(&self, st: &mut NodeState, pre: &NodeState, d: &DataTerm, w: &Weights) {
        let mut y = self.deform(st);
        for j in 0..self.nodes.len() {
            self.node_update(st, pre, &mut y, j, d, w);
        }
        for j in (0..self.nodes.len()).rev() {
            self.node_update(st, pre, &mut y, j, d, w);
        }
    }

    /// One Gauss-Newton step on all node transforms jointly (Eq. 8a with `pre = st`).
    ///
    /// `damping` adds `damping * diag(H_jj)` (Levenberg). Returns the number of CG
    /// iterations used.
    pub fn gauss_newton_step(
        &self,
        st: &mut NodeState,
        d: &DataTerm,
        w: &Weights,
        damping: f64,
        cg_tol: f64,
        cg_max: usize,
    ) -> usize {
        let y = self.deform(st);
        let jn = self.nodes.len();
        let kk = self.k;
        let inv_s2 = 1.0 / d.sigma2;
        let beta = w.beta_smooth;
        let id = Matrix3::identity();
        let zero = Matrix3::zeros();
        // Block rows, assembled independently (deterministic, parallel).
        let rows: Vec<(Vec<Matrix6<f64>>, Vector6<f64>)> = (0..jn)
            .into_par_iter()
            .map(|j| {
                let cols = &self.cols[j];
                let pos = |k: usize| cols.binary_search(&k).unwrap_or(0);
                let mut blocks = vec![Matrix6::zeros(); cols.len()];
                let mut g = Vector6::zeros();
                let nj = self.nodes[j];
                for &(m, wa) in &self.node_points[j] {
                    let p1 = d.p1[m];
                    if p1 <= 0.0 {
                        continue;
                    }
                    let a = p1 * inv_s2;
                    let r = y[m] - v3(d.px, m) / p1;
                    let pa = st.r[j] * (self.rest[m] - nj);
                    let sa = -skew(&pa);
                    add_top(&mut g, a * wa * pa.cross(&r));
                    add_bottom(&mut g, a * wa * r);
                    for b in 0..kk {
                        let kb = self.pn_idx[m * kk + b];
                        let wb = self.pn_w[m * kk + b];
                        if wb <= 0.0 {
                            continue;
                        }
                        let pb = st.r[kb] * (self.rest[m] - self.nodes[kb]);
                        let sb = -skew(&pb);
                        let blk = block6(&(sa.transpose() * sb), &sa.transpose(), &sb, &id);
                        blocks[pos(kb)] += (a * wa * wb) * blk;
                    }
                }
                if beta > 0.0 {
                    for &e in &self.edges_out[j] {
                        let k = self.edges[e].1;
                        let b = st.r[j] * (self.nodes[k] - nj);
                        let r = b + nj + st.t[j] - self.nodes[k] - st.t[k];
                        let s = -skew(&b);
                        add_top(&mut g, beta * b.cross(&r));
                        add_bottom(&mut g, beta * r);
                        blocks[pos(j)] +=
                            beta * block6(&(s.transpose() * s), &s.transpose(), &s, &id);
                        blocks[pos(k)] += beta * block6(&zero, &(-s.transpose()), &zero, &(-id));
                    }
                    for &e in &self.edges_in[j] {
                        let k = self.edges[e].0;
                        let nk = self.nodes[k];
                        let b = st.r[k] * (nj - nk);
                        let r = b + nk + st.t[k] - nj - st.t[j];
                        let s = -skew(&b);
                        add_bottom(&mut g, -beta * r);
                        blocks[pos(j)] += beta * block6(&zero, &zero, &zero, &id);
                        blocks[pos(k)] += beta * block6(&zero, &zero, &(-s), &(-id));
                    }
                }
                let dj = pos(j);
                for a in 0..3 {
                    blocks[dj][(a, a)] += 2.0 * w.beta_small;
                    blocks[dj][(a + 3, a + 3)] += w.beta_small;
                }
                let diag = blocks[dj].diagonal();
                let scale = diag.max().max(1e-300);
                for a in 0..6 {
                    blocks[dj][(a, a)] += damping * diag[a] + 1e-12 * scale;
                }
                (blocks, g)
            })
            .collect();
        // Block-Jacobi preconditioner.
        let precond: Vec<Matrix6<f64>> = rows
            .iter()
            .enumerate()
            .map(|(j, (blocks, _))| {
                let dj = self.cols[j].binary_search(&j).unwrap_or(0);
                blocks[dj]
                    .cholesky()
                    .map(|c| c.inverse())
                    .unwrap_or_else(|| {
                        Matrix6::from_diagonal(&blocks[dj].diagonal().map(|v| {
                            if v > 0.0 {
                                1.0 / v
                            } else {
                                0.0
                            }
                        }))
                    })
            })
            .collect();
        let matvec = |x: &[Vector6<f64>]| -> Vec<Vector6<f64>> {
            (0..jn)
                .into_par_iter()
                .map(|j| {
                    let mut s = Vector6::zeros();
                    for (c, &k) in self.cols[j].iter().enumerate() {
                        s += rows[j].0[c] * x[k];
                    }
                    s
                })
                .collect()
        };
        let dot = |a: &[Vector6<f64>], b: &[Vector6<f64>]| -> f64 {
            a.iter().zip(b).map(|(u, v)| u.dot(v)).sum()
        };
        let bvec: Vec<Vector6<f64>> = rows.iter().map(|(_, g)| -g).collect();
        let mut x = vec![Vector6::zeros(); jn];
        let mut r = bvec.clone();
        let bnorm = dot(&bvec, &bvec).sqrt();
        let mut iters = 0;
        if bnorm > 0.0 && bnorm.is_finite() {
            let mut z: Vec<Vector6<f64>> = r.iter().zip(&precond).map(|(v, p)| p * v).collect();
            let mut p = z.clone();
            let mut rz = dot(&r, &z);
            while iters < cg_max {
                iters += 1;
                let ap = matvec(&p);
                let pap = dot(&p, &ap);
                if !(pap > 0.0) {
                    break;
                }
                let alpha = rz / pap;
                for jj in 0..jn {
                    x[jj] += alpha * p[jj];
                    r[jj] -= alpha * ap[jj];
                }
                if dot(&r, &r).sqrt() <= cg_tol * bnorm {
                    break;
                }
                z = r.iter().zip(&precond).map(|(v, p)| p * v).collect();
                let rz_new = dot(&r, &z);
                let bet = rz_new / rz;
                rz = rz_new;
                for jj in 0..jn {
                    p[jj] = z[jj] + bet * p[jj];
                }
            }
        }
        for j in 0..jn {
            let dx = x[j];
            if dx.iter().all(|v| v.is_finite()) {
                let om = Vector3::new(dx[0], dx[1], dx[2]);
                st.r[j] = Rotation3::new(om).into_inner() * st.r[j];
                st.t[j] += Vector3::new(dx[3], dx[4], dx[5]);
            }
        }
        iters
    }

    /// Rigid (global) alignment of `y'` to the E-step targets by weighted Kabsch, applied to
    /// every node: `R_j <- R R_j`, `T_j <- R (n_j + T_j) + t - n_j`.
    pub fn rigid_step(&self, st: &mut NodeState, d: &DataTerm) {
        let y = self.deform(st);
        let mut src = Vec::new();
        let mut dst = Vec::new();
        let mut wts = Vec::new();
        for (m, ym) in y.iter().enumerate() {
            if d.p1[m] > 1e-12 {
                src.push(*ym);
                dst.push(v3(d.px, m) / d.p1[m]);
                wts.push(d.p1[m]);
            }
        }
        if src.len() < 3 {
            return;
        }
        let (r, t) = kabsch(&src, &dst, Some(&wts));
        for j in 0..self.nodes.len() {
            st.r[j] = r * st.r[j];
            st.t[j] = r * (self.nodes[j] + st.t[j]) + t - self.nodes[j];
        }
    }
}

/// M-step solver (Eq. 8a).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Solver {
    /// One joint Gauss-Newton step on all nodes per EM iteration (default).
    GaussNewton,
    /// The paper's node-by-node closed form, forward then backward sweep (§4.3).
    Sweeps,
}

/// Parameters of [`register_frame`] that stay the same for every frame of a sequence (see
/// `RegistrationConfig` for meanings and defaults). The E-step runs in single precision with
/// double-precision sums ([`Precision::Single`]).
#[derive(Debug, Clone, Copy)]
pub struct FrameParams {
    /// Outlier weight of Eq. 1.
    pub omega: f64,
    /// `beta_smooth` (absolute), or the ratio `lambda` when `beta_relative`.
    pub beta_smooth: f64,
    /// Use `beta_smooth_eff = lambda * N_p / (sigma^2 * n_edges)` each iteration.
    pub beta_relative: bool,
    pub beta_small: f64,
    /// Floor of Eq. 12, m^2.
    pub sigma2_min: f64,
    /// Coarse-to-fine schedule: during the first `k` iterations, with
    /// `k = ceil(log(sigma2_start / anneal_floor) / log(1 / anneal))`, sigma^2 is capped at
    /// `max(anneal * sigma^2, anneal_floor)` (Eq. 12 when lower); afterwards plain Eq. 12.
    /// `anneal = 1` disables it.
    pub anneal: f64,
    pub anneal_floor: f64,
    pub max_iter: usize,
    /// Relative change of Eq. 8a that stops the EM.
    pub tol: f64,
    /// Truncated E-step: pairs beyond `cutoff * sigma` ignored; `None` = dense.
    pub cutoff: Option<f64>,
    pub solver: Solver,
    /// Levenberg damping, CG tolerance and iteration cap of [`Graph::gauss_newton_step`].
    pub damping: f64,
    pub cg_tol: f64,
    pub cg_max: usize,
    /// Coarse-data E-step: while the voxel grid of side `subsample * sigma` holds fewer than
    /// half as many cells as data points, the E-step runs on the voxel centroids weighted by
    /// their point counts ([`voxel_downsample_with`], [`estep_weighted`]); 0 = always full
    /// data.
    pub subsample: f64,
    /// Early stop (after the coarse phase): the RMS displacement of the deformed template in
    /// one iteration falls below `motion_tol * sigma`; 0 = off.
    pub motion_tol: f64,
    /// Normal agreement (pointrig deviation): with `kappa > 0`, rest normals on the graph and
    /// data normals given, each posterior carries the von Mises-Fisher factor
    /// `exp(kappa (n_i . n~_m - 1))` ([`estep_normals`]); 0 = positions only (paper).
    pub kappa: f64,
}

/// Precision of [`register_frame`]'s E-step.
const PRECISION: Precision = Precision::Single;

/// Result of [`register_frame`].
#[derive(Debug, Clone)]
pub struct FrameResult {
    pub state: NodeState,
    pub points: Vec<Vector3<f64>>,
    pub sigma2: f64,
    pub iterations: usize,
    pub energy: f64,
    /// `N_p` of the last E-step and the number of data points N.
    pub n_p: f64,
    pub n_data: usize,
    /// `(sigma^2, energy)` after each iteration.
    pub history: Vec<(f64, f64)>,
}

fn flat(y: &[Vector3<f64>]) -> Vec<f64> {
    y.iter().flat_map(|v| [v.x, v.y, v.z]).collect()
}

/// Algorithm 1 for one frame: EM from the node transforms `init` against data `x` (N, 3),
/// with optional data normals `xn` (N, 3) used when `p.kappa > 0` and the graph has rest
/// normals ([`FrameParams::kappa`]), starting at `sigma2_start` (m^2).
///
/// Each iteration: E-step (Eq. 4, truncated if `cutoff`), then a rigid Kabsch step
/// (first `rigid_iters` iterations) or the M-step solver, then sigma^2 by Eq. 12 (floored at
/// `sigma2_min`). Stops after `max_iter` iterations or when the relative change of Eq. 8a
/// falls below `tol`, or when the matched mass `N_p` vanishes.
pub fn register_frame(
    g: &Graph,
    init: NodeState,
    x: &[f64],
    xn: Option<&[f64]>,
    p: &FrameParams,
    sigma2_start: f64,
    rigid_iters: usize,
) -> CoreResult<FrameResult> {
    g.check_state(&init)?;
    if !(sigma2_start > 0.0 && sigma2_start.is_finite()) || !(p.sigma2_min > 0.0) {
        return Err(CoreError::InvalidInput(
            "sigma2_start and sigma2_min must be positive".into(),
        ));
    }
    let n = x.len() / 3;
    let mut st = init;
    let mut s2 = sigma2_start.max(p.sigma2_min);
    let mut e_prev: Option<f64> = None;
    let mut energy = f64::NAN;
    let mut n_p = 0.0;
    let mut iterations = 0;
    let mut history = Vec::new();
    let n_edges = g.n_edges().max(1) as f64;
    let k_coarse =
        if p.anneal > 0.0 && p.anneal < 1.0 && s2 > p.anneal_floor && p.anneal_floor > 0.0 {
            ((s2 / p.anneal_floor).ln() / (1.0 / p.anneal).ln()).ceil() as usize
        } else {
            0
        };
    let mut full_data = !(p.subsample > 0.0);
    let mut y_cur = g.deform(&st);
    // Data normals are used only with rest normals on the graph and kappa > 0.
    let xn = match xn {
        Some(v) if p.kappa > 0.0 && g.has_normals() => {
            if v.len() != x.len() || !v.iter().all(|a| a.is_finite()) {
                return Err(CoreError::InvalidInput(format!(
                    "data normals must be finite with shape ({n}, 3)"
                )));
            }
            Some(v)
        }
        _ => None,
    };
    // Points (flat), weights and normals (empty without normals) of a voxel grid of side h.
    let downsample = |h: f64| {
        let (c, w, mut nm) = voxel_downsample_with(x, xn, h);
        for v in nm.chunks_exact_mut(3) {
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            if l > 1e-9 {
                v.iter_mut().for_each(|a| *a /= l);
            }
        }
        (c, w, nm)
    };
    let any_estep = |y: &[f64], yn: &[f64], xs: &[f64], ws: Option<&[f64]>, xns: &[f64], s2| {
        if xn.is_some() {
            let nr = Normals {
                y: yn,
                x: xns,
                kappa: p.kappa,
            };
            estep_normals(y, xs, ws, nr, s2, p.omega, p.cutoff, PRECISION)
        } else {
            estep_weighted(y, xs, ws, s2, p.omega, p.cutoff, PRECISION)
        }
    };
    let full_estep =
        |y: &[f64], yn: &[f64], s2: f64| any_estep(y, yn, x, None, xn.unwrap_or(&[]), s2);
    for it in 0..p.max_iter {
        let y = flat(&y_cur);
        let yn = if xn.is_some() {
            flat(&g.deform_normals(&st))
        } else {
            Vec::new()
        };
        let es = if full_data {
            full_estep(&y, &yn, s2)?
        } else {
            let (xs, ws, nm) = downsample(p.subsample * s2.sqrt());
            if 2 * ws.len() >= n {
                full_data = true;
                full_estep(&y, &yn, s2)?
            } else {
                any_estep(&y, &yn, &xs, Some(&ws), &nm, s2)?
            }
        };
        n_p = es.stats.n_p;
        if !(n_p > 1e-9 * n as f64) {
            break;
        }
        let d = DataTerm {
            p1: &es.p1,
            px: &es.px,
            sum_x2: es.stats.sum_x2,
            n_p,
            sigma2: s2,
        };
        let beta = if p.beta_relative {
            p.beta_smooth * n_p / (s2 * n_edges)
        } else {
            p.beta_smooth
        };
        let w = Weights {
            beta_smooth: beta,
            beta_small: p.beta_small,
        };
        let pre = st.clone();
        if it < rigid_iters {
            g.rigid_step(&mut st, &d);
        } else {
            match p.solver {
                Solver::GaussNewton => {
                    g.gauss_newton_step(&mut st, &d, &w, p.damping, p.cg_tol, p.cg_max);
                }
                Solver::Sweeps => g.sweeps(&mut st, &pre, &d, &w),
            }
        }
        let yn = g.deform(&st);
        let dsq = Graph::data_sq(&yn, &d);
        let eq12 = dsq / (3.0 * n_p);
        let s2_new = if it < k_coarse {
            eq12.min((p.anneal * s2).max(p.anneal_floor))
        } else {
            eq12
        }
        .max(p.sigma2_min);
        energy = dsq / (2.0 * s2_new)
            + 1.5 * n_p * s2_new.ln()
            + 0.5 * beta * g.e_smooth(&st)
            + 0.5 * p.beta_small * Graph::e_small(&st, &pre);
        iterations = it + 1;
        history.push((s2_new, energy));
        let motion = (yn
            .iter()
            .zip(&y_cur)
            .map(|(a, b)| (a - b).norm_squared())
            .sum::<f64>()
            / yn.len().max(1) as f64)
            .sqrt();
        y_cur = yn;
        let settled = it >= rigid_iters.max(k_coarse)
            && ((p.motion_tol > 0.0 && motion <= p.motion_tol * s2_new.sqrt())
                || e_prev
                    .is_some_and(|e0| (energy - e0).abs() <= p.tol * energy.abs().max(1e-300)));
        // Converged on the voxel centroids: finish on the full data.
        let converged = settled && full_data;
        if settled {
            full_data = true;
        }
        // The last iteration always sees the full data.
        if it + 2 == p.max_iter {
            full_data = true;
        }
        s2 = s2_new;
        e_prev = Some(energy);
        if converged {
            break;
        }
    }
    let points = y_cur;
    Ok(FrameResult {
        state: st,
        points,
        sigma2: s2,
        iterations,
        energy,
        n_p,
        n_data: n,
        history,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn toy() -> (Graph, Vec<f64>) {
        let m = 60;
        let rest: Vec<f64> = (0..m)
            .flat_map(|i| {
                let f = i as f64;
                [f * 0.01, (f * 0.7).sin() * 0.05, (f * 1.3).cos() * 0.05]
            })
            .collect();
        let nodes: Vec<f64> = (0..6)
            .flat_map(|j| [j as f64 * 0.1 + 0.05, 0.0, 0.0])
            .collect();
        let mut idx = vec![];
        let mut w = vec![];
        for i in 0..m {
            let x = i as f64 * 0.01;
            let j0 = (((x - 0.05) / 0.1).floor().max(0.0) as i64).min(4);
            idx.extend([j0, j0 + 1]);
            w.extend([0.5, 0.5]);
        }
        let edges: Vec<i64> = (0..5).flat_map(|j| [j, j + 1, j + 1, j]).collect();
        (
            Graph::new(&rest, &nodes, &idx, &w, 2, &edges).unwrap(),
            rest,
        )
    }

    #[test]
    fn node_updates_never_increase_energy() {
        let (g, rest) = toy();
        let m = g.n_points();
        let p1: Vec<f64> = (0..m).map(|i| 0.5 + 0.4 * (i as f64).sin()).collect();
        let px: Vec<f64> = (0..3 * m)
            .map(|i| p1[i / 3] * (rest[i] + 0.02 * ((i as f64) * 0.37).cos()))
            .collect();
        let sx2: f64 = (0..m)
            .map(|i| v3(&px, i).norm_squared() / p1[i])
            .sum::<f64>()
            + 0.1;
        let d = DataTerm {
            p1: &p1,
            px: &px,
            sum_x2: sx2,
            n_p: p1.iter().sum(),
            sigma2: 1e-3,
        };
        let w = Weights {
            beta_smooth: 10.0,
            beta_small: 1.0,
        };
        let mut st = NodeState::identity(g.n_nodes());
        let pre = st.clone();
        let mut y = g.deform(&st);
        let mut e = g.energy(&st, &pre, &d, &w);
        for j in (0..g.n_nodes()).chain((0..g.n_nodes()).rev()) {
            g.node_update(&mut st, &pre, &mut y, j, &d, &w);
            let e2 = g.energy(&st, &pre, &d, &w);
            assert!(e2 <= e + 1e-9 * e.abs(), "node {j}: {e} -> {e2}");
            assert!((st.r[j].determinant() - 1.0).abs() < 1e-10);
            e = e2;
        }
        let y2 = g.deform(&st);
        for (a, b) in y.iter().zip(&y2) {
            assert!((a - b).norm() < 1e-12);
        }
        let mut st2 = NodeState::identity(g.n_nodes());
        let e0 = g.energy(&st2, &st2.clone(), &d, &w);
        g.gauss_newton_step(&mut st2, &d, &w, 0.0, 1e-10, 500);
        let e1 = g.energy(&st2, &pre, &d, &w);
        assert!(e1 < e0);
    }
}
