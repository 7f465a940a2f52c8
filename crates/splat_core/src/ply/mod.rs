//! PLY files: a hand-written reader and writer for the `vertex` element.
//!
//! Why not a crate: ply-rs(-bw) parses every row into a `HashMap<String, Property>`, which
//! costs ~1 s per million vertices; plyfile + numpy reads the same file in ~30 ms. Reading
//! whole columns straight out of the byte buffer (`read.rs`) is what makes us at least as
//! fast (see benches/results/pointcloud.md). The format is small: `header.rs` parses the
//! text header, `read.rs` decodes ascii / binary little / big endian data into typed
//! columns, `write.rs` writes typed columns back.
//!
//! Only the `vertex` element is returned; other elements (faces, edges, ...) are parsed
//! only to find where they end, so a truncated file or a lying header is still detected
//! (an error before the vertex element, a warning after it unless the read is strict).
//! `claims.rs` checks the header's counts against the file's length before any
//! allocation (`check.rs`: the same check alone, before a command deletes anything);
//! `read_ascii.rs` decodes ascii data. Files are written atomically.

mod check;
mod claims;
mod header;
mod read;
mod read_ascii;
mod write;

pub use check::check_vertex_data;
pub use header::{parse_header, Element, Format, Header, Property, ScalarType};
pub use read::{
    read_vertex_columns, read_vertex_columns_from_bytes, read_vertex_fields,
    read_vertex_fields_from_bytes, Field, VertexFields, VertexTable,
};
pub use write::{
    write_vertex_columns, write_vertex_columns_to_vec, write_vertex_fields,
    write_vertex_fields_to_vec, FieldRef,
};

/// One decoded scalar property: a column of `count` values in the file's type.
#[derive(Debug, Clone, PartialEq)]
pub enum Column {
    I8(Vec<i8>),
    U8(Vec<u8>),
    I16(Vec<i16>),
    U16(Vec<u16>),
    I32(Vec<i32>),
    U32(Vec<u32>),
    F32(Vec<f32>),
    F64(Vec<f64>),
}

/// A borrowed column to write; the variant decides the PLY type.
#[derive(Debug, Clone, Copy)]
pub enum ColumnRef<'a> {
    I8(&'a [i8]),
    U8(&'a [u8]),
    I16(&'a [i16]),
    U16(&'a [u16]),
    I32(&'a [i32]),
    U32(&'a [u32]),
    F32(&'a [f32]),
    F64(&'a [f64]),
}

impl Column {
    pub fn scalar_type(&self) -> ScalarType {
        match self {
            Column::I8(_) => ScalarType::I8,
            Column::U8(_) => ScalarType::U8,
            Column::I16(_) => ScalarType::I16,
            Column::U16(_) => ScalarType::U16,
            Column::I32(_) => ScalarType::I32,
            Column::U32(_) => ScalarType::U32,
            Column::F32(_) => ScalarType::F32,
            Column::F64(_) => ScalarType::F64,
        }
    }

    pub fn len(&self) -> usize {
        self.as_ref().len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn as_ref(&self) -> ColumnRef<'_> {
        match self {
            Column::I8(v) => ColumnRef::I8(v),
            Column::U8(v) => ColumnRef::U8(v),
            Column::I16(v) => ColumnRef::I16(v),
            Column::U16(v) => ColumnRef::U16(v),
            Column::I32(v) => ColumnRef::I32(v),
            Column::U32(v) => ColumnRef::U32(v),
            Column::F32(v) => ColumnRef::F32(v),
            Column::F64(v) => ColumnRef::F64(v),
        }
    }
}

impl ColumnRef<'_> {
    pub fn scalar_type(&self) -> ScalarType {
        match self {
            ColumnRef::I8(_) => ScalarType::I8,
            ColumnRef::U8(_) => ScalarType::U8,
            ColumnRef::I16(_) => ScalarType::I16,
            ColumnRef::U16(_) => ScalarType::U16,
            ColumnRef::I32(_) => ScalarType::I32,
            ColumnRef::U32(_) => ScalarType::U32,
            ColumnRef::F32(_) => ScalarType::F32,
            ColumnRef::F64(_) => ScalarType::F64,
        }
    }

    pub fn len(&self) -> usize {
        match self {
            ColumnRef::I8(v) => v.len(),
            ColumnRef::U8(v) => v.len(),
            ColumnRef::I16(v) => v.len(),
            ColumnRef::U16(v) => v.len(),
            ColumnRef::I32(v) => v.len(),
            ColumnRef::U32(v) => v.len(),
            ColumnRef::F32(v) => v.len(),
            ColumnRef::F64(v) => v.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}
