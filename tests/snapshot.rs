//! Snapshots (`register --snapshot`, `eval --snapshots`) and the merged coloured PLY (`--aligned --merged`).
//!
//! The oracle for the pictures is the decoded PNG: pixels are classified by the documented colours and
//! counted per panel, independently of the renderer's own coverage counts, and must match them exactly
//! (dots are whole pixels without anti-aliasing, so every pixel is exactly one of the documented colours).

mod common;

use common::{room_corner, room_pair, temp_dir};
use dpr_gpu::PointCloud;
use dpr_gpu::io::{LoadOptions, read_cloud, write_ply, write_ply_with_colors};
use dpr_gpu::pose::transform_point;
use dpr_gpu::snapshot::text::TEXT_RGB;
use dpr_gpu::snapshot::{
    BACKGROUND_RGB, GAP_RGB, LINE_RGBA, Label, OVERLAP_RGB, Row, SOURCE_RGB, Snapshot, SnapshotOptions, TARGET_RGB,
    View, merged_pair, render_snapshot, write_snapshot,
};

const LINE_RGB: [u8; 3] = [LINE_RGBA[0], LINE_RGBA[1], LINE_RGBA[2]];
use nalgebra::Matrix4;
use std::path::Path;
use std::process::{Command, Output};

/// Per-panel pixel counts read back from PNG bytes: (source only, target only, overlap, background).
fn decoded_counts(png: &[u8], snapshot: &Snapshot, side: u32) -> Vec<[u64; 4]> {
    let image = tiny_skia::Pixmap::decode_png(png).expect("the PNG decodes");
    snapshot
        .panels
        .iter()
        .map(|p| {
            let mut counts = [0u64; 4];
            for y in p.y..p.y + side {
                for x in p.x..p.x + side {
                    let c = image.pixel(x, y).unwrap();
                    assert_eq!(c.alpha(), 255, "opaque image");
                    let rgb = [c.red(), c.green(), c.blue()];
                    let k = [SOURCE_RGB, TARGET_RGB, OVERLAP_RGB, BACKGROUND_RGB]
                        .iter()
                        .position(|&known| known == rgb)
                        .unwrap_or_else(|| panic!("pixel ({x}, {y}) has an undocumented colour {rgb:?}"));
                    counts[k] += 1;
                }
            }
            counts
        })
        .collect()
}

/// (source, target, target_from_source) of the room moved only a little (10 degrees, 0.15 m), so the scans
/// already overlap in part before registration.
fn nearby_pair() -> (PointCloud, PointCloud, Matrix4<f64>) {
    let truth = Matrix4::new_translation(&nalgebra::Vector3::new(0.15, -0.1, 0.05))
        * Matrix4::from_euler_angles(0.0, 0.0, 10f64.to_radians());
    let target = room_corner(32, 20_000).transformed(&truth);
    (room_corner(31, 20_000), target, truth)
}

#[test]
fn the_after_image_overlaps_more_than_the_before_image() {
    // Far apart before (a large pose): the after row must overlap at least twice as much. Nearby before (10
    // degrees): the projections of the dense clouds already overlap a lot, and registration still adds 10%.
    for ((source, target, truth), gain) in [(room_pair(5, 20_000), 2.0), (nearby_pair(), 1.1)] {
        let options = SnapshotOptions::default();
        let snapshot = render_snapshot(&source, &target, &truth, &options).unwrap();
        let png = snapshot.encode_png().unwrap();
        let decoded = decoded_counts(&png, &snapshot, options.panel_px);
        let mut overlap = [0u64; 2];
        for (panel, counts) in snapshot.panels.iter().zip(&decoded) {
            // The decoded picture agrees with the renderer's coverage, pixel class by pixel class.
            assert_eq!(counts[2], panel.overlap_pixels, "{panel:?}");
            assert_eq!(counts[0], panel.source_pixels - panel.overlap_pixels, "{panel:?}");
            assert_eq!(counts[1], panel.target_pixels - panel.overlap_pixels, "{panel:?}");
            overlap[usize::from(panel.row == Row::After)] += counts[2];
            if panel.row == Row::After {
                // Registered with the true pose, most of the drawn target is covered by the source too.
                assert!(panel.overlap_pixels * 10 > panel.target_pixels * 6, "{panel:?}");
            }
        }
        assert_eq!(overlap, [snapshot.overlap_pixels(Row::Before), snapshot.overlap_pixels(Row::After)]);
        eprintln!("overlap pixels: before {} after {}", overlap[0], overlap[1]);
        let (before, after) = (overlap[0] as f64, overlap[1] as f64);
        assert!(after > gain * before + 1000.0, "overlap before {before} after {after}");
        // A wrong pose (the truth's inverse) overlaps less than the truth.
        let wrong = render_snapshot(&source, &target, &truth.try_inverse().unwrap(), &options).unwrap();
        let wrong = wrong.overlap_pixels(Row::After) as f64;
        assert!(gain * wrong < after, "overlap with a wrong pose {wrong}, with the truth {after}");
    }
}

