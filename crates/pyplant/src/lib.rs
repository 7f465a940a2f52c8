//! Python bindings of `splat_core`, imported as `plantdreamer._core`.
//!
//! Each submodule converts arrays and errors for one area of the core and registers its
//! functions; no math lives here.

use pyo3::prelude::*;
use pyo3::types::PyDict;

mod arrays;
mod coverage;
mod culling;
mod errors;
mod ints;
mod native;
mod ply;
mod pointcloud;
mod raster;
mod raster_args;
mod raster_results;
mod sh;

pub use errors::to_pyerr;
pub use native::run_native;

/// The kernels allocate and free tens of MiB per call (splats, tile lists, images);
/// glibc's malloc hands such blocks back to the OS on free, so every call paid again for
/// fresh zeroed pages (~10 ms per forward at 100k Gaussians). mimalloc keeps them.
#[global_allocator]
static ALLOC: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// Build facts: versions, the rayon pool size, the most `threads=` a call accepts, and
/// whether this is an optimised build.
#[pyfunction]
fn info(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("version", env!("CARGO_PKG_VERSION"))?;
    d.set_item("core_version", splat_core::VERSION)?;
    d.set_item("threads", splat_core::threads::default_threads())?;
    d.set_item("max_threads", splat_core::threads::max_threads())?;
    d.set_item("debug_build", cfg!(debug_assertions))?;
    d.set_item("blend_kernel", splat_core::raster::blend_kernel())?;
    Ok(d)
}

#[pymodule]
#[pyo3(name = "_core")]
fn core_module(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    errors::register(m)?;
    ply::register(m)?;
    pointcloud::register(m)?;
    m.add_function(wrap_pyfunction!(info, m)?)?;
    culling::register(m)?;
    coverage::register(m)?;
    raster::register(m)?;
    sh::register(m)?;
    Ok(())
}
