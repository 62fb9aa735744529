//! Thin PyO3 binding layer: array conversion and checks, GIL release, error mapping.
//!
//! Every function here validates shapes `(n, 3)`, dtype float64, C-contiguity and
//! finiteness before handing plain slices to `crate::core`, and releases the GIL (`py.detach`)
//! around work that can take long. Core errors become Python exceptions in one place
//! (`to_pyerr`), never panics.

use numpy::{
    PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods,
};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::core::error::{check_finite, check_points, CoreError};

mod basic;
mod joints;
mod registration;
mod structure;

/// Borrow a numpy array's data only when it is C-contiguous (row-major).
///
/// rust-numpy's `as_slice` also accepts Fortran-ordered arrays, whose flat data would then be
/// read transposed; every binding goes through this instead.
pub(crate) trait CSlice<T> {
    /// The data as a flat row-major slice, or `ValueError` naming the array.
    fn c_slice(&self, name: &str) -> PyResult<&[T]>;
}

impl<T: numpy::Element, D: numpy::ndarray::Dimension> CSlice<T>
    for numpy::PyReadonlyArray<'_, T, D>
{
    fn c_slice(&self, name: &str) -> PyResult<&[T]> {
        let contiguous = self.is_c_contiguous();
        match self.as_slice() {
            Ok(s) if contiguous => Ok(s),
            _ => Err(input_err(format!(
                "{name}: array must be C-contiguous (use numpy.ascontiguousarray)"
            ))),
        }
    }
}

/// Map a core error to the matching class of `pointrig.errors` (one place for the mapping).
pub(crate) fn to_pyerr(py: Python<'_>, err: CoreError) -> PyErr {
    let (class, msg) = match &err {
        CoreError::InvalidInput(_) | CoreError::NonFinite(_) => ("InputError", err.to_string()),
        CoreError::Convergence(_) => ("ConvergenceError", err.to_string()),
        CoreError::Numerical(_) => ("NumericalError", err.to_string()),
    };
    match py
        .import("pointrig.errors")
        .and_then(|m| m.getattr(class))
        .and_then(|cls| cls.call1((msg.clone(),)))
    {
        Ok(exc) => PyErr::from_value(exc),
        Err(_) => PyValueError::new_err(msg),
    }
}

/// Borrow an `(n, cols)` float64 C-contiguous, finite array as a flat row-major slice.
pub(crate) fn flat2<'a>(
    py: Python<'_>,
    arr: &'a PyReadonlyArray2<'_, f64>,
    name: &str,
    cols: usize,
) -> PyResult<&'a [f64]> {
    let shape = arr.shape();
    if shape[1] != cols {
        return Err(input_err(format!(
            "{name}: expected shape (n, {cols}), got ({}, {})",
            shape[0], shape[1]
        )));
    }
    let s = arr.c_slice(name)?;
    check_finite(name, s).map_err(|e| to_pyerr(py, e))?;
    Ok(s)
}

/// Borrow an `(n, 3)` point array (metres) as a flat row-major slice; coordinates beyond
/// `MAX_COORD` are an `InputError`.
pub(crate) fn points<'a>(
    py: Python<'_>,
    arr: &'a PyReadonlyArray2<'_, f64>,
    name: &str,
) -> PyResult<&'a [f64]> {
    let s = flat2(py, arr, name, 3)?;
    check_points(name, s).map_err(|e| to_pyerr(py, e))?;
    Ok(s)
}

/// A `pointrig.errors.InputError` (a `ValueError`) with `msg`: the binding's own argument
/// checks (shapes, lengths, indices) raise the same class as the core's.
pub(crate) fn input_err(msg: impl Into<String>) -> PyErr {
    let msg = msg.into();
    Python::attach(|py| {
        match py
            .import("pointrig.errors")
            .and_then(|m| m.getattr("InputError"))
            .and_then(|cls| cls.call1((msg.clone(),)))
        {
            Ok(exc) => PyErr::from_value(exc),
            Err(_) => PyValueError::new_err(msg),
        }
    })
}

/// Non-negative int64 values as indices; a negative one is an `InputError` naming `name`.
pub(crate) fn to_indices(values: &[i64], name: &str) -> PyResult<Vec<usize>> {
    values
        .iter()
        .map(|&v| usize::try_from(v).map_err(|_| input_err(format!("{name}: negative index {v}"))))
        .collect()
}

/// Borrow a 1-D float64 contiguous, finite array.
pub(crate) fn flat1<'a>(
    py: Python<'_>,
    arr: &'a PyReadonlyArray1<'_, f64>,
    name: &str,
) -> PyResult<&'a [f64]> {
    let s = arr.c_slice(name)?;
    check_finite(name, s).map_err(|e| to_pyerr(py, e))?;
    Ok(s)
}

/// Build an `(n, cols)` numpy array from a flat row-major buffer.
pub(crate) fn to_array2<'py>(
    py: Python<'py>,
    data: Vec<f64>,
    cols: usize,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let rows = data.len().checked_div(cols).unwrap_or(0);
    PyArray1::from_vec(py, data).reshape([rows, cols])
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    basic::register(m)?;
    registration::register(m)?;
    structure::register(m)?;
    joints::register(m)?;
    Ok(())
}
