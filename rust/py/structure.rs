//! Bindings for step 2, skeletal structure extraction (§5.2-5.3): per-cluster Kabsch fits,
//! residual matrix and Eq. 15 swap residuals (`crate::core::cluster`).

use numpy::{
    PyArray1, PyArrayDyn, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArrayDyn,
    PyUntypedArrayMethods,
};
use pyo3::prelude::*;

use super::CSlice;

use super::{input_err, points, to_array2, to_pyerr};
use crate::core::cluster;
use crate::core::error::check_finite;

/// Borrow an n-d float64 C-contiguous finite array whose trailing dims equal `tail`;
/// returns the flat slice and the leading dims.
fn flat_nd<'a>(
    py: Python<'_>,
    arr: &'a PyReadonlyArrayDyn<'_, f64>,
    name: &str,
    lead: usize,
    tail: &[usize],
) -> PyResult<(&'a [f64], Vec<usize>)> {
    let shape = arr.shape();
    if shape.len() != lead + tail.len() || &shape[lead..] != tail {
        return Err(input_err(format!(
            "{name}: expected {lead} leading dims then {tail:?}, got shape {shape:?}"
        )));
    }
    let s = arr.c_slice(name)?;
    check_finite(name, s).map_err(|e| to_pyerr(py, e))?;
    Ok((s, shape[..lead].to_vec()))
}

fn check_frames(f_pts: &[usize], m: usize) -> PyResult<usize> {
    if f_pts[1] != m {
        return Err(input_err(format!(
            "points must be (F, M={m}, 3), got M={}",
            f_pts[1]
        )));
    }
    Ok(f_pts[0])
}

/// Per (cluster, frame) weighted Kabsch (Eq. 14): returns `R (F, K, 3, 3)`, `T (F, K, 3)`,
/// `counts (K,)`.
#[pyfunction]
#[pyo3(signature = (rest, points_seq, labels, n_clusters, weights=None))]
#[allow(clippy::type_complexity)]
fn cluster_fit<'py>(
    py: Python<'py>,
    rest: PyReadonlyArray2<'py, f64>,
    points_seq: PyReadonlyArrayDyn<'py, f64>,
    labels: PyReadonlyArray1<'py, i64>,
    n_clusters: usize,
    weights: Option<PyReadonlyArray1<'py, f64>>,
) -> PyResult<(
    Bound<'py, PyArrayDyn<f64>>,
    Bound<'py, PyArrayDyn<f64>>,
    Bound<'py, PyArray1<i64>>,
)> {
    let q = points(py, &rest, "rest")?;
    let m = q.len() / 3;
    let (y, lead) = flat_nd(py, &points_seq, "points", 2, &[3])?;
    let f = check_frames(&lead, m)?;
    let l = labels.c_slice("labels")?;
    let w = match &weights {
        Some(w) => Some(w.c_slice("weights")?),
        None => None,
    };
    let fits = py
        .detach(|| cluster::fit_clusters(q, y, l, n_clusters, w))
        .map_err(|e| to_pyerr(py, e))?;
    let r = PyArray1::from_vec(py, fits.r).reshape(vec![f, n_clusters, 3, 3])?;
    let t = PyArray1::from_vec(py, fits.t).reshape(vec![f, n_clusters, 3])?;
    let counts: Vec<i64> = fits.counts.iter().map(|&c| c as i64).collect();
    Ok((r, t, PyArray1::from_vec(py, counts)))
}

/// Residual summed over frames for candidate bones: `(M, C)` m^2, `inf` where candidate is -1.
#[pyfunction]
fn cluster_residuals<'py>(
    py: Python<'py>,
    rest: PyReadonlyArray2<'py, f64>,
    points_seq: PyReadonlyArrayDyn<'py, f64>,
    rotations: PyReadonlyArrayDyn<'py, f64>,
    translations: PyReadonlyArrayDyn<'py, f64>,
    candidates: PyReadonlyArray2<'py, i64>,
) -> PyResult<Bound<'py, numpy::PyArray2<f64>>> {
    let q = points(py, &rest, "rest")?;
    let m = q.len() / 3;
    let (y, lead) = flat_nd(py, &points_seq, "points", 2, &[3])?;
    check_frames(&lead, m)?;
    let (r, _) = flat_nd(py, &rotations, "R", 2, &[3, 3])?;
    let (t, _) = flat_nd(py, &translations, "T", 2, &[3])?;
    let c = candidates.shape()[1];
    let cand = candidates.c_slice("candidates")?;
    let out = py
        .detach(|| cluster::cluster_residuals(q, y, r, t, cand, c))
        .map_err(|e| to_pyerr(py, e))?;
    to_array2(py, out, c)
}

/// Directed halves of the Eq. 15 edge weight per pair: `(P, 2)` m^2, `e_ij = sum of the row`.
#[pyfunction]
fn swap_residuals<'py>(
    py: Python<'py>,
    rest: PyReadonlyArray2<'py, f64>,
    points_seq: PyReadonlyArrayDyn<'py, f64>,
    labels: PyReadonlyArray1<'py, i64>,
    rotations: PyReadonlyArrayDyn<'py, f64>,
    translations: PyReadonlyArrayDyn<'py, f64>,
    pairs: PyReadonlyArray2<'py, i64>,
) -> PyResult<Bound<'py, numpy::PyArray2<f64>>> {
    let q = points(py, &rest, "rest")?;
    let m = q.len() / 3;
    let (y, lead) = flat_nd(py, &points_seq, "points", 2, &[3])?;
    check_frames(&lead, m)?;
    let l = labels.c_slice("labels")?;
    let (r, _) = flat_nd(py, &rotations, "R", 2, &[3, 3])?;
    let (t, _) = flat_nd(py, &translations, "T", 2, &[3])?;
    if pairs.shape()[1] != 2 {
        return Err(input_err("pairs must be (P, 2)"));
    }
    let p = pairs.c_slice("pairs")?;
    let out = py
        .detach(|| cluster::swap_residuals(q, y, l, r, t, p))
        .map_err(|e| to_pyerr(py, e))?;
    to_array2(py, out, 2)
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(cluster_fit, m)?)?;
    m.add_function(wrap_pyfunction!(cluster_residuals, m)?)?;
    m.add_function(wrap_pyfunction!(swap_residuals, m)?)?;
    Ok(())
}
