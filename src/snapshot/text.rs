//! Words in the picture: short ASCII labels drawn with the 8 x 8 bitmap font of the `font8x8` crate, each glyph
//! pixel an integer-scaled square, on an opaque box so the words read over points. What was drawn where is kept
//! as [`Label`]s, so callers (and tests) can read the text layer back.

use tiny_skia::{Paint, Pixmap, Rect, Transform};

/// Colour of label text (near black).
pub const TEXT_RGB: [u8; 3] = [33, 33, 33];
/// Side of one glyph cell in font pixels.
pub const GLYPH_PX: u32 = 8;

/// One piece of text drawn into the image.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Label {
    /// The text (ASCII; other characters are drawn as `?`).
    pub text: String,
    /// Left edge of the first glyph cell (pixels).
    pub x: u32,
    /// Top edge of the glyph cells (pixels).
    pub y: u32,
    /// Image pixels per font pixel.
    pub scale: u32,
}

impl Label {
    /// Width of the drawn text in pixels.
    pub fn width(&self) -> u32 {
        text_width(&self.text, self.scale)
    }

    /// Whether the glyph pixel (`column`, `row`) of character `index` is set (the font's bitmap; bit 0 of a
    /// row byte is the leftmost pixel).
    pub fn glyph_pixel(&self, index: usize, column: u32, row: u32) -> bool {
        let c = self.text.as_bytes().get(index).copied().unwrap_or(b' ');
        glyph(c)[row as usize] & (1 << column) != 0
    }
}

/// Width in pixels of `text` at `scale`.
pub fn text_width(text: &str, scale: u32) -> u32 {
    text.len() as u32 * GLYPH_PX * scale
}

/// The font's bitmap of an ASCII byte; `?` for anything else.
fn glyph(c: u8) -> [u8; 8] {
    let c = if c.is_ascii() && !c.is_ascii_control() { c } else { b'?' };
    font8x8::legacy::BASIC_LEGACY[c as usize]
}

/// A solid opaque paint without anti-aliasing.
fn solid(rgb: [u8; 3]) -> Paint<'static> {
    let mut paint = Paint { anti_alias: false, ..Paint::default() };
    paint.set_color_rgba8(rgb[0], rgb[1], rgb[2], 255);
    paint
}

/// Fills the pixel rectangle (`x`, `y`, `w`, `h`) with `rgb` (clipped to the image).
pub(super) fn fill(image: &mut Pixmap, x: u32, y: u32, w: u32, h: u32, rgb: [u8; 3]) {
    if let Some(rect) = Rect::from_xywh(x as f32, y as f32, w as f32, h as f32) {
        image.fill_rect(rect, &solid(rgb), Transform::identity(), None);
    }
}

/// Draws `text` with its top-left corner at (`x`, `y`): every glyph cell filled with `box_rgb`, then the set
/// glyph pixels in [`TEXT_RGB`]. Non-ASCII characters become `?` (so a label's byte length is its glyph count).
pub(super) fn draw(image: &mut Pixmap, text: &str, x: u32, y: u32, scale: u32, box_rgb: [u8; 3]) -> Label {
    let text: String = text.chars().map(|c| if c.is_ascii() && !c.is_ascii_control() { c } else { '?' }).collect();
    let label = Label { text, x, y, scale };
    fill(image, x, y, label.width(), GLYPH_PX * scale, box_rgb);
    let ink = solid(TEXT_RGB);
    for (i, c) in label.text.bytes().enumerate() {
        for (row, bits) in glyph(c).iter().enumerate() {
            for column in 0..GLYPH_PX {
                if bits & (1 << column) != 0 {
                    let px = x + (i as u32 * GLYPH_PX + column) * scale;
                    let py = y + row as u32 * scale;
                    if let Some(rect) = Rect::from_xywh(px as f32, py as f32, scale as f32, scale as f32) {
                        image.fill_rect(rect, &ink, Transform::identity(), None);
                    }
                }
            }
        }
    }
    label
}
