//! Decoding PLY data into typed columns of the `vertex` element.
//!
//! Binary rows without list properties have a fixed stride, so each column is gathered
//! straight from the byte buffer (in parallel over columns). Rows with lists, and ascii
//! files (`read_ascii.rs`), are walked row by row. Before anything is allocated, the
//! header's element counts are checked against the length of the data (`claims.rs`), so
//! memory is bounded by the file, not by what its header claims.
//!
//! Every element is walked to its end so that a truncated file, a lying element count or
//! trailing garbage is reported instead of silently read. Problems in or before the vertex
//! element are errors. Problems after it (a truncated face element, extra rows at the end,
//! as some writers emit) are errors with `strict`; otherwise the vertex element is returned
//! with a warning that says what was ignored, as plyfile, Open3D and trimesh read them.

use std::path::Path;

use rayon::prelude::*;

use super::claims::check_claimed_sizes;
use super::header::{parse_header, Element, Format, Property, ScalarType};
use super::read_ascii::read_ascii;
use super::Column;
use crate::memory::try_vec;
use crate::{CoreError, CoreResult};

/// The `vertex` element of a PLY file: its scalar properties in header order.
/// List properties of the vertex element are skipped.
#[derive(Debug, Clone, PartialEq)]
pub struct VertexTable {
    pub count: usize,
    pub columns: Vec<(String, Column)>,
    pub format: Format,
    pub comments: Vec<String>,
    /// What a lenient read ignored (see the module documentation); each names the file.
    pub warnings: Vec<String>,
}

/// Properties read together: `values` holds `names.len()` values per row, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Field {
    pub names: Vec<String>,
    pub values: Column,
}

/// The vertex element as fields: each requested group whose properties all exist with one
/// type becomes one interleaved field (e.g. x, y, z as an [N, 3] block, gathered in one
/// pass); every other scalar property is a field of its own. Header order otherwise.
#[derive(Debug, Clone, PartialEq)]
pub struct VertexFields {
    pub count: usize,
    pub fields: Vec<Field>,
    pub format: Format,
    pub comments: Vec<String>,
    /// What a lenient read ignored (see the module documentation); each names the file.
    pub warnings: Vec<String>,
}

/// Reads the `vertex` element of the PLY file at `path`.
pub fn read_vertex_columns(path: &Path, strict: bool) -> CoreResult<VertexTable> {
    let bytes = std::fs::read(path).map_err(|e| CoreError::io(path, e))?;
    read_vertex_columns_from_bytes(&bytes, path, strict)
}

/// Reads the `vertex` element from the bytes of a whole PLY file; `path` names it in errors.
pub fn read_vertex_columns_from_bytes(
    bytes: &[u8],
    path: &Path,
    strict: bool,
) -> CoreResult<VertexTable> {
    let f = read_vertex_fields_from_bytes(bytes, path, &[], strict)?;
    let columns = f
        .fields
        .into_iter()
        .map(|mut field| (field.names.swap_remove(0), field.values))
        .collect();
    Ok(VertexTable {
        count: f.count,
        columns,
        format: f.format,
        comments: f.comments,
        warnings: f.warnings,
    })
}

/// Reads the `vertex` element of the file at `path`, grouping properties (see `VertexFields`).
pub fn read_vertex_fields(
    path: &Path,
    groups: &[Vec<String>],
    strict: bool,
) -> CoreResult<VertexFields> {
    let bytes = std::fs::read(path).map_err(|e| CoreError::io(path, e))?;
    read_vertex_fields_from_bytes(&bytes, path, groups, strict)
}

pub fn read_vertex_fields_from_bytes(
    bytes: &[u8],
    path: &Path,
    groups: &[Vec<String>],
    strict: bool,
) -> CoreResult<VertexFields> {
    let header = parse_header(bytes, path)?;
    let err = |msg: String| CoreError::ply(path, msg);
    let vertex = header
        .elements
        .iter()
        .position(|e| e.name == "vertex")
        .ok_or_else(|| err("the file has no 'vertex' element".into()))?;
    let data = &bytes[header.data_start..];
    check_claimed_sizes(&header.elements[..=vertex], header.format, data.len()).map_err(err)?;
    let failed = |failure| match failure {
        Failure::Data(problem) => err(problem),
        Failure::Memory(memory) => memory,
    };
    let plan = plan(&header.elements[vertex], groups);
    let mut lenience = Lenience {
        strict,
        warnings: Vec::new(),
    };
    let columns = match header.format {
        Format::Ascii => read_ascii(data, &header.elements, vertex, &mut lenience),
        Format::BinaryLittleEndian => {
            read_binary(data, &header.elements, vertex, false, &plan, &mut lenience)
        }
        Format::BinaryBigEndian => {
            read_binary(data, &header.elements, vertex, true, &plan, &mut lenience)
        }
    }
    .map_err(failed)?;
    let fields = match columns {
        Decoded::Fields(fields) => fields,
        Decoded::Columns(cols) => assemble(cols, &plan),
    };
    Ok(VertexFields {
        count: header.elements[vertex].count,
        fields,
        format: header.format,
        comments: header.comments,
        warnings: lenience
            .warnings
            .into_iter()
            .map(|w| format!("{}: {w}", path.display()))
            .collect(),
    })
}

