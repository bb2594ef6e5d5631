//! PLY: reader for ascii, binary_little_endian and binary_big_endian files; binary little-endian writer.
//!
//! The `vertex` element must have scalar `x y z` properties; `nx ny nz` are used when all three are present.
//! Every other vertex property and every other element (faces with list properties, edges...) is read past
//! and validated but not kept.

use super::{
    CloudBuilder, LoadOptions, LoadReport, Scalar, TextLines, at_byte, at_line, capped_capacity, ends_after, line_str,
    parse_number,
};
use crate::cloud::PointCloud;
use crate::error::Result;
use std::path::Path;

/// How the body is encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Encoding {
    /// Whitespace separated text, one element item per line.
    Ascii,
    /// Packed binary; `big_endian` picks the byte order.
    Binary {
        /// True for `binary_big_endian`.
        big_endian: bool,
    },
}

/// The type of one property.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    /// One value.
    Scalar(Scalar),
    /// A count of type `count`, then that many values of type `item`.
    List {
        /// Type of the leading count (an integer type).
        count: Scalar,
        /// Type of each item.
        item: Scalar,
    },
}

/// One `property` line.
#[derive(Clone, Debug)]
struct Property {
    /// Property name.
    name: String,
    /// Property type.
    kind: Kind,
}

/// One `element` line and its properties.
#[derive(Clone, Debug)]
struct Element {
    /// Element name ("vertex", "face"...).
    name: String,
    /// Number of items the header declares (untrusted).
    count: u64,
    /// Properties in file order.
    properties: Vec<Property>,
    /// Header line of the `element` line.
    line: usize,
}

impl Element {
    /// Bytes per item when every property is a scalar; `None` with list properties.
    fn fixed_stride(&self) -> Option<usize> {
        self.properties
            .iter()
            .map(|p| match p.kind {
                Kind::Scalar(s) => Some(s.size()),
                Kind::List { .. } => None,
            })
            .sum()
    }

    /// The fewest bytes one binary item can take (lists empty).
    fn min_binary_size(&self) -> usize {
        self.properties
            .iter()
            .map(|p| match p.kind {
                Kind::Scalar(s) | Kind::List { count: s, .. } => s.size(),
            })
            .sum()
    }
}

/// A parsed header.
#[derive(Debug)]
struct Header {
    /// Body encoding.
    encoding: Encoding,
    /// Elements in file order.
    elements: Vec<Element>,
    /// Offset of the first body byte.
    body_start: usize,
    /// Line number of `end_header`.
    end_line: usize,
}

/// Where the vertex element's values go: for each property, the slot in x, y, z, nx, ny, nz (if kept).
#[derive(Debug)]
struct VertexLayout {
    /// Index of the vertex element in [`Header::elements`].
    element: usize,
    /// One entry per vertex property.
    slots: Vec<Option<usize>>,
    /// True when nx, ny and nz are all present.
    normals: bool,
}

/// Parses a PLY file's bytes.
pub(super) fn parse(path: &Path, data: &[u8], options: &LoadOptions) -> Result<(PointCloud, LoadReport)> {
    let header = parse_header(path, data)?;
    let layout = vertex_layout(path, &header)?;
    let vertex = &header.elements[layout.element];
    let body = &data[header.body_start..];
    let min_item = match header.encoding {
        Encoding::Ascii => 2 * vertex.properties.len(),
        Encoding::Binary { .. } => vertex.min_binary_size(),
    };
    let capacity = capped_capacity(vertex.count, body.len(), min_item);
    let mut builder = CloudBuilder::new(options, layout.normals, capacity);
    match header.encoding {
        Encoding::Ascii => read_ascii_body(path, data, &header, &layout, &mut builder)?,
        Encoding::Binary { big_endian } => {
            let mut reader = BinaryReader { path, data, pos: header.body_start, big_endian };
            for (i, element) in header.elements.iter().enumerate() {
                let sink = (i == layout.element).then_some((&layout, &mut builder));
                reader.element(element, sink)?;
            }
        }
    }
    Ok(builder.finish())
}

