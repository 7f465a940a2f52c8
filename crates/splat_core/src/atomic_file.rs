//! Replacing a file atomically: a reader (or a crash) sees the old file or the new one,
//! never a mix or a truncated file.
//!
//! The bytes go to a temporary file in the destination's folder (same file system, so the
//! rename cannot turn into a copy), which is flushed to disk (fsync) and then renamed over
//! the destination; the folder is fsynced last so the rename itself survives a power cut.
//! On any failure (a full disk, a file-size limit, a missing folder) the temporary file is
//! removed and the previous file at the destination is left as it was.
//!
//! The temporary file is named `.<name>.<pid>-<n>.tmp` (hidden, unique per process and
//! call) and created exclusively; `<name>` is shortened when the whole would pass the
//! 255 bytes a file name may have, so a destination of any valid name has a temporary. A destination that exists keeps its permission bits; a
//! destination that is a symbolic link has the file it points to replaced, not the link.

use std::fs::{self, File, OpenOptions};
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use crate::{CoreError, CoreResult};

/// Writes `bytes` to `path` atomically (see the module documentation).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> CoreResult<()> {
    let target = resolve_link(path);
    let tmp = temporary_path(&target).map_err(|e| CoreError::io(path, e))?;
    let result = write_then_rename(&target, &tmp, bytes);
    if result.is_err() {
        // Best effort: the error that matters is the write's.
        let _ = fs::remove_file(&tmp);
    }
    result.map_err(|e| CoreError::io(path, e))?;
    sync_folder(&target);
    Ok(())
}

/// The file a symbolic link points to (so the link survives), else `path` itself.
fn resolve_link(path: &Path) -> PathBuf {
    match fs::symlink_metadata(path) {
        Ok(meta) if meta.file_type().is_symlink() => {
            fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf())
        }
        _ => path.to_path_buf(),
    }
}

fn temporary_path(target: &Path) -> io::Result<PathBuf> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let name = target.file_name().ok_or_else(|| {
        io::Error::new(io::ErrorKind::InvalidInput, "the path does not name a file")
    })?;
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let tail = format!(".{}-{n}.tmp", std::process::id());
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(shortened(name, NAME_MAX - 1 - tail.len()));
    tmp_name.push(tail);
    Ok(target.with_file_name(tmp_name))
}

/// Bytes in one file name on the file systems plantdreamer writes to.
const NAME_MAX: usize = 255;

/// `name` cut to at most `room` bytes (on a character boundary where it is UTF-8).
fn shortened(name: &std::ffi::OsStr, room: usize) -> std::ffi::OsString {
    let Some(text) = name.to_str() else {
        return name.to_os_string(); // not UTF-8: left as it is
    };
    let mut end = text.len().min(room);
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    text[..end.max(1).min(text.len())].into()
}

fn write_then_rename(target: &Path, tmp: &Path, bytes: &[u8]) -> io::Result<()> {
    let mut file = OpenOptions::new().write(true).create_new(true).open(tmp)?;
    file.write_all(bytes)?;
    if let Ok(meta) = fs::metadata(target) {
        if meta.is_file() {
            file.set_permissions(meta.permissions())?;
        }
    }
    file.sync_all()?;
    drop(file);
    fs::rename(tmp, target)
}

/// Makes the rename durable. Some file systems cannot fsync a folder; the file is in place
/// by then, so that is not reported as a failed write.
fn sync_folder(target: &Path) {
    let folder = match target.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    if let Ok(dir) = File::open(folder) {
        let _ = dir.sync_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("splat_core_atomic_{name}_{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn entries(dir: &Path) -> Vec<String> {
        let mut names: Vec<String> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }

    #[test]
    fn replaces_the_file_and_leaves_no_temporary() {
        let dir = scratch("replace");
        let path = dir.join("a.ply");
        write_atomic(&path, b"old").unwrap();
        write_atomic(&path, b"new contents").unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"new contents");
        assert_eq!(entries(&dir), vec!["a.ply".to_string()]);
        fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn a_name_as_long_as_allowed_still_gets_a_temporary() {
        let dir = scratch("long");
        let path = dir.join(format!("{}.ply", "p".repeat(251)));
        write_atomic(&path, b"old").unwrap();
        write_atomic(&path, b"new").unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"new");
        assert_eq!(entries(&dir).len(), 1);
        fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn failure_keeps_the_old_file_and_cleans_up() {
        let dir = scratch("fail");
        let path = dir.join("a.ply");
        fs::write(&path, b"old").unwrap();
        // A folder where the file should go: the rename fails after the write.
        let blocked = dir.join("sub");
        fs::create_dir(&blocked).unwrap();
        fs::write(blocked.join("x"), b"").unwrap();
        assert!(matches!(
            write_atomic(&blocked, b"new"),
            Err(CoreError::Io { .. })
        ));
        assert!(write_atomic(&dir.join("missing").join("a.ply"), b"new").is_err());
        assert_eq!(fs::read(&path).unwrap(), b"old");
        assert_eq!(entries(&dir), vec!["a.ply".to_string(), "sub".to_string()]);
        fs::remove_dir_all(dir).unwrap();
    }

    #[cfg(unix)]
    #[test]
    fn keeps_permissions_and_symbolic_links() {
        use std::os::unix::fs::PermissionsExt;
        let dir = scratch("links");
        let real = dir.join("real.ply");
        fs::write(&real, b"old").unwrap();
        fs::set_permissions(&real, fs::Permissions::from_mode(0o640)).unwrap();
        let link = dir.join("link.ply");
        std::os::unix::fs::symlink(&real, &link).unwrap();
        write_atomic(&link, b"new").unwrap();
        assert!(fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink());
        assert_eq!(fs::read(&real).unwrap(), b"new");
        let mode = fs::metadata(&real).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o640);
        fs::remove_dir_all(dir).unwrap();
    }
}