/// What becomes of a problem found after the vertex element: an error when strict, else a
/// warning (the caller then stops reading and returns the vertex element).
pub(super) struct Lenience {
    strict: bool,
    warnings: Vec<String>,
}

impl Lenience {
    pub(super) fn past_vertex(&mut self, problem: String) -> Result<(), String> {
        if self.strict {
            return Err(problem);
        }
        self.warnings.push(format!(
            "{problem} (read the vertex element, which is complete, and ignored the rest)"
        ));
        Ok(())
    }
}

/// One planned field: (name, scalar index, byte offset in a fixed row) per member, and type.
struct Planned {
    members: Vec<(String, usize, usize)>,
    ty: ScalarType,
}

fn plan(element: &Element, groups: &[Vec<String>]) -> Vec<Planned> {
    let mut scalars = Vec::new();
    let mut offset = 0;
    for p in &element.properties {
        if let Property::Scalar { name, ty } = p {
            scalars.push((name.clone(), scalars.len(), offset, *ty));
            offset += ty.size();
        }
    }
    let mut taken = vec![false; scalars.len()];
    let mut planned: Vec<(usize, Planned)> = Vec::new();
    for group in groups {
        let found: Option<Vec<&(String, usize, usize, ScalarType)>> = group
            .iter()
            .map(|g| scalars.iter().find(|s| &s.0 == g))
            .collect();
        let Some(found) = found else { continue };
        let ty = found.first().map(|f| f.3);
        if found.is_empty() || found.iter().any(|f| Some(f.3) != ty || taken[f.1]) {
            continue;
        }
        for f in &found {
            taken[f.1] = true;
        }
        let first = found.iter().map(|f| f.1).min().unwrap_or(0);
        let members = found.iter().map(|f| (f.0.clone(), f.1, f.2)).collect();
        planned.push((
            first,
            Planned {
                members,
                ty: found[0].3,
            },
        ));
    }
    for s in &scalars {
        if !taken[s.1] {
            planned.push((
                s.1,
                Planned {
                    members: vec![(s.0.clone(), s.1, s.2)],
                    ty: s.3,
                },
            ));
        }
    }
    planned.sort_by_key(|p| p.0);
    planned.into_iter().map(|p| p.1).collect()
}

pub(super) enum Decoded {
    /// Fields already assembled by the fast path.
    Fields(Vec<Field>),
    /// One column per scalar property, in header order.
    Columns(Vec<Column>),
}

fn assemble(mut cols: Vec<Column>, plan: &[Planned]) -> Vec<Field> {
    plan.iter()
        .map(|p| {
            let names = p.members.iter().map(|m| m.0.clone()).collect();
            let values = if p.members.len() == 1 {
                std::mem::replace(&mut cols[p.members[0].1], Column::U8(Vec::new()))
            } else {
                let parts: Vec<&Column> = p.members.iter().map(|m| &cols[m.1]).collect();
                interleave(&parts)
            };
            Field { names, values }
        })
        .collect()
}

/// Row-major interleaving of same-typed columns.
fn interleave(parts: &[&Column]) -> Column {
    macro_rules! go {
        ($variant:ident) => {{
            let cols: Vec<&Vec<_>> = parts
                .iter()
                .filter_map(|c| match c {
                    Column::$variant(v) => Some(v),
                    _ => None,
                })
                .collect();
            let n = cols.first().map_or(0, |c| c.len());
            Column::$variant(
                (0..n)
                    .flat_map(|i| cols.iter().map(move |c| c[i]))
                    .collect(),
            )
        }};
    }
    match parts[0] {
        Column::I8(_) => go!(I8),
        Column::U8(_) => go!(U8),
        Column::I16(_) => go!(I16),
        Column::U16(_) => go!(U16),
        Column::I32(_) => go!(I32),
        Column::U32(_) => go!(U32),
        Column::F32(_) => go!(F32),
        Column::F64(_) => go!(F64),
    }
}

pub(super) fn scalar_names(element: &Element) -> impl Iterator<Item = (&str, ScalarType)> {
    element.properties.iter().filter_map(|p| match p {
        Property::Scalar { name, ty } => Some((name.as_str(), *ty)),
        Property::List { .. } => None,
    })
}

/// A decode that failed: its data (a PlyError naming the file) or the memory for its
/// columns (`CoreError::OutOfMemory`, never an abort: `memory.rs`).
pub(super) enum Failure {
    Data(String),
    Memory(CoreError),
}

