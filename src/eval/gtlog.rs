//! The 3DMatch / Redwood trajectory files: `gt.log` (and result logs) and `gt.info`.
//!
//! A `.log` file is a sequence of 5-line records: a header `i j n` (fragment indices and fragment count), then a
//! 4x4 matrix, one row per line. The matrix of record `i j` maps fragment j into fragment i: x_i = T x_j.
//! A `.info` file has 7-line records: the same header and a 6x6 information matrix (rows and columns ordered
//! translation then rotation, element (0, 0) = number of points). Records are keyed by (i, j); their order in
//! the file is not significant (Redwood files are unsorted). Blank lines and lines starting with `#` are
//! skipped. Errors name the file and the line.

use crate::error::{Error, Result};
use nalgebra::{Matrix4, Matrix6, SMatrix};
use std::collections::HashMap;
use std::path::Path;

/// One record of a `.log` file.
#[derive(Clone, Debug, PartialEq)]
pub struct LogRecord {
    /// First fragment index (the target frame).
    pub i: usize,
    /// Second fragment index (the source).
    pub j: usize,
    /// Number of fragments in the scene (third header field).
    pub n: usize,
    /// The pose of fragment j in fragment i's frame: x_i = i_from_j x_j. (A trajectory log's records `k k N`
    /// hold world_from_k here.)
    pub i_from_j: Matrix4<f64>,
}

/// One record of a `.info` file.
#[derive(Clone, Debug, PartialEq)]
pub struct InfoRecord {
    /// First fragment index.
    pub i: usize,
    /// Second fragment index.
    pub j: usize,
    /// Number of fragments in the scene.
    pub n: usize,
    /// The 6x6 information matrix (translation first, then rotation).
    pub information: Matrix6<f64>,
}

/// Lines that carry data, with their 1-based line numbers.
fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines().enumerate().map(|(k, l)| (k + 1, l.trim())).filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
}

fn parse_header(path: &Path, line: usize, text: &str) -> Result<(usize, usize, usize)> {
    let fields: Vec<&str> = text.split_whitespace().collect();
    let ints: Option<Vec<usize>> = fields.iter().map(|f| f.parse::<usize>().ok()).collect();
    match ints.as_deref() {
        Some([i, j, n]) => Ok((*i, *j, *n)),
        _ => Err(Error::parse(
            path,
            format!("line {line}"),
            format!("expected a record header `i j n` (three non-negative integers), found `{text}`"),
        )),
    }
}

fn parse_row<const C: usize>(path: &Path, line: usize, text: &str) -> Result<[f64; C]> {
    let values: Vec<f64> = text
        .split_whitespace()
        .map(|f| {
            f.parse::<f64>().map_err(|_| Error::parse(path, format!("line {line}"), format!("`{f}` is not a number")))
        })
        .collect::<Result<_>>()?;
    if values.len() != C {
        return Err(Error::parse(
            path,
            format!("line {line}"),
            format!("expected {C} numbers in a matrix row, found {}", values.len()),
        ));
    }
    if let Some(v) = values.iter().find(|v| !v.is_finite()) {
        return Err(Error::parse(path, format!("line {line}"), format!("non-finite matrix entry {v}")));
    }
    Ok(std::array::from_fn(|k| values[k]))
}

/// A record's header `(i, j, n)`, its matrix and the header's line number.
type Record<const R: usize> = ((usize, usize, usize), SMatrix<f64, R, R>, usize);

/// Parses records of a header plus a `R x R` matrix.
fn parse_records<const R: usize>(text: &str, path: &Path) -> Result<Vec<Record<R>>> {
    let mut lines = data_lines(text);
    let mut out = Vec::new();
    let mut seen: HashMap<(usize, usize), usize> = HashMap::new();
    while let Some((line, header)) = lines.next() {
        let (i, j, n) = parse_header(path, line, header)?;
        if let Some(first) = seen.insert((i, j), line) {
            return Err(Error::parse(
                path,
                format!("line {line}"),
                format!("duplicate record for pair ({i}, {j}) (first at line {first})"),
            ));
        }
        let mut m = SMatrix::<f64, R, R>::zeros();
        for r in 0..R {
            let Some((row_line, row)) = lines.next() else {
                return Err(Error::parse(
                    path,
                    format!("line {line}"),
                    format!("record ({i}, {j}) is truncated: {r} of {R} matrix rows"),
                ));
            };
            let values = parse_row::<R>(path, row_line, row)?;
            for (c, v) in values.into_iter().enumerate() {
                m[(r, c)] = v;
            }
        }
        out.push(((i, j, n), m, line));
    }
    Ok(out)
}

