//! CPU twin of `shaders/dense_input_grad.wgsl`, and what the trainer runs: the gradient w.r.t. one input slice
//! of a dense layer, `dx[g, c] += sum_o dz_g[g, o] W[o, off + c]` (shapes and `dz_g` as in
//! [`crate::cpu::dense_weight_grad`]). Every element is its starting value plus the products added one by one
//! in increasing `o`, as the shader adds them.

use crate::cpu::dense_weight_grad::{SliceShape, group_row_sums};
use crate::cpu::gemm::gemm_acc;

/// Accumulates into `dx` (`groups x width`) the gradient of the slice, given `dz` (`rows x out_dim`) and the
/// layer's weight (`out_dim x in_dim`, PyTorch layout). Panics when a slice is too short for `shape`.
pub fn dense_input_grad(shape: &SliceShape, dz: &[f32], weight: &[f32], dx: &mut [f32]) {
    let (out_dim, width) = (shape.out_dim, shape.width);
    let w = &weight[shape.offset..];
    if shape.rows_per_group <= 1 {
        gemm_acc(shape.rows, width, out_dim, dz, out_dim, w, shape.in_dim, dx, width);
    } else {
        let sums = group_row_sums(&dz[..shape.rows * out_dim], shape.rows_per_group, out_dim);
        gemm_acc(shape.groups(), width, out_dim, &sums, out_dim, w, shape.in_dim, dx, width);
    }
}
