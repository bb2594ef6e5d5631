//! Drawing one panel with tiny-skia: each cloud into its own coverage layer (square dots, no anti-aliasing, so
//! every touched pixel is fully covered), the layers composited so that overlap gets a colour of its own,
//! then optional correspondence lines on top.

use super::views::PanelFrame;
use super::{BACKGROUND_RGB, LINE_RGBA, SOURCE_RGB, TARGET_RGB};
use nalgebra::Vector3;
use tiny_skia::{BlendMode, Color, FillRule, Paint, PathBuilder, Pixmap, PixmapPaint, Rect, Stroke, Transform};

/// Pixels of one panel covered by each cloud.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct Coverage {
    /// Pixels covered by source points.
    pub(super) source: u64,
    /// Pixels covered by target points.
    pub(super) target: u64,
    /// Pixels covered by both.
    pub(super) both: u64,
}

/// A solid paint of `rgb` (opaque), without anti-aliasing.
fn solid(rgb: [u8; 3]) -> Paint<'static> {
    let mut paint = Paint { anti_alias: false, ..Paint::default() };
    paint.set_color_rgba8(rgb[0], rgb[1], rgb[2], 255);
    paint
}

/// A transparent `side` x `side` layer with a `dot_px` square of `rgb` at every point inside the panel.
fn dots(points: &[Vector3<f64>], frame: &PanelFrame, side: u32, dot_px: u32, rgb: [u8; 3]) -> Pixmap {
    let mut layer = Pixmap::new(side, side).expect("panel size checked by the options");
    let paint = solid(rgb);
    let limit = f64::from(side);
    let half = f64::from(dot_px) / 2.0;
    for p in points {
        let (x, y) = frame.pixel(p);
        if !(0.0..limit).contains(&x) || !(0.0..limit).contains(&y) {
            continue;
        }
        // Whole-pixel squares: coverage is exact, and the colours of the composite are exact too.
        let (left, top) = ((x - half).round() as f32, (y - half).round() as f32);
        if let Some(rect) = Rect::from_xywh(left, top, dot_px as f32, dot_px as f32) {
            layer.fill_rect(rect, &paint, Transform::identity(), None);
        }
    }
    layer
}

/// Counts the pixels covered in each layer and in both.
fn coverage(source: &Pixmap, target: &Pixmap) -> Coverage {
    let mut c = Coverage::default();
    for (s, t) in source.pixels().iter().zip(target.pixels()) {
        let (s, t) = (s.alpha() > 0, t.alpha() > 0);
        c.source += u64::from(s);
        c.target += u64::from(t);
        c.both += u64::from(s && t);
    }
    c
}

/// Renders one panel: target points in [`TARGET_RGB`], source points in [`SOURCE_RGB`], pixels hit by both in
/// their even mix ([`super::OVERLAP_RGB`]), the rest [`BACKGROUND_RGB`]; then `lines` (pairs of points already
/// in the panel's frame) in [`LINE_RGBA`], each with a dot at its target end.
pub(super) fn panel(
    source: &[Vector3<f64>],
    target: &[Vector3<f64>],
    lines: &[(Vector3<f64>, Vector3<f64>)],
    frame: &PanelFrame,
    side: u32,
    dot_px: u32,
) -> (Pixmap, Coverage) {
    let source_layer = dots(source, frame, side, dot_px, SOURCE_RGB);
    let target_layer = dots(target, frame, side, dot_px, TARGET_RGB);
    let counts = coverage(&source_layer, &target_layer);
    let mut canvas = Pixmap::new(side, side).expect("panel size checked by the options");
    let draw = |canvas: &mut Pixmap, layer: &Pixmap, opacity: f32, blend_mode: BlendMode| {
        let paint = PixmapPaint { opacity, blend_mode, ..PixmapPaint::default() };
        canvas.draw_pixmap(0, 0, layer.as_ref(), &paint, Transform::identity(), None);
    };
    // Target opaque; source at half opacity over it (overlap = the even mix, source alone = half-transparent
    // orange); the source again underneath everything (fills source-only pixels to opaque orange, leaves
    // opaque pixels alone); the background last, underneath.
    draw(&mut canvas, &target_layer, 1.0, BlendMode::SourceOver);
    draw(&mut canvas, &source_layer, 0.5, BlendMode::SourceOver);
    draw(&mut canvas, &source_layer, 1.0, BlendMode::DestinationOver);
    let mut background = solid(BACKGROUND_RGB);
    background.blend_mode = BlendMode::DestinationOver;
    let whole = Rect::from_xywh(0.0, 0.0, side as f32, side as f32).expect("positive panel size");
    canvas.fill_rect(whole, &background, Transform::identity(), None);
    draw_lines(&mut canvas, lines, frame);
    (canvas, counts)
}

/// Strokes `lines` (from, to) as thin anti-aliased segments with a small dot at `to`.
fn draw_lines(canvas: &mut Pixmap, lines: &[(Vector3<f64>, Vector3<f64>)], frame: &PanelFrame) {
    if lines.is_empty() {
        return;
    }
    let mut segments = PathBuilder::new();
    let mut ends = PathBuilder::new();
    for (from, to) in lines {
        let (a, b) = (frame.pixel(from), frame.pixel(to));
        segments.move_to(a.0 as f32, a.1 as f32);
        segments.line_to(b.0 as f32, b.1 as f32);
        ends.push_circle(b.0 as f32, b.1 as f32, 1.5);
    }
    let mut paint = Paint::default();
    paint.set_color(Color::from_rgba8(LINE_RGBA[0], LINE_RGBA[1], LINE_RGBA[2], LINE_RGBA[3]));
    if let Some(path) = segments.finish() {
        canvas.stroke_path(&path, &paint, &Stroke { width: 1.0, ..Stroke::default() }, Transform::identity(), None);
    }
    if let Some(path) = ends.finish() {
        canvas.fill_path(&path, &paint, FillRule::Winding, Transform::identity(), None);
    }
}
