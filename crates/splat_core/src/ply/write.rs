//! Writing typed columns as the `vertex` element of a PLY file.
//!
//! Binary files are always little endian (what every 3DGS viewer expects). Rows are
//! interleaved in parallel over fixed chunks, so the bytes do not depend on the thread count.
//! ASCII floats use Rust's shortest round-trip formatting, so ascii files round-trip too.

use std::io::Write;
use std::path::Path;

use rayon::prelude::*;

use super::ColumnRef;
use crate::{CoreError, CoreResult};

const CHUNK_ROWS: usize = 16 * 1024;

/// Writes `columns` (name, values) as the vertex element of a PLY file at `path`.
pub fn write_vertex_columns(
    path: &Path,
    columns: &[(&str, ColumnRef<'_>)],
    binary: bool,
    comments: &[&str],
) -> CoreResult<()> {
    let bytes = write_vertex_columns_to_vec(columns, binary, comments)?;
    let mut file = std::fs::File::create(path).map_err(|e| CoreError::io(path, e))?;
    file.write_all(&bytes).map_err(|e| CoreError::io(path, e))?;
    Ok(())
}

fn check_columns(columns: &[(&str, ColumnRef<'_>)], comments: &[&str]) -> CoreResult<usize> {
    let n = columns.first().map_or(0, |(_, c)| c.len());
    for (i, (name, col)) in columns.iter().enumerate() {
        if name.is_empty() || name.chars().any(|c| c.is_whitespace() || c.is_control()) {
            return Err(CoreError::input(format!(
                "PLY property name {name:?} must be non-empty without whitespace"
            )));
        }
        if columns[..i].iter().any(|(other, _)| other == name) {
            return Err(CoreError::input(format!(
                "PLY property '{name}' appears twice"
            )));
        }
        if col.len() != n {
            return Err(CoreError::input(format!(
                "PLY property '{name}' has {} values, the first property has {n}",
                col.len()
            )));
        }
    }
    if let Some(c) = comments.iter().find(|c| c.contains(['\n', '\r'])) {
        return Err(CoreError::input(format!(
            "PLY comment {c:?} must be one line"
        )));
    }
    Ok(n)
}

/// The bytes of the PLY file `write_vertex_columns` would write.
pub fn write_vertex_columns_to_vec(
    columns: &[(&str, ColumnRef<'_>)],
    binary: bool,
    comments: &[&str],
) -> CoreResult<Vec<u8>> {
    let n = check_columns(columns, comments)?;
    let mut out = String::from("ply\n");
    out += if binary {
        "format binary_little_endian 1.0\n"
    } else {
        "format ascii 1.0\n"
    };
    for c in comments {
        out += &format!("comment {c}\n");
    }
    out += &format!("element vertex {n}\n");
    for (name, col) in columns {
        out += &format!("property {} {name}\n", col.scalar_type().ply_name());
    }
    out += "end_header\n";
    let mut bytes = out.into_bytes();
    if binary {
        bytes.extend_from_slice(&binary_rows(columns, n));
    } else {
        bytes.extend_from_slice(ascii_rows(columns, n).as_bytes());
    }
    Ok(bytes)
}

fn binary_rows(columns: &[(&str, ColumnRef<'_>)], n: usize) -> Vec<u8> {
    let stride: usize = columns.iter().map(|(_, c)| c.scalar_type().size()).sum();
    let mut buf = vec![0u8; n * stride];
    if stride == 0 {
        return buf;
    }
    buf.par_chunks_mut(stride * CHUNK_ROWS)
        .enumerate()
        .for_each(|(chunk, out)| {
            let first = chunk * CHUNK_ROWS;
            let mut offset = 0;
            for (_, col) in columns {
                macro_rules! go {
                    ($v:expr) => {{
                        let values = &$v[first..first + out.len() / stride];
                        let size = std::mem::size_of_val(&values[0]);
                        for (row, value) in out.chunks_exact_mut(stride).zip(values) {
                            row[offset..offset + size].copy_from_slice(&value.to_le_bytes());
                        }
                        size
                    }};
                }
                offset += match col {
                    ColumnRef::I8(v) => go!(v),
                    ColumnRef::U8(v) => go!(v),
                    ColumnRef::I16(v) => go!(v),
                    ColumnRef::U16(v) => go!(v),
                    ColumnRef::I32(v) => go!(v),
                    ColumnRef::U32(v) => go!(v),
                    ColumnRef::F32(v) => go!(v),
                    ColumnRef::F64(v) => go!(v),
                };
            }
        });
    buf
}

fn ascii_rows(columns: &[(&str, ColumnRef<'_>)], n: usize) -> String {
    use std::fmt::Write as _;
    let chunks: Vec<String> = (0..n.div_ceil(CHUNK_ROWS))
        .into_par_iter()
        .map(|chunk| {
            let mut s = String::new();
            for row in chunk * CHUNK_ROWS..((chunk + 1) * CHUNK_ROWS).min(n) {
                for (i, (_, col)) in columns.iter().enumerate() {
                    if i > 0 {
                        s.push(' ');
                    }
                    // Writing to a String cannot fail.
                    let _ = match col {
                        ColumnRef::I8(v) => write!(s, "{}", v[row]),
                        ColumnRef::U8(v) => write!(s, "{}", v[row]),
                        ColumnRef::I16(v) => write!(s, "{}", v[row]),
                        ColumnRef::U16(v) => write!(s, "{}", v[row]),
                        ColumnRef::I32(v) => write!(s, "{}", v[row]),
                        ColumnRef::U32(v) => write!(s, "{}", v[row]),
                        ColumnRef::F32(v) => write!(s, "{:?}", v[row]),
                        ColumnRef::F64(v) => write!(s, "{:?}", v[row]),
                    };
                }
                s.push('\n');
            }
            s
        })
        .collect();
    chunks.concat()
}
