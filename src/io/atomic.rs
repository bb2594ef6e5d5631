//! Atomic file replacement: write a temp file beside the destination, flush it to disk, rename it over.

use crate::error::{Error, Result};
use std::ffi::OsString;
use std::fs::{self, File, OpenOptions};
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Distinguishes temp files of concurrent writes from one process.
static NEXT_TEMP: AtomicU64 = AtomicU64::new(0);

/// Writes `bytes` to `path` through a temp file `.<name>.tmp-<pid>-<n>` in the same directory; see
/// [`super::write_atomic`].
pub(super) fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    // Never replace a symlink, a FIFO or a device with a regular file: write through a symlink to the file it
    // names, and write to special files directly (a rename cannot apply to them).
    if let Ok(link) = fs::symlink_metadata(path) {
        if link.file_type().is_symlink() {
            return match fs::canonicalize(path) {
                Ok(resolved) => write_atomic(&resolved, bytes).map_err(|e| relabel(e, path)),
                Err(_) => {
                    let source = io::Error::new(io::ErrorKind::NotFound, "dangling symbolic link; not replacing it");
                    Err(Error::io(path, source))
                }
            };
        }
        if !link.is_file() && !link.is_dir() {
            return write_special(path, bytes);
        }
    }
    let Some(name) = path.file_name() else {
        let source = io::Error::new(io::ErrorKind::InvalidInput, "the path has no file name");
        return Err(Error::io(path, source));
    };
    let dir = match path.parent() {
        Some(parent) if !parent.as_os_str().is_empty() => parent,
        _ => Path::new("."),
    };
    let temp = temp_path(dir, name);
    match write_synced(&temp, bytes).and_then(|()| fs::rename(&temp, path)) {
        Ok(()) => {
            sync_dir(dir);
            Ok(())
        }
        Err(source) => {
            let _ = fs::remove_file(&temp);
            Err(Error::io(path, source))
        }
    }
}

/// Writes `bytes` straight into an existing special file (FIFO, device), without creating or truncating.
fn write_special(path: &Path, bytes: &[u8]) -> Result<()> {
    let mut file = OpenOptions::new().write(true).open(path).map_err(|e| Error::io(path, e))?;
    file.write_all(bytes).map_err(|e| Error::io(path, e))
}

/// An I/O error about a symlink's target, renamed to the path the user gave.
fn relabel(e: Error, path: &Path) -> Error {
    match e {
        Error::Io { source, .. } => Error::io(path, source),
        other => other,
    }
}

/// A fresh temp-file path in `dir` for the destination file `name`.
fn temp_path(dir: &Path, name: &std::ffi::OsStr) -> PathBuf {
    let mut temp = OsString::from(".");
    temp.push(name);
    let n = NEXT_TEMP.fetch_add(1, Ordering::Relaxed);
    temp.push(format!(".tmp-{}-{n}", std::process::id()));
    dir.join(temp)
}

/// Creates `temp` (which must not exist), writes `bytes` and flushes them to disk.
fn write_synced(temp: &Path, bytes: &[u8]) -> io::Result<()> {
    let mut file = OpenOptions::new().write(true).create_new(true).open(temp)?;
    file.write_all(bytes)?;
    file.sync_all()
}

/// Best effort: flushes the directory entry of the rename to disk (Unix only; elsewhere a no-op).
fn sync_dir(dir: &Path) {
    if cfg!(unix)
        && let Ok(handle) = File::open(dir)
    {
        let _ = handle.sync_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn temp_names_are_hidden_and_unique() {
        let a = temp_path(Path::new("d"), std::ffi::OsStr::new("out.ply"));
        let b = temp_path(Path::new("d"), std::ffi::OsStr::new("out.ply"));
        assert_ne!(a, b);
        let name = a.file_name().unwrap().to_string_lossy().into_owned();
        assert!(name.starts_with(".out.ply.tmp-"), "{name}");
        assert_eq!(a.parent(), Some(Path::new("d")));
    }

    #[test]
    fn path_without_file_name_is_an_io_error() {
        assert!(matches!(write_atomic(Path::new("/"), b"x"), Err(Error::Io { .. })));
    }
}
