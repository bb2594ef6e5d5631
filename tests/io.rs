//! Integration tests for point-cloud input/output: round trips, every supported encoding, filtering, a malformed
//! corpus (each case must give a parse error naming the file and a location, never a panic) and atomic writes.

mod common;
use dpr_gpu::io::{LoadOptions, LoadReport, ZeroPoints, read_cloud, write_atomic, write_ply};
use dpr_gpu::{Error, PointCloud, Result};
use proptest::prelude::*;
use std::path::{Path, PathBuf};

/// A scratch directory for one test (removed on drop), with helpers for the files in it.
struct TempDir(common::TestDir);

impl TempDir {
    /// Creates a fresh directory whose name starts with `tag`.
    fn new(tag: &str) -> TempDir {
        TempDir(common::temp_dir(tag))
    }

    /// Writes `bytes` to the file `name` in this directory and returns its path.
    fn file(&self, name: &str, bytes: &[u8]) -> PathBuf {
        let path = self.0.join(name);
        std::fs::write(&path, bytes).unwrap();
        path
    }

    /// Names of the entries in this directory, sorted.
    fn entries(&self) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(&self.0)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }
}

/// Reads with default options.
fn read(path: &Path) -> Result<(PointCloud, LoadReport)> {
    read_cloud(path, &LoadOptions::default())
}

/// Writes `bytes` as `name` in a fresh temp dir and reads it with default options.
fn load(name: &str, bytes: &[u8]) -> Result<(PointCloud, LoadReport)> {
    let dir = TempDir::new("load");
    read(&dir.file(name, bytes))
}

/// Writes `bytes` as `name`, reads it, and asserts a parse error whose message names the file, has a location of
/// kind `location` ("line " or "byte ") and contains `needle`. Returns the message.
fn parse_error(name: &str, bytes: &[u8], location: &str, needle: &str) -> String {
    let result = load(name, bytes);
    check_parse_error(result, name, location, needle)
}

/// Asserts `result` is an [`Error::Parse`] as described in [`parse_error`] and returns its message.
fn check_parse_error(result: Result<(PointCloud, LoadReport)>, name: &str, location: &str, needle: &str) -> String {
    let err = match result {
        Ok((cloud, _)) => panic!("{name}: expected a parse error, loaded {} points", cloud.len()),
        Err(err) => err,
    };
    let message = err.to_string();
    assert!(matches!(err, Error::Parse { .. }), "not a parse error: {message}");
    assert!(message.contains(name), "error does not name the file: {message}");
    assert!(message.contains(location), "error has no '{location}' location: {message}");
    assert!(message.contains(needle), "error does not mention '{needle}': {message}");
    message
}

/// Appends numbers to a binary body in one byte order.
struct Body {
    /// The bytes so far.
    bytes: Vec<u8>,
    /// Byte order.
    big: bool,
}

impl Body {
    /// An empty body.
    fn new(big: bool) -> Body {
        Body { bytes: Vec::new(), big }
    }

    /// Appends raw bytes (already in the right order).
    fn raw(&mut self, le: &[u8], be: &[u8]) -> &mut Body {
        self.bytes.extend_from_slice(if self.big { be } else { le });
        self
    }

    /// Appends an f32.
    fn f32(&mut self, v: f32) -> &mut Body {
        self.raw(&v.to_le_bytes(), &v.to_be_bytes())
    }

    /// Appends an f64.
    fn f64(&mut self, v: f64) -> &mut Body {
        self.raw(&v.to_le_bytes(), &v.to_be_bytes())
    }

    /// Appends an i32.
    fn i32(&mut self, v: i32) -> &mut Body {
        self.raw(&v.to_le_bytes(), &v.to_be_bytes())
    }

    /// Appends an i16.
    fn i16(&mut self, v: i16) -> &mut Body {
        self.raw(&v.to_le_bytes(), &v.to_be_bytes())
    }

    /// Appends a u8.
    fn u8(&mut self, v: u8) -> &mut Body {
        self.bytes.push(v);
        self
    }
}

/// `header` followed by `body`.
fn concat(header: &str, body: &[u8]) -> Vec<u8> {
    let mut bytes = header.as_bytes().to_vec();
    bytes.extend_from_slice(body);
    bytes
}