/// Parses the header up to and including `end_header`.
fn parse_header(path: &Path, data: &[u8]) -> Result<Header> {
    let mut lines = TextLines::new(data, 0, 0);
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    let end_line = loop {
        let Some((n, raw)) = lines.next_raw() else {
            return Err(at_line(path, lines.eof_line(), "header ends without an 'end_header' line"));
        };
        if n > 1 && std::str::from_utf8(raw).is_err() {
            return Err(at_line(path, n, "binary data in the header: no 'end_header' line before it"));
        }
        let line = line_str(path, n, raw)?;
        if n == 1 {
            if line.trim() != "ply" {
                return Err(at_line(path, 1, "not a PLY file: the first line must be 'ply'"));
            }
            continue;
        }
        let mut words = line.split_ascii_whitespace();
        match words.next() {
            None | Some("comment") | Some("obj_info") => {}
            Some("format") => encoding = Some(parse_format(path, n, words.collect())?),
            Some("element") => {
                let element = parse_element(path, n, words.collect())?;
                if element.name == "vertex" && elements.iter().any(|e| e.name == "vertex") {
                    return Err(at_line(path, n, "more than one 'vertex' element"));
                }
                elements.push(element);
            }
            Some("property") => {
                let property = parse_property(path, n, words.collect())?;
                let element =
                    elements.last_mut().ok_or_else(|| at_line(path, n, "'property' line before any 'element' line"))?;
                element.properties.push(property);
            }
            Some("end_header") => break n,
            Some(other) if other.parse::<f64>().is_ok() => {
                return Err(at_line(path, n, "data before 'end_header' (the header has no 'end_header' line)"));
            }
            Some(other) => return Err(at_line(path, n, format!("unknown header keyword '{other}'"))),
        }
    };
    let encoding = encoding.ok_or_else(|| at_line(path, end_line, "header has no 'format' line"))?;
    Ok(Header { encoding, elements, body_start: lines.pos(), end_line })
}

/// Parses the words after `format`: an encoding and a version.
fn parse_format(path: &Path, line: usize, words: Vec<&str>) -> Result<Encoding> {
    let encoding = match words.first().copied() {
        Some("ascii") => Encoding::Ascii,
        Some("binary_little_endian") => Encoding::Binary { big_endian: false },
        Some("binary_big_endian") => Encoding::Binary { big_endian: true },
        Some(other) => return Err(at_line(path, line, format!("unknown PLY format '{other}'"))),
        None => return Err(at_line(path, line, "'format' line has no format")),
    };
    if words.len() != 2 {
        return Err(at_line(path, line, "expected 'format <encoding> <version>'"));
    }
    Ok(encoding)
}

/// Parses the words after `element`: a name and a count.
fn parse_element(path: &Path, line: usize, words: Vec<&str>) -> Result<Element> {
    let [name, count] = words[..] else {
        return Err(at_line(path, line, "expected 'element <name> <count>'"));
    };
    let count = count
        .parse::<u64>()
        .map_err(|_| at_line(path, line, format!("element '{name}' has an invalid count '{count}'")))?;
    Ok(Element { name: name.to_string(), count, properties: Vec::new(), line })
}

/// Parses the words after `property`: `<type> <name>` or `list <count type> <item type> <name>`.
fn parse_property(path: &Path, line: usize, words: Vec<&str>) -> Result<Property> {
    let scalar =
        |name: &str| scalar_type(name).ok_or_else(|| at_line(path, line, format!("unknown property type '{name}'")));
    match words[..] {
        ["list", count, item, name] => {
            let count = scalar(count)?;
            if !count.is_integer() {
                return Err(at_line(path, line, format!("list count type of '{name}' must be an integer type")));
            }
            Ok(Property { name: name.to_string(), kind: Kind::List { count, item: scalar(item)? } })
        }
        [ty, name] if ty != "list" => Ok(Property { name: name.to_string(), kind: Kind::Scalar(scalar(ty)?) }),
        _ => Err(at_line(path, line, "expected 'property <type> <name>' or 'property list <type> <type> <name>'")),
    }
}

/// The scalar type for a PLY type name (classic names and their sized aliases).
fn scalar_type(name: &str) -> Option<Scalar> {
    Some(match name {
        "char" | "int8" => Scalar::I8,
        "uchar" | "uint8" => Scalar::U8,
        "short" | "int16" => Scalar::I16,
        "ushort" | "uint16" => Scalar::U16,
        "int" | "int32" => Scalar::I32,
        "uint" | "uint32" => Scalar::U32,
        "float" | "float32" => Scalar::F32,
        "double" | "float64" => Scalar::F64,
        _ => return None,
    })
}

