//! PCD (Point Cloud Library) reader: `DATA ascii` and `DATA binary` (little endian); `binary_compressed` is
//! refused with a clear error.
//!
//! Fields `x y z` are required (COUNT 1); `normal_x normal_y normal_z` are used when all three are present.
//! Other fields (rgb, intensity, curvature, multi-count descriptors, `_` padding) are read past.

use super::{
    CloudBuilder, LoadOptions, LoadReport, Scalar, TextLines, at_byte, at_line, capped_capacity, ends_after, line_str,
    parse_number,
};
use crate::cloud::PointCloud;
use crate::error::Result;
use std::path::Path;

/// Most values one point record may hold (the sum of every field's COUNT); real descriptors such as
/// VFH (308) stay far below it, and it bounds every per-point allocation and offset.
const MAX_VALUES_PER_POINT: usize = 1 << 16;

/// How the body is stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Data {
    /// One point per line.
    Ascii,
    /// Packed little-endian records.
    Binary,
}

/// One field of a point record.
#[derive(Clone, Debug)]
struct Field {
    /// Field name.
    name: String,
    /// Value type.
    ty: Scalar,
    /// Values per point.
    count: usize,
}

/// A header entry: the line it was on and its words after the keyword.
type Entry<'a> = (usize, Vec<&'a str>);

/// The raw header lines that matter, by keyword.
#[derive(Default)]
struct RawHeader<'a> {
    /// FIELDS line.
    fields: Option<Entry<'a>>,
    /// SIZE line.
    size: Option<Entry<'a>>,
    /// TYPE line.
    ty: Option<Entry<'a>>,
    /// COUNT line.
    count: Option<Entry<'a>>,
    /// WIDTH line.
    width: Option<Entry<'a>>,
    /// HEIGHT line.
    height: Option<Entry<'a>>,
    /// POINTS line.
    points: Option<Entry<'a>>,
}

/// A validated header.
#[derive(Debug)]
struct Header {
    /// Fields in record order.
    fields: Vec<Field>,
    /// Number of points (untrusted until checked against the body).
    points: u64,
    /// Body encoding.
    data: Data,
    /// Offset of the first body byte.
    body_start: usize,
    /// Line number of the DATA line.
    data_line: usize,
}

/// Where x, y, z (and normals) sit in a record: (slot, value index in ascii tokens, byte offset, type).
struct Layout {
    /// One entry per kept value.
    columns: Vec<(usize, usize, usize, Scalar)>,
    /// True when the normal fields are present.
    normals: bool,
    /// Values (ascii tokens) per point.
    values_per_point: usize,
    /// Bytes per binary record.
    stride: usize,
}

/// Parses a PCD file's bytes.
pub(super) fn parse(path: &Path, data: &[u8], options: &LoadOptions) -> Result<(PointCloud, LoadReport)> {
    let header = parse_header(path, data)?;
    let layout = layout(path, &header)?;
    let body = &data[header.body_start..];
    let min_item = match header.data {
        Data::Ascii => 2 * layout.values_per_point,
        Data::Binary => layout.stride,
    };
    let capacity = capped_capacity(header.points, body.len(), min_item);
    let mut builder = CloudBuilder::new(options, layout.normals, capacity);
    match header.data {
        Data::Ascii => read_ascii(path, data, &header, &layout, &mut builder)?,
        Data::Binary => read_binary(path, data, &header, &layout, &mut builder)?,
    }
    Ok(builder.finish())
}

