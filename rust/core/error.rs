//! The core error enum. The binding layer maps each variant to one Python exception class
//! (see `rust/py/mod.rs` and `python/pointrig/errors.py`).

use std::fmt;

/// Every failure the numeric core can report. No kernel panics on bad input; it returns one
/// of these instead.
#[derive(Debug, Clone, PartialEq)]
pub enum CoreError {
    /// An argument has the wrong shape, length, size or value (maps to
    /// `pointrig.errors.InputError`, a `ValueError`).
    InvalidInput(String),
    /// An array holds NaN or infinite values (maps to `pointrig.errors.InputError`).
    NonFinite(String),
    /// An iterative solver failed to make progress (maps to `pointrig.errors.ConvergenceError`).
    Convergence(String),
    /// A linear system was singular or not positive definite (maps to `NumericalError`).
    Numerical(String),
}

impl fmt::Display for CoreError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CoreError::InvalidInput(m) => write!(f, "invalid input: {m}"),
            CoreError::NonFinite(m) => write!(f, "non-finite values: {m}"),
            CoreError::Convergence(m) => write!(f, "did not converge: {m}"),
            CoreError::Numerical(m) => write!(f, "numerical failure: {m}"),
        }
    }
}

impl std::error::Error for CoreError {}

/// Result alias used by every kernel.
pub type CoreResult<T> = Result<T, CoreError>;

/// Check that a flat buffer holds only finite values.
pub fn check_finite(name: &str, data: &[f64]) -> CoreResult<()> {
    match data.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(i) => Err(CoreError::NonFinite(format!(
            "{name}: element {i} (row {}) is {}",
            i / 3,
            data[i]
        ))),
    }
}

/// Largest coordinate magnitude, metres, that point arrays may hold: far beyond any depth
/// camera's reach, and small enough that squared distances and the sums of millions of them
/// stay finite and that grid cell indices cannot overflow.
pub const MAX_COORD: f64 = 1e12;

/// Check that flat `(n, 3)` points are finite and within [`MAX_COORD`] metres of the origin
/// along every axis.
pub fn check_points(name: &str, data: &[f64]) -> CoreResult<()> {
    check_finite(name, data)?;
    match data.iter().position(|v| v.abs() > MAX_COORD) {
        None => Ok(()),
        Some(i) => Err(CoreError::InvalidInput(format!(
            "{name}: element {i} (row {}) is {:e}, beyond the {MAX_COORD:e} m the kernels \
             accept (points must be in metres)",
            i / 3,
            data[i]
        ))),
    }
}

/// Check that an output of `count` elements can be allocated: an `InvalidInput` error
/// naming `what` when the count overflows or exceeds [`MAX_ELEMENTS`], instead of an
/// allocation failure that would abort the process.
pub fn check_size(what: &str, count: Option<usize>) -> CoreResult<usize> {
    match count {
        Some(c) if c <= MAX_ELEMENTS => Ok(c),
        _ => Err(CoreError::InvalidInput(format!(
            "{what}: the result would hold more than {MAX_ELEMENTS} values"
        ))),
    }
}

/// Largest number of values one kernel result may hold (2^31 float64 values, 16 GiB).
pub const MAX_ELEMENTS: usize = 1 << 31;
