//! Bindings for step 3, LBS-based joint learning (§6.4): skinning, weight QP, bone sweeps.
//!
//! Shapes crossing the boundary (all float64 C-contiguous unless stated):
//! rest points `q (M, 3)`; sparse weights `idx (M, K) int64`, `w (M, K)`; rotations
//! `R (F*B, 9)` (row-major 3x3 per frame and bone), translations `T (F*B, 3)`; data weights
//! `a (F, M)`; targets `z (F*M, 3)`; `bone_parent (B,) int64`; `joints (B, 3)`.

use numpy::{
    PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods,
};
use pyo3::prelude::*;

use super::CSlice;

use super::{flat1, flat2, input_err, points, to_array2, to_indices, to_pyerr};
use crate::core::lbs::{self, Dims, SparseWeights};
use crate::core::qp;
use crate::core::track;

fn indices(arr: &PyReadonlyArray2<'_, i64>, name: &str) -> PyResult<(Vec<usize>, usize)> {
    Ok((to_indices(arr.c_slice(name)?, name)?, arr.shape()[1]))
}

fn parents(arr: &PyReadonlyArray1<'_, i64>) -> PyResult<Vec<i64>> {
    Ok(arr.c_slice("bone_parent")?.to_vec())
}

/// Work out (F, M, B) from the bone arrays and check they agree.
fn dims(q: &[f64], r: &[f64], t: &[f64], n_frames: usize) -> PyResult<Dims> {
    let m = q.len() / 3;
    if n_frames == 0 || !r.len().is_multiple_of(9 * n_frames) {
        return Err(input_err(format!(
            "R: expected shape (F*B, 9) with F = {n_frames}, got {} rows",
            r.len() / 9
        )));
    }
    let b = r.len() / (9 * n_frames);
    if t.len() != 3 * b * n_frames {
        return Err(input_err(format!(
            "T: expected shape ({}, 3), got ({}, 3)",
            b * n_frames,
            t.len() / 3
        )));
    }
    Ok(Dims { f: n_frames, m, b })
}

#[allow(clippy::type_complexity)]
fn rt_out<'py>(
    py: Python<'py>,
    r: Vec<f64>,
    t: Vec<f64>,
) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>)> {
    Ok((to_array2(py, r, 9)?, to_array2(py, t, 3)?))
}

/// Linear blend skinning (Eq. 13) into every frame: returns `(F*M, 3)`.
#[pyfunction]
fn lbs_skin<'py>(
    py: Python<'py>,
    q: PyReadonlyArray2<'py, f64>,
    idx: PyReadonlyArray2<'py, i64>,
    w: PyReadonlyArray2<'py, f64>,
    r: PyReadonlyArray2<'py, f64>,
    t: PyReadonlyArray2<'py, f64>,
    n_frames: usize,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let q = points(py, &q, "rest_points")?;
    let (idx, k) = indices(&idx, "idx")?;
    let w = flat2(py, &w, "w", k)?;
    let r = flat2(py, &r, "R", 9)?;
    let t = points(py, &t, "T")?;
    let d = dims(q, r, t, n_frames)?;
    let sw = SparseWeights { idx: &idx, w, k };
    let out = py
        .detach(|| lbs::skin(q, sw, r, t, d))
        .map_err(|e| to_pyerr(py, e))?;
    to_array2(py, out, 3)
}

/// Point weights by Eq. (22): returns `idx (M, k) int64, w (M, k), residual (M,)`.
#[pyfunction]
#[pyo3(signature = (q, r, t, a, z, n_frames, k, allowed=None))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn lbs_fit_weights<'py>(
    py: Python<'py>,
    q: PyReadonlyArray2<'py, f64>,
    r: PyReadonlyArray2<'py, f64>,
    t: PyReadonlyArray2<'py, f64>,
    a: PyReadonlyArray2<'py, f64>,
    z: PyReadonlyArray2<'py, f64>,
    n_frames: usize,
    k: usize,
    allowed: Option<PyReadonlyArray2<'py, bool>>,
) -> PyResult<(
    Bound<'py, PyArray2<i64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray1<f64>>,
)> {
    let q = points(py, &q, "rest_points")?;
    let r = flat2(py, &r, "R", 9)?;
    let t = points(py, &t, "T")?;
    let d = dims(q, r, t, n_frames)?;
    let a = flat2(py, &a, "a", d.m)?;
    let z = points(py, &z, "z")?;
    let al = match &allowed {
        Some(al) => Some(al.c_slice("allowed")?.to_vec()),
        None => None,
    };
    let (idx, w, res) = py
        .detach(|| lbs::fit_weights(q, r, t, a, z, d, k, al.as_deref()))
        .map_err(|e| to_pyerr(py, e))?;
    let idx: Vec<i64> = idx.into_iter().map(|v| v as i64).collect();
    let idx = PyArray1::from_vec(py, idx).reshape([d.m, k])?;
    Ok((idx, to_array2(py, w, k)?, PyArray1::from_vec(py, res)))
}