/// Finds the vertex element and maps its x, y, z (and nx, ny, nz) properties to slots.
fn vertex_layout(path: &Path, header: &Header) -> Result<VertexLayout> {
    let element = header
        .elements
        .iter()
        .position(|e| e.name == "vertex")
        .ok_or_else(|| at_line(path, header.end_line, "no 'vertex' element in the header"))?;
    let vertex = &header.elements[element];
    let find = |name: &str| vertex.properties.iter().position(|p| p.name == name);
    let missing: Vec<String> = ["x", "y", "z"].iter().filter(|n| find(n).is_none()).map(|n| format!("'{n}'")).collect();
    if !missing.is_empty() {
        let noun = if missing.len() == 1 { "property" } else { "properties" };
        return Err(at_line(path, vertex.line, format!("vertex element has no {} {noun}", missing.join(", "))));
    }
    let normals = ["nx", "ny", "nz"].iter().all(|n| find(n).is_some());
    let wanted: &[&str] = if normals { &["x", "y", "z", "nx", "ny", "nz"] } else { &["x", "y", "z"] };
    let mut slots = vec![None; vertex.properties.len()];
    for (slot, name) in wanted.iter().enumerate() {
        let index = find(name).unwrap_or_default();
        if matches!(vertex.properties[index].kind, Kind::List { .. }) {
            return Err(at_line(path, vertex.line, format!("vertex property '{name}' is a list, not a number")));
        }
        slots[index] = Some(slot);
    }
    Ok(VertexLayout { element, slots, normals })
}

/// Reads an ascii body: each element item on its own line, blank lines ignored, extra lines at the end ignored.
fn read_ascii_body(
    path: &Path,
    data: &[u8],
    header: &Header,
    layout: &VertexLayout,
    builder: &mut CloudBuilder,
) -> Result<()> {
    let mut lines = TextLines::new(data, header.body_start, header.end_line);
    let mut values = [0.0f64; 6];
    for (e, element) in header.elements.iter().enumerate() {
        if element.properties.is_empty() {
            continue;
        }
        let slots = (e == layout.element).then_some(layout.slots.as_slice());
        for done in 0..element.count {
            let Some((n, raw)) = lines.next_nonblank() else {
                return Err(at_line(path, lines.eof_line(), ends_after(done, element.count, &element.name)));
            };
            let text = line_str(path, n, raw)?;
            parse_ascii_item(path, n, text, element, slots, &mut values)?;
            if slots.is_some() {
                builder.push(&values);
            }
        }
    }
    Ok(())
}

/// Parses one ascii item of `element`; values of properties with a slot go to `values`.
fn parse_ascii_item(
    path: &Path,
    line: usize,
    text: &str,
    element: &Element,
    slots: Option<&[Option<usize>]>,
    values: &mut [f64; 6],
) -> Result<()> {
    let mut tokens = text.split_ascii_whitespace();
    if element.fixed_stride().is_some() {
        let (expected, found) = (element.properties.len(), tokens.clone().count());
        if expected != found {
            return Err(at_line(
                path,
                line,
                format!("expected {expected} values for a '{}' element, found {found}", element.name),
            ));
        }
    }
    for (i, property) in element.properties.iter().enumerate() {
        let mut next = |what: &str| {
            tokens.next().ok_or_else(|| at_line(path, line, format!("line ends before {what} '{}'", property.name)))
        };
        match property.kind {
            Kind::Scalar(_) => {
                let token = next("property")?;
                let value = parse_number(path, line, token, || format!("property '{}'", property.name))?;
                if let Some(slot) = slots.and_then(|s| s[i]) {
                    values[slot] = value;
                }
            }
            Kind::List { .. } => {
                let token = next("list")?;
                let count = token.parse::<u64>().map_err(|_| {
                    at_line(path, line, format!("'{token}' is not a valid count for list '{}'", property.name))
                })?;
                for _ in 0..count {
                    let token = next("the end of list")?;
                    parse_number(path, line, token, || format!("an item of list '{}'", property.name))?;
                }
            }
        }
    }
    if tokens.next().is_some() {
        return Err(at_line(path, line, format!("more values than the '{}' element declares", element.name)));
    }
    Ok(())
}

/// Reads a binary body element by element, checking every read against the bytes available.
struct BinaryReader<'a> {
    /// The file (for errors).
    path: &'a Path,
    /// The whole file.
    data: &'a [u8],
    /// Offset of the next byte to read.
    pos: usize,
    /// Byte order.
    big_endian: bool,
}

