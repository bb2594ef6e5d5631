//! CPU twin of `shaders/max_pool_backward.wgsl`, and what the trainer runs: the backward pass of
//! [`crate::cpu::max_pool::max_pool`].

/// Backward of `crate::cpu::max_pool::max_pool`: each output's gradient goes to the row that attains the
/// maximum in its group and channel, the lowest such row on ties. Returns `groups * rows_per_group x channels`.
pub fn max_pool_backward(x: &[f32], groups: usize, rows_per_group: usize, channels: usize, d_out: &[f32]) -> Vec<f32> {
    let mut dx = vec![0.0; x.len()];
    max_pool_backward_acc(x, groups, rows_per_group, channels, d_out, &mut dx);
    dx
}

/// [`max_pool_backward`], accumulating into `dx`.
pub fn max_pool_backward_acc(
    x: &[f32],
    groups: usize,
    rows_per_group: usize,
    channels: usize,
    d_out: &[f32],
    dx: &mut [f32],
) {
    if rows_per_group == 0 {
        return;
    }
    let mut best_row = vec![0usize; channels];
    let mut best_val = vec![0f32; channels];
    for g in 0..groups {
        let base = g * rows_per_group;
        best_row.fill(0);
        best_val.copy_from_slice(&x[base * channels..][..channels]);
        for r in 1..rows_per_group {
            let row = &x[(base + r) * channels..][..channels];
            for c in 0..channels {
                // Strictly greater: the lowest row keeps a tie.
                if row[c] > best_val[c] {
                    best_val[c] = row[c];
                    best_row[c] = r;
                }
            }
        }
        for (c, &r) in best_row.iter().enumerate() {
            dx[(base + r) * channels + c] += d_out[g * channels + c];
        }
    }
}
