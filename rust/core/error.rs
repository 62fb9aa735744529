//! The core error enum. The binding layer maps each variant to one Python exception class
//! (see `rust/py/mod.rs` and `python/pointrig/errors.py`).

use std::fmt;

/// Every failure the numeric core can report. No kernel panics on bad input; it returns one
/// of these instead.
#[derive(Debug, Clone, PartialEq)]
pub enum CoreError {
    /// An argument has the wrong shape, length or value (maps to `ValueError`).
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
