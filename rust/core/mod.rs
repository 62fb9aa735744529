//! Numeric kernels, one file per kernel family. No PyO3 here.

pub mod error;
pub mod rotation;

pub mod chord;
pub mod cluster;
pub mod deform;
pub mod gmm;
pub mod lbs;
pub mod nearest;
pub mod neighbors;
pub mod qp;
pub mod track;

pub use error::{CoreError, CoreResult};
