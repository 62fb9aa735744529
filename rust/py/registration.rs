//! Bindings for step 1, non-rigid registration (§4): the E-step sufficient statistics.

use numpy::{PyArray1, PyArray2, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::{points, to_array2, to_pyerr};
use crate::core::gmm::{self, Precision};

type EStepOut<'py> = (
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyDict>,
);

/// E-step of Eq. 4 as sufficient statistics (see `_core.pyi`).
#[pyfunction]
#[pyo3(signature = (y, x, sigma2, omega, cutoff=None, single=false))]
fn gmm_estep<'py>(
    py: Python<'py>,
    y: PyReadonlyArray2<'py, f64>,
    x: PyReadonlyArray2<'py, f64>,
    sigma2: f64,
    omega: f64,
    cutoff: Option<f64>,
    single: bool,
) -> PyResult<EStepOut<'py>> {
    let ys = points(py, &y, "y")?;
    let xs = points(py, &x, "x")?;
    let prec = if single {
        Precision::Single
    } else {
        Precision::Double
    };
    let r = py
        .detach(|| gmm::estep(ys, xs, sigma2, omega, cutoff, prec))
        .map_err(|e| to_pyerr(py, e))?;
    let st = r.stats;
    let d = PyDict::new(py);
    d.set_item("n_p", st.n_p)?;
    d.set_item("sum_sq", st.sum_sq)?;
    d.set_item("sum_x2", st.sum_x2)?;
    d.set_item("nll", st.nll)?;
    d.set_item("e_gmm", st.e_gmm)?;
    d.set_item("trunc_bound", st.trunc_bound)?;
    d.set_item("n_pairs", st.n_pairs)?;
    Ok((
        PyArray1::from_vec(py, r.p1),
        PyArray1::from_vec(py, r.pt1),
        to_array2(py, r.px, 3)?,
        d,
    ))
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(gmm_estep, m)?)?;
    Ok(())
}
