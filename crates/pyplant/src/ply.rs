//! Bindings of `splat_core::ply`: the vertex element as named, typed columns.
//!
//! Python (`plantdreamer.io`) decides what the columns mean (positions, colours, normals,
//! Gaussians); this layer only moves arrays.

use std::path::PathBuf;

use numpy::{PyArray1, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyList;
use splat_core::ply::{self, Column, ColumnRef, FieldRef, Format};

use crate::errors::InputError;
use crate::run_native;

fn column_to_py<'py>(py: Python<'py>, col: Column) -> Bound<'py, PyAny> {
    match col {
        Column::I8(v) => PyArray1::from_vec(py, v).into_any(),
        Column::U8(v) => PyArray1::from_vec(py, v).into_any(),
        Column::I16(v) => PyArray1::from_vec(py, v).into_any(),
        Column::U16(v) => PyArray1::from_vec(py, v).into_any(),
        Column::I32(v) => PyArray1::from_vec(py, v).into_any(),
        Column::U32(v) => PyArray1::from_vec(py, v).into_any(),
        Column::F32(v) => PyArray1::from_vec(py, v).into_any(),
        Column::F64(v) => PyArray1::from_vec(py, v).into_any(),
    }
}

/// The vertex element as read by `read_ply_vertex`: count, [(names, array)], format,
/// comments, warnings.
type VertexRead<'py> = (
    usize,
    Bound<'py, PyList>,
    &'static str,
    Vec<String>,
    Vec<String>,
);

/// Reads the vertex element: (count, [(names, array)], format, comments, warnings). Each
/// group of `groups` whose properties exist with one type comes back as one
/// [N, len(group)] array; every other scalar property as a 1-D array of its own. Problems
/// after the vertex element are `warnings` (`plantdreamer.io` issues them as PlyWarning),
/// or a PlyError when `strict`.
#[pyfunction]
#[pyo3(signature = (path, groups=Vec::new(), strict=false))]
fn read_ply_vertex<'py>(
    py: Python<'py>,
    path: PathBuf,
    groups: Vec<Vec<String>>,
    strict: bool,
) -> PyResult<VertexRead<'py>> {
    let table = run_native(py, || ply::read_vertex_fields(&path, &groups, strict))?;
    let fields = PyList::empty(py);
    for field in table.fields {
        let width = field.names.len();
        let array = column_to_py(py, field.values);
        let array = if width == 1 {
            array
        } else {
            array.call_method1("reshape", ((table.count, width),))?
        };
        fields.append((field.names, array))?;
    }
    let format = match table.format {
        Format::Ascii => "ascii",
        Format::BinaryLittleEndian => "binary_little_endian",
        Format::BinaryBigEndian => "binary_big_endian",
    };
    Ok((table.count, fields, format, table.comments, table.warnings))
}

/// Checks that the vertex element of the PLY file at `path` will load, from its header and
/// the file's length where they settle it (binary rows of fixed size), else by reading it;
/// raises what the read would raise (PlyError for a file cut short).
#[pyfunction]
fn check_ply_vertex(py: Python<'_>, path: PathBuf) -> PyResult<()> {
    run_native(py, || ply::check_vertex_data(&path))
}

/// A C-contiguous array of one of the eight PLY scalar types, borrowed for the write.
enum Held<'py> {
    I8(PyReadonlyArrayDyn<'py, i8>),
    U8(PyReadonlyArrayDyn<'py, u8>),
    I16(PyReadonlyArrayDyn<'py, i16>),
    U16(PyReadonlyArrayDyn<'py, u16>),
    I32(PyReadonlyArrayDyn<'py, i32>),
    U32(PyReadonlyArrayDyn<'py, u32>),
    F32(PyReadonlyArrayDyn<'py, f32>),
    F64(PyReadonlyArrayDyn<'py, f64>),
}

/// Borrows `obj` as the values of properties `names`: shape [N] for one name, [N, len] for
/// several, C-contiguous.
fn hold<'py>(names: &[String], obj: &Bound<'py, PyAny>) -> PyResult<Held<'py>> {
    let shape_ok = |shape: &[usize]| match shape {
        [_] => names.len() == 1,
        [_, w] => *w == names.len(),
        _ => false,
    };
    macro_rules! try_as {
        ($variant:ident, $t:ty) => {
            if let Ok(a) = obj.extract::<PyReadonlyArrayDyn<'py, $t>>() {
                if !shape_ok(a.shape()) {
                    return Err(InputError::new_err(format!(
                        "values of {names:?} must have shape [N] (one name) or [N, {}], got {:?}",
                        names.len(),
                        a.shape()
                    )));
                }
                if !a.is_c_contiguous() {
                    return Err(InputError::new_err(format!(
                        "values of {names:?} must be C-contiguous"
                    )));
                }
                return Ok(Held::$variant(a));
            }
        };
    }
    try_as!(I8, i8);
    try_as!(U8, u8);
    try_as!(I16, i16);
    try_as!(U16, u16);
    try_as!(I32, i32);
    try_as!(U32, u32);
    try_as!(F32, f32);
    try_as!(F64, f64);
    Err(InputError::new_err(format!(
        "values of {names:?} must be an array of int8/uint8/int16/uint16/int32/uint32/float32/float64"
    )))
}

fn as_ref<'a>(held: &'a Held<'_>) -> PyResult<ColumnRef<'a>> {
    let err = |e: numpy::AsSliceError| InputError::new_err(e.to_string());
    Ok(match held {
        Held::I8(a) => ColumnRef::I8(a.as_slice().map_err(err)?),
        Held::U8(a) => ColumnRef::U8(a.as_slice().map_err(err)?),
        Held::I16(a) => ColumnRef::I16(a.as_slice().map_err(err)?),
        Held::U16(a) => ColumnRef::U16(a.as_slice().map_err(err)?),
        Held::I32(a) => ColumnRef::I32(a.as_slice().map_err(err)?),
        Held::U32(a) => ColumnRef::U32(a.as_slice().map_err(err)?),
        Held::F32(a) => ColumnRef::F32(a.as_slice().map_err(err)?),
        Held::F64(a) => ColumnRef::F64(a.as_slice().map_err(err)?),
    })
}

/// Writes [(names, array)] as the vertex element (binary little endian or ascii); an
/// [N, k] array fills k properties of one type, without splitting it first. The file is
/// replaced atomically: on failure the previous file at `path` is left as it was.
#[pyfunction]
#[pyo3(signature = (path, fields, binary=true, comments=Vec::new()))]
fn write_ply_vertex(
    py: Python<'_>,
    path: PathBuf,
    fields: Vec<(Vec<String>, Bound<'_, PyAny>)>,
    binary: bool,
    comments: Vec<String>,
) -> PyResult<()> {
    let held = fields
        .iter()
        .map(|(names, obj)| hold(names, obj))
        .collect::<PyResult<Vec<_>>>()?;
    let refs = fields
        .iter()
        .zip(&held)
        .map(|((names, _), h)| {
            Ok(FieldRef {
                names: names.iter().map(String::as_str).collect(),
                values: as_ref(h)?,
            })
        })
        .collect::<PyResult<Vec<_>>>()?;
    let comments: Vec<&str> = comments.iter().map(String::as_str).collect();
    run_native(py, || {
        ply::write_vertex_fields(&path, &refs, binary, &comments)
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(read_ply_vertex, m)?)?;
    m.add_function(wrap_pyfunction!(check_ply_vertex, m)?)?;
    m.add_function(wrap_pyfunction!(write_ply_vertex, m)?)?;
    Ok(())
}