#[test]
fn the_png_decodes_to_the_documented_size_and_is_deterministic() {
    let (source, target, truth) = room_pair(6, 3_000);
    let default = SnapshotOptions::default();
    // Three bands of text (over each row, the legend under them): 8-pixel glyphs (twice as big from 160-pixel
    // panels) and a gap each.
    assert_eq!(default.image_size(), (3 * 360 + 4 * 4, 2 * 360 + 3 * 4 + 3 * (16 + 4)));
    let two = SnapshotOptions { views: vec![View::Top, View::Side], panel_px: 100, gap_px: 3, ..default.clone() };
    assert_eq!(two.image_size(), (2 * 100 + 3 * 3, 2 * 100 + 3 * 3 + 3 * (8 + 3)));
    for options in [&default, &two] {
        let snapshot = render_snapshot(&source, &target, &truth, options).unwrap();
        let png = snapshot.encode_png().unwrap();
        let image = tiny_skia::Pixmap::decode_png(&png).unwrap();
        assert_eq!((image.width(), image.height()), options.image_size());
        assert_eq!(image.data(), snapshot.rgba());
        assert_eq!(snapshot.panels.len(), 2 * options.views.len());
        let again = render_snapshot(&source, &target, &truth, options).unwrap().encode_png().unwrap();
        assert_eq!(png, again, "same inputs, same bytes");
    }
}

/// The pixels of every label, read from the image, against the font's own bitmaps (font8x8, bit 0 leftmost):
/// text colour exactly where a glyph bit is set, the label's box colour everywhere else in its cells.
fn assert_label_pixels(snapshot: &Snapshot, label: &Label, box_rgb: [u8; 3]) {
    let width = snapshot.width() as usize;
    let pixel = |x: u32, y: u32| {
        let i = (y as usize * width + x as usize) * 4;
        [snapshot.rgba()[i], snapshot.rgba()[i + 1], snapshot.rgba()[i + 2]]
    };
    for (i, c) in label.text.bytes().enumerate() {
        let glyph = font8x8::legacy::BASIC_LEGACY[c as usize];
        for (row, bits) in glyph.iter().enumerate() {
            for column in 0..8u32 {
                let expected = if bits & (1 << column) != 0 { TEXT_RGB } else { box_rgb };
                for (dx, dy) in (0..label.scale).flat_map(|dx| (0..label.scale).map(move |dy| (dx, dy))) {
                    let x = label.x + (i as u32 * 8 + column) * label.scale + dx;
                    let y = label.y + row as u32 * label.scale + dy;
                    assert_eq!(pixel(x, y), expected, "'{}' char {i} at ({x}, {y})", label.text);
                }
            }
        }
    }
}