impl From<String> for Failure {
    fn from(problem: String) -> Self {
        Failure::Data(problem)
    }
}

/// An empty column with room for `capacity` values, reserved fallibly.
pub(super) fn empty_column(ty: ScalarType, capacity: usize) -> Result<Column, Failure> {
    Ok(match ty {
        ScalarType::I8 => Column::I8(try_vec(capacity).map_err(Failure::Memory)?),
        ScalarType::U8 => Column::U8(try_vec(capacity).map_err(Failure::Memory)?),
        ScalarType::I16 => Column::I16(try_vec(capacity).map_err(Failure::Memory)?),
        ScalarType::U16 => Column::U16(try_vec(capacity).map_err(Failure::Memory)?),
        ScalarType::I32 => Column::I32(try_vec(capacity).map_err(Failure::Memory)?),
        ScalarType::U32 => Column::U32(try_vec(capacity).map_err(Failure::Memory)?),
        ScalarType::F32 => Column::F32(try_vec(capacity).map_err(Failure::Memory)?),
        ScalarType::F64 => Column::F64(try_vec(capacity).map_err(Failure::Memory)?),
    })
}

// ---------------------------------------------------------------------------------------
// Binary

macro_rules! array {
    ($bytes:expr) => {
        // The slice always has the array's length (it is cut with the type's size).
        $bytes.try_into().unwrap_or_default()
    };
}

macro_rules! decode {
    ($t:ty, $bytes:expr, $be:expr) => {{
        let raw = array!($bytes);
        if $be {
            <$t>::from_be_bytes(raw)
        } else {
            <$t>::from_le_bytes(raw)
        }
    }};
}

/// Gathers one field (its members' byte offsets) from fixed-stride rows, row-major.
fn gather(
    rows: &[u8],
    stride: usize,
    offsets: &[usize],
    ty: ScalarType,
    be: bool,
) -> Result<Column, Failure> {
    macro_rules! go {
        ($variant:ident, $t:ty) => {{
            const S: usize = std::mem::size_of::<$t>();
            let mut out = try_vec(rows.len() / stride * offsets.len()).map_err(Failure::Memory)?;
            match offsets {
                [o] => out.extend(
                    rows.chunks_exact(stride)
                        .map(|row| decode!($t, &row[*o..*o + S], be)),
                ),
                [a, b, c] => {
                    for row in rows.chunks_exact(stride) {
                        out.push(decode!($t, &row[*a..*a + S], be));
                        out.push(decode!($t, &row[*b..*b + S], be));
                        out.push(decode!($t, &row[*c..*c + S], be));
                    }
                }
                _ => {
                    for row in rows.chunks_exact(stride) {
                        for &o in offsets {
                            out.push(decode!($t, &row[o..o + S], be));
                        }
                    }
                }
            }
            Column::$variant(out)
        }};
    }
    Ok(match ty {
        ScalarType::I8 => go!(I8, i8),
        ScalarType::U8 => go!(U8, u8),
        ScalarType::I16 => go!(I16, i16),
        ScalarType::U16 => go!(U16, u16),
        ScalarType::I32 => go!(I32, i32),
        ScalarType::U32 => go!(U32, u32),
        ScalarType::F32 => go!(F32, f32),
        ScalarType::F64 => go!(F64, f64),
    })
}

fn push_binary(column: &mut Column, bytes: &[u8], be: bool) {
    match column {
        Column::I8(v) => v.push(decode!(i8, bytes, be)),
        Column::U8(v) => v.push(decode!(u8, bytes, be)),
        Column::I16(v) => v.push(decode!(i16, bytes, be)),
        Column::U16(v) => v.push(decode!(u16, bytes, be)),
        Column::I32(v) => v.push(decode!(i32, bytes, be)),
        Column::U32(v) => v.push(decode!(u32, bytes, be)),
        Column::F32(v) => v.push(decode!(f32, bytes, be)),
        Column::F64(v) => v.push(decode!(f64, bytes, be)),
    }
}

/// Reads a list length (an integer of type `ty`) and rejects negative ones.
fn list_len(bytes: &[u8], ty: ScalarType, be: bool) -> Result<usize, String> {
    let n: i64 = match ty {
        ScalarType::I8 => decode!(i8, bytes, be).into(),
        ScalarType::U8 => decode!(u8, bytes, be).into(),
        ScalarType::I16 => decode!(i16, bytes, be).into(),
        ScalarType::U16 => decode!(u16, bytes, be).into(),
        ScalarType::I32 => decode!(i32, bytes, be).into(),
        ScalarType::U32 => decode!(u32, bytes, be).into(),
        ScalarType::F32 | ScalarType::F64 => return Err("list count of a float type".into()),
    };
    usize::try_from(n).map_err(|_| format!("negative list length {n}"))
}