/// Parses the text of a `.log` file; `path` is only used in error messages. Every matrix must be a rigid motion
/// ([`crate::pose::rigidity_problem`]).
pub fn parse_log(text: &str, path: &Path) -> Result<Vec<LogRecord>> {
    parse_records::<4>(text, path)?
        .into_iter()
        .map(|((i, j, n), i_from_j, line)| match crate::pose::rigidity_problem(&i_from_j) {
            None => Ok(LogRecord { i, j, n, i_from_j }),
            Some(problem) => Err(Error::parse(path, format!("line {line}"), format!("record ({i}, {j}): {problem}"))),
        })
        .collect()
}

/// Parses the text of a `.info` file; `path` is only used in error messages.
pub fn parse_info(text: &str, path: &Path) -> Result<Vec<InfoRecord>> {
    Ok(parse_records::<6>(text, path)?
        .into_iter()
        .map(|((i, j, n), information, _)| InfoRecord { i, j, n, information })
        .collect())
}

/// Reads a `.log` file.
pub fn read_log(path: &Path) -> Result<Vec<LogRecord>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    parse_log(&text, path)
}

/// Reads a `.info` file.
pub fn read_info(path: &Path) -> Result<Vec<InfoRecord>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    parse_info(&text, path)
}

/// C's `%15.8e`: 8 decimals, an exponent with sign and at least two digits, right-aligned in 15 columns.
pub fn format_e(x: f64) -> String {
    let s = format!("{x:.8e}");
    let (mantissa, exp) = s.split_once('e').unwrap_or((&s, "0"));
    let exp: i32 = exp.parse().unwrap_or(0);
    let sign = if exp < 0 { '-' } else { '+' };
    format!("{:>15}", format!("{mantissa}e{sign}{:02}", exp.abs()))
}

fn format_records<const R: usize>(
    records: impl Iterator<Item = ((usize, usize, usize), SMatrix<f64, R, R>)>,
) -> String {
    let mut out = String::new();
    for ((i, j, n), m) in records {
        out.push_str(&format!("{i}\t{j}\t{n}\n"));
        for r in 0..R {
            let row: Vec<String> = (0..R).map(|c| format_e(m[(r, c)])).collect();
            out.push_str(&row.join("\t"));
            out.push('\n');
        }
    }
    out
}

/// The text of a `.log` file holding `records` in the given order (tab-separated, `%15.8e` numbers).
pub fn format_log(records: &[LogRecord]) -> String {
    format_records::<4>(records.iter().map(|r| ((r.i, r.j, r.n), r.i_from_j)))
}

/// The text of a `.info` file holding `records` in the given order.
pub fn format_info(records: &[InfoRecord]) -> String {
    format_records::<6>(records.iter().map(|r| ((r.i, r.j, r.n), r.information)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn format_e_matches_c() {
        assert_eq!(format_e(0.996926560), " 9.96926560e-01");
        assert_eq!(format_e(-0.115576939), "-1.15576939e-01");
        assert_eq!(format_e(0.0), " 0.00000000e+00");
        assert_eq!(format_e(1234.5), " 1.23450000e+03");
    }

    #[test]
    fn official_layout_parses() {
        let text = "0\t 1\t 60\t\n 9.96926560e-01\t  6.68735757e-02\t -4.06664421e-02\t -1.15576939e-01\t\n\
                    -6.61289946e-02\t  9.97617877e-01\t  1.94008687e-02\t -3.87705398e-02\t\n\
                     4.18675510e-02\t -1.66517807e-02\t  9.98977765e-01\t  1.14874890e-01\t\n\
                     0.00000000e+00\t  0.00000000e+00\t  0.00000000e+00\t  1.00000000e+00\t\n";
        let r = parse_log(text, Path::new("gt.log")).unwrap();
        assert_eq!((r[0].i, r[0].j, r[0].n), (0, 1, 60));
        assert!((r[0].i_from_j[(0, 3)] + 0.115576939).abs() < 1e-15);
    }

    #[test]
    fn errors_name_file_and_line() {
        let bad_header = "0 1\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n";
        let e = parse_log(bad_header, Path::new("x/gt.log")).unwrap_err().to_string();
        assert!(e.contains("x/gt.log") && e.contains("line 1"), "{e}");
        let bad_number = "0 1 2\n1 0 0 0\n0 1 zero 0\n0 0 1 0\n0 0 0 1\n";
        let e = parse_log(bad_number, Path::new("gt.log")).unwrap_err().to_string();
        assert!(e.contains("line 3") && e.contains("zero"), "{e}");
        let truncated = "0 1 2\n1 0 0 0\n0 1 0 0\n";
        let e = parse_log(truncated, Path::new("gt.log")).unwrap_err().to_string();
        assert!(e.contains("truncated"), "{e}");
        let dup = "0 1 2\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n0 1 2\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n";
        let e = parse_log(dup, Path::new("gt.log")).unwrap_err().to_string();
        assert!(e.contains("line 6") && e.contains("duplicate"), "{e}");
        let short_info = "0 1 2\n1 0 0 0 0 0\n";
        assert!(parse_info(short_info, Path::new("gt.info")).is_err());
    }
}