impl<'a> BinaryReader<'a> {
    /// Bytes left after `pos`.
    fn remaining(&self) -> usize {
        self.data.len().saturating_sub(self.pos)
    }

    /// Reads (or, without a sink, skips) every item of `element`; vertex values go to `sink`.
    fn element(&mut self, element: &Element, sink: Option<(&VertexLayout, &mut CloudBuilder)>) -> Result<()> {
        if element.properties.is_empty() || element.count == 0 {
            return Ok(());
        }
        match element.fixed_stride() {
            Some(stride) => self.fixed_element(element, stride, sink),
            None => self.list_element(element, sink),
        }
    }

    /// Reads an element whose items all have `stride` bytes, after checking the whole element fits.
    fn fixed_element(
        &mut self,
        element: &Element,
        stride: usize,
        sink: Option<(&VertexLayout, &mut CloudBuilder)>,
    ) -> Result<()> {
        let total = usize::try_from(element.count).ok().and_then(|c| c.checked_mul(stride));
        let end = total.and_then(|t| self.pos.checked_add(t));
        let Some(bytes) = end.and_then(|end| self.data.get(self.pos..end)) else {
            let done = self.remaining() / stride;
            let at = self.pos + done * stride;
            return Err(at_byte(self.path, at, ends_after(done as u64, element.count, &element.name)));
        };
        self.pos += bytes.len();
        let Some((layout, builder)) = sink else { return Ok(()) };
        let mut offsets = Vec::new();
        let mut offset = 0;
        for (property, slot) in element.properties.iter().zip(&layout.slots) {
            if let (Kind::Scalar(ty), Some(slot)) = (property.kind, slot) {
                offsets.push((*slot, offset, ty));
            }
            offset += property_size(property.kind);
        }
        let mut values = [0.0f64; 6];
        for item in bytes.chunks_exact(stride) {
            for &(slot, offset, ty) in &offsets {
                values[slot] = item.get(offset..).and_then(|b| ty.decode(b, self.big_endian)).unwrap_or(f64::NAN);
            }
            builder.push(&values);
        }
        Ok(())
    }

    /// Reads an element with list properties item by item.
    fn list_element(&mut self, element: &Element, mut sink: Option<(&VertexLayout, &mut CloudBuilder)>) -> Result<()> {
        let path = self.path;
        let mut values = [0.0f64; 6];
        for done in 0..element.count {
            for (i, property) in element.properties.iter().enumerate() {
                let eof = |at: usize| at_byte(path, at, ends_after(done, element.count, &element.name));
                match property.kind {
                    Kind::Scalar(ty) => {
                        let value = self.scalar(ty).ok_or_else(|| eof(self.pos))?;
                        if let Some(slot) = sink.as_ref().and_then(|(layout, _)| layout.slots[i]) {
                            values[slot] = value;
                        }
                    }
                    Kind::List { count, item } => {
                        let at = self.pos;
                        let n = self.scalar(count).ok_or_else(|| eof(at))?;
                        if n < 0.0 {
                            let message = format!("list '{}' has a negative count {n}", property.name);
                            return Err(at_byte(path, at, message));
                        }
                        let len = (n as usize).checked_mul(item.size()).filter(|&l| l <= self.remaining());
                        let Some(len) = len else { return Err(eof(self.pos)) };
                        self.pos += len;
                    }
                }
            }
            if let Some((_, builder)) = sink.as_mut() {
                builder.push(&values);
            }
        }
        Ok(())
    }

    /// Reads one scalar at `pos` and advances; `None` when the file ends first.
    fn scalar(&mut self, ty: Scalar) -> Option<f64> {
        let value = ty.decode(self.data.get(self.pos..)?, self.big_endian)?;
        self.pos += ty.size();
        Some(value)
    }
}

/// Bytes a property takes in a binary item (lists: just the count).
fn property_size(kind: Kind) -> usize {
    match kind {
        Kind::Scalar(s) | Kind::List { count: s, .. } => s.size(),
    }
}