/// The arrays both bone sweeps take, converted and shape-checked once (borrowed from the
/// caller's numpy arrays; `idx` and `parent` are owned conversions).
struct SweepInput<'a> {
    q: &'a [f64],
    idx: Vec<usize>,
    w: &'a [f64],
    k: usize,
    r: &'a [f64],
    t: &'a [f64],
    a: &'a [f64],
    z: &'a [f64],
    r_pre: &'a [f64],
    parent: Vec<i64>,
    joints: &'a [f64],
    d: Dims,
}

impl<'a> SweepInput<'a> {
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        q: &'a PyReadonlyArray2<'_, f64>,
        idx: &'a PyReadonlyArray2<'_, i64>,
        w: &'a PyReadonlyArray2<'_, f64>,
        r: &'a PyReadonlyArray2<'_, f64>,
        t: &'a PyReadonlyArray2<'_, f64>,
        a: &'a PyReadonlyArray2<'_, f64>,
        z: &'a PyReadonlyArray2<'_, f64>,
        r_pre: &'a PyReadonlyArray2<'_, f64>,
        bone_parent: &'a PyReadonlyArray1<'_, i64>,
        joints: &'a PyReadonlyArray2<'_, f64>,
        n_frames: usize,
    ) -> PyResult<Self> {
        let q = points(py, q, "rest_points")?;
        let (idx, k) = indices(idx, "idx")?;
        let w = flat2(py, w, "w", k)?;
        let r = flat2(py, r, "R", 9)?;
        let t = points(py, t, "T")?;
        let d = dims(q, r, t, n_frames)?;
        Ok(SweepInput {
            q,
            idx,
            w,
            k,
            r,
            t,
            a: flat2(py, a, "a", d.m)?,
            z: points(py, z, "z")?,
            r_pre: flat2(py, r_pre, "R_pre", 9)?,
            parent: parents(bone_parent)?,
            joints: points(py, joints, "joints")?,
            d,
        })
    }

    fn weights(&self) -> SparseWeights<'_> {
        SparseWeights {
            idx: &self.idx,
            w: self.w,
            k: self.k,
        }
    }
}

/// The paper's bone update (Eqs. 23-26) in every frame: returns new `(R, T)`.
#[pyfunction]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn lbs_sweep_paper<'py>(
    py: Python<'py>,
    q: PyReadonlyArray2<'py, f64>,
    idx: PyReadonlyArray2<'py, i64>,
    w: PyReadonlyArray2<'py, f64>,
    r: PyReadonlyArray2<'py, f64>,
    t: PyReadonlyArray2<'py, f64>,
    a: PyReadonlyArray2<'py, f64>,
    z: PyReadonlyArray2<'py, f64>,
    r_pre: PyReadonlyArray2<'py, f64>,
    t_pre: PyReadonlyArray2<'py, f64>,
    bone_parent: PyReadonlyArray1<'py, i64>,
    joints: PyReadonlyArray2<'py, f64>,
    alpha: f64,
    gamma: f64,
    n_frames: usize,
) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>)> {
    let s = SweepInput::new(
        py,
        &q,
        &idx,
        &w,
        &r,
        &t,
        &a,
        &z,
        &r_pre,
        &bone_parent,
        &joints,
        n_frames,
    )?;
    let t_pre = points(py, &t_pre, "T_pre")?;
    if !alpha.is_finite() || !gamma.is_finite() {
        return Err(input_err("alpha and gamma must be finite"));
    }
    let (mut rr, mut tt) = (s.r.to_vec(), s.t.to_vec());
    py.detach(|| {
        lbs::sweep_paper(
            s.q,
            s.weights(),
            &mut rr,
            &mut tt,
            s.a,
            s.z,
            s.r_pre,
            t_pre,
            &s.parent,
            s.joints,
            alpha,
            gamma,
            s.d,
        )
    })
    .map_err(|e| to_pyerr(py, e))?;
    rt_out(py, rr, tt)
}