#[test]
fn panels_and_legend_are_labelled_in_words() {
    let (source, target, truth) = room_pair(10, 3_000);
    let lines: Vec<([f32; 3], [f32; 3])> =
        source.points.iter().step_by(100).map(|&p| (p, transform_point(&truth, p))).collect();
    let options = SnapshotOptions { lines, ..SnapshotOptions::default() };
    let snapshot = render_snapshot(&source, &target, &truth, &options).unwrap();
    let texts: Vec<&str> = snapshot.labels.iter().map(|l| l.text.as_str()).collect();
    let expected = ["before: top", "before: front", "before: side", "after: top", "after: front", "after: side"];
    assert_eq!(texts[..6], expected);
    assert_eq!(texts[6..], ["source", "target", "both", "inlier matches"]);
    for (label, panel) in snapshot.labels.iter().zip(&snapshot.panels) {
        // Just over its own panel, left-aligned with it, on the ground between panels.
        assert_eq!((label.x, label.y + 16 + 4), (panel.x, panel.y), "{label:?} over {panel:?}");
        assert!(label.x + label.width() <= panel.x + 360, "{label:?}");
        assert_label_pixels(&snapshot, label, GAP_RGB);
    }
    let legend_top = snapshot.panels.last().unwrap().y + 360 + 4;
    for (label, swatch) in snapshot.labels[6..].iter().zip([SOURCE_RGB, TARGET_RGB, OVERLAP_RGB, LINE_RGB]) {
        assert_eq!((label.y, label.scale), (legend_top, 2), "{label:?}");
        assert_label_pixels(&snapshot, label, GAP_RGB);
        // The colour swatch one cell to the left of its words.
        let (x, y) = (label.x - 16 - 8, label.y + 8);
        let i = (y as usize * snapshot.width() as usize + x as usize) * 4;
        assert_eq!(snapshot.rgba()[i..i + 3], swatch, "swatch of '{}'", label.text);
    }
    // Without lines the legend has no line entry; small panels get small letters, and only what fits.
    let small = SnapshotOptions { views: vec![View::Front], panel_px: 64, ..SnapshotOptions::default() };
    let snapshot = render_snapshot(&source, &target, &truth, &small).unwrap();
    let texts: Vec<&str> = snapshot.labels.iter().map(|l| l.text.as_str()).collect();
    assert_eq!(texts, ["before", "after", "source"]);
    assert!(snapshot.labels.iter().all(|l| l.scale == 1));
    for label in &snapshot.labels {
        assert_label_pixels(&snapshot, label, GAP_RGB);
    }
}

#[test]
fn large_clouds_are_thinned_to_the_point_budget() {
    let (source, target, truth) = room_pair(7, 200_000);
    let options = SnapshotOptions { max_points_per_cloud: 1_000, dot_px: 1, ..SnapshotOptions::default() };
    let snapshot = render_snapshot(&source, &target, &truth, &options).unwrap();
    for p in &snapshot.panels {
        assert!(p.source_pixels <= 1_000 && p.target_pixels <= 1_000, "{p:?}");
        assert!(p.source_pixels > 300 && p.target_pixels > 300, "{p:?}");
    }
}

#[test]
fn lines_are_drawn_in_the_after_row_only() {
    let (source, target, truth) = room_pair(8, 5_000);
    let plain = SnapshotOptions::default();
    let lines: Vec<([f32; 3], [f32; 3])> =
        source.points.iter().step_by(50).map(|&p| (p, transform_point(&truth, p))).collect();
    let with_lines = SnapshotOptions { lines, ..plain.clone() };
    let a = render_snapshot(&source, &target, &truth, &plain).unwrap();
    let b = render_snapshot(&source, &target, &truth, &with_lines).unwrap();
    let row_bytes = |s: &Snapshot, row: Row| -> Vec<u8> {
        let y0 = s.panels.iter().find(|p| p.row == row).unwrap().y as usize;
        let stride = s.width() as usize * 4;
        s.rgba()[y0 * stride..(y0 + plain.panel_px as usize) * stride].to_vec()
    };
    assert_eq!(row_bytes(&a, Row::Before), row_bytes(&b, Row::Before));
    assert_ne!(row_bytes(&a, Row::After), row_bytes(&b, Row::After));
    assert_eq!(a.panels, b.panels, "lines do not change the clouds' coverage");
}