/// A small cloud with normals (one zero-length normal, which must survive).
fn sample_with_normals() -> PointCloud {
    PointCloud {
        points: vec![[0.5, -1.25, 3.0], [1e-3, 2e5, -7.5], [0.0, 0.0, 1.0]],
        normals: Some(vec![[0.0, 0.0, 1.0], [0.6, 0.8, 0.0], [0.0, 0.0, 0.0]]),
    }
}

// ---------------------------------------------------------------------------------------------------------------
// Round trips and supported encodings.

#[test]
fn write_ply_round_trip_without_normals() {
    let dir = TempDir::new("rt-plain");
    let cloud = PointCloud::from_points(vec![[1.0, 2.0, 3.0], [-4.5, 0.25, 1e-7], [f32::MAX, f32::MIN, 0.0]]);
    let path = dir.0.join("out.ply");
    write_ply(&path, &cloud).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    assert!(bytes.starts_with(b"ply\nformat binary_little_endian 1.0\n"));
    let (loaded, report) = read(&path).unwrap();
    assert_eq!(loaded, cloud);
    assert_eq!(report, LoadReport::default());
}

#[test]
fn write_ply_round_trip_with_normals() {
    let dir = TempDir::new("rt-normals");
    let cloud = sample_with_normals();
    let path = dir.0.join("out.PLY");
    write_ply(&path, &cloud).unwrap();
    let (loaded, report) = read(&path).unwrap();
    assert_eq!(loaded, cloud);
    assert_eq!(report, LoadReport::default());
}

#[test]
fn write_ply_of_empty_cloud_reads_back_empty() {
    let dir = TempDir::new("rt-empty");
    let path = dir.0.join("empty.ply");
    write_ply(&path, &PointCloud::default()).unwrap();
    let (loaded, _) = read(&path).unwrap();
    assert!(loaded.is_empty());
}

#[test]
fn write_ply_rejects_mismatched_normals() {
    let dir = TempDir::new("rt-mismatch");
    let cloud = PointCloud { points: vec![[0.0; 3]; 2], normals: Some(vec![[0.0; 3]]) };
    let err = write_ply(&dir.0.join("bad.ply"), &cloud).unwrap_err();
    assert!(matches!(err, Error::InvalidInput(_)), "{err}");
    assert!(dir.entries().is_empty(), "{:?}", dir.entries());
}

#[test]
fn ascii_ply_hand_written_with_comments_and_crlf() {
    let text = "ply\r\nformat ascii 1.0\r\ncomment made by hand\r\nobj_info scanner 7\r\nelement vertex 3\r\n\
                property float x\r\nproperty float y\r\nproperty float z\r\nproperty float nx\r\nproperty float ny\r\n\
                property float nz\r\nend_header\r\n0.5 -1.25 3 0 0 1\r\n\r\n1e-3 2e5 -7.5 0.6 0.8 0\r\n0 0 1 0 0 0\r\n";
    let (cloud, report) = load("hand.ply", text.as_bytes()).unwrap();
    assert_eq!(cloud, sample_with_normals());
    assert_eq!(report, LoadReport::default());
}

#[test]
fn big_endian_ply_with_double_coordinates() {
    let header = "ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty float64 x\nproperty float64 y\n\
                  property float64 z\nproperty float32 nx\nproperty float32 ny\nproperty float32 nz\nend_header\n";
    let expected = sample_with_normals();
    let mut body = Body::new(true);
    for (p, n) in expected.points.iter().zip(expected.normals.as_ref().unwrap()) {
        for &v in p {
            body.f64(v as f64);
        }
        for &v in n {
            body.f32(v);
        }
    }
    let (cloud, _) = load("be.ply", &concat(header, &body.bytes)).unwrap();
    assert_eq!(cloud, expected);
}

/// Header of a PLY whose vertices carry colours and other extras, with a face element first and an edge element
/// after the vertices.
fn mixed_header(format: &str) -> String {
    format!(
        "ply\nformat {format} 1.0\nelement face 2\nproperty list uchar int vertex_indices\nproperty uint8 flags\n\
         element vertex 2\nproperty uchar red\nproperty double x\nproperty int16 quality\nproperty float y\n\
         property uchar green\nproperty float z\nproperty uchar blue\nproperty int confidence\n\
         element edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n"
    )
}

