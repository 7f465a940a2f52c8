//! The single point where core errors become Python exceptions.

use pyo3::create_exception;
use pyo3::exceptions::{
    PyException, PyFileNotFoundError, PyMemoryError, PyOSError, PyPermissionError,
};
use pyo3::prelude::*;
use splat_core::CoreError;

create_exception!(
    plantdreamer._core,
    PlantDreamerError,
    PyException,
    "Base class of every error plantdreamer raises on purpose."
);
create_exception!(
    plantdreamer._core,
    InputError,
    PlantDreamerError,
    "An argument or input file content is unusable (shape, dtype, NaN, out of range)."
);
create_exception!(
    plantdreamer._core,
    PlyError,
    PlantDreamerError,
    "A PLY file is malformed, truncated or inconsistent with its header."
);

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("PlantDreamerError", py.get_type::<PlantDreamerError>())?;
    m.add("InputError", py.get_type::<InputError>())?;
    m.add("PlyError", py.get_type::<PlyError>())?;
    Ok(())
}

/// Maps a core error to the matching Python exception; OS errors keep their built-in types.
pub fn to_pyerr(err: CoreError) -> PyErr {
    let message = err.to_string();
    match err {
        CoreError::Input(_) => InputError::new_err(message),
        CoreError::Ply { .. } => PlyError::new_err(message),
        CoreError::Io { source, .. } => match source.kind() {
            std::io::ErrorKind::NotFound => PyFileNotFoundError::new_err(message),
            std::io::ErrorKind::PermissionDenied => PyPermissionError::new_err(message),
            // A file too large for the memory left (std::fs::read reserves fallibly).
            std::io::ErrorKind::OutOfMemory => PyMemoryError::new_err(message),
            _ => PyOSError::new_err(message),
        },
        // Never an abort: the buffers sized by the data are reserved fallibly (memory.rs).
        CoreError::OutOfMemory { .. } => PyMemoryError::new_err(message),
        CoreError::Internal(_) => PlantDreamerError::new_err(message),
    }
}