fn truncated(element: &Element, row: usize) -> String {
    format!(
        "truncated file: element '{}' declares {} rows but the data ends in row {row}",
        element.name, element.count
    )
}

/// Walks one element with list properties; pushes its scalars into `columns` if given.
/// Returns the number of bytes the element occupies.
fn walk_binary_rows(
    data: &[u8],
    element: &Element,
    be: bool,
    mut columns: Option<&mut Vec<Column>>,
) -> Result<usize, String> {
    let mut pos = 0usize;
    for row in 0..element.count {
        let mut scalar = 0;
        for p in &element.properties {
            match p {
                Property::Scalar { ty, .. } => {
                    let end = pos + ty.size();
                    let bytes = data.get(pos..end).ok_or_else(|| truncated(element, row))?;
                    if let Some(cols) = columns.as_deref_mut() {
                        push_binary(&mut cols[scalar], bytes, be);
                    }
                    scalar += 1;
                    pos = end;
                }
                Property::List {
                    name,
                    count_ty,
                    item_ty,
                } => {
                    let end = pos + count_ty.size();
                    let bytes = data.get(pos..end).ok_or_else(|| truncated(element, row))?;
                    let n = list_len(bytes, *count_ty, be).map_err(|e| {
                        format!("element '{}' row {row}, list '{name}': {e}", element.name)
                    })?;
                    let len = n
                        .checked_mul(item_ty.size())
                        .ok_or_else(|| truncated(element, row))?;
                    pos = end
                        .checked_add(len)
                        .filter(|&e| e <= data.len())
                        .ok_or_else(|| truncated(element, row))?;
                }
            }
        }
    }
    Ok(pos)
}

fn read_binary(
    data: &[u8],
    elements: &[Element],
    vertex: usize,
    be: bool,
    plan: &[Planned],
    lenience: &mut Lenience,
) -> Result<Decoded, Failure> {
    let mut pos = 0usize;
    let mut out = Decoded::Columns(Vec::new());
    for (i, element) in elements.iter().enumerate() {
        let rest = &data[pos..];
        if i == vertex {
            let (decoded, len) = read_binary_vertex(rest, element, be, plan)?;
            out = decoded;
            pos += len;
            continue;
        }
        let len = match element.fixed_row_size() {
            Some(stride) => fixed_len(rest, element, stride),
            None => walk_binary_rows(rest, element, be, None),
        };
        match len {
            Ok(len) => pos += len,
            Err(problem) if i > vertex => {
                lenience.past_vertex(problem)?;
                return Ok(out);
            }
            Err(problem) => return Err(problem.into()),
        }
    }
    let trailing = &data[pos..];
    if trailing.iter().any(|b| !b.is_ascii_whitespace()) {
        lenience.past_vertex(format!(
            "{} bytes of data after the last element: the header's element counts do not match the file",
            trailing.len()
        ))?;
    }
    Ok(out)
}

/// Bytes of an element of fixed-size rows, if the data holds them.
fn fixed_len(rest: &[u8], element: &Element, stride: usize) -> Result<usize, String> {
    element
        .count
        .checked_mul(stride)
        .filter(|&len| len <= rest.len())
        .ok_or_else(|| {
            format!(
                "truncated file: element '{}' declares {} rows of {stride} bytes but only {} bytes of data follow",
                element.name, element.count, rest.len()
            )
        })
}

/// Decodes the vertex element at the start of `rest`; returns it and the bytes it takes.
fn read_binary_vertex(
    rest: &[u8],
    element: &Element,
    be: bool,
    plan: &[Planned],
) -> Result<(Decoded, usize), Failure> {
    if let Some(stride) = element.fixed_row_size() {
        let len = fixed_len(rest, element, stride)?;
        let rows = &rest[..len];
        let fields = plan
            .par_iter()
            .map(|p| {
                let offsets: Vec<usize> = p.members.iter().map(|m| m.2).collect();
                let values = if stride == 0 {
                    empty_column(p.ty, 0)?
                } else {
                    gather(rows, stride, &offsets, p.ty, be)?
                };
                Ok(Field {
                    names: p.members.iter().map(|m| m.0.clone()).collect(),
                    values,
                })
            })
            .collect::<Result<Vec<_>, Failure>>()?;
        return Ok((Decoded::Fields(fields), len));
    }
    // The header's count was checked against the data length (claims.rs): the columns'
    // capacity is bounded by the file.
    let mut cols: Vec<Column> = scalar_names(element)
        .map(|(_, ty)| empty_column(ty, element.count))
        .collect::<Result<_, _>>()?;
    let len = walk_binary_rows(rest, element, be, Some(&mut cols))?;
    Ok((Decoded::Columns(cols), len))
}
