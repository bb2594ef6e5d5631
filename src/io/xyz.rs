//! XYZ text (.xyz, .txt, .pts): one point per line, values separated by whitespace or by commas.
//!
//! Columns: `x y z` (3), `x y z` plus one or two ignored columns (4 or 5), or 6 or more columns, where
//! columns 4-6 may be normals or colour: they are read as normals only when every row's (c4, c5, c6) has unit
//! length (or is zero); otherwise the file is refused and the user says which with [`XyzColumns`]
//! (`--xyz-columns x,y,z,r,g,b`). `.pts` files, whose columns 4-7 are usually intensity and colour, never
//! yield normals unless [`XyzColumns`] says so. Every data line must have the same number of columns. Lines starting with
//! `#` and blank lines are skipped. A first data line holding a single non-negative integer is taken as the
//! point-count line of the PTS convention and skipped.

use super::{CloudBuilder, LoadOptions, LoadReport, TextLines, at_line, capped_capacity, line_str, parse_number};
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use std::path::Path;

/// Largest deviation from 1 of a row's (c4, c5, c6) length for the columns to count as unit normals.
pub const UNIT_NORMAL_TOLERANCE: f64 = 0.01;

/// What each column of an XYZ file holds, as named by the user (`x,y,z,nx,ny,nz` or `x,y,z,r,g,b`...).
/// Columns named anything but `x y z nx ny nz` are ignored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct XyzColumns {
    /// 0-based column of x, y, z, nx, ny, nz; `u8::MAX` for the normals when absent.
    slots: [u8; 6],
    /// Columns per line.
    count: u8,
}

impl XyzColumns {
    /// Parses a comma-separated list of column names; `x`, `y` and `z` are required, `nx ny nz` all or none.
    pub fn parse(spec: &str) -> Result<XyzColumns> {
        let names: Vec<&str> = spec.split(',').map(str::trim).collect();
        let bad = |m: String| Error::invalid(format!("--xyz-columns '{spec}': {m}"));
        if names.len() < 3 || names.len() > 64 {
            return Err(bad(format!("expected 3 to 64 column names, got {}", names.len())));
        }
        let mut slots = [u8::MAX; 6];
        for (i, name) in names.iter().enumerate() {
            let slot = ["x", "y", "z", "nx", "ny", "nz"].iter().position(|k| k.eq_ignore_ascii_case(name));
            if let Some(k) = slot {
                if slots[k] != u8::MAX {
                    return Err(bad(format!("column '{name}' named twice")));
                }
                slots[k] = i as u8;
            }
        }
        if slots[..3].contains(&u8::MAX) {
            return Err(bad("x, y and z are required".into()));
        }
        let normals = slots[3..].iter().filter(|&&s| s != u8::MAX).count();
        if normals != 0 && normals != 3 {
            return Err(bad("give all of nx, ny, nz or none".into()));
        }
        Ok(XyzColumns { slots, count: names.len() as u8 })
    }

    /// True when the columns include normals.
    pub fn has_normals(&self) -> bool {
        self.slots[3] != u8::MAX
    }
}

/// The column count fixed by the first data line, and that line's number.
#[derive(Clone, Copy, Debug)]
struct Columns {
    /// Columns per line.
    count: usize,
    /// The line that fixed it.
    line: usize,
}

/// Parses an XYZ text file's bytes.
/// `columns_456_are_normals` is false for formats whose extra columns are not normals (PTS).
pub(super) fn parse(
    path: &Path,
    data: &[u8],
    options: &LoadOptions,
    columns_456_are_normals: bool,
) -> Result<(PointCloud, LoadReport)> {
    let mut lines = TextLines::new(data, 0, 0);
    let mut tokens: Vec<&str> = Vec::new();
    let mut columns: Option<Columns> = None;
    let mut builder: Option<CloudBuilder> = None;
    let mut first_data_line = true;
    let mut not_normal: Option<(usize, f64)> = None;
    while let Some((n, raw)) = lines.next_nonblank() {
        let text = line_str(path, n, raw)?.trim();
        if text.starts_with('#') {
            continue;
        }
        split_columns(path, n, text, &mut tokens)?;
        if std::mem::take(&mut first_data_line) && tokens.len() == 1 && tokens[0].parse::<u64>().is_ok() {
            continue;
        }
        let cols = match columns {
            Some(cols) => cols,
            None => *columns.insert(first_columns(path, n, tokens.len())?),
        };
        if tokens.len() != cols.count {
            let message = format!(
                "{} columns, but line {} has {}; every line must have the same number of columns",
                tokens.len(),
                cols.line,
                cols.count
            );
            return Err(at_line(path, n, message));
        }
        if let Some(spec) = &options.xyz_columns
            && usize::from(spec.count) != cols.count
        {
            let message = format!("{} columns, but --xyz-columns names {}", cols.count, spec.count);
            return Err(at_line(path, n, message));
        }
        let normals = match &options.xyz_columns {
            Some(spec) => spec.has_normals(),
            None => columns_456_are_normals && cols.count >= 6,
        };
        let builder = builder.get_or_insert_with(|| {
            let capacity = capped_capacity(u64::MAX, data.len(), 2 * cols.count);
            CloudBuilder::new(options, normals, capacity)
        });
        let mut values = [0.0f64; 6];
        let used = if normals { 6 } else { 3 };
        for (k, value) in values.iter_mut().enumerate().take(used) {
            let i = options.xyz_columns.map_or(k, |spec| usize::from(spec.slots[k]));
            *value = parse_number(path, n, tokens[i], || column_hint(i))?;
        }
        if normals && options.xyz_columns.is_none() && not_normal.is_none() {
            let length = (values[3] * values[3] + values[4] * values[4] + values[5] * values[5]).sqrt();
            if length != 0.0 && (length - 1.0).abs() > UNIT_NORMAL_TOLERANCE {
                not_normal = Some((n, length));
            }
        }
        builder.push(&values);
    }
    if let Some((n, length)) = not_normal {
        let message = format!(
            "columns 4-6 are not unit normals (length {length:.3} here): they may be colour; say what the columns \
             hold with --xyz-columns, e.g. x,y,z,r,g,b or x,y,z,nx,ny,nz"
        );
        return Err(at_line(path, n, message));
    }
    Ok(builder.unwrap_or_else(|| CloudBuilder::new(options, false, 0)).finish())
}