/// Reads header lines up to and including DATA.
fn parse_header(path: &Path, data: &[u8]) -> Result<Header> {
    let mut lines = TextLines::new(data, 0, 0);
    let mut raw = RawHeader::default();
    let (data_line, kind) = loop {
        let Some((n, bytes)) = lines.next_raw() else {
            return Err(at_line(path, lines.eof_line(), "header ends without a DATA line"));
        };
        if n > 1 && std::str::from_utf8(bytes).is_err() {
            return Err(at_line(path, n, "binary data in the header: no DATA line before it"));
        }
        let line = line_str(path, n, bytes)?.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let mut words = line.split_ascii_whitespace();
        let keyword = words.next().unwrap_or_default();
        let entry = Some((n, words.collect::<Vec<_>>()));
        match keyword.to_ascii_uppercase().as_str() {
            "VERSION" | "VIEWPOINT" => {}
            "FIELDS" => raw.fields = entry,
            "SIZE" => raw.size = entry,
            "TYPE" => raw.ty = entry,
            "COUNT" => raw.count = entry,
            "WIDTH" => raw.width = entry,
            "HEIGHT" => raw.height = entry,
            "POINTS" => raw.points = entry,
            "DATA" => break (n, entry.map(|(_, w)| w).unwrap_or_default()),
            _ if keyword.parse::<f64>().is_ok() => {
                return Err(at_line(path, n, "point data before the DATA line (the header has no DATA line)"));
            }
            _ => return Err(at_line(path, n, format!("unknown header keyword '{keyword}'"))),
        }
    };
    let data_kind = match kind[..] {
        ["ascii"] => Data::Ascii,
        ["binary"] => Data::Binary,
        ["binary_compressed"] => {
            let message = "DATA binary_compressed is not supported; re-save the file as binary or ascii";
            return Err(at_line(path, data_line, message));
        }
        _ => return Err(at_line(path, data_line, format!("unknown DATA kind '{}'", kind.join(" ")))),
    };
    let fields = fields(path, data_line, &raw)?;
    let points = point_count(path, data_line, &raw)?;
    Ok(Header { fields, points, data: data_kind, body_start: lines.pos(), data_line })
}

/// Builds the field list from FIELDS, SIZE, TYPE and COUNT (default 1 each).
fn fields<'a>(path: &Path, data_line: usize, raw: &RawHeader<'a>) -> Result<Vec<Field>> {
    let required = |entry: &Option<Entry<'a>>, name: &str| {
        entry.clone().ok_or_else(|| at_line(path, data_line, format!("header has no {name} line")))
    };
    let (_, names) = required(&raw.fields, "FIELDS")?;
    let (size_line, sizes) = required(&raw.size, "SIZE")?;
    let (type_line, types) = required(&raw.ty, "TYPE")?;
    let (count_line, counts) = raw.count.clone().unwrap_or((data_line, vec!["1"; names.len()]));
    for (line, list, name) in [(size_line, &sizes, "SIZE"), (type_line, &types, "TYPE"), (count_line, &counts, "COUNT")]
    {
        if list.len() != names.len() {
            let message = format!("{name} has {} entries but FIELDS has {}", list.len(), names.len());
            return Err(at_line(path, line, message));
        }
    }
    let mut fields = Vec::with_capacity(names.len());
    for i in 0..names.len() {
        let ty = field_type(types[i], sizes[i]).ok_or_else(|| {
            let message = format!("field '{}' has an unsupported TYPE/SIZE {}/{}", names[i], types[i], sizes[i]);
            at_line(path, type_line, message)
        })?;
        let count = counts[i].parse::<usize>().ok().filter(|&c| c > 0).ok_or_else(|| {
            at_line(path, count_line, format!("field '{}' has an invalid COUNT '{}'", names[i], counts[i]))
        })?;
        if count > MAX_VALUES_PER_POINT {
            let message =
                format!("field '{}' has COUNT {count}; at most {MAX_VALUES_PER_POINT} are supported", names[i]);
            return Err(at_line(path, count_line, message));
        }
        fields.push(Field { name: names[i].to_string(), ty, count });
    }
    Ok(fields)
}

/// The scalar type for a PCD TYPE letter and SIZE.
fn field_type(ty: &str, size: &str) -> Option<Scalar> {
    Some(match (ty, size) {
        ("F", "4") => Scalar::F32,
        ("F", "8") => Scalar::F64,
        ("I", "1") => Scalar::I8,
        ("I", "2") => Scalar::I16,
        ("I", "4") => Scalar::I32,
        ("I", "8") => Scalar::I64,
        ("U", "1") => Scalar::U8,
        ("U", "2") => Scalar::U16,
        ("U", "4") => Scalar::U32,
        ("U", "8") => Scalar::U64,
        _ => return None,
    })
}