#[test]
fn ply_with_faces_and_extra_vertex_properties_in_every_encoding() {
    let expected = PointCloud::from_points(vec![[1.5, -2.0, 3.25], [4.0, 5.0, -6.0]]);
    // Binary, both byte orders.
    for big in [false, true] {
        let mut body = Body::new(big);
        body.u8(3).i32(0).i32(1).i32(0).u8(9); // face 0: a triangle
        body.u8(0).u8(1); // face 1: empty list
        for p in &expected.points {
            body.u8(255).f64(p[0] as f64).i16(-3).f32(p[1]).u8(128).f32(p[2]).u8(0).i32(-70000);
        }
        body.i32(0).i32(1); // edge
        let format = if big { "binary_big_endian" } else { "binary_little_endian" };
        let (cloud, report) = load("mixed.ply", &concat(&mixed_header(format), &body.bytes)).unwrap();
        assert_eq!(cloud, expected, "{format}");
        assert_eq!(report, LoadReport::default());
    }
    // Ascii.
    let body = "3 0 1 0 9\n0 1\n255 1.5 -3 -2 128 3.25 0 -70000\n255 4 -3 5 128 -6 0 -70000\n0 1\n";
    let (cloud, _) = load("mixed.ply", &concat(&mixed_header("ascii"), body.as_bytes())).unwrap();
    assert_eq!(cloud, expected);
}

#[test]
fn ply_type_aliases_are_accepted() {
    let types = ["char", "uchar", "short", "ushort", "int", "uint", "float", "double"];
    let aliases = ["int8", "uint8", "int16", "uint16", "int32", "uint32", "float32", "float64"];
    for ty in types.iter().chain(&aliases) {
        let header = format!(
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty {ty} x\nproperty {ty} y\nproperty {ty} z\n\
             property {ty} extra\nend_header\n"
        );
        let (cloud, _) = load("types.ply", &concat(&header, b"1 2 3 4\n")).unwrap();
        assert_eq!(cloud.points, vec![[1.0, 2.0, 3.0]], "{ty}");
    }
}

#[test]
fn partial_normals_are_ignored() {
    let header = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n\
                  property float nx\nproperty float ny\nend_header\n";
    let (cloud, _) = load("partial.ply", &concat(header, b"1 2 3 0 1\n")).unwrap();
    assert_eq!(cloud, PointCloud::from_points(vec![[1.0, 2.0, 3.0]]));
}

#[test]
fn pcd_ascii_with_normals_rgb_and_multi_count_fields() {
    let text = "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n\
                FIELDS x y z rgb normal_x normal_y normal_z curvature fpfh\nSIZE 4 4 4 4 4 4 4 4 4\n\
                TYPE F F F F F F F F F\nCOUNT 1 1 1 1 1 1 1 1 3\nWIDTH 2\nHEIGHT 2\nVIEWPOINT 0 0 0 1 0 0 0\n\
                POINTS 4\nDATA ascii\n\
                0.5 -1.25 3 4.2108e+06 0 0 1 0.01 1 2 3\n\
                0.001 200000 -7.5 4.2108e+06 0.6 0.8 0 0.01 1 2 3\n\
                nan nan nan 0 nan nan nan nan 0 0 0\n\
                0 0 1 4.2108e+06 0 0 0 0 1 2 3\n";
    let (cloud, report) = load("scan.pcd", text.as_bytes()).unwrap();
    assert_eq!(cloud, sample_with_normals());
    assert_eq!(report, LoadReport { dropped_non_finite: 1, dropped_zero: 0, origin: [0; 3] });
}