/// Joint-constrained bone update (our deviation, docs/joints.md): returns new `(R, T)`.
/// `smooth` (optional, one weight per bone) adds the temporal rotation term.
#[pyfunction]
#[pyo3(signature = (q, idx, w, r, t, a, z, r_pre, bone_parent, joints, gamma, n_frames, smooth=None))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn lbs_sweep_articulated<'py>(
    py: Python<'py>,
    q: PyReadonlyArray2<'py, f64>,
    idx: PyReadonlyArray2<'py, i64>,
    w: PyReadonlyArray2<'py, f64>,
    r: PyReadonlyArray2<'py, f64>,
    t: PyReadonlyArray2<'py, f64>,
    a: PyReadonlyArray2<'py, f64>,
    z: PyReadonlyArray2<'py, f64>,
    r_pre: PyReadonlyArray2<'py, f64>,
    bone_parent: PyReadonlyArray1<'py, i64>,
    joints: PyReadonlyArray2<'py, f64>,
    gamma: f64,
    n_frames: usize,
    smooth: Option<PyReadonlyArray1<'py, f64>>,
) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>)> {
    let s = SweepInput::new(
        py,
        &q,
        &idx,
        &w,
        &r,
        &t,
        &a,
        &z,
        &r_pre,
        &bone_parent,
        &joints,
        n_frames,
    )?;
    if !gamma.is_finite() {
        return Err(input_err("gamma must be finite"));
    }
    let smooth: &[f64] = match &smooth {
        Some(v) => flat1(py, v, "smooth")?,
        None => &[],
    };
    let (mut rr, mut tt) = (s.r.to_vec(), s.t.to_vec());
    py.detach(|| {
        lbs::sweep_articulated(
            s.q,
            s.weights(),
            &mut rr,
            &mut tt,
            s.a,
            s.z,
            s.r_pre,
            &s.parent,
            s.joints,
            gamma,
            smooth,
            s.d,
        )
    })
    .map_err(|e| to_pyerr(py, e))?;
    rt_out(py, rr, tt)
}

type FramesOut<'py> = (
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<f64>>,
);

/// Truncated E-step of every frame in one call, parallel over frames (see `_core.pyi`).
#[pyfunction]
#[pyo3(signature = (x, v, offsets, tau, omega, cutoff=None, single=false, xn=None, vn=None, kappa=0.0))]
#[allow(clippy::too_many_arguments)]
fn lbs_estep_frames<'py>(
    py: Python<'py>,
    x: PyReadonlyArray2<'py, f64>,
    v: PyReadonlyArray2<'py, f64>,
    offsets: PyReadonlyArray1<'py, i64>,
    tau: PyReadonlyArray1<'py, f64>,
    omega: f64,
    cutoff: Option<f64>,
    single: bool,
    xn: Option<PyReadonlyArray2<'py, f64>>,
    vn: Option<PyReadonlyArray2<'py, f64>>,
    kappa: f64,
) -> PyResult<FramesOut<'py>> {
    let xs = points(py, &x, "x")?;
    let vs = points(py, &v, "v")?;
    let normals = match (&xn, &vn) {
        (Some(a), Some(b)) if kappa > 0.0 => {
            Some((points(py, a, "xn")?, points(py, b, "vn")?, kappa))
        }
        _ => None,
    };
    let taus = flat1(py, &tau, "tau")?;
    let offs = to_indices(offsets.c_slice("offsets")?, "offsets")?;
    let prec = if single {
        crate::core::gmm::Precision::Single
    } else {
        crate::core::gmm::Precision::Double
    };
    let r = py
        .detach(|| lbs::estep_frames(xs, vs, &offs, taus, omega, cutoff, prec, normals))
        .map_err(|e| to_pyerr(py, e))?;
    let f = taus.len();
    let m = r.p1.len() / f.max(1);
    Ok((
        to_array2(py, r.p1, m.max(1))?,
        to_array2(py, r.px, 3)?,
        PyArray1::from_vec(py, r.n_p),
        PyArray1::from_vec(py, r.sum_x2),
    ))
}

type SumsOut<'py> = (
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
);

/// Per-frame sums of the articulated joint solve (see `_core.pyi`).
#[pyfunction]
fn lbs_joint_normal_sums<'py>(
    py: Python<'py>,
    ws: PyReadonlyArray2<'py, f64>,
    a: PyReadonlyArray2<'py, f64>,
    r: PyReadonlyArray2<'py, f64>,
) -> PyResult<SumsOut<'py>> {
    let e = ws.shape()[1];
    let m = ws.shape()[0];
    let wss = flat2(py, &ws, "ws", e)?;
    let as_ = flat2(py, &a, "a", m)?;
    let rs = points(py, &r, "r")?;
    let [s0, d0, s1, s2, d1] = py
        .detach(|| lbs::joint_normal_sums(wss, e, as_, rs))
        .map_err(|err| to_pyerr(py, err))?;
    Ok((
        PyArray1::from_vec(py, s0),
        to_array2(py, d0, 3)?,
        to_array2(py, s1, e)?,
        to_array2(py, s2, e * e)?,
        to_array2(py, d1, 3 * e)?,
    ))
}