/// Parses the single number of a header entry.
fn entry_number(path: &Path, entry: &Entry, name: &str) -> Result<u64> {
    match entry.1[..] {
        [word] => word.parse::<u64>().ok(),
        _ => None,
    }
    .ok_or_else(|| at_line(path, entry.0, format!("{name} must be one non-negative integer")))
}

/// The number of points: POINTS, or WIDTH * HEIGHT; both must agree when both are given.
fn point_count(path: &Path, data_line: usize, raw: &RawHeader) -> Result<u64> {
    let width = raw.width.as_ref().map(|e| entry_number(path, e, "WIDTH")).transpose()?;
    let height = raw.height.as_ref().map(|e| entry_number(path, e, "HEIGHT")).transpose()?;
    let points = raw.points.as_ref().map(|e| entry_number(path, e, "POINTS")).transpose()?;
    let grid = width.map(|w| w.checked_mul(height.unwrap_or(1)));
    match (points, grid) {
        (Some(p), Some(g)) if g != Some(p) => {
            let line = raw.points.as_ref().map_or(data_line, |e| e.0);
            let message =
                format!("POINTS {p} does not match WIDTH x HEIGHT ({} x {})", width.unwrap_or(0), height.unwrap_or(1));
            Err(at_line(path, line, message))
        }
        (Some(p), _) => Ok(p),
        (None, Some(Some(g))) => Ok(g),
        (None, Some(None)) => Err(at_line(path, data_line, "WIDTH x HEIGHT overflows")),
        (None, None) => Err(at_line(path, data_line, "header has neither POINTS nor WIDTH")),
    }
}

/// Locates x, y, z and the normals in a record.
fn layout(path: &Path, header: &Header) -> Result<Layout> {
    let mut positions = Vec::with_capacity(header.fields.len());
    let (mut value, mut offset) = (0usize, 0usize);
    for field in &header.fields {
        positions.push((value, offset));
        value += field.count;
        offset += field.count * field.ty.size();
        if value > MAX_VALUES_PER_POINT {
            let message = format!("a point has more than {MAX_VALUES_PER_POINT} values (sum of COUNT)");
            return Err(at_line(path, header.data_line, message));
        }
    }
    let find = |name: &str| header.fields.iter().position(|f| f.name == name);
    let missing: Vec<String> = ["x", "y", "z"].iter().filter(|n| find(n).is_none()).map(|n| format!("'{n}'")).collect();
    if !missing.is_empty() {
        let noun = if missing.len() == 1 { "field" } else { "fields" };
        return Err(at_line(path, header.data_line, format!("no {} {noun} in FIELDS", missing.join(", "))));
    }
    let normals = ["normal_x", "normal_y", "normal_z"].iter().all(|n| find(n).is_some());
    let mut wanted = vec!["x", "y", "z"];
    if normals {
        wanted.extend(["normal_x", "normal_y", "normal_z"]);
    }
    let mut columns = Vec::with_capacity(wanted.len());
    for (slot, name) in wanted.iter().enumerate() {
        let index = find(name).unwrap_or_default();
        let field = &header.fields[index];
        if field.count != 1 {
            let message = format!("field '{name}' has COUNT {}; expected 1", field.count);
            return Err(at_line(path, header.data_line, message));
        }
        let (value, offset) = positions[index];
        columns.push((slot, value, offset, field.ty));
    }
    Ok(Layout { columns, normals, values_per_point: value, stride: offset })
}

/// Reads an ascii body: one point per line, blank lines ignored, every value must be a number.
fn read_ascii(path: &Path, data: &[u8], header: &Header, layout: &Layout, builder: &mut CloudBuilder) -> Result<()> {
    let mut lines = TextLines::new(data, header.body_start, header.data_line);
    let mut tokens = Vec::with_capacity(layout.values_per_point);
    let mut parsed = Vec::with_capacity(layout.values_per_point);
    let mut values = [0.0f64; 6];
    for done in 0..header.points {
        let Some((n, raw)) = lines.next_nonblank() else {
            return Err(at_line(path, lines.eof_line(), ends_after(done, header.points, "point")));
        };
        tokens.clear();
        tokens.extend(line_str(path, n, raw)?.split_ascii_whitespace());
        if tokens.len() != layout.values_per_point {
            let message = format!("expected {} values per point, found {}", layout.values_per_point, tokens.len());
            return Err(at_line(path, n, message));
        }
        parsed.clear();
        for (i, token) in tokens.iter().enumerate() {
            parsed.push(parse_number(path, n, token, || format!("value {} of the point", i + 1))?);
        }
        for &(slot, value, _, _) in &layout.columns {
            values[slot] = parsed[value];
        }
        builder.push(&values);
    }
    Ok(())
}