#[test]
fn write_snapshot_checks_its_path_and_replaces_atomically() {
    let dir = temp_dir("snapshot-paths");
    let (source, target, truth) = room_pair(9, 2_000);
    let options = SnapshotOptions { panel_px: 64, ..SnapshotOptions::default() };
    let write = |p: &Path| write_snapshot(p, &source, &target, &truth, &options);
    let missing = write(&dir.join("no/such/folder/x.png")).unwrap_err().to_string();
    assert!(missing.contains("does not exist") && missing.contains("x.png"), "{missing}");
    let folder = write(&dir).unwrap_err().to_string();
    assert!(folder.contains("is a directory"), "{folder}");
    let jpeg = write(&dir.join("x.jpg")).unwrap_err().to_string();
    assert!(jpeg.contains("PNG") && jpeg.contains("x.jpg"), "{jpeg}");
    let out = dir.join("snap.PNG");
    std::fs::write(&out, b"old").unwrap();
    write(&out).unwrap();
    let image = tiny_skia::Pixmap::load_png(&out).unwrap();
    assert_eq!((image.width(), image.height()), options.image_size());
    let leftovers: Vec<_> = std::fs::read_dir(&dir).unwrap().filter_map(|e| e.ok()).collect();
    assert_eq!(leftovers.len(), 1, "no temp files left: {leftovers:?}");
}

/// The vertex colours of a binary little-endian PLY whose vertices are `float x y z [nx ny nz]` then
/// `uchar red green blue` (parsed here by hand, independently of the writer).
fn ply_colors(bytes: &[u8]) -> Vec<[u8; 3]> {
    let end = b"end_header\n";
    let at = bytes.windows(end.len()).position(|w| w == end).unwrap() + end.len();
    let header = std::str::from_utf8(&bytes[..at]).unwrap();
    assert!(header.contains("property uchar red\nproperty uchar green\nproperty uchar blue\nend_header"));
    let floats = header.lines().filter(|l| l.starts_with("property float")).count();
    let stride = floats * 4 + 3;
    assert_eq!((bytes.len() - at) % stride, 0);
    bytes[at..].chunks_exact(stride).map(|v| [v[floats * 4], v[floats * 4 + 1], v[floats * 4 + 2]]).collect()
}

#[test]
fn the_merged_ply_holds_the_moved_source_and_the_target_in_two_colours() {
    let dir = temp_dir("snapshot-merged");
    let (source, target, truth) = room_pair(10, 3_000);
    let target = PointCloud::from_points(target.points[..2_500].to_vec());
    let (merged, colors) = merged_pair(&source.transformed(&truth), &target);
    let path = dir.join("merged.ply");
    write_ply_with_colors(&path, &merged, &colors).unwrap();
    let (back, _) = read_cloud(&path, &LoadOptions::default()).unwrap();
    assert_eq!(back.len(), source.len() + target.len());
    for (got, p) in back.points.iter().zip(&source.points) {
        let want = transform_point(&truth, *p);
        assert!((0..3).all(|k| (got[k] - want[k]).abs() < 1e-5), "{got:?} vs {want:?}");
    }
    assert_eq!(&back.points[source.len()..], &target.points[..]);
    let read_colors = ply_colors(&std::fs::read(&path).unwrap());
    assert_eq!(read_colors.len(), back.len());
    assert!(read_colors[..source.len()].iter().all(|&c| c == SOURCE_RGB));
    assert!(read_colors[source.len()..].iter().all(|&c| c == TARGET_RGB));
    // Mismatched colours are refused, naming the file.
    let err = write_ply_with_colors(&path, &merged, &colors[1..]).unwrap_err().to_string();
    assert!(err.contains("merged.ply") && err.contains("colours"), "{err}");
}

