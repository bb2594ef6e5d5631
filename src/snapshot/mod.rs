//! A picture of a registration: one PNG with the two scans before and after `target_from_source` is applied.
//!
//! Layout: a grid of 2 rows by 1 to 3 columns of square panels on a grey ground. The top row is **before**
//! (source and target as given, each in its own frame), the bottom row **after** (the source moved by
//! `target_from_source`). Each column is one orthographic [`View`] (default: top, front, side) taken along the
//! target's principal axes (see [`ViewAxes`]); each panel frames the points it shows (uniform scale, the
//! extreme 0.2% of points along each panel axis ignored). A line of text over each panel names its row and
//! view (`before: top`), and a legend line under the panels names the colours (an 8 x 8 bitmap
//! font compiled in, [`text`]); [`Snapshot::labels`] lists every word drawn and where.
//!
//! Colours (colour-blind safe, Okabe-Ito): target points [`TARGET_RGB`] (blue), source points [`SOURCE_RGB`]
//! (orange), pixels hit by both their even mix [`OVERLAP_RGB`] (olive), background [`BACKGROUND_RGB`]
//! (white). Points are `dot_px`-square dots without depth order, so a well-registered pair shows mostly the
//! overlap colour where the scans share surfaces. Optional correspondence lines (e.g. the inliers, see
//! [`inlier_lines`]) are drawn in the after row in [`LINE_RGBA`] (reddish purple), each with a dot at its
//! target end.
//!
//! Rendering (tiny-skia, which also encodes the PNG) is deterministic: the same inputs give the same bytes.
//! Clouds larger than [`SnapshotOptions::max_points_per_cloud`] are thinned by a fixed stride (every k-th
//! point), so a snapshot of millions of points stays fast.

mod raster;
pub mod text;
mod views;

pub use text::Label;
pub use views::{View, ViewAxes};

use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::io::{check_output_path, write_atomic};
use crate::settings::Correspondence;
use nalgebra::{Matrix4, Vector3};
use std::path::Path;
use tiny_skia::{Color, Pixmap, PixmapPaint, Transform};

/// Colour of source points (Okabe-Ito orange).
pub const SOURCE_RGB: [u8; 3] = [230, 159, 0];
/// Colour of target points (Okabe-Ito blue).
pub const TARGET_RGB: [u8; 3] = [0, 114, 178];
/// Colour of pixels hit by both clouds: the even mix of [`SOURCE_RGB`] and [`TARGET_RGB`] (as tiny-skia's
/// 8-bit pipeline rounds it; each channel within 1 of the exact mean).
pub const OVERLAP_RGB: [u8; 3] = [115, 137, 89];
/// Colour of empty panel pixels.
pub const BACKGROUND_RGB: [u8; 3] = [255, 255, 255];
/// Colour of the ground between panels.
pub const GAP_RGB: [u8; 3] = [190, 190, 190];
/// Colour and opacity of correspondence lines (Okabe-Ito reddish purple).
pub const LINE_RGBA: [u8; 4] = [204, 121, 167, 230];

/// Largest accepted panel side in pixels.
pub const MAX_PANEL_PX: u32 = 2048;
/// Smallest accepted panel side in pixels.
pub const MIN_PANEL_PX: u32 = 32;

/// A row of the snapshot grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Row {
    /// Top row: both scans as given.
    Before,
    /// Bottom row: the source moved by `target_from_source`.
    After,
}

impl Row {
    /// The row's name as labelled in the picture: `before` or `after`.
    pub fn name(self) -> &'static str {
        match self {
            Row::Before => "before",
            Row::After => "after",
        }
    }
}

/// How a snapshot is drawn.
#[derive(Clone, Debug, PartialEq)]
pub struct SnapshotOptions {
    /// The views, one column each, left to right (1 to 3, no repeats).
    pub views: Vec<View>,
    /// The frame the views are taken in.
    pub axes: ViewAxes,
    /// Side of each square panel in pixels ([`MIN_PANEL_PX`]..=[`MAX_PANEL_PX`]).
    pub panel_px: u32,
    /// Width of the ground around and between panels in pixels (at most 64).
    pub gap_px: u32,
    /// Side of each point's square dot in pixels (1 to 16).
    pub dot_px: u32,
    /// Most points drawn per cloud; larger clouds are thinned to every k-th point (k = ceil(n / this)).
    pub max_points_per_cloud: usize,
    /// Lines drawn in the after row: (point in the source frame, point in the target frame), e.g. the inlier
    /// correspondences from [`inlier_lines`]; thinned by a fixed stride beyond `max_lines`.
    pub lines: Vec<([f32; 3], [f32; 3])>,
    /// Most lines drawn.
    pub max_lines: usize,
}