/// Encodes `cloud` as binary little-endian PLY, with `uchar red green blue` per vertex when `colors` is given;
/// an error message when the normals or colours don't match the points one to one.
pub(super) fn encode_binary_le(cloud: &PointCloud, colors: Option<&[[u8; 3]]>) -> Result<Vec<u8>, String> {
    let normals = super::checked_normals(cloud)?;
    if let Some(c) = colors
        && c.len() != cloud.points.len()
    {
        return Err(format!("{} colours for {} points", c.len(), cloud.points.len()));
    }
    let mut header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment written by dpr-gpu\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\n",
        cloud.points.len()
    );
    if normals.is_some() {
        header.push_str("property float nx\nproperty float ny\nproperty float nz\n");
    }
    if colors.is_some() {
        header.push_str("property uchar red\nproperty uchar green\nproperty uchar blue\n");
    }
    header.push_str("end_header\n");
    let stride = if normals.is_some() { 24 } else { 12 } + if colors.is_some() { 3 } else { 0 };
    let mut bytes = Vec::with_capacity(header.len() + cloud.points.len() * stride);
    bytes.extend_from_slice(header.as_bytes());
    for (i, point) in cloud.points.iter().enumerate() {
        let normal = normals.map(|n| &n[i]);
        for value in point.iter().chain(normal.into_iter().flatten()) {
            bytes.extend_from_slice(&value.to_le_bytes());
        }
        if let Some(c) = colors {
            bytes.extend_from_slice(&c[i]);
        }
    }
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Parses `text` as a PLY file named "t.ply".
    fn parse_str(data: &[u8]) -> Result<(PointCloud, LoadReport)> {
        parse(Path::new("t.ply"), data, &LoadOptions::default())
    }

    #[test]
    fn type_aliases_match() {
        for (a, b) in [("char", "int8"), ("uchar", "uint8"), ("short", "int16"), ("ushort", "uint16")] {
            assert_eq!(scalar_type(a), scalar_type(b));
        }
        for (a, b) in [("int", "int32"), ("uint", "uint32"), ("float", "float32"), ("double", "float64")] {
            assert_eq!(scalar_type(a), scalar_type(b));
        }
        assert_eq!(scalar_type("float17"), None);
    }

    #[test]
    fn ascii_with_lists_and_crlf() {
        let data = b"ply\r\nformat ascii 1.0\r\ncomment hi\r\nelement vertex 2\r\nproperty float x\r\n\
            property float y\r\nproperty float z\r\nelement face 1\r\nproperty list uchar int vertex_indices\r\n\
            end_header\r\n1 2 3\r\n4 5 6\r\n2 0 1\r\n";
        let (cloud, _) = parse_str(data).unwrap();
        assert_eq!(cloud.points, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
        assert_eq!(cloud.normals, None);
    }

    #[test]
    fn ascii_list_count_mismatch_is_an_error() {
        let data = b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n\
            property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n1 2 3\n3 0 1\n";
        let err = parse_str(data).unwrap_err().to_string();
        assert!(err.contains("line 11") && err.contains("vertex_indices"), "{err}");
    }

    #[test]
    fn binary_negative_list_count_is_an_error() {
        let mut data = b"ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\n\
            property float y\nproperty float z\nelement face 1\nproperty list char int vertex_indices\nend_header\n"
            .to_vec();
        let at = data.len();
        data.push(0xff);
        let err = parse_str(&data).unwrap_err().to_string();
        assert!(err.contains(&format!("byte {at}")) && err.contains("negative"), "{err}");
    }

    #[test]
    fn encode_rejects_mismatched_normals() {
        let cloud = PointCloud { points: vec![[0.0; 3]], normals: Some(vec![]) };
        assert!(encode_binary_le(&cloud, None).is_err());
    }

    #[test]
    fn colours_are_written_after_the_floats_and_read_back_as_points() {
        let cloud = PointCloud { points: vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], normals: None };
        assert!(encode_binary_le(&cloud, Some(&[[1, 2, 3]])).is_err());
        let bytes = encode_binary_le(&cloud, Some(&[[1, 2, 3], [250, 251, 252]])).unwrap();
        let text = String::from_utf8_lossy(&bytes);
        assert!(text.contains("property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"));
        let body = &bytes[text.find("end_header\n").unwrap() + "end_header\n".len()..];
        assert_eq!(body.len(), 2 * 15);
        assert_eq!(&body[12..15], &[1, 2, 3]);
        assert_eq!(&body[27..30], &[250, 251, 252]);
        assert_eq!(parse_str(&bytes).unwrap().0, cloud);
    }
}