fn dpr(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_dpr-gpu")).args(args).output().expect("binary runs")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A small seeded model (32 points per patch) so CPU runs stay short.
fn small_weights(dir: &Path) -> String {
    let w = dir.join("w.safetensors");
    let o = dpr(&["init-weights", w.to_str().unwrap(), "--seed", "3", "--points", "32", "--grid", "8"]);
    assert!(o.status.success(), "{}", stderr(&o));
    w.to_str().unwrap().to_string()
}

#[test]
fn register_writes_a_snapshot_and_a_merged_ply_and_refuses_bad_paths() {
    let dir = temp_dir("snapshot-cli");
    let (source, target, _) = room_pair(11, 4_000);
    let (s, t) = (dir.join("s.ply"), dir.join("t.ply"));
    write_ply(&s, &source).unwrap();
    write_ply(&t, &target).unwrap();
    let weights = small_weights(&dir);
    let (s, t) = (s.to_str().unwrap(), t.to_str().unwrap());
    let base = ["register", s, t, "--weights", &weights, "--keypoints", "150", "--estimator", "ransac", "--json"];
    let run = |extra: &[&str]| dpr(&[&base[..], extra].concat());
    let fails = |extra: &[&str], needle: &str| {
        let o = run(extra);
        let err = stderr(&o);
        assert!(!o.status.success() && err.contains(needle) && !err.contains("panicked"), "{extra:?}: {err}");
    };

    let before = std::fs::read(s).unwrap();
    fails(&["--snapshot", dir.join("missing/x.png").to_str().unwrap()], "does not exist");
    fails(&["--snapshot", s], "a snapshot is a PNG");
    let link = dir.join("link.png");
    std::os::unix::fs::symlink(s, &link).unwrap();
    fails(&["--snapshot", link.to_str().unwrap()], "refusing to overwrite input");
    fails(&["--aligned", dir.join("a.xyz").to_str().unwrap(), "--merged"], "*.ply");
    fails(&["--merged"], "--aligned");
    let same = dir.join("same.png");
    fails(&["--snapshot", same.to_str().unwrap(), "--out", same.to_str().unwrap()], "same file");
    assert_eq!(std::fs::read(s).unwrap(), before);

    let (png, merged) = (dir.join("snap.png"), dir.join("merged.ply"));
    let o = run(&["--snapshot", png.to_str().unwrap(), "--aligned", merged.to_str().unwrap(), "--merged"]);
    assert!(matches!(o.status.code(), Some(0 | 3)), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let rows = v["target_from_source"].as_array().unwrap();
    let estimate = Matrix4::from_fn(|r, c| rows[r][c].as_f64().unwrap());
    let image = tiny_skia::Pixmap::load_png(&png).unwrap();
    assert_eq!((image.width(), image.height()), SnapshotOptions::default().image_size());
    // The picture is the library's rendering of the same clouds and pose, plus the inlier correspondences in
    // the after (bottom) row.
    let expected = render_snapshot(&source, &target, &estimate, &SnapshotOptions::default()).unwrap();
    let after_row = expected.panels.iter().find(|p| p.row == Row::After).unwrap().y as usize;
    let half = after_row * image.width() as usize * 4;
    let differ = |range: std::ops::Range<usize>| {
        image.data()[range.clone()].iter().zip(&expected.rgba()[range]).filter(|(a, b)| a != b).count()
    };
    let (before, after) = (differ(0..half), differ(half..image.data().len()));
    // The pose went through 9-digit JSON: a handful of dots may land one pixel over.
    assert!(before * 1000 < half, "{before} bytes of the before row differ");
    assert!(after > before + 100, "the inlier lines are missing from the after row ({after} vs {before})");
    let written: Vec<&str> = v["written"].as_array().unwrap().iter().map(|w| w.as_str().unwrap()).collect();
    let said = format!("snapshot written to {} (top row before, bottom row after registration", png.display());
    assert!(written.iter().any(|w| w.starts_with(&said)), "{written:?}");
    let (back, _) = read_cloud(&merged, &LoadOptions::default()).unwrap();
    assert_eq!(back.len(), source.len() + target.len());
    assert_eq!(&back.points[source.len()..], &target.points[..]);
    let first = transform_point(&estimate, source.points[0]);
    assert!((0..3).all(|k| (back.points[0][k] - first[k]).abs() < 1e-4));
    let colors = ply_colors(&std::fs::read(&merged).unwrap());
    assert_eq!(colors.iter().filter(|&&c| c == SOURCE_RGB).count(), source.len());
    assert_eq!(colors.iter().filter(|&&c| c == TARGET_RGB).count(), target.len());
}

#[test]
fn eval_writes_one_snapshot_per_pair_estimator_and_angle() {
    let dir = temp_dir("snapshot-eval");
    let (source, target, truth) = room_pair(12, 3_000);
    write_ply(&dir.join("a.ply"), &source).unwrap();
    write_ply(&dir.join("b.ply"), &target).unwrap();
    let numbers: Vec<String> =
        (0..4).flat_map(|r| (0..4).map(move |c| (r, c))).map(|(r, c)| truth[(r, c)].to_string()).collect();
    std::fs::write(dir.join("pairs.txt"), format!("a.ply b.ply {}\n", numbers.join(" "))).unwrap();
    let weights = small_weights(&dir);
    let (pairs, out, snaps) = (dir.join("pairs.txt"), dir.join("out"), dir.join("snaps"));
    let args = [
        "eval",
        pairs.to_str().unwrap(),
        "--weights",
        &weights,
        "--keypoints",
        "120",
        "--estimator",
        "both",
        "--rotate",
        "0,90",
        "--out",
        out.to_str().unwrap(),
        "--snapshots",
        snaps.to_str().unwrap(),
    ];
    let o = dpr(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let scene = dir.canonicalize().unwrap().file_name().unwrap().to_string_lossy().into_owned();
    let mut found = 0;
    for estimator in ["relativenet", "ransac"] {
        for angle in ["rot0", "rot90"] {
            let png = snaps.join(estimator).join(angle).join(&scene).join("a_to_b.png");
            let image = tiny_skia::Pixmap::load_png(&png).unwrap_or_else(|e| panic!("{}: {e}", png.display()));
            assert_eq!((image.width(), image.height()), SnapshotOptions::default().image_size());
            found += 1;
        }
    }
    assert_eq!(found, 4);
    let log_only = dpr(&["eval", pairs.to_str().unwrap(), "--log", "x.log", "--snapshots", snaps.to_str().unwrap()]);
    assert!(!log_only.status.success() && stderr(&log_only).contains("--snapshots"), "{}", stderr(&log_only));
}

/// The picture the README shows, `examples/pair/snapshot.png`, is what `register --snapshot` draws today on the
/// example pair with the CLI's defaults (CPU backend): the same size and labels, the before row (which does not
/// depend on the registration) identical, and the whole image identical but for a few pixels (a CPU without the
/// bf16 instructions computes its codewords in f32, which may move an inlier mark). Regenerate it with the
/// command in docs/snapshot.md when the drawing changes.
#[test]
fn the_committed_example_snapshot_is_what_register_draws_today() {
    let dir = temp_dir("snapshot-example");
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/pair");
    let drawn = dir.join("snapshot.png");
    let (source, target) = (example.join("cloud_bin_1.ply"), example.join("cloud_bin_0.ply"));
    let o = dpr(&[
        "register",
        source.to_str().unwrap(),
        target.to_str().unwrap(),
        "--backend",
        "cpu",
        "--snapshot",
        drawn.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let committed = tiny_skia::Pixmap::load_png(example.join("snapshot.png")).unwrap();
    let today = tiny_skia::Pixmap::load_png(&drawn).unwrap();
    assert_eq!((committed.width(), committed.height()), (today.width(), today.height()), "regenerate the picture");
    let options = SnapshotOptions::default();
    let before_rows =
        (options.gap_px + options.text_band_px() + options.panel_px) as usize * today.width() as usize * 4;
    assert!(committed.data()[..before_rows] == today.data()[..before_rows], "the before row differs: regenerate");
    let differing = committed.pixels().iter().zip(today.pixels()).filter(|(a, b)| a != b).count();
    assert!(differing * 200 < today.pixels().len(), "{differing} pixels differ: regenerate the picture");
}