impl Default for SnapshotOptions {
    fn default() -> Self {
        SnapshotOptions {
            views: vec![View::Top, View::Front, View::Side],
            axes: ViewAxes::Principal,
            panel_px: 360,
            gap_px: 4,
            dot_px: 2,
            max_points_per_cloud: 50_000,
            lines: Vec::new(),
            max_lines: 2_000,
        }
    }
}

impl SnapshotOptions {
    /// Checks every field is in its documented range.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(Error::invalid(format!("snapshot: {m}")));
        if self.views.is_empty() || self.views.len() > 3 {
            return bad(format!("1 to 3 views are drawn, {} given", self.views.len()));
        }
        if self.views.iter().enumerate().any(|(i, v)| self.views[..i].contains(v)) {
            return bad(format!("a view is repeated in {:?}", self.views));
        }
        if !(MIN_PANEL_PX..=MAX_PANEL_PX).contains(&self.panel_px) {
            return bad(format!("panel size {} px is outside {MIN_PANEL_PX}..={MAX_PANEL_PX}", self.panel_px));
        }
        if self.gap_px > 64 {
            return bad(format!("gap {} px is over 64", self.gap_px));
        }
        if !(1..=16).contains(&self.dot_px) {
            return bad(format!("dot size {} px is outside 1..=16", self.dot_px));
        }
        if self.max_points_per_cloud == 0 {
            return bad("max_points_per_cloud must be at least 1".into());
        }
        Ok(())
    }

    /// (width, height) in pixels of the image these options give: `views * panel_px + (views + 1) * gap_px`
    /// by `2 * panel_px + 3 * gap_px` plus three text bands ([`SnapshotOptions::text_band_px`]: one over each
    /// row of panels, the legend under them).
    pub fn image_size(&self) -> (u32, u32) {
        let columns = self.views.len() as u32;
        let height = 2 * self.panel_px + 3 * self.gap_px + 3 * self.text_band_px();
        (columns * self.panel_px + (columns + 1) * self.gap_px, height)
    }

    /// Image pixels per font pixel of the labels: 2 for panels of 160 px or more, else 1.
    pub fn label_scale(&self) -> u32 {
        if self.panel_px >= 160 { 2 } else { 1 }
    }

    /// Height of a band of text: one line of glyphs and a gap under it.
    pub fn text_band_px(&self) -> u32 {
        text::GLYPH_PX * self.label_scale() + self.gap_px
    }

    /// Top edge of the panels of row `r` (0: before, 1: after) in the image.
    fn row_top(&self, r: u32) -> u32 {
        self.gap_px + r * (self.text_band_px() + self.panel_px + self.gap_px) + self.text_band_px()
    }
}

/// What one panel shows, and where it is in the image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct PanelCoverage {
    /// The row (before / after).
    pub row: Row,
    /// The view (column).
    pub view: View,
    /// Left edge of the panel in the image (pixels).
    pub x: u32,
    /// Top edge of the panel in the image (pixels).
    pub y: u32,
    /// Panel pixels hit by source points.
    pub source_pixels: u64,
    /// Panel pixels hit by target points.
    pub target_pixels: u64,
    /// Panel pixels hit by both (drawn in [`OVERLAP_RGB`]).
    pub overlap_pixels: u64,
}

/// A rendered snapshot: the image and what each panel covers.
#[derive(Clone, Debug)]
pub struct Snapshot {
    /// The image (every pixel opaque).
    image: Pixmap,
    /// One entry per panel, row by row, left to right.
    pub panels: Vec<PanelCoverage>,
    /// Every piece of text drawn: the panels' labels (row by row, left to right), then the legend's.
    pub labels: Vec<Label>,
}

impl Snapshot {
    /// Image width in pixels.
    pub fn width(&self) -> u32 {
        self.image.width()
    }

