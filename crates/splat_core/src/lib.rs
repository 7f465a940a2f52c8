//! plantdreamer's compute core: pure Rust, no Python.
//!
//! Every public function takes plain slices (structure of arrays) and returns
//! `Result<_, CoreError>`; the `pyplant` crate is the only place that knows about Python.
#![deny(unsafe_code)]

pub mod atomic_file;
pub mod culling;
pub mod error;
pub mod memory;
pub mod ply;
pub mod pointcloud;
pub mod raster;
#[cfg(test)]
mod test_rng;
pub mod threads;

pub use error::{CoreError, CoreResult};

/// Version of the core crate, reported by `plantdreamer info`.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");
