//! CPU twin of `shaders/unit_rows.wgsl`: rows scaled to unit length and weighted, written as one column block
//! of wider rows (the side-by-side matching rows of codewords at several patch radii).

/// Writes each of the `rows` rows of `input` (`width` values each) times `weight / length` into columns
/// `column..column + width` of the rows of `out` (`out_width` values each); `length` is the square root of the
/// row's squares summed in order, at least 1e-12. Other columns keep their contents; rows that do not fit
/// `out` are skipped.
pub fn unit_rows(input: &[f32], width: usize, weight: f32, column: usize, out_width: usize, out: &mut [f32]) {
    if width == 0 || column + width > out_width {
        return;
    }
    for (row, x) in input.chunks_exact(width).enumerate() {
        let at = row * out_width + column;
        let Some(slot) = out.get_mut(at..at + width) else { return };
        let sum = x.iter().fold(0.0f32, |s, &v| s + v * v);
        let scale = weight / sum.sqrt().max(1e-12);
        for (o, &v) in slot.iter_mut().zip(x) {
            *o = v * scale;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_are_unit_rows_times_their_weight() {
        let a = [3.0, 4.0, 0.0, 0.0, 0.0, 2.0];
        let b = [1.0, 0.0, 0.0, 0.0];
        let mut out = vec![f32::NAN; 2 * 5];
        unit_rows(&a, 3, 1.0, 0, 5, &mut out);
        unit_rows(&b, 2, 0.5, 3, 5, &mut out);
        assert_eq!(out, vec![0.6, 0.8, 0.0, 0.5, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0]);
        // A zero row stays zero; a block past the row is refused.
        let mut z = vec![7.0; 2];
        unit_rows(&[0.0, 0.0], 2, 1.0, 0, 2, &mut z);
        assert_eq!(z, vec![0.0, 0.0]);
        unit_rows(&[1.0, 1.0], 2, 1.0, 1, 2, &mut z);
        assert_eq!(z, vec![0.0, 0.0]);
    }
}
