//! Whether a PLY file's vertex element will load, known before a command deletes anything
//! and without reading its data where the header settles it.
//!
//! The header is read (its first MiB at most) and its claims checked against the file's
//! length (`claims.rs`): in a binary file whose elements up to the vertex element have
//! fixed-size rows (no list property), that check is exact, so a file cut short is refused
//! while only its header was read. Rows of unknown size (lists before the vertices, ascii
//! data) are walked by the reader itself (`read.rs`), which then decodes the file once.

use std::fs::File;
use std::io::Read;
use std::path::Path;

use super::claims::check_claimed_sizes;
use super::header::{parse_header, Format, MAX_HEADER_BYTES};
use super::read::read_vertex_fields;
use crate::{CoreError, CoreResult};

/// `Ok` when the vertex element of the PLY file at `path` will load (as the lenient reader
/// reads it); else the error the read would give.
pub fn check_vertex_data(path: &Path) -> CoreResult<()> {
    let file = File::open(path).map_err(|e| CoreError::io(path, e))?;
    let length = file.metadata().map_err(|e| CoreError::io(path, e))?.len();
    let mut head = Vec::new();
    file.take(MAX_HEADER_BYTES as u64 + 1)
        .read_to_end(&mut head)
        .map_err(|e| CoreError::io(path, e))?;
    let header = parse_header(&head, path)?;
    let err = |msg: String| CoreError::ply(path, msg);
    let vertex = header
        .elements
        .iter()
        .position(|e| e.name == "vertex")
        .ok_or_else(|| err("the file has no 'vertex' element".into()))?;
    let data =
        usize::try_from(length.saturating_sub(header.data_start as u64)).unwrap_or(usize::MAX);
    let upto = &header.elements[..=vertex];
    check_claimed_sizes(upto, header.format, data).map_err(err)?;
    let fixed = header.format != Format::Ascii && upto.iter().all(|e| e.fixed_row_size().is_some());
    if !fixed {
        read_vertex_fields(path, &[], false)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(dir: &Path, name: &str, bytes: &[u8]) -> std::path::PathBuf {
        let path = dir.join(name);
        std::fs::write(&path, bytes).unwrap();
        path
    }

    fn binary(rows: usize, keep: usize) -> Vec<u8> {
        let mut bytes = format!(
            "ply\nformat binary_little_endian 1.0\nelement vertex {rows}\n\
             property float x\nproperty float y\nproperty float z\nend_header\n"
        )
        .into_bytes();
        bytes.extend(std::iter::repeat_n(0u8, 12 * rows));
        bytes.truncate(bytes.len() - 12 * rows + keep);
        bytes
    }

    #[test]
    fn a_file_cut_short_is_refused_from_its_header() {
        let dir = std::env::temp_dir().join(format!("ply-check-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let whole = file(&dir, "whole.ply", &binary(100, 1200));
        assert!(check_vertex_data(&whole).is_ok());
        let cut = file(&dir, "cut.ply", &binary(100, 1199));
        let msg = check_vertex_data(&cut).unwrap_err().to_string();
        assert!(msg.contains("truncated file"), "{msg}");
        let ascii = file(
            &dir,
            "ascii.ply",
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n2\nx\n",
        );
        let msg = check_vertex_data(&ascii).unwrap_err().to_string();
        assert!(msg.contains("ascii.ply"), "{msg}");
        let not_ply = file(&dir, "notes.ply", b"my notes\n");
        assert!(check_vertex_data(&not_ply).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