    /// Image height in pixels.
    pub fn height(&self) -> u32 {
        self.image.height()
    }

    /// The pixels, row by row, 4 bytes (R, G, B, A) each; every pixel is opaque (A = 255).
    pub fn rgba(&self) -> &[u8] {
        // tiny-skia stores premultiplied colour, which equals straight colour for opaque pixels.
        self.image.data()
    }

    /// The image as PNG file bytes (RGBA, 8 bits per channel).
    pub fn encode_png(&self) -> Result<Vec<u8>> {
        self.image.encode_png().map_err(|e| Error::invalid(format!("snapshot: PNG encoding failed: {e}")))
    }

    /// Pixels hit by both clouds, summed over the panels of `row`.
    pub fn overlap_pixels(&self, row: Row) -> u64 {
        self.panels.iter().filter(|p| p.row == row).map(|p| p.overlap_pixels).sum()
    }
}

/// Every k-th point of `cloud` (k = ceil(n / max)), as `f64` vectors mapped by `transform`.
fn thinned(cloud: &PointCloud, max: usize, transform: &Matrix4<f64>) -> Vec<Vector3<f64>> {
    let stride = cloud.len().div_ceil(max).max(1);
    cloud.points.iter().step_by(stride).map(|p| moved(transform, *p)).collect()
}

/// The point (as `f64`) of a source-frame or target-frame position under `transform`.
fn moved(transform: &Matrix4<f64>, p: [f32; 3]) -> Vector3<f64> {
    let v = Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
    transform.fixed_view::<3, 3>(0, 0) * v + transform.fixed_view::<3, 1>(0, 3)
}

/// Renders the snapshot of `source` and `target` before and after `target_from_source` (p_target = T
/// p_source) into memory; see the [module docs](self) for the layout and colours.
///
/// Errors: [`Error::InvalidInput`] for options out of range, an empty cloud, a non-finite coordinate or a
/// non-finite transform.
pub fn render_snapshot(
    source: &PointCloud,
    target: &PointCloud,
    target_from_source: &Matrix4<f64>,
    options: &SnapshotOptions,
) -> Result<Snapshot> {
    options.validate()?;
    for (what, cloud) in [("snapshot source", source), ("snapshot target", target)] {
        cloud.validate(what)?;
        if cloud.is_empty() {
            return Err(Error::invalid(format!("{what}: the cloud has no points")));
        }
    }
    if !target_from_source.iter().all(|v| v.is_finite()) {
        return Err(Error::invalid("snapshot: target_from_source has a non-finite entry"));
    }
    let identity = Matrix4::identity();
    let max = options.max_points_per_cloud;
    let (source_as_given, target_points) = (thinned(source, max, &identity), thinned(target, max, &identity));
    let source_moved = thinned(source, max, target_from_source);
    let axes = views::frame_axes(options.axes, &target_points);
    let line_stride = options.lines.len().div_ceil(options.max_lines.max(1)).max(1);
    let lines: Vec<(Vector3<f64>, Vector3<f64>)> = options
        .lines
        .iter()
        .step_by(line_stride)
        .map(|(s, t)| (moved(target_from_source, *s), moved(&identity, *t)))
        .filter(|(a, b)| a.iter().chain(b.iter()).all(|c| c.is_finite()))
        .collect();

    let (width, height) = options.image_size();
    let mut image = Pixmap::new(width, height).expect("image size checked by the options");
    image.fill(Color::from_rgba8(GAP_RGB[0], GAP_RGB[1], GAP_RGB[2], 255));
    let mut panels = Vec::new();
    let mut labels = Vec::new();
    let (side, gap) = (options.panel_px, options.gap_px);
    for (r, row) in [Row::Before, Row::After].into_iter().enumerate() {
        let (shown, row_lines): (&[Vector3<f64>], &[_]) = match row {
            Row::Before => (&source_as_given, &[]),
            Row::After => (&source_moved, &lines),
        };
        for (c, &view) in options.views.iter().enumerate() {
            let frame = views::PanelFrame::fit(view, &axes, &[shown, &target_points], side);
            let (pixels, counts) = raster::panel(shown, &target_points, row_lines, &frame, side, options.dot_px);
            let (x, y) = (gap + c as u32 * (side + gap), options.row_top(r as u32));
            image.draw_pixmap(
                x as i32,
                y as i32,
                pixels.as_ref(),
                &PixmapPaint::default(),
                Transform::identity(),
                None,
            );
            labels.extend(panel_label(&mut image, options, row, view, (x, y)));
            panels.push(PanelCoverage {
                row,
                view,
                x,
                y,
                source_pixels: counts.source,
                target_pixels: counts.target,
                overlap_pixels: counts.both,
            });
        }
    }
    labels.extend(legend(&mut image, options, !lines.is_empty()));
    Ok(Snapshot { image, panels, labels })
}

