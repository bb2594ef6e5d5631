//! Output safety: before a command runs, every output path is checked against every input by file identity
//! (device and inode, so hard links and symlinks are caught, not just equal names), against the other outputs,
//! and for a usable parent folder. See [`check_outputs`].

use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// Identity of an existing file: (device, inode) on Unix; the canonical path elsewhere.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FileId {
    /// Device and inode numbers.
    Inode(u64, u64),
    /// Canonical path (platforms without inode numbers).
    Path(PathBuf),
}

/// The identity of the file at `path` (symlinks followed), or `None` when nothing is there.
pub fn file_id(path: &Path) -> Option<FileId> {
    let meta = std::fs::metadata(path).ok()?;
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        let _ = path;
        Some(FileId::Inode(meta.dev(), meta.ino()))
    }
    #[cfg(not(unix))]
    {
        let _ = meta;
        path.canonicalize().ok().map(FileId::Path)
    }
}

/// Where an output path will land: its identity when it exists, else its canonical folder joined with its name.
fn landing(path: &Path) -> Option<FileId> {
    file_id(path).or_else(|| {
        let parent = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
        Some(FileId::Path(parent.canonicalize().ok()?.join(path.file_name()?)))
    })
}

/// True for an existing character device (such as `/dev/null`), which several outputs may share.
fn is_char_device(path: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        std::fs::metadata(path).is_ok_and(|m| m.file_type().is_char_device())
    }
    #[cfg(not(unix))]
    {
        let _ = path;
        false
    }
}

/// Checks, before any work is done, that the outputs (`(flag, path)` pairs such as `("--out", p)`) can be
/// written without harm:
/// - no output is the same file as an input (compared by identity: hard links and symlinks count);
/// - no two outputs land on one file (a character device such as `/dev/null` may be shared);
/// - no output is a directory, and each output's parent folder exists.
///
/// Errors: [`Error::InvalidInput`] naming the flag, the path and the clash.
pub fn check_outputs(inputs: &[&Path], outputs: &[(&str, &Path)]) -> Result<()> {
    let input_ids: Vec<(&Path, FileId)> = inputs.iter().filter_map(|p| Some((*p, file_id(p)?))).collect();
    let mut seen: Vec<(&str, &Path, FileId)> = Vec::new();
    for &(flag, path) in outputs {
        check_output_path(flag, path)?;
        let Some(id) = landing(path) else { continue };
        if let Some((input, _)) = input_ids.iter().find(|(_, i)| *i == id) {
            return Err(Error::invalid(format!(
                "refusing to overwrite input file {} with {flag} {} (same file)",
                input.display(),
                path.display()
            )));
        }
        if let Some((other, other_path, _)) = seen.iter().find(|(_, _, i)| *i == id)
            && !is_char_device(path)
        {
            return Err(Error::invalid(format!(
                "{flag} {} and {other} {} are the same file: give each output its own path",
                path.display(),
                other_path.display()
            )));
        }
        seen.push((flag, path, id));
    }
    Ok(())
}

/// Fails early (not after a long run) when `path` cannot be an output file: a name ending in a path separator
/// (a folder, not a file), a directory in its place, a dangling symbolic link, a missing parent folder, or a
/// folder where no file can be created (permissions, a read-only or full file system: probed by creating and
/// removing a temp file as the write will). An existing device or FIFO is written in place and not probed.
pub fn check_output_path(flag: &str, path: &Path) -> Result<()> {
    let text = path.as_os_str().to_string_lossy();
    if text.ends_with('/') || text.ends_with(std::path::MAIN_SEPARATOR) {
        return Err(Error::invalid(format!(
            "{flag} {}: ends with a path separator, so it names a folder; give a file name",
            path.display()
        )));
    }
    if path.is_dir() {
        return Err(Error::invalid(format!("{flag} {} is a directory", path.display())));
    }
    let parent = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    if !parent.is_dir() {
        return Err(Error::invalid(format!("{flag} {}: folder {} does not exist", path.display(), parent.display())));
    }
    let is_link = std::fs::symlink_metadata(path).is_ok_and(|m| m.file_type().is_symlink());
    let resolved = match std::fs::canonicalize(path) {
        Ok(resolved) => resolved,
        Err(_) if is_link => {
            return Err(Error::invalid(format!("{flag} {}: a dangling symbolic link", path.display())));
        }
        Err(_) => path.to_path_buf(),
    };
    if std::fs::metadata(&resolved).is_ok_and(|m| !m.is_file()) {
        return Ok(());
    }
    let folder = resolved.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = resolved.file_name().unwrap_or(path.as_os_str());
    super::atomic::probe_folder(folder, name).map_err(|e| {
        Error::invalid(format!("{flag} {}: cannot create files in {}: {e}", path.display(), folder.display()))
    })
}