/// Reads a binary body: `points` packed little-endian records, checked to fit before reading.
fn read_binary(path: &Path, data: &[u8], header: &Header, layout: &Layout, builder: &mut CloudBuilder) -> Result<()> {
    let body = &data[header.body_start..];
    let total = usize::try_from(header.points).ok().and_then(|p| p.checked_mul(layout.stride));
    let Some(records) = total.and_then(|t| body.get(..t)) else {
        let done = body.len() / layout.stride;
        let at = header.body_start + done * layout.stride;
        return Err(at_byte(path, at, ends_after(done as u64, header.points, "point")));
    };
    let mut values = [0.0f64; 6];
    for record in records.chunks_exact(layout.stride) {
        for &(slot, _, offset, ty) in &layout.columns {
            values[slot] = record.get(offset..).and_then(|b| ty.decode(b, false)).unwrap_or(f64::NAN);
        }
        builder.push(&values);
    }
    Ok(())
}

/// Encodes `cloud` as a binary PCD (v0.7) file: `x y z`, plus `normal_x normal_y normal_z` with normals.
pub(super) fn encode_binary(cloud: &PointCloud) -> Result<Vec<u8>, String> {
    let normals = super::checked_normals(cloud)?;
    let (fields, size, ty, count) = if normals.is_some() {
        ("x y z normal_x normal_y normal_z", "4 4 4 4 4 4", "F F F F F F", "1 1 1 1 1 1")
    } else {
        ("x y z", "4 4 4", "F F F", "1 1 1")
    };
    let n = cloud.points.len();
    let header = format!(
        "# .PCD v0.7 - written by dpr-gpu\nVERSION 0.7\nFIELDS {fields}\nSIZE {size}\nTYPE {ty}\nCOUNT {count}\n\
         WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n"
    );
    let mut bytes = header.into_bytes();
    for (i, point) in cloud.points.iter().enumerate() {
        for value in point.iter().chain(normals.map(|ns| &ns[i]).into_iter().flatten()) {
            bytes.extend_from_slice(&value.to_le_bytes());
        }
    }
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Parses `data` as a PCD file named "t.pcd".
    fn parse_bytes(data: &[u8]) -> Result<(PointCloud, LoadReport)> {
        parse(Path::new("t.pcd"), data, &LoadOptions::default())
    }

    #[test]
    fn ascii_with_extra_fields_and_counts() {
        let data = b"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z rgb hist\nSIZE 4 4 4 4 4\nTYPE F F F U F\n\
            COUNT 1 1 1 1 2\nWIDTH 2\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA ascii\n\
            1 2 3 255 0.5 0.5\nnan 0 0 1 0 0\n";
        let (cloud, report) = parse_bytes(data).unwrap();
        assert_eq!(cloud.points, vec![[1.0, 2.0, 3.0]]);
        assert_eq!(report.dropped_non_finite, 1);
    }

    #[test]
    fn compressed_is_refused() {
        let data = b"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1\nPOINTS 1\nDATA binary_compressed\n";
        let err = parse_bytes(data).unwrap_err().to_string();
        assert!(err.contains("line 6") && err.contains("binary_compressed is not supported"), "{err}");
    }

    #[test]
    fn points_must_match_width_and_height() {
        let data = b"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 2\nHEIGHT 2\nPOINTS 3\nDATA ascii\n";
        let err = parse_bytes(data).unwrap_err().to_string();
        assert!(err.contains("line 6") && err.contains("POINTS 3"), "{err}");
    }

    #[test]
    fn bad_type_size_is_an_error() {
        let data = b"FIELDS x y z\nSIZE 4 4 2\nTYPE F F F\nPOINTS 0\nDATA ascii\n";
        let err = parse_bytes(data).unwrap_err().to_string();
        assert!(err.contains("line 3") && err.contains("F/2"), "{err}");
    }
}
