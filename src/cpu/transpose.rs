//! CPU twin of `shaders/transpose.wgsl`: a row-major matrix transposed. Builds every layer's forward weight
//! (`in x out`) from the stored one (`out x in`, [`crate::model::linear::Linear::from_weights`]), as the device
//! trainer does after each step.

/// `x` (`rows x cols`, row-major) transposed: `cols x rows`, `out[c * rows + r] = x[r * cols + c]`.
pub fn transpose(x: &[f32], rows: usize, cols: usize) -> Vec<f32> {
    let mut out = vec![0.0; rows * cols];
    for (r, row) in x.chunks_exact(cols.max(1)).take(rows).enumerate() {
        for (c, &v) in row.iter().enumerate() {
            out[c * rows + r] = v;
        }
    }
    out
}
