//! Point-cloud files: PLY (ascii, binary little/big endian), PCD (ascii, binary) and XYZ text in; binary PLY out.
//! Outputs are written atomically (temp file + rename).
//!
//! Readers load the whole file into memory and never trust a count from a header: binary bodies are checked
//! against the bytes that are actually there before anything is read, and preallocation is capped. Every
//! malformed file gives [`Error::Parse`] with a location: `line N` for headers and text bodies, `byte N` for
//! binary bodies (the offset of the value that is missing or bad).

mod atomic;
mod bounded;
mod list;
mod outputs;
mod pcd;
mod ply;
mod scan_check;
mod xyz;

use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use std::path::Path;

pub use bounded::{MAX_HEADER_BYTES, MAX_INPUT_BYTES, MAX_LINE_BYTES, read_file_bounded};
pub use list::{MAX_LIST_BYTES, list_text, parse_scan_list, read_list};
pub use outputs::{FileId, check_output_path, check_outputs, file_id};
pub use scan_check::{MAX_ROUNDING_PER_EXTENT, check_scan};
pub use xyz::{UNIT_NORMAL_TOLERANCE, XyzColumns};

/// File extensions [`read_cloud`] understands (lower case, without the dot).
pub const SUPPORTED_EXTENSIONS: &[&str] = &["ply", "pcd", "xyz", "txt", "pts"];

/// What loading does with points exactly at (0, 0, 0), where many LiDAR and depth sensors write a beam or
/// pixel that returned nothing.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ZeroPoints {
    /// Drop them when there are at least [`MIN_NO_RETURN_POINTS`] (a sensor's no-return pattern: a surface is
    /// never sampled twice at exactly the origin), keep a lone one.
    #[default]
    Auto,
    /// Keep every point.
    Keep,
    /// Drop every point exactly at (0, 0, 0).
    Drop,
}

/// With [`ZeroPoints::Auto`], this many points exactly at (0, 0, 0) or more are taken for sensor no-returns and
/// dropped: one point there can be a real sample, two identical ones at exactly the origin cannot.
pub const MIN_NO_RETURN_POINTS: usize = 2;

impl ZeroPoints {
    /// `Drop` for true, `Keep` for false, `Auto` for none (the bindings' `drop_zero_points` keyword).
    pub fn from_flag(drop: Option<bool>) -> Self {
        match drop {
            None => ZeroPoints::Auto,
            Some(true) => ZeroPoints::Drop,
            Some(false) => ZeroPoints::Keep,
        }
    }

    /// Whether `count` points exactly at (0, 0, 0) are dropped.
    pub fn drops(self, count: usize) -> bool {
        match self {
            ZeroPoints::Auto => count >= MIN_NO_RETURN_POINTS,
            ZeroPoints::Keep => false,
            ZeroPoints::Drop => true,
        }
    }
}

/// Options applied while loading.
#[derive(Clone, Copy, Debug, Default)]
pub struct LoadOptions {
    /// Points exactly at (0, 0, 0): by default dropped when there are several (sensor no-returns).
    pub zero_points: ZeroPoints,
    /// What the columns of XYZ/TXT/PTS files hold; `None` decides by content (see [`XyzColumns`]).
    pub xyz_columns: Option<XyzColumns>,
    /// A shift subtracted from every point in `f64` before the conversion to `f32`, for georeferenced clouds
    /// whose coordinates are too large for `f32`; the shift used is reported in [`LoadReport::origin`].
    pub origin: OriginShift,
}

/// Coordinates from this magnitude on (1e4 units: 1 mm spacing in `f32`) make [`OriginShift::Auto`] shift.
pub const LARGE_COORDINATE: f64 = 1e4;

/// How [`read_cloud`] shifts coordinates before converting them to `f32`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum OriginShift {
    /// No shift.
    #[default]
    None,
    /// When the first point has a coordinate of magnitude [`LARGE_COORDINATE`] or more, subtract that point
    /// rounded to whole units; otherwise no shift.
    Auto,
    /// Subtract this point (whole units), e.g. the origin chosen for the other cloud of a pair.
    At([i64; 3]),
}