#[test]
fn pcd_binary_with_padding_and_integer_fields() {
    let header = "VERSION .7\nFIELDS x y z rgb normal_x normal_y normal_z _ label\nSIZE 4 4 4 4 4 4 4 1 2\n\
                  TYPE F F F U F F F U I\nCOUNT 1 1 1 1 1 1 1 3 1\nWIDTH 3\nHEIGHT 1\nPOINTS 3\nDATA binary\n";
    let expected = sample_with_normals();
    let mut body = Body::new(false);
    for (p, n) in expected.points.iter().zip(expected.normals.as_ref().unwrap()) {
        body.f32(p[0]).f32(p[1]).f32(p[2]).raw(&[1, 2, 3, 0], &[]);
        body.f32(n[0]).f32(n[1]).f32(n[2]).u8(0).u8(0).u8(0).i16(-5);
    }
    let (cloud, _) = load("scan.pcd", &concat(header, &body.bytes)).unwrap();
    assert_eq!(cloud, expected);
}

#[test]
fn pcd_binary_doubles_without_normals() {
    let header = "FIELDS intensity x y z\nSIZE 2 8 8 8\nTYPE U F F F\nWIDTH 2\nDATA binary\n";
    let mut body = Body::new(false);
    body.raw(&[7, 0], &[]).f64(1.0).f64(2.0).f64(3.0);
    body.raw(&[7, 0], &[]).f64(-1.0).f64(-2.0).f64(-3.0);
    let (cloud, _) = load("d.pcd", &concat(header, &body.bytes)).unwrap();
    assert_eq!(cloud, PointCloud::from_points(vec![[1.0, 2.0, 3.0], [-1.0, -2.0, -3.0]]));
}

#[test]
fn xyz_three_columns_with_comments_and_blank_lines() {
    let text = "# exported by hand\n\n1 2 3\n  # indented comment\n4\t5   6\r\n\n-7.5e0 8 9";
    let (cloud, report) = load("points.xyz", text.as_bytes()).unwrap();
    assert_eq!(cloud, PointCloud::from_points(vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [-7.5, 8.0, 9.0]]));
    assert_eq!(report, LoadReport::default());
}

#[test]
fn xyz_six_columns_give_normals_and_extra_columns_are_ignored() {
    let text = "# x y z nx ny nz\n0.5 -1.25 3 0 0 1 99\n1e-3 2e5 -7.5 0.6 0.8 0 99\n0 0 1 0 0 0 99\n";
    let (cloud, _) = load("normals.txt", text.as_bytes()).unwrap();
    assert_eq!(cloud, sample_with_normals());
}

#[test]
fn csv_style_commas() {
    let text = "# x,y,z,nx,ny,nz\n0.5, -1.25, 3, 0, 0, 1\n1e-3,2e5,-7.5,0.6,0.8,0\n0 ,0 ,1 ,0 ,0 ,0\n";
    let (cloud, _) = load("points.xyz", text.as_bytes()).unwrap();
    assert_eq!(cloud, sample_with_normals());
}

