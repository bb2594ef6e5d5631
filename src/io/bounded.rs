//! Bounded reading of cloud files: the whole input, a header and every text line have size limits, checked
//! while reading, so an input that never ends (`/dev/zero`, `/dev/urandom`, a FIFO) or a single huge line fails
//! with a clear error in bounded memory instead of growing without limit.

use super::{Format, at_line};
use crate::error::{Error, Result};
use std::fs::File;
use std::io::Read;
use std::path::Path;

/// Largest cloud file read, in bytes (4 GiB). Larger files are refused before any byte is read (regular
/// files) or once this many bytes have arrived (devices, FIFOs).
pub const MAX_INPUT_BYTES: u64 = 4 << 30;
/// Largest PLY/PCD header, in bytes (1 MiB): the header must end within this many bytes.
pub const MAX_HEADER_BYTES: usize = 1 << 20;
/// Longest line of a text file or text body, in bytes (1 MiB).
pub const MAX_LINE_BYTES: usize = 1 << 20;

/// Bytes requested from the file per read.
const CHUNK: usize = 1 << 20;

/// Reads `path` (a cloud of `format`) within the limits above. Text content (XYZ files, ascii PLY/PCD
/// bodies) must not contain NUL bytes, which no text file has and every binary stream soon does.
pub(super) fn read_input(path: &Path, format: Format) -> Result<Vec<u8>> {
    let file = File::open(path).map_err(|e| Error::io(path, e))?;
    let meta = file.metadata().map_err(|e| Error::io(path, e))?;
    if meta.is_dir() {
        return Err(Error::invalid(format!("{}: is a directory, not a cloud file", path.display())));
    }
    if meta.is_file() && meta.len() > MAX_INPUT_BYTES {
        return Err(too_big(path, meta.len()));
    }
    let expected = if meta.is_file() { meta.len() as usize } else { CHUNK };
    read_checked(path, file, expected, format)
}

/// [`read_input`] for a cloud already in memory (`name` stands for its path in messages): the same limits and
/// text checks.
pub(super) fn check_bytes(name: &Path, bytes: &[u8], format: Format) -> Result<Vec<u8>> {
    if bytes.len() as u64 > MAX_INPUT_BYTES {
        return Err(too_big(name, bytes.len() as u64));
    }
    read_checked(name, bytes, bytes.len(), format)
}

/// Reads `source` (`expected` bytes or so) within the limits, checking text content as it arrives.
fn read_checked(path: &Path, source: impl Read, expected: usize, format: Format) -> Result<Vec<u8>> {
    let mut reader = Reader { path, source, data: Vec::with_capacity(expected.saturating_add(1)), eof: false };
    let text_from = match format {
        Format::Xyz => 0,
        Format::Ply | Format::Pcd => match reader.header(format)? {
            Some(body) => body,
            None => return Ok(reader.data),
        },
    };
    let is_text = text_from != usize::MAX;
    let mut checked = text_from;
    let mut line_start = text_from;
    loop {
        if is_text {
            check_text(path, &reader.data, &mut checked, &mut line_start)?;
        }
        if reader.eof {
            return Ok(reader.data);
        }
        reader.fill()?;
    }
}

/// Reads a whole file of at most `limit` bytes (checked before reading a regular file, and while reading
/// anything else, such as a device or FIFO, so `/dev/zero` fails quickly in bounded memory).
pub fn read_file_bounded(path: &Path, limit: u64) -> Result<Vec<u8>> {
    let file = File::open(path).map_err(|e| Error::io(path, e))?;
    let meta = file.metadata().map_err(|e| Error::io(path, e))?;
    if meta.is_dir() {
        return Err(Error::invalid(format!("{}: is a directory", path.display())));
    }
    let over = |n: u64| {
        Error::invalid(format!("{}: larger than the limit of {limit} bytes ({n} bytes or more)", path.display()))
    };
    if meta.is_file() && meta.len() > limit {
        return Err(over(meta.len()));
    }
    let mut data = Vec::new();
    file.take(limit + 1).read_to_end(&mut data).map_err(|e| Error::io(path, e))?;
    if data.len() as u64 > limit {
        return Err(over(data.len() as u64));
    }
    Ok(data)
}

/// The input being read and what has arrived so far.
struct Reader<'a, R: Read> {
    /// For error messages.
    path: &'a Path,
    /// The open file (or bytes in memory).
    source: R,
    /// Bytes read so far.
    data: Vec<u8>,
    /// True once the file has ended.
    eof: bool,
}

impl<R: Read> Reader<'_, R> {
    /// Reads one more chunk; fails when the input exceeds [`MAX_INPUT_BYTES`].
    fn fill(&mut self) -> Result<()> {
        let before = self.data.len();
        let got =
            (&mut self.source).take(CHUNK as u64).read_to_end(&mut self.data).map_err(|e| Error::io(self.path, e))?;
        self.eof = got == 0;
        if (before + got) as u64 > MAX_INPUT_BYTES {
            return Err(too_big(self.path, (before + got) as u64));
        }
        Ok(())
    }

    /// Reads until the PLY/PCD header ends; returns the offset where a text body starts (`usize::MAX` for a
    /// binary body), or `None` when the file ended inside the header (the parser then reports it).
    fn header(&mut self, format: Format) -> Result<Option<usize>> {
        loop {
            if let Some((end, text_body)) = header_end(&self.data, format) {
                return Ok(Some(if text_body { end } else { usize::MAX }));
            }
            if self.eof {
                return Ok(None);
            }
            if self.data.len() >= MAX_HEADER_BYTES {
                return Err(header_too_long(self.path, &self.data, format));
            }
            self.fill()?;
        }
    }
}