/// What loading did besides returning the cloud.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct LoadReport {
    /// Points dropped because a coordinate was NaN or infinite, or because the file gave them a normal with a
    /// NaN or infinite component.
    pub dropped_non_finite: usize,
    /// Points dropped because they were exactly (0, 0, 0) (see [`LoadOptions::zero_points`]).
    pub dropped_zero: usize,
    /// The origin subtracted from every point (see [`LoadOptions::origin`]); zero without a shift.
    pub origin: [i64; 3],
}

/// Reads a cloud, choosing the format from the extension (.ply, .pcd, .xyz/.txt/.pts).
///
/// Filtering, applied point by point:
/// - a point with a NaN or infinite coordinate (after conversion to `f32`, so values beyond the `f32` range
///   count too) is dropped and counted in [`LoadReport::dropped_non_finite`];
/// - a point with finite coordinates but a NaN or infinite normal component is dropped as well and also
///   counted as non-finite, so the returned cloud always passes [`PointCloud::validate`];
/// - points exactly at (0, 0, 0) in the file (before any origin shift) are dropped and counted in
///   [`LoadReport::dropped_zero`] when [`LoadOptions::zero_points`] says so: by default when there are at least
///   [`MIN_NO_RETURN_POINTS`] of them.
///
/// Normals are taken from the file when it has all three components (PLY `nx ny nz`, PCD
/// `normal_x normal_y normal_z`, XYZ columns 4 to 6) and are returned as stored: not normalised, and zero-length
/// normals are kept. A file with no points gives an empty cloud (callers decide whether that is an error).
///
/// Reading is bounded (see [`MAX_INPUT_BYTES`], [`MAX_HEADER_BYTES`], [`MAX_LINE_BYTES`]): an endless or
/// oversized input, an overlong header or line, or a NUL byte in text fails without reading on.
///
/// Errors: [`Error::InvalidInput`] for an unknown extension, a directory or an input over the size limit,
/// [`Error::Io`] when the file cannot be read, [`Error::Parse`] for malformed contents.
pub fn read_cloud(path: &Path, options: &LoadOptions) -> Result<(PointCloud, LoadReport)> {
    let format = Format::from_path(path)?;
    let data = bounded::read_input(path, format)?;
    parse_cloud(path, format, &data, options)
}

/// [`read_cloud`] for a file's contents already in memory (a browser's `File`, an upload): `name` gives the
/// format by its extension and names the input in messages; the same limits, checks and filtering apply.
pub fn read_cloud_bytes(name: &str, bytes: &[u8], options: &LoadOptions) -> Result<(PointCloud, LoadReport)> {
    let path = Path::new(name);
    let format = Format::from_path(path)?;
    let data = bounded::check_bytes(path, bytes, format)?;
    parse_cloud(path, format, &data, options)
}

/// Parses the checked contents `data` of the cloud file `path` in `format`.
fn parse_cloud(path: &Path, format: Format, data: &[u8], options: &LoadOptions) -> Result<(PointCloud, LoadReport)> {
    match format {
        Format::Ply => ply::parse(path, data, options),
        Format::Pcd => pcd::parse(path, data, options),
        Format::Xyz => {
            // PTS files conventionally carry `x y z intensity r g b`: never read their columns 4-6 as normals.
            let is_pts = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("pts"));
            xyz::parse(path, data, options, !is_pts)
        }
    }
}

/// Builds a cloud from in-memory rows `x y z nx ny nz` (the normal part is ignored unless `with_normals`),
/// applying exactly the filtering and origin shift [`read_cloud`] applies to a file's points: rows with a NaN
/// or infinite coordinate (after conversion to `f32`), or with a non-finite normal when normals are given, are
/// dropped and counted; exact zeros are dropped as `options.zero_points` says. Bindings (the Python package) use it so
/// that arrays and files are treated alike.
pub fn cloud_from_rows(
    rows: impl IntoIterator<Item = [f64; 6]>,
    with_normals: bool,
    options: &LoadOptions,
) -> (PointCloud, LoadReport) {
    let rows = rows.into_iter();
    let mut builder = CloudBuilder::new(options, with_normals, rows.size_hint().0.min(MAX_PREALLOC));
    for row in rows {
        builder.push(&row);
    }
    builder.finish()
}

