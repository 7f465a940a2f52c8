//! The one error type of the core. Bindings map each variant to a Python exception.

use std::path::PathBuf;

pub type CoreResult<T> = Result<T, CoreError>;

#[derive(Debug, thiserror::Error)]
pub enum CoreError {
    /// The caller passed something unusable: wrong length, NaN where a number is needed,
    /// a non-positive voxel size, too few points for the requested neighbours, ...
    #[error("{0}")]
    Input(String),

    /// A PLY file is malformed, truncated, or lies in its header.
    #[error("{path}: {message}")]
    Ply { path: PathBuf, message: String },

    /// An operating-system error while reading or writing `path`.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// A buffer sized by the data could not be allocated (a memory limit, too little
    /// memory): reported instead of aborting the process (`memory.rs`).
    #[error("out of memory: {} could not be allocated", human_bytes(*.bytes))]
    OutOfMemory { bytes: u128 },

    /// A broken internal invariant. Never expected; reported instead of panicking.
    #[error("internal error: {0}")]
    Internal(String),
}

impl CoreError {
    pub fn input(message: impl Into<String>) -> Self {
        Self::Input(message.into())
    }

    pub fn ply(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::Ply {
            path: path.into(),
            message: message.into(),
        }
    }

    /// `len` values of `T` could not be allocated.
    pub fn out_of_memory<T>(len: usize) -> Self {
        Self::OutOfMemory {
            bytes: len as u128 * std::mem::size_of::<T>() as u128,
        }
    }

    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            source,
        }
    }
}

/// Checks that a flat slice holds `n` rows of `width` values; names the argument on failure.
pub fn check_len<T>(name: &str, data: &[T], n: usize, width: usize) -> CoreResult<()> {
    let expected = n.checked_mul(width).ok_or_else(|| {
        CoreError::input(format!(
            "{name}: {n} rows of {width} overflow the address space"
        ))
    })?;
    if data.len() != expected {
        return Err(CoreError::input(format!(
            "{name}: expected {n} x {width} = {expected} values, got {}",
            data.len()
        )));
    }
    Ok(())
}

/// A byte count for messages: "512 bytes", "3.2 GiB", "8192.0 PiB".
pub fn human_bytes(bytes: u128) -> String {
    const UNITS: [&str; 5] = ["KiB", "MiB", "GiB", "TiB", "PiB"];
    if bytes < 1024 {
        return format!("{bytes} bytes");
    }
    let mut value = bytes as f64 / 1024.0;
    let mut unit = 0;
    while value >= 1024.0 && unit + 1 < UNITS.len() {
        value /= 1024.0;
        unit += 1;
    }
    format!("{value:.1} {}", UNITS[unit])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn human_bytes_picks_a_unit() {
        assert_eq!(human_bytes(512), "512 bytes");
        assert_eq!(human_bytes(3 << 30), "3.0 GiB");
        assert_eq!(human_bytes(1 << 70), "1048576.0 PiB");
    }

    #[test]
    fn check_len_names_the_argument() {
        let err = check_len("means", &[0.0f32; 5], 2, 3).unwrap_err();
        assert_eq!(err.to_string(), "means: expected 2 x 3 = 6 values, got 5");
        assert!(check_len("means", &[0.0f32; 6], 2, 3).is_ok());
    }

    #[test]
    fn check_len_rejects_overflow() {
        let err = check_len::<f32>("x", &[], usize::MAX, 3).unwrap_err();
        assert!(err.to_string().contains("overflow"));
    }

    #[test]
    fn io_error_keeps_path_and_kind() {
        let err = CoreError::io(
            "/nope.ply",
            std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
        );
        assert_eq!(err.to_string(), "/nope.ply: no such file");
        match err {
            CoreError::Io { source, .. } => assert_eq!(source.kind(), std::io::ErrorKind::NotFound),
            _ => unreachable!(),
        }
    }
}
