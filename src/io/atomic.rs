//! Atomic file replacement: write a temp file beside the destination, flush it to disk, rename it over.
//! Temp files a crashed writer left (`kill -9`, a size limit) are removed by the next write to the same
//! destination: see [`remove_stale_temps`].

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
    remove_stale_temps(dir, name);
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

/// Checks that a file can be created in `dir` (permissions, a read-only file system, a full folder) by creating
/// and removing a temp file there, as the write of `name` will; errors name `dir`.
pub(super) fn probe_folder(dir: &Path, name: &std::ffi::OsStr) -> io::Result<()> {
    remove_stale_temps(dir, name);
    let temp = temp_path(dir, name);
    OpenOptions::new().write(true).create_new(true).open(&temp)?;
    fs::remove_file(&temp)
}

/// The process id in a temp name `.<name>.tmp-<pid>-<n>` of destination `name`, if `entry` is one.
fn temp_owner(entry: &std::ffi::OsStr, name: &std::ffi::OsStr) -> Option<u32> {
    let entry = entry.to_str()?;
    let rest = entry.strip_prefix('.')?.strip_prefix(name.to_str()?)?.strip_prefix(".tmp-")?;
    let (pid, n) = rest.split_once('-')?;
    n.parse::<u64>().ok()?;
    pid.parse().ok()
}

/// True while process `pid` runs (or when that cannot be told, so a live writer's temp file is never taken).
fn process_alive(pid: u32) -> bool {
    if pid == std::process::id() {
        return true;
    }
    #[cfg(target_os = "linux")]
    {
        !Path::new("/proc/self").exists() || Path::new(&format!("/proc/{pid}")).exists()
    }
    #[cfg(not(target_os = "linux"))]
    {
        true
    }
}

/// Removes the temp files of earlier writes to `dir/name` whose writer no longer runs (killed during the write):
/// without this they stay forever, hidden, up to the size of the largest output.
fn remove_stale_temps(dir: &Path, name: &std::ffi::OsStr) {
    let Ok(entries) = fs::read_dir(dir) else { return };
    for entry in entries.flatten() {
        let file_name = entry.file_name();
        if let Some(pid) = temp_owner(&file_name, name)
            && !process_alive(pid)
            && entry.file_type().is_ok_and(|t| t.is_file())
        {
            let _ = fs::remove_file(entry.path());
        }
    }
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
    fn temp_owner_reads_the_pid_of_this_destination_only() {
        let name = std::ffi::OsStr::new("out.ply");
        let owner = |e: &str| temp_owner(std::ffi::OsStr::new(e), name);
        assert_eq!(owner(".out.ply.tmp-123-4"), Some(123));
        assert_eq!(owner(".out.ply.tmp-123-x"), None);
        assert_eq!(owner(".out.plyx.tmp-123-4"), None);
        assert_eq!(owner(".other.ply.tmp-123-4"), None);
        assert_eq!(owner("out.ply.tmp-123-4"), None);
    }

    #[test]
    fn path_without_file_name_is_an_io_error() {
        assert!(matches!(write_atomic(Path::new("/"), b"x"), Err(Error::Io { .. })));
    }
}