/// Writes `cloud` as binary little-endian PLY (normals included when present), atomically.
///
/// The vertex element has `float x y z`, plus `float nx ny nz` when the cloud has normals. Fails with
/// [`Error::InvalidInput`] when the normals do not match the points one to one, and [`Error::Io`] when the file
/// cannot be written.
pub fn write_ply(path: &Path, cloud: &PointCloud) -> Result<()> {
    let bytes = ply::encode_binary_le(cloud, None)
        .map_err(|message| Error::invalid(format!("{}: {message}", path.display())))?;
    write_atomic(path, &bytes)
}

/// Writes `cloud` as binary little-endian PLY with one colour per point, atomically: the vertex element has
/// `float x y z`, `float nx ny nz` when the cloud has normals, then `uchar red green blue` (the names common
/// viewers such as MeshLab, CloudCompare and Open3D read). Fails with [`Error::InvalidInput`] when the normals
/// or `colors` do not match the points one to one, and [`Error::Io`] when the file cannot be written.
pub fn write_ply_with_colors(path: &Path, cloud: &PointCloud, colors: &[[u8; 3]]) -> Result<()> {
    let bytes = ply::encode_binary_le(cloud, Some(colors))
        .map_err(|message| Error::invalid(format!("{}: {message}", path.display())))?;
    write_atomic(path, &bytes)
}

/// Writes `cloud` in the format its extension names: `.ply` (binary PLY), `.pcd` (binary PCD) or
/// `.xyz`/`.txt` (text, `x y z [nx ny nz]` per line), atomically. Other extensions are refused (see
/// [`check_writable_cloud_path`]), never written as PLY under another name.
pub fn write_cloud(path: &Path, cloud: &PointCloud) -> Result<()> {
    check_writable_cloud_path(path)?;
    if path.extension().is_none() {
        return write_ply(path, cloud);
    }
    let bytes = match Format::from_path(path)? {
        Format::Ply => return write_ply(path, cloud),
        Format::Pcd => pcd::encode_binary(cloud),
        Format::Xyz => xyz::encode_text(cloud),
    }
    .map_err(|message| Error::invalid(format!("{}: {message}", path.display())))?;
    write_atomic(path, &bytes)
}

/// Checks that [`write_cloud`] can write `path`'s extension (.ply, .pcd, .xyz, .txt). An existing device or
/// FIFO without an extension (`/dev/null`, `/dev/stdout`) takes binary PLY.
pub fn check_writable_cloud_path(path: &Path) -> Result<()> {
    let ext = path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase());
    match ext.as_deref() {
        Some("ply" | "pcd" | "xyz" | "txt") => Ok(()),
        None if is_special_file(path) => Ok(()),
        _ => Err(Error::invalid(format!(
            "{}: cannot write this extension; use .ply, .pcd, .xyz or .txt",
            path.display()
        ))),
    }
}

/// True for an existing file that is neither a regular file nor a folder (a device, a FIFO).
fn is_special_file(path: &Path) -> bool {
    std::fs::metadata(path).is_ok_and(|m| !m.is_file() && !m.is_dir())
}

/// Writes `bytes` to `path` atomically: a temp file beside it (`.<name>.tmp-<pid>-<n>`), flushed to disk, then
/// renamed over `path`, so readers see either the old contents or the new ones, never a partial file. The temp
/// file is removed when anything fails. A symlink is written through (the file it names is replaced, the link
/// kept); an existing FIFO or device is written directly, never replaced. Refusing to overwrite inputs is the
/// caller's job (see [`check_outputs`]).
///
/// Errors: [`Error::Io`] naming `path`.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    atomic::write_atomic(path, bytes)
}

