//! Writing typed fields as the `vertex` element of a PLY file.
//!
//! A field is one or more properties of one type stored row-major (x, y, z as an [N, 3]
//! block, or one column), so callers hand over their arrays without splitting them first.
//! Binary files are always little endian (what every 3DGS viewer expects). Rows are
//! interleaved in parallel over fixed chunks, so the bytes do not depend on the thread count.
//! ASCII floats use Rust's shortest round-trip formatting, so ascii files round-trip too.

use std::path::Path;

use rayon::prelude::*;

use super::ColumnRef;
use crate::atomic_file::write_atomic;
use crate::memory::try_grow;
use crate::{CoreError, CoreResult};

const CHUNK_ROWS: usize = 16 * 1024;

/// Properties `names` stored row-major in `values` (`names.len()` values per row).
#[derive(Debug, Clone)]
pub struct FieldRef<'a> {
    pub names: Vec<&'a str>,
    pub values: ColumnRef<'a>,
}

/// Writes `columns` (name, values) as the vertex element of a PLY file at `path`.
pub fn write_vertex_columns(
    path: &Path,
    columns: &[(&str, ColumnRef<'_>)],
    binary: bool,
    comments: &[&str],
) -> CoreResult<()> {
    write_vertex_fields(path, &singles(columns), binary, comments)
}

/// The bytes of the PLY file `write_vertex_columns` would write.
pub fn write_vertex_columns_to_vec(
    columns: &[(&str, ColumnRef<'_>)],
    binary: bool,
    comments: &[&str],
) -> CoreResult<Vec<u8>> {
    write_vertex_fields_to_vec(&singles(columns), binary, comments)
}

fn singles<'a>(columns: &[(&'a str, ColumnRef<'a>)]) -> Vec<FieldRef<'a>> {
    columns
        .iter()
        .map(|(name, values)| FieldRef {
            names: vec![*name],
            values: *values,
        })
        .collect()
}

/// Writes `fields` as the vertex element of a PLY file at `path`, atomically: on failure the
/// previous file at `path` is left as it was.
pub fn write_vertex_fields(
    path: &Path,
    fields: &[FieldRef<'_>],
    binary: bool,
    comments: &[&str],
) -> CoreResult<()> {
    let bytes = write_vertex_fields_to_vec(fields, binary, comments)?;
    write_atomic(path, &bytes)
}

/// Checks names and lengths; returns the row count.
fn check_fields(fields: &[FieldRef<'_>], comments: &[&str]) -> CoreResult<usize> {
    let mut n = None;
    let mut seen: Vec<&str> = Vec::new();
    for field in fields {
        let width = field.names.len();
        if width == 0 {
            return Err(CoreError::input(
                "a PLY field needs at least one property name",
            ));
        }
        for name in &field.names {
            if name.is_empty() || name.chars().any(|c| c.is_whitespace() || c.is_control()) {
                return Err(CoreError::input(format!(
                    "PLY property name {name:?} must be non-empty without whitespace"
                )));
            }
            if !name.is_ascii() {
                return Err(CoreError::input(format!(
                    "PLY property name {name:?} must be ASCII (other readers, plyfile among \
                     them, reject other characters in a header)"
                )));
            }
            if seen.contains(name) {
                return Err(CoreError::input(format!(
                    "PLY property '{name}' appears twice"
                )));
            }
            seen.push(name);
        }
        let len = field.values.len();
        if len % width != 0 {
            return Err(CoreError::input(format!(
                "PLY properties {:?}: {len} values do not fill rows of {width}",
                field.names
            )));
        }
        let rows = len / width;
        match n {
            None => n = Some(rows),
            Some(n) if n != rows => {
                return Err(CoreError::input(format!(
                    "PLY properties {:?} have {rows} rows, the first field has {n}",
                    field.names
                )))
            }
            Some(_) => {}
        }
    }
    if let Some(c) = comments.iter().find(|c| c.contains(['\n', '\r'])) {
        return Err(CoreError::input(format!(
            "PLY comment {c:?} must be one line"
        )));
    }
    if let Some(c) = comments.iter().find(|c| !c.is_ascii()) {
        return Err(CoreError::input(format!(
            "PLY comment {c:?} must be ASCII (other readers, plyfile among them, reject \
             other characters in a header)"
        )));
    }
    Ok(n.unwrap_or(0))
}

/// The bytes of the PLY file `write_vertex_fields` would write.
pub fn write_vertex_fields_to_vec(
    fields: &[FieldRef<'_>],
    binary: bool,
    comments: &[&str],
) -> CoreResult<Vec<u8>> {
    let n = check_fields(fields, comments)?;
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
    for field in fields {
        for name in &field.names {
            out += &format!(
                "property {} {name}\n",
                field.values.scalar_type().ply_name()
            );
        }
    }
    out += "end_header\n";
    let mut bytes = out.into_bytes();
    if binary {
        let stride = row_bytes(fields);
        let size = n.checked_mul(stride).ok_or(CoreError::OutOfMemory {
            bytes: n as u128 * stride as u128,
        })?;
        let header = bytes.len();
        try_grow(&mut bytes, size)?; // the rows are written in place: one buffer
        bytes.resize(header + size, 0);
        binary_rows(fields, stride, &mut bytes[header..]);
    } else {
        bytes.extend_from_slice(ascii_rows(fields, n).as_bytes());
    }
    Ok(bytes)
}

/// Bytes of one binary row.
fn row_bytes(fields: &[FieldRef<'_>]) -> usize {
    fields
        .iter()
        .map(|f| f.names.len() * f.values.scalar_type().size())
        .sum()
}

/// The binary rows into `buf` (`stride` bytes each).
fn binary_rows(fields: &[FieldRef<'_>], stride: usize, buf: &mut [u8]) {
    if stride == 0 {
        return;
    }
    buf.par_chunks_mut(stride * CHUNK_ROWS)
        .enumerate()
        .for_each(|(chunk, out)| {
            let first = chunk * CHUNK_ROWS;
            let rows = out.len() / stride;
            let mut offset = 0;
            for field in fields {
                let w = field.names.len();
                macro_rules! go {
                    ($v:expr) => {{
                        let values = &$v[first * w..(first + rows) * w];
                        let size = std::mem::size_of_val(&values[0]);
                        for (row, vals) in out.chunks_exact_mut(stride).zip(values.chunks_exact(w))
                        {
                            for (j, value) in vals.iter().enumerate() {
                                let at = offset + j * size;
                                row[at..at + size].copy_from_slice(&value.to_le_bytes());
                            }
                        }
                        size * w
                    }};
                }
                offset += match field.values {
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
}

fn ascii_rows(fields: &[FieldRef<'_>], n: usize) -> String {
    use std::fmt::Write as _;
    let chunks: Vec<String> = (0..n.div_ceil(CHUNK_ROWS))
        .into_par_iter()
        .map(|chunk| {
            let mut s = String::new();
            for row in chunk * CHUNK_ROWS..((chunk + 1) * CHUNK_ROWS).min(n) {
                let mut first = true;
                for field in fields {
                    let w = field.names.len();
                    for i in row * w..(row + 1) * w {
                        if !first {
                            s.push(' ');
                        }
                        first = false;
                        // Writing to a String cannot fail.
                        let _ = match field.values {
                            ColumnRef::I8(v) => write!(s, "{}", v[i]),
                            ColumnRef::U8(v) => write!(s, "{}", v[i]),
                            ColumnRef::I16(v) => write!(s, "{}", v[i]),
                            ColumnRef::U16(v) => write!(s, "{}", v[i]),
                            ColumnRef::I32(v) => write!(s, "{}", v[i]),
                            ColumnRef::U32(v) => write!(s, "{}", v[i]),
                            ColumnRef::F32(v) => write!(s, "{:?}", v[i]),
                            ColumnRef::F64(v) => write!(s, "{:?}", v[i]),
                        };
                    }
                }
                s.push('\n');
            }
            s
        })
        .collect();
    chunks.concat()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ply::read_vertex_columns_from_bytes;
    use crate::ply::Column;

    #[test]
    fn blocks_and_columns_round_trip_in_both_formats() {
        let xyz = [1.0f32, 2.0, 3.0, -4.5, 5.25, f32::MIN_POSITIVE];
        let rgb = [0u8, 128, 255, 7, 8, 9];
        let label = [-3i32, 70000];
        for binary in [true, false] {
            let fields = [
                FieldRef {
                    names: vec!["x", "y", "z"],
                    values: ColumnRef::F32(&xyz),
                },
                FieldRef {
                    names: vec!["red", "green", "blue"],
                    values: ColumnRef::U8(&rgb),
                },
                FieldRef {
                    names: vec!["label"],
                    values: ColumnRef::I32(&label),
                },
            ];
            let bytes = write_vertex_fields_to_vec(&fields, binary, &["hi"]).unwrap();
            let t = read_vertex_columns_from_bytes(&bytes, Path::new("t.ply"), true).unwrap();
            assert_eq!(t.count, 2);
            assert_eq!(
                t.columns[1],
                ("y".to_string(), Column::F32(vec![2.0, 5.25]))
            );
            assert_eq!(t.columns[5], ("blue".to_string(), Column::U8(vec![255, 9])));
            assert_eq!(
                t.columns[6],
                ("label".to_string(), Column::I32(vec![-3, 70000]))
            );
            assert_eq!(t.comments, vec!["hi".to_string()]);
        }
    }

    #[test]
    fn inconsistent_fields_are_input_errors() {
        let a = [1.0f32; 6];
        let b = [1u8; 3];
        let bad = [
            vec![FieldRef {
                names: vec!["x", "y", "z"],
                values: ColumnRef::F32(&a[..5]),
            }],
            vec![
                FieldRef {
                    names: vec!["x", "y", "z"],
                    values: ColumnRef::F32(&a),
                },
                FieldRef {
                    names: vec!["r"],
                    values: ColumnRef::U8(&b),
                },
            ],
            vec![FieldRef {
                names: vec!["x", "x"],
                values: ColumnRef::F32(&a),
            }],
            vec![FieldRef {
                names: vec!["a b"],
                values: ColumnRef::U8(&b),
            }],
            vec![FieldRef {
                names: vec![],
                values: ColumnRef::U8(&b),
            }],
        ];
        for fields in bad {
            assert!(matches!(
                write_vertex_fields_to_vec(&fields, true, &[]),
                Err(CoreError::Input(_))
            ));
        }
        let one = [FieldRef {
            names: vec!["x"],
            values: ColumnRef::U8(&b),
        }];
        assert!(write_vertex_fields_to_vec(&one, true, &["two\nlines"]).is_err());
        let accented = [FieldRef {
            names: vec!["\u{e9}t\u{e9}"],
            values: ColumnRef::U8(&b),
        }];
        for (fields, comments) in [(&accented[..], &[][..]), (&one[..], &["caf\u{e9}"][..])] {
            let err = write_vertex_fields_to_vec(fields, true, comments).unwrap_err();
            assert!(matches!(err, CoreError::Input(_)), "{err}");
            assert!(err.to_string().contains("ASCII"), "{err}");
        }
    }
}
