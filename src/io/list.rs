//! Line-based list files (scan lists, pairs files): read within a size limit, refused with a clear error when
//! the file is a point cloud or binary data instead of text.

use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// Largest list file read, in bytes (64 MiB: a million scan paths).
pub const MAX_LIST_BYTES: u64 = 64 << 20;

/// What kind of point cloud `bytes` (the file `path`) is, by its magic or, for text clouds, its extension.
fn cloud_kind(path: &Path, bytes: &[u8]) -> Option<&'static str> {
    if bytes.starts_with(b"ply\n") || bytes.starts_with(b"ply\r\n") {
        return Some("PLY");
    }
    if bytes.starts_with(b"# .PCD") || bytes.starts_with(b"VERSION") || bytes.starts_with(b"FIELDS") {
        return Some("PCD");
    }
    let ext = path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase());
    match ext.as_deref() {
        Some("ply") => Some("PLY"),
        Some("pcd") => Some("PCD"),
        Some("xyz" | "pts") => Some("XYZ"),
        _ => None,
    }
}

/// `bytes` of the list file `path` as text. A point cloud (by its magic or extension) or binary data (a NUL
/// byte, invalid UTF-8) is refused, naming the file, what it is, and `what` was expected (e.g. "a scan list").
pub fn list_text(path: &Path, bytes: Vec<u8>, what: &str) -> Result<String> {
    if let Some(kind) = cloud_kind(path, &bytes) {
        return Err(Error::invalid(format!("{}: is a {kind} point cloud, not {what}", path.display())));
    }
    let binary = |at: usize| Error::parse(path, format!("byte {at}"), format!("binary data, not {what} (text)"));
    let nul = bytes.iter().position(|&b| b == 0);
    match String::from_utf8(bytes) {
        Err(e) => Err(binary(nul.unwrap_or(usize::MAX).min(e.utf8_error().valid_up_to()))),
        Ok(_) if nul.is_some() => Err(binary(nul.unwrap_or(0))),
        Ok(text) => Ok(text),
    }
}

/// Reads the list file `path` (at most [`MAX_LIST_BYTES`]) as text; see [`list_text`].
pub fn read_list(path: &Path, what: &str) -> Result<String> {
    list_text(path, super::read_file_bounded(path, MAX_LIST_BYTES)?, what)
}

/// The paths of a scan list: one per line, relative to `base` (absolute ones kept), surrounding blanks trimmed,
/// blank lines and `#` comments skipped.
pub fn parse_scan_list(text: &str, base: &Path) -> Vec<PathBuf> {
    text.lines().map(str::trim).filter(|l| !l.is_empty() && !l.starts_with('#')).map(|l| base.join(l)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clouds_and_binary_data_are_named_not_decoded() {
        let e = list_text(Path::new("a.txt"), b"ply\nformat ascii 1.0\n".to_vec(), "a scan list").unwrap_err();
        assert!(e.to_string().contains("a.txt: is a PLY point cloud, not a scan list"), "{e}");
        let e = list_text(Path::new("c.pcd"), b"1 2 3\n".to_vec(), "a pairs file").unwrap_err().to_string();
        assert!(e.contains("PCD point cloud"), "{e}");
        let e = list_text(Path::new("l.txt"), b"a.ply\n\xff\xfe".to_vec(), "a scan list").unwrap_err().to_string();
        assert!(e.contains("l.txt: byte 6: binary data"), "{e}");
        assert_eq!(list_text(Path::new("l.txt"), b"a.ply\n".to_vec(), "a scan list").unwrap(), "a.ply\n");
    }

    #[test]
    fn scan_lists_skip_comments_and_keep_absolute_paths() {
        let list = parse_scan_list("# scans\n a.ply \n\n/abs/b.pcd\n", Path::new("dir"));
        assert_eq!(list, vec![PathBuf::from("dir/a.ply"), PathBuf::from("/abs/b.pcd")]);
    }
}
