//! CPU twin of `shaders/transpose.wgsl`: a row-major matrix transposed. Builds every layer's forward weight
//! (`in x out`) from the stored one (`out x in`, [`crate::model::linear::Linear::from_weights`]), as the device
//! trainer does after each step.

/// `x` (`rows x cols`, row-major) transposed: `cols x rows`, `out[c * rows + r] = x[r * cols + c]`.
/// Walked in 32 x 32 blocks, so that the reads and the writes of a block stay in a few cache lines (a plain
/// row-by-row walk writes a new line for every value of a wide matrix).
pub fn transpose(x: &[f32], rows: usize, cols: usize) -> Vec<f32> {
    const BLOCK: usize = 32;
    assert!(x.len() >= rows * cols, "transpose: matrix too short");
    let mut out = vec![0.0; rows * cols];
    for r0 in (0..rows).step_by(BLOCK) {
        for c0 in (0..cols).step_by(BLOCK) {
            for r in r0..(r0 + BLOCK).min(rows) {
                for c in c0..(c0 + BLOCK).min(cols) {
                    out[c * rows + r] = x[r * cols + c];
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_value_lands_at_its_mirrored_place_whatever_the_blocks() {
        for (rows, cols) in [(0, 3), (1, 1), (5, 70), (33, 31), (64, 96), (100, 3)] {
            let x: Vec<f32> = (0..rows * cols).map(|i| i as f32).collect();
            let t = transpose(&x, rows, cols);
            for r in 0..rows {
                for c in 0..cols {
                    assert_eq!(t[c * rows + r], x[r * cols + c], "{rows}x{cols} at {r},{c}");
                }
            }
            assert_eq!(transpose(&t, cols, rows), x);
        }
    }
}
