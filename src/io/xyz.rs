//! XYZ text (.xyz, .txt, .pts): one point per line, values separated by whitespace or by commas.
//!
//! Columns: `x y z` (3), `x y z` plus one or two ignored columns (4 or 5), or `x y z nx ny nz ...` (6 or more,
//! columns after the sixth ignored; `.pts` files, whose columns 4-7 are usually intensity and colour, never
//! yield normals). Every data line must have the same number of columns. Lines starting with
//! `#` and blank lines are skipped. A first data line holding a single non-negative integer is taken as the
//! point-count line of the PTS convention and skipped.

use super::{CloudBuilder, LoadOptions, LoadReport, TextLines, at_line, capped_capacity, line_str, parse_number};
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use std::path::Path;

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
        let normals = columns_456_are_normals && cols.count >= 6;
        let builder = builder.get_or_insert_with(|| {
            let capacity = capped_capacity(u64::MAX, data.len(), 2 * cols.count);
            CloudBuilder::new(options, normals, capacity)
        });
        let mut values = [0.0f64; 6];
        let used = if normals { 6 } else { 3 };
        for (i, token) in tokens.iter().take(used).enumerate() {
            values[i] = parse_number(path, n, token, || column_hint(i))?;
        }
        builder.push(&values);
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
        assert!(parse_bytes(data).unwrap().0.normals.is_some());
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