#[test]
fn pts_with_count_line() {
    let (cloud, _) = load("scan.pts", b"2\n1 2 3 10 255 0 0\n4 5 6 12 0 255 0\n").unwrap();
    assert_eq!(cloud.points, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
}

// ---------------------------------------------------------------------------------------------------------------
// Filtering.

#[test]
fn non_finite_points_are_dropped_and_counted() {
    let header = "ply\nformat ascii 1.0\nelement vertex 6\nproperty float x\nproperty float y\nproperty float z\n\
                  property float nx\nproperty float ny\nproperty float nz\nend_header\n";
    let body = "1 2 3 0 0 1\nnan 2 3 0 0 1\n1 inf 3 0 0 1\n1 2 -inf 0 0 1\n4 5 6 nan 0 1\n7 8 9 0 0 0\n";
    let (cloud, report) = load("nan.ply", &concat(header, body.as_bytes())).unwrap();
    assert_eq!(cloud.points, vec![[1.0, 2.0, 3.0], [7.0, 8.0, 9.0]]);
    assert_eq!(cloud.normals, Some(vec![[0.0, 0.0, 1.0], [0.0, 0.0, 0.0]]));
    assert_eq!(report, LoadReport { dropped_non_finite: 4, dropped_zero: 0, origin: [0; 3] });
    cloud.validate("nan.ply").unwrap();

    // Binary: NaN, infinity, and a double too large for f32.
    let header = "ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty double x\nproperty double y\n\
                  property double z\nend_header\n";
    let mut body = Body::new(false);
    body.f64(f64::NAN).f64(0.0).f64(0.0).f64(1.0).f64(f64::NEG_INFINITY).f64(0.0);
    body.f64(1e300).f64(0.0).f64(0.0).f64(1.0).f64(2.0).f64(3.0);
    let (cloud, report) = load("nan.ply", &concat(header, &body.bytes)).unwrap();
    assert_eq!(cloud.points, vec![[1.0, 2.0, 3.0]]);
    assert_eq!(report.dropped_non_finite, 3);

    let (cloud, report) = load("nan.xyz", b"1 2 3\nNaN 1 1\n4 5 6\n1 1 infinity\n").unwrap();
    assert_eq!(cloud.points, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
    assert_eq!(report, LoadReport { dropped_non_finite: 2, dropped_zero: 0, origin: [0; 3] });
}

/// Points exactly at the origin (-0.0 counts) are sensor no-returns when there are two or more: dropped by
/// default and counted; `Keep` keeps them, `Drop` drops even a lone one.
#[test]
fn zero_points_are_dropped_as_a_pattern_or_on_request() {
    use dpr_gpu::io::ZeroPoints;
    let dir = TempDir::new("zero");
    let cloud =
        PointCloud::from_points(vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [-0.0, 0.0, -0.0], [f32::NAN, 0.0, 0.0]]);
    let path = dir.0.join("zero.ply");
    write_ply(&path, &cloud).unwrap();
    let with = |zero_points| read_cloud(&path, &LoadOptions { zero_points, ..LoadOptions::default() }).unwrap();

    let (filtered, report) = read(&path).unwrap();
    assert_eq!(filtered.points, vec![[1.0, 0.0, 0.0]]);
    assert_eq!(report, LoadReport { dropped_non_finite: 1, dropped_zero: 2, origin: [0; 3] });
    let (kept, report) = with(ZeroPoints::Keep);
    assert_eq!(kept.len(), 3);
    assert_eq!(report, LoadReport { dropped_non_finite: 1, dropped_zero: 0, origin: [0; 3] });

    let lone = dir.0.join("lone.ply");
    write_ply(&lone, &PointCloud::from_points(vec![[0.0; 3], [1.0, 2.0, 3.0]])).unwrap();
    let (cloud, report) = read(&lone).unwrap();
    assert_eq!((cloud.len(), report.dropped_zero), (2, 0), "one point at the origin can be a real sample");
    let (cloud, _) =
        read_cloud(&lone, &LoadOptions { zero_points: ZeroPoints::Drop, ..LoadOptions::default() }).unwrap();
    assert_eq!(cloud.points, vec![[1.0, 2.0, 3.0]]);
}

#[test]
fn zero_points_with_normals_drop_their_normals() {
    let dir = TempDir::new("zero-normals");
    let path = dir.file("z.xyz", b"0 0 0 1 0 0\n1 1 1 0 1 0\n");
    let (cloud, report) =
        read_cloud(&path, &LoadOptions { zero_points: dpr_gpu::io::ZeroPoints::Drop, ..LoadOptions::default() })
            .unwrap();
    assert_eq!(cloud.points, vec![[1.0, 1.0, 1.0]]);
    assert_eq!(cloud.normals, Some(vec![[0.0, 1.0, 0.0]]));
    assert_eq!(report.dropped_zero, 1);
}

// ---------------------------------------------------------------------------------------------------------------
// Malformed corpus.

/// Header of the truncation corpus file.
const CORPUS_HEADER: &str = "ply\nformat binary_little_endian 1.0\ncomment truncation corpus\nelement vertex 5\n\
                             property float x\nproperty float y\nproperty float z\nproperty float nx\n\
                             property float ny\nproperty float nz\nelement face 1\n\
                             property list uchar int vertex_indices\nend_header\n";

/// A binary PLY (header, 5 vertices with normals and one triangle) and the length of its header.
fn corpus_file(big: bool) -> (Vec<u8>, usize) {
    let mut body = Body::new(big);
    for i in 0..5 {
        let v = i as f32;
        body.f32(v).f32(v + 0.5).f32(-v).f32(0.0).f32(0.0).f32(1.0);
    }
    body.u8(3).i32(0).i32(1).i32(2);
    let header = if big {
        CORPUS_HEADER.replace("binary_little_endian", "binary_big_endian")
    } else {
        CORPUS_HEADER.to_string()
    };
    (concat(&header, &body.bytes), header.len())
}

#[test]
fn every_truncation_of_a_binary_ply_is_an_error() {
    let dir = TempDir::new("truncations");
    for big in [false, true] {
        let (full, header_len) = corpus_file(big);
        let path = dir.file("corpus.ply", &full);
        let (cloud, _) = read(&path).unwrap();
        assert_eq!(cloud.len(), 5);
        assert_eq!(cloud.normals.as_ref().map(Vec::len), Some(5));
        for cut in 0..full.len() {
            let path = dir.file("corpus.ply", &full[..cut]);
            // Cutting only the final newline of the header still leaves a complete header.
            let location = if cut + 1 < header_len { "line " } else { "byte " };
            check_parse_error(read(&path), "corpus.ply", location, "");
        }
    }
}

#[test]
fn truncated_vertex_data_reports_where_and_how_much() {
    let (full, _) = corpus_file(false);
    let cut = CORPUS_HEADER.len() + 2 * 24 + 10;
    let message = parse_error("cut.ply", &full[..cut], "byte ", "file ends after 2 of 5 vertices");
    assert!(message.contains(&format!("byte {}", CORPUS_HEADER.len() + 48)), "{message}");
    let cut = full.len() - 3;
    parse_error("cut.ply", &full[..cut], "byte ", "file ends after 0 of 1 faces");
}

#[test]
fn giant_counts_error_without_allocating() {
    let header = "ply\nformat binary_little_endian 1.0\nelement vertex 1000000000000\nproperty float x\n\
                  property float y\nproperty float z\nend_header\n";
    parse_error("giant.ply", &concat(header, &[0; 60]), "byte ", "of 1000000000000 vertices");
    let ascii = header.replace("binary_little_endian", "ascii");
    parse_error("giant.ply", &concat(&ascii, b"1 2 3\n"), "line ", "file ends after 1 of 1000000000000 vertices");
    let huge = header.replace("1000000000000", "18446744073709551615");
    parse_error("giant.ply", &concat(&huge, &[0; 60]), "byte ", "vertices");

    // A face list whose count claims far more items than the file holds.
    let header = "ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\nproperty float y\n\
                  property float z\nelement face 1000000000000\nproperty list uint int vertex_indices\nend_header\n";
    let mut body = Body::new(false);
    body.raw(&u32::MAX.to_le_bytes(), &[]).i32(0);
    parse_error("giant.ply", &concat(header, &body.bytes), "byte ", "file ends after 0 of 1000000000000 faces");

    let pcd = "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1000000000000\nHEIGHT 1000000000000\nDATA binary\n";
    parse_error("giant.pcd", &concat(pcd, &[0; 40]), "line ", "overflows");
    let pcd = "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1000000000000\nHEIGHT 1\nDATA binary\n";
    parse_error("giant.pcd", &concat(pcd, &[0; 40]), "byte ", "file ends after 3 of 1000000000000 points");
}

#[test]
fn malformed_ply_headers() {
    let good = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n\
                end_header\n1 2 3\n";
    load("good.ply", good.as_bytes()).unwrap();
    let case = |from: &str, to: &str, location: &str, needle: &str| {
        parse_error("bad.ply", good.replacen(from, to, 1).as_bytes(), location, needle);
    };
    case("ply\n", "plyx\n", "line 1", "not a PLY file");
    case("ascii", "binary_middle_endian", "line 2", "unknown PLY format 'binary_middle_endian'");
    case("format ascii 1.0\n", "", "line 6", "no 'format' line");
    case("float y", "float17 y", "line 5", "unknown property type 'float17'");
    case("property float z\n", "", "line 3", "vertex element has no 'z' property");
    case("property float y\nproperty float z\n", "", "line 3", "no 'y', 'z' properties");
    case("vertex 1", "vertex -1", "line 3", "invalid count '-1'");
    case("vertex 1", "vertex", "line 3", "expected 'element <name> <count>'");
    case("element vertex 1\n", "", "line 3", "'property' line before any 'element' line");
    case("end_header\n", "", "line 7", "'end_header'");
    case("end_header", "end_headr", "line 7", "unknown header keyword 'end_headr'");
    case("element vertex", "element point", "line 7", "no 'vertex' element");
    case("property float z", "property list uchar float z", "line 3", "'z' is a list");
    case("property float z", "property list float int z", "line 6", "must be an integer type");
}

#[test]
fn malformed_ascii_ply_bodies() {
    let header = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n\
                  end_header\n";
    let case = |body: &str, location: &str, needle: &str| {
        parse_error("body.ply", &concat(header, body.as_bytes()), location, needle);
    };
    case("1 2 3\n4 5\n", "line 9", "expected 3 values for a 'vertex' element, found 2");
    case("1 2 3 4\n4 5 6\n", "line 8", "expected 3 values for a 'vertex' element, found 4");
    case("1 2 3\n4 abc 6\n", "line 9", "'abc' is not a number (property 'y')");
    case("1 2 3\n", "line 9", "file ends after 1 of 2 vertices");
    parse_error("body.ply", &concat(header, b"1 2 3\n\xff\n"), "line 9", "not valid UTF-8");
}

#[test]
fn malformed_pcd_files() {
    let good = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nHEIGHT 1\nPOINTS 2\n\
                DATA ascii\n1 2 3\n4 5 6\n";
    assert_eq!(load("good.pcd", good.as_bytes()).unwrap().0.len(), 2);
    let case = |from: &str, to: &str, location: &str, needle: &str| {
        parse_error("bad.pcd", good.replacen(from, to, 1).as_bytes(), location, needle);
    };
    case("DATA ascii\n", "", "line 9", "no DATA line");
    case("DATA ascii\n1 2 3\n4 5 6\n", "", "line 9", "without a DATA line");
    case("DATA ascii", "DATA binary_compressed", "line 9", "binary_compressed is not supported");
    case("DATA ascii", "DATA zip", "line 9", "unknown DATA kind 'zip'");
    case("FIELDS x y z", "FIELDS x y w", "line 9", "no 'z' field");
    case("SIZE 4 4 4", "SIZE 4 4", "line 3", "SIZE has 2 entries but FIELDS has 3");
    case("TYPE F F F", "TYPE F F Q", "line 4", "unsupported TYPE/SIZE Q/4");
    case("COUNT 1 1 1", "COUNT 1 1 2", "line 9", "field 'z' has COUNT 2");
    case("COUNT 1 1 1", "COUNT 1 1 x", "line 5", "invalid COUNT 'x'");
    case("POINTS 2", "POINTS 3", "line 8", "does not match WIDTH x HEIGHT");
    case("POINTS 2", "POINTS two", "line 8", "POINTS must be one non-negative integer");
    case("VERSION", "COLOUR", "line 1", "unknown header keyword 'COLOUR'");
    case("4 5 6\n", "4 5\n", "line 11", "expected 3 values per point, found 2");
    case("4 5 6\n", "4 5 six\n", "line 11", "'six' is not a number");
    case("4 5 6\n", "", "line 11", "file ends after 1 of 2 points");

    let binary = "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 2\nDATA binary\n";
    let message = parse_error("bad.pcd", &concat(binary, &[0; 23]), "byte ", "file ends after 1 of 2 points");
    assert!(message.contains(&format!("byte {}", binary.len() + 12)), "{message}");
}

#[test]
fn malformed_xyz_files() {
    parse_error("ragged.xyz", b"1 2 3\n4 5 6\n7 8 9 1 0 0\n", "line 3", "6 columns, but line 1 has 3");
    parse_error("ragged.txt", b"# c\n1,2,3,0,0,1\n1,2,3\n", "line 3", "3 columns, but line 2 has 6");
    parse_error("short.xyz", b"1 2\n", "line 1", "at least 3 columns");
    parse_error("word.xyz", b"1 2 3\n4 five 6\n", "line 2", "'five' is not a number (column 2)");
    parse_error("empty.xyz", b"1,2,3\n4,,6\n", "line 2", "column 2 is empty");
}

#[test]
fn unknown_extension_and_missing_file() {
    let dir = TempDir::new("ext");
    let path = dir.file("cloud.obj", b"v 1 2 3\n");
    let err = read(&path).unwrap_err();
    let message = err.to_string();
    assert!(matches!(err, Error::InvalidInput(_)), "{message}");
    assert!(message.contains(".obj") && message.contains(".ply") && message.contains(".pcd"), "{message}");

    let missing = dir.0.join("missing.ply");
    let err = read(&missing).unwrap_err();
    assert!(matches!(&err, Error::Io { path, .. } if path == &missing), "{err}");
    assert!(err.to_string().contains("missing.ply"));
}

// ---------------------------------------------------------------------------------------------------------------
// Atomic writes.

#[test]
fn write_atomic_replaces_contents_and_leaves_no_temp_file() {
    let dir = TempDir::new("atomic");
    let path = dir.file("out.txt", b"old contents that are longer");
    write_atomic(&path, b"new").unwrap();
    assert_eq!(std::fs::read(&path).unwrap(), b"new");
    assert_eq!(dir.entries(), vec!["out.txt".to_string()]);

    let fresh = dir.0.join("fresh.bin");
    write_atomic(&fresh, &[1, 2, 3]).unwrap();
    assert_eq!(std::fs::read(&fresh).unwrap(), [1, 2, 3]);
    assert_eq!(dir.entries(), vec!["fresh.bin".to_string(), "out.txt".to_string()]);
}

#[test]
fn write_atomic_failure_is_an_io_error_naming_the_destination() {
    let dir = TempDir::new("atomic-fail");
    let missing_dir = dir.0.join("no-such-dir").join("out.ply");
    let err = write_atomic(&missing_dir, b"x").unwrap_err();
    assert!(matches!(&err, Error::Io { path, .. } if path == &missing_dir), "{err}");

    // Renaming over a directory fails after the temp file was written: the temp file must be gone.
    std::fs::create_dir(dir.0.join("taken")).unwrap();
    std::fs::write(dir.0.join("taken").join("inside"), b"keep").unwrap();
    let err = write_atomic(&dir.0.join("taken"), b"x").unwrap_err();
    assert!(matches!(err, Error::Io { .. }), "{err}");
    assert_eq!(dir.entries(), vec!["taken".to_string()]);
}

// ---------------------------------------------------------------------------------------------------------------
// Property test.

/// Any finite f32 (normal, subnormal or zero, either sign).
fn finite() -> impl Strategy<Value = f32> {
    prop::num::f32::NORMAL | prop::num::f32::SUBNORMAL | prop::num::f32::ZERO
}

/// Random finite clouds with and without normals.
fn clouds() -> impl Strategy<Value = PointCloud> {
    (0usize..48, any::<bool>()).prop_flat_map(|(n, with_normals)| {
        let points = prop::collection::vec([finite(), finite(), finite()], n);
        let normals = prop::collection::vec([finite(), finite(), finite()], n);
        (points, normals)
            .prop_map(move |(points, normals)| PointCloud { points, normals: with_normals.then_some(normals) })
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn write_ply_read_cloud_round_trip(cloud in clouds()) {
        let dir = TempDir::new("prop");
        let path = dir.0.join("cloud.ply");
        write_ply(&path, &cloud).unwrap();
        // Every point kept: the strategy draws exact zeros, and two points at (0, 0, 0) are otherwise dropped as
        // a sensor's no-returns (`ZeroPoints::Auto`, tested on its own above).
        let keep = LoadOptions { zero_points: ZeroPoints::Keep, ..LoadOptions::default() };
        let (loaded, report) = read_cloud(&path, &keep).unwrap();
        prop_assert_eq!(report, LoadReport::default());
        prop_assert_eq!(loaded.points.len(), cloud.points.len());
        // Bitwise comparison: -0.0 and subnormals must survive exactly.
        let bits = |c: &PointCloud| {
            let flat = |v: &[[f32; 3]]| v.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
            (flat(&c.points), c.normals.as_deref().map(flat))
        };
        prop_assert_eq!(bits(&loaded), bits(&cloud));
    }
}