/// What the error for a bad token in column `i` (0-based) says about it.
fn column_hint(i: usize) -> String {
    if i == 0 { "column 1; write column names as a '#' comment".to_string() } else { format!("column {}", i + 1) }
}

/// Checks the column count of the first data line.
fn first_columns(path: &Path, line: usize, count: usize) -> Result<Columns> {
    if count < 3 {
        let message = format!("expected at least 3 columns (x y z), found {count}");
        return Err(at_line(path, line, message));
    }
    Ok(Columns { count, line })
}

/// Splits a data line into `tokens`: on commas (each field trimmed, none empty) when the line has a comma, on
/// whitespace otherwise.
fn split_columns<'a>(path: &Path, line: usize, text: &'a str, tokens: &mut Vec<&'a str>) -> Result<()> {
    tokens.clear();
    if text.contains(',') {
        tokens.extend(text.split(',').map(str::trim));
        if let Some(i) = tokens.iter().position(|t| t.is_empty()) {
            return Err(empty_field(path, line, i));
        }
    } else {
        tokens.extend(text.split_ascii_whitespace());
    }
    Ok(())
}

/// The error for an empty comma-separated field (0-based column `i`).
fn empty_field(path: &Path, line: usize, i: usize) -> Error {
    at_line(path, line, format!("column {} is empty", i + 1))
}

/// Encodes `cloud` as XYZ text: `x y z` per line, plus `nx ny nz` with normals (shortest exact decimals).
pub(super) fn encode_text(cloud: &PointCloud) -> Result<Vec<u8>, String> {
    use std::fmt::Write;
    let normals = super::checked_normals(cloud)?;
    let mut text = String::with_capacity(cloud.points.len() * 40);
    text.push_str(if normals.is_some() { "# x y z nx ny nz\n" } else { "# x y z\n" });
    for (i, p) in cloud.points.iter().enumerate() {
        let _ = write!(text, "{} {} {}", p[0], p[1], p[2]);
        if let Some(n) = normals.map(|ns| ns[i]) {
            let _ = write!(text, " {} {} {}", n[0], n[1], n[2]);
        }
        text.push('\n');
    }
    Ok(text.into_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Parses `data` as an XYZ file named "t.xyz".
    fn parse_bytes(data: &[u8]) -> Result<(PointCloud, LoadReport)> {
        parse(Path::new("t.xyz"), data, &LoadOptions::default(), true)
    }

    #[test]
    fn pts_colour_columns_are_not_normals() {
        let data = b"1 2 3 40 255 0 0\n4 5 6 41 0 255 0\n";
        let (cloud, _) = parse(Path::new("t.pts"), data, &LoadOptions::default(), false).unwrap();
        assert_eq!(cloud.points, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
        assert_eq!(cloud.normals, None);
        let err = parse_bytes(data).unwrap_err().to_string();
        assert!(err.contains("line 1") && err.contains("--xyz-columns"), "{err}");
    }

    #[test]
    fn pts_count_line_is_skipped_and_extra_columns_ignored() {
        let (cloud, _) = parse_bytes(b"2\n1 2 3 7\n4 5 6 8\n").unwrap();
        assert_eq!(cloud.points, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
        assert_eq!(cloud.normals, None);
    }

    #[test]
    fn empty_comma_field_is_an_error() {
        let err = parse_bytes(b"1,,2\n").unwrap_err().to_string();
        assert!(err.contains("line 1") && err.contains("column 2 is empty"), "{err}");
    }

    #[test]
    fn too_few_columns_is_an_error() {
        let err = parse_bytes(b"# c\n1 2\n").unwrap_err().to_string();
        assert!(err.contains("line 2") && err.contains("at least 3 columns"), "{err}");
    }

    #[test]
    fn empty_file_gives_empty_cloud() {
        let (cloud, report) = parse_bytes(b"# nothing\n\n").unwrap();
        assert!(cloud.is_empty());
        assert_eq!(report, LoadReport::default());
    }

    #[test]
    fn header_row_gets_a_hint() {
        let err = parse_bytes(b"x,y,z\n1,2,3\n").unwrap_err().to_string();
        assert!(err.contains("'x' is not a number") && err.contains("'#' comment"), "{err}");
    }
}
