//! Backward passes of the CPU reference layers: the dense layer (with its concatenation-by-slices and per-group
//! term), ReLU and max-pool.
//!
//! Weights are in the PyTorch layout `[out, in]` (as stored in `Weights`); gradients use the same layout and
//! are *accumulated* into the buffers the caller passes, so several uses of a layer (or several samples) can
//! share one gradient buffer.

use crate::cpu::dense_grad_bf16::{PackedOutputGrad, dense_input_grad_bf16, dense_weight_grad_bf16};
use crate::cpu::dense_input_grad::dense_input_grad;
use crate::cpu::dense_weight_grad::{SliceShape, bias_grad, dense_weight_grad};
use crate::cpu::gemm::{BF16_MIN_IN_DIM, Precision};
use crate::cpu::gemm_bf16::Bf16Unit;
use crate::cpu::group_row_sums::group_row_sums;
pub use crate::cpu::max_pool_backward::{max_pool_backward, max_pool_backward_acc};
pub use crate::cpu::relu_backward::relu_backward;

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

/// Backward of one dense layer
/// `out[r] = act(b + W_g · g[r / rows_per_group] + sum_s W_s · x_s[r])` over `rows` rows, in f32: exactly
/// [`dense_backward_at`] with [`Precision::F32`].
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
    let inputs = LayerInputs { rows, rows_per_group, group, segments };
    dense_backward_at(Precision::F32, layer, &inputs, out, d_out, grads);
}

/// What a dense layer multiplied: `rows` rows of per-row `segments` and, optionally, a per-group input shared
/// by each `rows_per_group` rows.
#[derive(Clone, Copy, Debug)]
pub struct LayerInputs<'a, 's> {
    /// Rows of the per-row inputs (and of the output).
    pub rows: usize,
    /// Rows that share one row of the per-group input.
    pub rows_per_group: usize,
    /// The per-group input (`rows / rows_per_group x width`) with its weight columns, or `None`.
    pub group: Option<Segment<'a>>,
    /// The per-row inputs.
    pub segments: &'s [Segment<'a>],
}

/// Whether a layer's backward multiplies run in bf16 at `precision`: bf16 asked for and available, and the
/// layer at least [`BF16_MIN_IN_DIM`] wide in and out with at least that many rows (the narrow first and last
/// layers, RelativeNet's one row per pair and the per-patch terms stay f32).
pub fn bf16_backward(precision: Precision, layer: &DenseLayer<'_>, rows: usize) -> bool {
    precision == Precision::Bf16
        && Precision::Bf16.is_available()
        && [layer.in_dim, layer.out_dim, rows].iter().all(|&d| d >= BF16_MIN_IN_DIM)
}

/// [`dense_backward`] at `precision`: in bf16 ([`bf16_backward`]) the per-row slices' weight and input
/// gradients are bf16 products summed in f32 (`crate::cpu::dense_grad_bf16`, on AMX tiles where the CPU has
/// them, the output gradient packed once for every slice); the bias, the ReLU mask and the per-group slice stay
/// f32.
pub fn dense_backward_at(
    precision: Precision,
    layer: &DenseLayer<'_>,
    inputs: &LayerInputs<'_, '_>,
    out: &[f32],
    d_out: &[f32],
    grads: &mut DenseGrads<'_>,
) {
    let LayerInputs { rows, rows_per_group, group, segments } = *inputs;
    let (n_in, n_out) = (layer.in_dim, layer.out_dim);
    debug_assert_eq!(out.len(), rows * n_out);
    debug_assert_eq!(d_out.len(), rows * n_out);
    let dz = if layer.relu { relu_backward(out, d_out) } else { d_out.to_vec() };
    let shape =
        |rows: usize, width: usize, offset: usize| SliceShape { rows, out_dim: n_out, in_dim: n_in, width, offset };
    let packed = bf16_backward(precision, layer, rows).then(|| PackedOutputGrad::new(&dz, rows, n_out));
    bias_grad(rows, n_out, &dz, grads.bias);
    for (s, seg) in segments.iter().enumerate() {
        let slice = shape(rows, seg.width, seg.offset);
        let dx = grads.segments.get_mut(s).and_then(Option::as_deref_mut);
        match &packed {
            Some(p) => {
                dense_weight_grad_bf16(Bf16Unit::Tiles, &slice, p, seg.x, grads.weight);
                if let Some(dx) = dx {
                    dense_input_grad_bf16(Bf16Unit::Tiles, &slice, p, layer.weight, dx);
                }
            }
            None => {
                dense_weight_grad(&slice, &dz, seg.x, grads.weight, None);
                if let Some(dx) = dx {
                    dense_input_grad(&slice, &dz, layer.weight, dx);
                }
            }
        }
    }
    if let Some(g) = group {
        // The group term's input is shared by the group's rows: sum their output gradients first.
        let rpg = rows_per_group.max(1);
        let sums = group_row_sums(&dz, rpg, n_out);
        let slice = shape(rows / rpg, g.width, g.offset);
        dense_weight_grad(&slice, &sums, g.x, grads.weight, None);
        if let Some(dg) = grads.group.as_deref_mut() {
            dense_input_grad(&slice, &sums, layer.weight, dg);
        }
    }
}