/// The error for a file over [`MAX_INPUT_BYTES`].
fn too_big(path: &Path, bytes: u64) -> Error {
    Error::invalid(format!(
        "{}: input exceeds the limit of {} GiB (read {bytes} bytes so far)",
        path.display(),
        MAX_INPUT_BYTES >> 30
    ))
}

/// The error for a header that does not end within [`MAX_HEADER_BYTES`]: a wrong magic line, binary data,
/// or an overlong header.
fn header_too_long(path: &Path, data: &[u8], format: Format) -> Error {
    let first = data.split(|&b| b == b'\n').next().unwrap_or_default();
    if format == Format::Ply && first.trim_ascii() != b"ply" {
        return at_line(path, 1, "not a PLY file: the first line must be 'ply'");
    }
    if data.contains(&0) {
        let end = if format == Format::Ply { "'end_header'" } else { "DATA" };
        return Error::parse(path, "header", format!("binary data before the header's {end} line"));
    }
    let end = if format == Format::Ply { "an 'end_header' line" } else { "a DATA line" };
    Error::parse(
        path,
        "header",
        format!("no {end} within the first {} MiB (the header size limit)", MAX_HEADER_BYTES >> 20),
    )
}

/// Where the header of `data` ends (offset of the first body byte) and whether the body is text, when the
/// header's last line (PLY `end_header`, PCD `DATA ...`) is within `data`.
fn header_end(data: &[u8], format: Format) -> Option<(usize, bool)> {
    let mut pos = 0;
    let mut text_body = false;
    while let Some(len) = data[pos..].iter().position(|&b| b == b'\n') {
        let line = data[pos..pos + len].trim_ascii();
        pos += len + 1;
        let mut words = line.split(u8::is_ascii_whitespace).filter(|w| !w.is_empty());
        let first = words.next().unwrap_or_default();
        match format {
            Format::Ply if first == b"format" => text_body = words.next() == Some(b"ascii"),
            Format::Ply if line == b"end_header" => return Some((pos, text_body)),
            Format::Pcd if first.eq_ignore_ascii_case(b"DATA") => {
                return Some((pos, words.next().is_some_and(|w| w.eq_ignore_ascii_case(b"ascii"))));
            }
            _ => {}
        }
    }
    None
}

/// Checks the text bytes of `data` from `*checked` on: no NUL byte, no line longer than [`MAX_LINE_BYTES`].
/// `line_start` is the offset where the current line began.
fn check_text(path: &Path, data: &[u8], checked: &mut usize, line_start: &mut usize) -> Result<()> {
    for (i, &b) in data.iter().enumerate().skip(*checked) {
        if b == b'\n' {
            *line_start = i + 1;
        } else if b == 0 {
            let line = line_number(data, i);
            return Err(at_line(path, line, "NUL byte in a text file (binary data, or a device such as /dev/zero)"));
        }
        if i.saturating_sub(*line_start) >= MAX_LINE_BYTES {
            let line = line_number(data, i);
            return Err(at_line(
                path,
                line,
                format!("line longer than {} MiB (the line length limit)", MAX_LINE_BYTES >> 20),
            ));
        }
    }
    *checked = data.len();
    Ok(())
}

/// The 1-based line number of byte `offset`.
fn line_number(data: &[u8], offset: usize) -> usize {
    1 + data[..offset].iter().filter(|&&b| b == b'\n').count()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_end_finds_encoding() {
        let ply = b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n";
        assert_eq!(header_end(ply, Format::Ply), Some((ply.len() - 2, true)));
        let bin = b"ply\nformat binary_little_endian 1.0\nend_header\n\x00\x01";
        assert_eq!(header_end(bin, Format::Ply), Some((bin.len() - 2, false)));
        assert_eq!(header_end(b"ply\nformat ascii 1.0\n", Format::Ply), None);
        let pcd = b"# c\nFIELDS x y z\nDATA binary\n\x00";
        assert_eq!(header_end(pcd, Format::Pcd), Some((pcd.len() - 1, false)));
    }

    #[test]
    fn text_check_finds_nul_and_long_lines() {
        let (mut checked, mut start) = (0, 0);
        let err = check_text(Path::new("a.xyz"), b"1 2 3\n4 \x005 6\n", &mut checked, &mut start).unwrap_err();
        assert!(err.to_string().contains("line 2") && err.to_string().contains("NUL"), "{err}");
        let long = vec![b'1'; MAX_LINE_BYTES + 1];
        let (mut checked, mut start) = (0, 0);
        let err = check_text(Path::new("a.xyz"), &long, &mut checked, &mut start).unwrap_err();
        assert!(err.to_string().contains("line 1") && err.to_string().contains("line length limit"), "{err}");
    }
}