/// Labels the panel whose top-left corner is `corner` with its row and view (`before: top`), in the text band
/// over it; the row's name alone where the whole does not fit the panel's width, nothing where that does not.
fn panel_label(
    image: &mut Pixmap,
    options: &SnapshotOptions,
    row: Row,
    view: View,
    corner: (u32, u32),
) -> Option<Label> {
    let scale = options.label_scale();
    let fits = |words: &str| text::text_width(words, scale) <= options.panel_px;
    let words = [format!("{}: {}", row.name(), view.name()), row.name().to_string()].into_iter().find(|w| fits(w))?;
    Some(text::draw(image, &words, corner.0, corner.1 - options.text_band_px(), scale, GAP_RGB))
}

/// Draws the legend band under the panels: a colour swatch and its meaning for the source, the target, their
/// overlap and (when drawn) the inlier lines, left to right, as many as fit the width.
fn legend(image: &mut Pixmap, options: &SnapshotOptions, with_lines: bool) -> Vec<Label> {
    let scale = options.label_scale();
    let cell = text::GLYPH_PX * scale;
    let y = options.row_top(2) - options.text_band_px();
    let line_rgb = [LINE_RGBA[0], LINE_RGBA[1], LINE_RGBA[2]];
    let mut items = vec![(SOURCE_RGB, "source"), (TARGET_RGB, "target"), (OVERLAP_RGB, "both")];
    if with_lines {
        items.push((line_rgb, "inlier matches"));
    }
    let mut x = options.gap_px;
    let mut labels = Vec::new();
    for (rgb, words) in items {
        let end = x + 2 * cell + text::text_width(words, scale);
        if end > image.width() {
            break;
        }
        text::fill(image, x, y, cell, cell, rgb);
        labels.push(text::draw(image, words, x + 2 * cell, y, scale, GAP_RGB));
        x = end + 2 * cell;
    }
    labels
}

/// One line saying how the picture is laid out, for the commands that write one.
pub fn describe_layout(options: &SnapshotOptions) -> String {
    let views: Vec<&str> = options.views.iter().map(|v| v.name()).collect();
    format!(
        "top row before, bottom row after registration; columns: {} views; source orange, target blue, both olive{}",
        views.join(", "),
        if options.lines.is_empty() { "" } else { ", inlier matches purple" }
    )
}

/// Checks, before any work is done, that `path` can take a snapshot: a `.png` name (or an existing device
/// such as `/dev/null`) in an existing folder, not a folder itself. `flag` names the option in messages
/// (e.g. "--snapshot"). Refusing to overwrite inputs is the caller's job (see [`crate::io::check_outputs`]).
pub fn check_snapshot_path(flag: &str, path: &Path) -> Result<()> {
    check_output_path(flag, path)?;
    let is_png = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("png"));
    let is_special = std::fs::metadata(path).is_ok_and(|m| !m.is_file() && !m.is_dir());
    if !is_png && !is_special {
        return Err(Error::invalid(format!("{flag} {}: a snapshot is a PNG image; name it *.png", path.display())));
    }
    Ok(())
}

/// Renders the snapshot (see [`render_snapshot`]) and writes it to `path` as PNG, atomically (temp file +
/// rename). The path is checked first with [`check_snapshot_path`].
///
/// Errors: as [`render_snapshot`] and [`check_snapshot_path`]; [`Error::Io`] naming `path` when writing fails.
pub fn write_snapshot(
    path: &Path,
    source: &PointCloud,
    target: &PointCloud,
    target_from_source: &Matrix4<f64>,
    options: &SnapshotOptions,
) -> Result<()> {
    check_snapshot_path("snapshot", path)?;
    let png = render_snapshot(source, target, target_from_source, options)?.encode_png()?;
    write_atomic(path, &png)
}

