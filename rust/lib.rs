//! pointrig native core.
//!
//! `core` is plain Rust (no PyO3) and is tested with `cargo test --no-default-features`.
//! `py` is the thin binding layer, compiled only with the default `python` feature, and is
//! exposed to Python as the private module `pointrig._core`.

pub mod core;

#[cfg(feature = "python")]
mod py;