/// The cloud's normals, checked to match its points one to one.
fn checked_normals(cloud: &PointCloud) -> std::result::Result<Option<&Vec<[f32; 3]>>, String> {
    match &cloud.normals {
        Some(n) if n.len() != cloud.points.len() => {
            Err(format!("{} normals for {} points", n.len(), cloud.points.len()))
        }
        other => Ok(other.as_ref()),
    }
}

/// The file formats [`read_cloud`] knows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    /// Stanford PLY.
    Ply,
    /// Point Cloud Library PCD.
    Pcd,
    /// Whitespace or comma separated text.
    Xyz,
}

impl Format {
    /// The format for `path`'s extension (case-insensitive).
    fn from_path(path: &Path) -> Result<Format> {
        let supported = SUPPORTED_EXTENSIONS.iter().map(|e| format!(".{e}")).collect::<Vec<_>>().join(", ");
        let Some(ext) = path.extension() else {
            return Err(Error::invalid(format!("{}: no file extension; supported: {supported}", path.display())));
        };
        let ext = ext.to_string_lossy().to_ascii_lowercase();
        match ext.as_str() {
            "ply" => Ok(Format::Ply),
            "pcd" => Ok(Format::Pcd),
            "xyz" | "txt" | "pts" => Ok(Format::Xyz),
            _ => Err(Error::invalid(format!(
                "{}: unsupported extension '.{ext}'; supported: {supported}",
                path.display()
            ))),
        }
    }
}

/// Most points preallocated up front, whatever a header claims; vectors grow past this as points arrive.
const MAX_PREALLOC: usize = 1 << 22;

/// A safe `Vec::with_capacity` for `count` items when each item needs at least `min_item_bytes` of the
/// `remaining_bytes`: never more than could possibly be in the file, and never more than [`MAX_PREALLOC`].
fn capped_capacity(count: u64, remaining_bytes: usize, min_item_bytes: usize) -> usize {
    let fits = remaining_bytes / min_item_bytes.max(1);
    usize::try_from(count).unwrap_or(usize::MAX).min(fits).min(MAX_PREALLOC)
}

/// An [`Error::Parse`] at a (1-based) line of a text file or header.
fn at_line(path: &Path, line: usize, message: impl Into<String>) -> Error {
    Error::parse(path, format!("line {line}"), message)
}

/// An [`Error::Parse`] at a byte offset of a binary body.
fn at_byte(path: &Path, offset: usize, message: impl Into<String>) -> Error {
    Error::parse(path, format!("byte {offset}"), message)
}

/// "vertices", "points", "'face' elements"...: how error messages count items of the element `name`.
fn items_noun(name: &str) -> String {
    match name {
        "vertex" => "vertices".to_string(),
        "point" => "points".to_string(),
        "face" => "faces".to_string(),
        other => format!("'{other}' elements"),
    }
}

/// The message for a body that ends after `done` of `total` items.
fn ends_after(done: u64, total: u64, name: &str) -> String {
    format!("file ends after {done} of {total} {}", items_noun(name))
}

/// Parses a text token as a number; `what` names the value in the error ("property 'x'", "column 2") and is
/// only called on failure.
fn parse_number(path: &Path, line: usize, token: &str, what: impl FnOnce() -> String) -> Result<f64> {
    token.parse::<f64>().map_err(|_| at_line(path, line, format!("'{token}' is not a number ({})", what())))
}

/// A binary scalar type shared by PLY and PCD.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Scalar {
    /// Signed 8-bit integer.
    I8,
    /// Unsigned 8-bit integer.
    U8,
    /// Signed 16-bit integer.
    I16,
    /// Unsigned 16-bit integer.
    U16,
    /// Signed 32-bit integer.
    I32,
    /// Unsigned 32-bit integer.
    U32,
    /// Signed 64-bit integer (PCD only).
    I64,
    /// Unsigned 64-bit integer (PCD only).
    U64,
    /// 32-bit float.
    F32,
    /// 64-bit float.
    F64,
}