/// The correspondences that are inliers of `target_from_source` (|T s - t| < `threshold`), as lines for
/// [`SnapshotOptions::lines`].
pub fn inlier_lines(
    correspondences: &[Correspondence],
    target_from_source: &Matrix4<f64>,
    threshold: f32,
) -> Vec<([f32; 3], [f32; 3])> {
    correspondences
        .iter()
        .filter(|c| {
            let t = Vector3::new(c.target_point[0], c.target_point[1], c.target_point[2]).map(f64::from);
            (moved(target_from_source, c.source_point) - t).norm() < f64::from(threshold)
        })
        .map(|c| (c.source_point, c.target_point))
        .collect()
}

/// The moved source followed by the target in one cloud, with per-point colours ([`SOURCE_RGB`] then
/// [`TARGET_RGB`]) for [`crate::io::write_ply_with_colors`]. Normals are kept when both clouds have them.
pub fn merged_pair(moved_source: &PointCloud, target: &PointCloud) -> (PointCloud, Vec<[u8; 3]>) {
    let points = moved_source.points.iter().chain(&target.points).copied().collect();
    let normals = match (&moved_source.normals, &target.normals) {
        (Some(a), Some(b)) => Some(a.iter().chain(b).copied().collect()),
        _ => None,
    };
    let colors = std::iter::repeat_n(SOURCE_RGB, moved_source.len())
        .chain(std::iter::repeat_n(TARGET_RGB, target.len()))
        .collect();
    (PointCloud { points, normals }, colors)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(offset: f32) -> PointCloud {
        PointCloud::from_points(
            (0..40).flat_map(|i| (0..40).map(move |j| [i as f32 * 0.05 + offset, j as f32 * 0.05, 0.0])).collect(),
        )
    }

    #[test]
    fn options_out_of_range_are_refused() {
        let cloud = square(0.0);
        let id = Matrix4::identity();
        for options in [
            SnapshotOptions { views: vec![], ..SnapshotOptions::default() },
            SnapshotOptions { views: vec![View::Top, View::Top], ..SnapshotOptions::default() },
            SnapshotOptions { panel_px: 8, ..SnapshotOptions::default() },
            SnapshotOptions { dot_px: 0, ..SnapshotOptions::default() },
            SnapshotOptions { max_points_per_cloud: 0, ..SnapshotOptions::default() },
        ] {
            assert!(matches!(render_snapshot(&cloud, &cloud, &id, &options), Err(Error::InvalidInput(_))));
        }
        let mut nan = id;
        nan[(0, 3)] = f64::NAN;
        assert!(render_snapshot(&cloud, &cloud, &nan, &SnapshotOptions::default()).is_err());
        let empty = PointCloud::default();
        let err = render_snapshot(&empty, &cloud, &id, &SnapshotOptions::default()).unwrap_err();
        assert!(err.to_string().contains("snapshot source"), "{err}");
    }

    #[test]
    fn identical_clouds_overlap_wherever_they_are_drawn() {
        let cloud = square(0.0);
        let snapshot = render_snapshot(&cloud, &cloud, &Matrix4::identity(), &SnapshotOptions::default()).unwrap();
        for p in &snapshot.panels {
            assert_eq!(p.source_pixels, p.target_pixels);
            assert_eq!(p.overlap_pixels, p.source_pixels);
        }
    }

    #[test]
    fn inlier_lines_keep_only_close_pairs() {
        let c = |s: [f32; 3], t: [f32; 3]| Correspondence {
            source_index: 0,
            target_index: 0,
            source_point: s,
            target_point: t,
            feature_distance: 0.0,
        };
        let shift = Matrix4::new_translation(&Vector3::new(1.0, 0.0, 0.0));
        let pairs = [c([0.0; 3], [1.0, 0.0, 0.0]), c([0.0; 3], [0.0; 3]), c([2.0, 0.0, 0.0], [3.05, 0.0, 0.0])];
        let lines = inlier_lines(&pairs, &shift, 0.1);
        assert_eq!(lines, vec![([0.0; 3], [1.0, 0.0, 0.0]), ([2.0, 0.0, 0.0], [3.05, 0.0, 0.0])]);
    }
}