/// Exact minimiser of `0.5 w^T H w - g^T w` on the probability simplex (Eq. 22, k <= 8).
#[pyfunction]
fn simplex_qp<'py>(
    py: Python<'py>,
    h: PyReadonlyArray2<'py, f64>,
    g: PyReadonlyArray1<'py, f64>,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let g = flat1(py, &g, "g")?;
    let k = g.len();
    let h = flat2(py, &h, "H", k)?;
    let w = qp::simplex_qp(h, g, k).map_err(|e| to_pyerr(py, e))?;
    Ok(PyArray1::from_vec(py, w))
}

type TrackOut<'py> = (
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
);

/// One frame of step 3's tracker (see `_core.pyi`).
#[pyfunction]
#[pyo3(signature = (q, labels, bone_parent, joints, v, r, t_root, iterations, tau0, tau_max,
                    floor, anneal, omega, cutoff, gamma, density, rest_normals=None,
                    v_normals=None, kappa=0.0, sweeps=1))]
#[allow(clippy::too_many_arguments)]
fn lbs_track_frame<'py>(
    py: Python<'py>,
    q: PyReadonlyArray2<'py, f64>,
    labels: PyReadonlyArray1<'py, i64>,
    bone_parent: PyReadonlyArray1<'py, i64>,
    joints: PyReadonlyArray2<'py, f64>,
    v: PyReadonlyArray2<'py, f64>,
    r: PyReadonlyArray2<'py, f64>,
    t_root: [f64; 3],
    iterations: usize,
    tau0: f64,
    tau_max: f64,
    floor: f64,
    anneal: f64,
    omega: f64,
    cutoff: Option<f64>,
    gamma: f64,
    density: f64,
    rest_normals: Option<PyReadonlyArray2<'py, f64>>,
    v_normals: Option<PyReadonlyArray2<'py, f64>>,
    kappa: f64,
    sweeps: usize,
) -> PyResult<TrackOut<'py>> {
    let qs = points(py, &q, "q")?;
    let vs = points(py, &v, "v")?;
    let js = points(py, &joints, "joints")?;
    let rs = flat2(py, &r, "R", 9)?;
    let parent = parents(&bone_parent)?;
    let labels = to_indices(labels.c_slice("labels")?, "labels")?;
    let scalars = [tau0, tau_max, floor, anneal, omega, gamma, density, kappa];
    if scalars.iter().any(|x| !x.is_finite())
        || t_root.iter().any(|x| !x.is_finite())
        || cutoff.is_some_and(|c| !c.is_finite())
    {
        return Err(input_err("lbs_track_frame: settings must be finite"));
    }
    if !(tau0 > 0.0 && tau_max > 0.0) {
        return Err(input_err("lbs_track_frame: tau0 and tau_max must be > 0"));
    }
    let normals = match (&rest_normals, &v_normals) {
        (Some(a), Some(b)) if kappa > 0.0 => Some((
            points(py, a, "rest_normals")?,
            points(py, b, "v_normals")?,
            kappa,
        )),
        _ => None,
    };
    let model = track::TrackModel {
        q: qs,
        labels: &labels,
        parent: &parent,
        joints: js,
        normals,
    };
    let settings = track::TrackSettings {
        iterations,
        sweeps,
        tau0,
        tau_max,
        floor,
        anneal,
        omega,
        cutoff,
        gamma,
        density,
    };
    let (rr, tt, xx) = py
        .detach(|| track::track_frame(&model, vs, rs, t_root, &settings))
        .map_err(|e| to_pyerr(py, e))?;
    Ok((
        to_array2(py, rr, 9)?,
        to_array2(py, tt, 3)?,
        to_array2(py, xx, 3)?,
    ))
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(lbs_skin, m)?)?;
    m.add_function(wrap_pyfunction!(lbs_fit_weights, m)?)?;
    m.add_function(wrap_pyfunction!(lbs_sweep_paper, m)?)?;
    m.add_function(wrap_pyfunction!(lbs_sweep_articulated, m)?)?;
    m.add_function(wrap_pyfunction!(simplex_qp, m)?)?;
    m.add_function(wrap_pyfunction!(lbs_estep_frames, m)?)?;
    m.add_function(wrap_pyfunction!(lbs_joint_normal_sums, m)?)?;
    m.add_function(wrap_pyfunction!(lbs_track_frame, m)?)?;
    Ok(())
}
