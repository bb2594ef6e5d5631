//! Backward passes of the CPU reference layers: the dense layer (with its concatenation-by-slices and per-group
//! term), ReLU and max-pool.
//!
//! Weights are in the PyTorch layout `[out, in]` (as stored in `Weights`); gradients use the same layout and
//! are *accumulated* into the buffers the caller passes, so several uses of a layer (or several samples) can
//! share one gradient buffer.

use crate::cpu::gemm::{gemm_acc, gemm_acc_at};

/// One per-row input slice of a dense layer: `x` is `rows x width`, and it multiplies the weight columns
/// `offset..offset + width`.
#[derive(Clone, Copy, Debug)]
pub struct Segment<'a> {
    /// The slice's data, row-major.
    pub x: &'a [f32],
    /// Its width.
    pub width: usize,
    /// First weight column it multiplies.
    pub offset: usize,
}

/// A dense layer as the backward pass sees it.
#[derive(Clone, Copy, Debug)]
pub struct DenseLayer<'a> {
    /// Weight, `out_dim x in_dim`, row-major (PyTorch layout).
    pub weight: &'a [f32],
    /// Full input width (every segment and the group term together).
    pub in_dim: usize,
    /// Output width.
    pub out_dim: usize,
    /// Whether the layer applies ReLU to its output.
    pub relu: bool,
}

/// Where a dense backward pass writes: parameter gradients (accumulated) and, optionally, input gradients.
#[derive(Debug)]
pub struct DenseGrads<'a> {
    /// `out_dim x in_dim`, accumulated.
    pub weight: &'a mut [f32],
    /// `out_dim`, accumulated.
    pub bias: &'a mut [f32],
    /// Gradient w.r.t. the per-group input (`groups x group_width`), accumulated; `None` skips it.
    pub group: Option<&'a mut [f32]>,
    /// Gradient w.r.t. each segment (`rows x width`), accumulated; `None` entries are skipped. Must have one
    /// entry per segment (or be empty to skip them all).
    pub segments: Vec<Option<&'a mut [f32]>>,
}

/// `d_out` masked by ReLU's derivative: passes where the layer's (post-ReLU) output is positive. At exactly
/// zero the derivative is taken as 0 (the output there is clamped).
pub fn relu_backward(out: &[f32], d_out: &[f32]) -> Vec<f32> {
    out.iter().zip(d_out).map(|(&y, &g)| if y > 0.0 { g } else { 0.0 }).collect()
}

/// Backward of one dense layer
/// `out[r] = act(b + W_g · g[r / rows_per_group] + sum_s W_s · x_s[r])` over `rows` rows.
///
/// `out` is the layer's output (after the activation; used for the ReLU mask) and `d_out` the gradient of the
/// loss w.r.t. it. `group` is the per-group input (`groups x width`, `groups = rows / rows_per_group`) with the
/// weight columns it multiplies, or `None`. The gradient w.r.t. a per-group input sums over the group's rows;
/// so does the weight gradient of its columns.
#[expect(clippy::too_many_arguments, reason = "BLAS-style and layer-shaped signatures")]
pub fn dense_backward(
    layer: &DenseLayer<'_>,
    rows: usize,
    rows_per_group: usize,
    out: &[f32],
    d_out: &[f32],
    group: Option<Segment<'_>>,
    segments: &[Segment<'_>],
    grads: &mut DenseGrads<'_>,
) {
    let (n_in, n_out) = (layer.in_dim, layer.out_dim);
    debug_assert_eq!(out.len(), rows * n_out);
    debug_assert_eq!(d_out.len(), rows * n_out);
    let dz = if layer.relu { relu_backward(out, d_out) } else { d_out.to_vec() };
    for r in 0..rows {
        for (b, &g) in grads.bias.iter_mut().zip(&dz[r * n_out..][..n_out]) {
            *b += g;
        }
    }
    if !segments.is_empty() {
        for (s, seg) in segments.iter().enumerate() {
            // dW[:, off..off + w] += dz^T · x_s
            gemm_acc_at(n_out, seg.width, rows, &dz, n_out, seg.x, seg.width, &mut grads.weight[seg.offset..], n_in);
            // dx_s += dz · W[:, off..off + w]
            if let Some(Some(dx)) = grads.segments.get_mut(s) {
                gemm_acc(rows, seg.width, n_out, &dz, n_out, &layer.weight[seg.offset..], n_in, dx, seg.width);
            }
        }
    }
    if let Some(g) = group {
        let rpg = rows_per_group.max(1);
        let groups = rows / rpg;
        // The group term's input is shared by the group's rows: sum their output gradients first.
        let mut dz_sum = vec![0.0f32; groups * n_out];
        for r in 0..groups * rpg {
            let dst = &mut dz_sum[(r / rpg) * n_out..][..n_out];
            for (d, &v) in dst.iter_mut().zip(&dz[r * n_out..][..n_out]) {
                *d += v;
            }
        }
        gemm_acc_at(n_out, g.width, groups, &dz_sum, n_out, g.x, g.width, &mut grads.weight[g.offset..], n_in);
        if let Some(dg) = grads.group.as_deref_mut() {
            gemm_acc(groups, g.width, n_out, &dz_sum, n_out, &layer.weight[g.offset..], n_in, dg, g.width);
        }
    }
}

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
