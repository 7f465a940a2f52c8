//! Bindings of `splat_core::ply`: the vertex element as named, typed columns.
//!
//! Python (`plantdreamer.io`) decides what the columns mean (positions, colours, normals,
//! Gaussians); this layer only moves arrays.

use std::path::PathBuf;

use numpy::{PyArray1, PyReadonlyArray1, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyList;
use splat_core::ply::{self, Column, ColumnRef, Format};

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

/// Reads the vertex element: (count, [(names, array)], format, comments). Each group of
/// `groups` whose properties exist with one type comes back as one [N, len(group)] array;
/// every other scalar property as a 1-D array of its own.
#[pyfunction]
#[pyo3(signature = (path, groups=Vec::new()))]
fn read_ply_vertex<'py>(
    py: Python<'py>,
    path: PathBuf,
    groups: Vec<Vec<String>>,
) -> PyResult<(usize, Bound<'py, PyList>, &'static str, Vec<String>)> {
    let table = run_native(py, || ply::read_vertex_fields(&path, &groups))?;
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
    Ok((table.count, fields, format, table.comments))
}

/// A 1-D contiguous array of one of the eight PLY scalar types, borrowed for the write.
enum Held<'py> {
    I8(PyReadonlyArray1<'py, i8>),
    U8(PyReadonlyArray1<'py, u8>),
    I16(PyReadonlyArray1<'py, i16>),
    U16(PyReadonlyArray1<'py, u16>),
    I32(PyReadonlyArray1<'py, i32>),
    U32(PyReadonlyArray1<'py, u32>),
    F32(PyReadonlyArray1<'py, f32>),
    F64(PyReadonlyArray1<'py, f64>),
}

fn hold<'py>(name: &str, obj: &Bound<'py, PyAny>) -> PyResult<Held<'py>> {
    macro_rules! try_as {
        ($variant:ident, $t:ty) => {
            if let Ok(a) = obj.extract::<PyReadonlyArray1<'py, $t>>() {
                if !a.is_c_contiguous() {
                    return Err(InputError::new_err(format!(
                        "column '{name}' must be contiguous"
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
        "column '{name}' must be a 1-D array of int8/uint8/int16/uint16/int32/uint32/float32/float64"
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

/// Writes [(name, 1-D array)] as the vertex element (binary little endian or ascii).
#[pyfunction]
#[pyo3(signature = (path, columns, binary=true, comments=Vec::new()))]
fn write_ply_vertex(
    py: Python<'_>,
    path: PathBuf,
    columns: Vec<(String, Bound<'_, PyAny>)>,
    binary: bool,
    comments: Vec<String>,
) -> PyResult<()> {
    let held = columns
        .iter()
        .map(|(name, obj)| hold(name, obj))
        .collect::<PyResult<Vec<_>>>()?;
    let refs = columns
        .iter()
        .zip(&held)
        .map(|((name, _), h)| Ok((name.as_str(), as_ref(h)?)))
        .collect::<PyResult<Vec<_>>>()?;
    let comments: Vec<&str> = comments.iter().map(String::as_str).collect();
    run_native(py, || {
        ply::write_vertex_columns(&path, &refs, binary, &comments)
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(read_ply_vertex, m)?)?;
    m.add_function(wrap_pyfunction!(write_ply_vertex, m)?)?;
    Ok(())
}