impl Scalar {
    /// Size in bytes.
    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::I64 | Scalar::U64 | Scalar::F64 => 8,
        }
    }

    /// True for the integer types.
    fn is_integer(self) -> bool {
        !matches!(self, Scalar::F32 | Scalar::F64)
    }

    /// Decodes the value at the start of `bytes`; `None` when `bytes` is shorter than [`Scalar::size`].
    fn decode(self, bytes: &[u8], big_endian: bool) -> Option<f64> {
        macro_rules! get {
            ($t:ty) => {{
                let raw = *bytes.first_chunk::<{ std::mem::size_of::<$t>() }>()?;
                (if big_endian { <$t>::from_be_bytes(raw) } else { <$t>::from_le_bytes(raw) }) as f64
            }};
        }
        Some(match self {
            Scalar::I8 => get!(i8),
            Scalar::U8 => get!(u8),
            Scalar::I16 => get!(i16),
            Scalar::U16 => get!(u16),
            Scalar::I32 => get!(i32),
            Scalar::U32 => get!(u32),
            Scalar::I64 => get!(i64),
            Scalar::U64 => get!(u64),
            Scalar::F32 => get!(f32),
            Scalar::F64 => get!(f64),
        })
    }
}

/// Iterates a byte buffer line by line, tracking 1-based line numbers and the offset of the next line.
struct TextLines<'a> {
    /// The whole file.
    data: &'a [u8],
    /// Offset of the next line.
    pos: usize,
    /// Number of the line returned last (0 before the first).
    line: usize,
}

impl<'a> TextLines<'a> {
    /// Lines of `data` starting at offset `pos`, where the line before `pos` is numbered `line`.
    fn new(data: &'a [u8], pos: usize, line: usize) -> Self {
        TextLines { data, pos, line }
    }

    /// The next line without its `\n` (a trailing `\r` is kept), or `None` at the end of the data.
    fn next_raw(&mut self) -> Option<(usize, &'a [u8])> {
        let rest = self.data.get(self.pos..).filter(|r| !r.is_empty())?;
        let len = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
        self.pos += (len + 1).min(rest.len());
        self.line += 1;
        Some((self.line, &rest[..len]))
    }

    /// The next line that is not blank, or `None` at the end of the data.
    fn next_nonblank(&mut self) -> Option<(usize, &'a [u8])> {
        std::iter::from_fn(|| self.next_raw()).find(|(_, l)| !l.iter().all(u8::is_ascii_whitespace))
    }

    /// Offset of the first byte after the lines returned so far.
    fn pos(&self) -> usize {
        self.pos
    }

    /// The line where the data ended (one past the last line returned), for "file ends" errors.
    fn eof_line(&self) -> usize {
        self.line + 1
    }
}

/// A line as text, without a trailing `\r`; a parse error when it is not UTF-8.
///
/// A UTF-8 byte-order mark on line 1 and a carriage return inside a line (CR-only line endings) are named as
/// such, since both are invisible in most editors.
fn line_str<'a>(path: &Path, line: usize, raw: &'a [u8]) -> Result<&'a str> {
    if line == 1 && raw.starts_with(b"\xEF\xBB\xBF") {
        return Err(at_line(path, line, "the file starts with a UTF-8 byte-order mark (BOM); save it without one"));
    }
    let body = raw.strip_suffix(b"\r").unwrap_or(raw);
    if body.contains(&b'\r') {
        return Err(at_line(path, line, "carriage return inside the line: CR-only line endings; convert them to LF"));
    }
    let text = std::str::from_utf8(raw).map_err(|_| at_line(path, line, "line is not valid UTF-8 text"))?;
    Ok(text.strip_suffix('\r').unwrap_or(text))
}

