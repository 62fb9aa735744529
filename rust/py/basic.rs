//! Bindings for small shared kernels (rotations, the depth pass's silhouette chords).

use nalgebra::Vector3;
use numpy::{PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;

use super::{flat1, flat2, input_err, points, to_array2, to_pyerr, CSlice};
use crate::core::{chord, rotation};

fn as_vecs(flat: &[f64]) -> Vec<Vector3<f64>> {
    flat.chunks_exact(3)
        .map(|c| Vector3::new(c[0], c[1], c[2]))
        .collect()
}

/// `(R (3, 3), t (3,))` returned to Python.
type RotationAndTranslation<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray1<f64>>);

/// Weighted absolute orientation (Kabsch, Eq. 14) with the det correction of Lemma 1.
#[pyfunction]
#[pyo3(signature = (src, dst, weights=None))]
fn kabsch<'py>(
    py: Python<'py>,
    src: PyReadonlyArray2<'py, f64>,
    dst: PyReadonlyArray2<'py, f64>,
    weights: Option<PyReadonlyArray1<'py, f64>>,
) -> PyResult<RotationAndTranslation<'py>> {
    let s = as_vecs(points(py, &src, "src")?);
    let d = as_vecs(points(py, &dst, "dst")?);
    if s.len() != d.len() {
        return Err(input_err(format!(
            "src and dst must have the same number of points, got {} and {}",
            s.len(),
            d.len()
        )));
    }
    let w = match &weights {
        Some(w) => {
            let w = flat1(py, w, "weights")?;
            if w.len() != s.len() {
                return Err(input_err("weights must have one entry per point"));
            }
            Some(w.to_vec())
        }
        None => None,
    };
    let (r, t) = py.detach(|| rotation::kabsch(&s, &d, w.as_deref()));
    let rv: Vec<f64> = (0..3)
        .flat_map(|i| (0..3).map(move |j| r[(i, j)]))
        .collect();
    Ok((
        to_array2(py, rv, 3)?,
        PyArray1::from_vec(py, t.iter().copied().collect()),
    ))
}

/// The shortest chord of a silhouette through a pixel (see `_core.pyi`).
#[pyfunction]
fn shortest_chord<'py>(
    py: Python<'py>,
    uv: PyReadonlyArray2<'py, f64>,
    centre: PyReadonlyArray1<'py, f64>,
    directions: PyReadonlyArray2<'py, f64>,
    band: f64,
    gap: f64,
) -> PyResult<Option<(f64, f64, usize)>> {
    if uv.shape()[1] != 2 {
        return Err(input_err(format!(
            "uv: expected shape (n, 2), got {:?}",
            uv.shape()
        )));
    }
    let u = uv.c_slice("uv")?; // rows with a non-finite value are left out, not refused
    let c = flat1(py, &centre, "centre")?;
    let &[c0, c1] = c else {
        return Err(input_err(format!(
            "centre: expected 2 values, got {}",
            c.len()
        )));
    };
    let d = flat2(py, &directions, "directions", 2)?;
    py.detach(|| chord::shortest_chord(u, [c0, c1], d, band, gap))
        .map_err(|e| to_pyerr(py, e))
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(kabsch, m)?)?;
    m.add_function(wrap_pyfunction!(shortest_chord, m)?)?;
    Ok(())
}