/// Collects points while loading, applying [`LoadOptions`] and counting what was dropped.
struct CloudBuilder {
    /// Points kept so far.
    points: Vec<[f32; 3]>,
    /// Normals kept so far, when the file has them.
    normals: Option<Vec<[f32; 3]>>,
    /// Drop counts.
    report: LoadReport,
    /// [`LoadOptions::zero_points`].
    zero_points: ZeroPoints,
    /// Indices in `points` of the kept points that were exactly (0, 0, 0) in the input (decided on at the end).
    zero_indices: Vec<usize>,
    /// [`LoadOptions::origin`]; `Auto` turns into `At` at the first finite point.
    origin: OriginShift,
}

impl CloudBuilder {
    /// An empty builder; `with_normals` when the file provides normals; `capacity` must already be capped.
    fn new(options: &LoadOptions, with_normals: bool, capacity: usize) -> Self {
        CloudBuilder {
            points: Vec::with_capacity(capacity),
            normals: with_normals.then(|| Vec::with_capacity(capacity)),
            report: LoadReport::default(),
            zero_points: options.zero_points,
            zero_indices: Vec::new(),
            origin: options.origin,
        }
    }

    /// Adds one point from `values` = x, y, z, nx, ny, nz (the normal part is ignored without normals), or
    /// drops and counts it (see [`read_cloud`] for the rules).
    fn push(&mut self, values: &[f64; 6]) {
        if self.origin == OriginShift::Auto && values[..3].iter().all(|c| c.is_finite()) {
            let large = values[..3].iter().any(|c| c.abs() >= LARGE_COORDINATE);
            self.origin = OriginShift::At(if large { [0, 1, 2].map(|i| values[i].round() as i64) } else { [0; 3] });
        }
        let o = match self.origin {
            OriginShift::At(o) => o.map(|c| c as f64),
            _ => [0.0; 3],
        };
        let p = [(values[0] - o[0]) as f32, (values[1] - o[1]) as f32, (values[2] - o[2]) as f32];
        let n = [values[3] as f32, values[4] as f32, values[5] as f32];
        let finite = |v: &[f32; 3]| v.iter().all(|c| c.is_finite());
        if !finite(&p) || (self.normals.is_some() && !finite(&n)) {
            self.report.dropped_non_finite += 1;
            return;
        }
        if values[..3].iter().all(|&c| c == 0.0) {
            if self.zero_points == ZeroPoints::Drop {
                self.report.dropped_zero += 1;
                return;
            }
            self.zero_indices.push(self.points.len());
        }
        self.points.push(p);
        if let Some(normals) = &mut self.normals {
            normals.push(n);
        }
    }

    /// The cloud and the drop counts.
    fn finish(mut self) -> (PointCloud, LoadReport) {
        if let OriginShift::At(o) = self.origin {
            self.report.origin = o;
        }
        if !self.zero_indices.is_empty() && self.zero_points.drops(self.zero_indices.len()) {
            self.report.dropped_zero += self.zero_indices.len();
            let mut keep = vec![true; self.points.len()];
            for &i in &self.zero_indices {
                keep[i] = false;
            }
            let mut kept = keep.iter();
            self.points.retain(|_| *kept.next().unwrap_or(&true));
            if let Some(normals) = &mut self.normals {
                let mut kept = keep.iter();
                normals.retain(|_| *kept.next().unwrap_or(&true));
            }
        }
        (PointCloud { points: self.points, normals: self.normals }, self.report)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cloud_in_memory_reads_as_the_same_file_does_and_bad_bytes_name_the_input() {
        let dir = std::env::temp_dir().join(format!("dpr_gpu_bytes_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let cloud = PointCloud {
            points: vec![[0.5, -1.0, 2.0], [1.5, 0.25, -3.0], [0.0, 0.0, 1.0]],
            normals: Some(vec![[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
        };
        for (name, text) in [("c.ply", None), ("c.xyz", Some("0.5 -1 2\n1.5 0.25 -3\n0 0 1\n"))] {
            let path = dir.join(name);
            match text {
                None => write_ply(&path, &cloud).unwrap(),
                Some(t) => std::fs::write(&path, t).unwrap(),
            }
            let from_file = read_cloud(&path, &LoadOptions::default()).unwrap().0;
            let bytes = std::fs::read(&path).unwrap();
            let from_bytes = read_cloud_bytes(name, &bytes, &LoadOptions::default()).unwrap().0;
            assert_eq!(from_bytes, from_file, "{name}");
            assert_eq!(from_bytes.points, cloud.points, "{name}");
        }
        let _ = std::fs::remove_dir_all(&dir);
        let cut = read_cloud_bytes("scan.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 9\nproperty float x\nproperty float y\nproperty float z\nend_header\n\x00\x00", &LoadOptions::default()).unwrap_err().to_string();
        assert!(cut.contains("scan.ply"), "{cut}");
        let nul = read_cloud_bytes("scan.xyz", b"1 2 3\n\x004 5 6\n", &LoadOptions::default()).unwrap_err().to_string();
        assert!(nul.contains("scan.xyz"), "{nul}");
        let ext = read_cloud_bytes("scan.obj", b"v 1 2 3", &LoadOptions::default()).unwrap_err().to_string();
        assert!(ext.contains("scan.obj") && ext.contains(".ply"), "{ext}");
    }

    #[test]
    fn scalar_decodes_both_endians() {
        assert_eq!(Scalar::I16.decode(&[0xff, 0xfe], false), Some(-257.0));
        assert_eq!(Scalar::I16.decode(&[0xff, 0xfe], true), Some(-2.0));
        assert_eq!(Scalar::U32.decode(&[1, 0, 0, 0], false), Some(1.0));
        assert_eq!(Scalar::F32.decode(&1.5f32.to_be_bytes(), true), Some(1.5));
        assert_eq!(Scalar::F64.decode(&[0; 7], false), None);
        assert!(Scalar::U8.is_integer() && !Scalar::F64.is_integer());
    }

    #[test]
    fn capacity_is_capped_by_bytes_and_constant() {
        assert_eq!(capped_capacity(1_000_000_000_000, 200, 12), 16);
        assert_eq!(capped_capacity(10, 1 << 30, 12), 10);
        assert_eq!(capped_capacity(u64::MAX, usize::MAX, 1), MAX_PREALLOC);
        assert_eq!(capped_capacity(5, 100, 0), 5);
    }

    #[test]
    fn text_lines_number_lines_and_track_offsets() {
        let data = b"a\r\n\n  \nb";
        let mut lines = TextLines::new(data, 0, 0);
        assert_eq!(lines.next_raw(), Some((1, &b"a\r"[..])));
        assert_eq!(lines.pos(), 3);
        assert_eq!(lines.next_nonblank(), Some((4, &b"b"[..])));
        assert_eq!(lines.next_raw(), None);
        assert_eq!(lines.eof_line(), 5);
    }

    #[test]
    fn builder_drops_and_counts() {
        let options = LoadOptions { zero_points: ZeroPoints::Drop, ..LoadOptions::default() };
        let mut b = CloudBuilder::new(&options, true, 4);
        b.push(&[1.0, 2.0, 3.0, 0.0, 0.0, 1.0]);
        b.push(&[f64::NAN, 2.0, 3.0, 0.0, 0.0, 1.0]);
        b.push(&[1.0, 2.0, 3.0, f64::INFINITY, 0.0, 1.0]);
        b.push(&[1e300, 2.0, 3.0, 0.0, 0.0, 1.0]);
        b.push(&[0.0, -0.0, 0.0, 0.0, 0.0, 1.0]);
        b.push(&[4.0, 5.0, 6.0, 0.0, 0.0, 0.0]);
        let (cloud, report) = b.finish();
        assert_eq!(cloud.points, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
        assert_eq!(cloud.normals, Some(vec![[0.0, 0.0, 1.0], [0.0, 0.0, 0.0]]));
        assert_eq!(report, LoadReport { dropped_non_finite: 3, dropped_zero: 1, origin: [0; 3] });
    }

    /// The default drops points exactly at the origin only when several are there (a sensor's no-returns); a lone
    /// one is kept, and `Keep` keeps them all. Checked against the expected clouds written out by hand.
    #[test]
    fn no_return_points_are_dropped_only_as_a_pattern() {
        let load = |zero_points, rows: &[[f64; 3]]| {
            let options = LoadOptions { zero_points, ..LoadOptions::default() };
            let mut b = CloudBuilder::new(&options, true, 0);
            for (i, r) in rows.iter().enumerate() {
                b.push(&[r[0], r[1], r[2], 0.0, 0.0, i as f64]);
            }
            b.finish()
        };
        let sweep = [[1.0, 2.0, 3.0], [0.0; 3], [4.0, 5.0, 6.0], [0.0; 3], [0.0, 0.0, 7.0], [0.0; 3]];
        let (cloud, report) = load(ZeroPoints::Auto, &sweep);
        assert_eq!(cloud.points, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [0.0, 0.0, 7.0]]);
        assert_eq!(cloud.normals, Some(vec![[0.0, 0.0, 0.0], [0.0, 0.0, 2.0], [0.0, 0.0, 4.0]]));
        assert_eq!(report.dropped_zero, 3);
        let (cloud, report) = load(ZeroPoints::Keep, &sweep);
        assert_eq!((cloud.len(), report.dropped_zero), (6, 0));
        let object = [[1.0, 2.0, 3.0], [0.0; 3], [4.0, 5.0, 6.0]];
        let (cloud, report) = load(ZeroPoints::Auto, &object);
        assert_eq!((cloud.points[1], report.dropped_zero), ([0.0; 3], 0));
        let (cloud, report) = load(ZeroPoints::Drop, &object);
        assert_eq!((cloud.len(), report.dropped_zero), (2, 1));
    }

    #[test]
    fn builder_ignores_normal_values_without_normals() {
        let mut b = CloudBuilder::new(&LoadOptions::default(), false, 0);
        b.push(&[0.0, 0.0, 0.0, f64::NAN, 0.0, 0.0]);
        let (cloud, report) = b.finish();
        assert_eq!(cloud.points, vec![[0.0; 3]]);
        assert_eq!(cloud.normals, None);
        assert_eq!(report, LoadReport::default());
    }

    #[test]
    fn rows_are_filtered_and_shifted_as_files_are() {
        let text = "1e5 2 3\nnan 1 1\n100001 5 inf\n1e300 0 0\n0 0 0\n100000.5 2.25 -3\n";
        let options =
            LoadOptions { zero_points: ZeroPoints::Drop, origin: OriginShift::Auto, ..LoadOptions::default() };
        let from_file = xyz::parse(Path::new("rows.xyz"), text.as_bytes(), &options, true).unwrap();
        let rows = text.lines().map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|t| t.parse().unwrap()).collect();
            [v[0], v[1], v[2], 0.0, 0.0, 0.0]
        });
        let from_rows = cloud_from_rows(rows, false, &options);
        assert_eq!(from_rows, from_file);
        assert_eq!(from_rows.0.points, vec![[0.0, 0.0, 0.0], [0.5, 0.25, -6.0]]);
        assert_eq!(from_rows.1, LoadReport { dropped_non_finite: 3, dropped_zero: 1, origin: [100_000, 2, 3] });
    }

    #[test]
    fn extensions_pick_formats() {
        assert_eq!(Format::from_path(Path::new("a/b.PLY")).ok(), Some(Format::Ply));
        assert_eq!(Format::from_path(Path::new("b.pcd")).ok(), Some(Format::Pcd));
        assert_eq!(Format::from_path(Path::new("b.Pts")).ok(), Some(Format::Xyz));
        let err = Format::from_path(Path::new("b.obj")).unwrap_err().to_string();
        assert!(err.contains("'.obj'") && err.contains(".ply") && err.contains(".pts"), "{err}");
        let err = Format::from_path(Path::new("noext")).unwrap_err().to_string();
        assert!(err.contains("no file extension"), "{err}");
    }
}
