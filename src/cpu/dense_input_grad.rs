//! CPU twin of `shaders/dense_input_grad.wgsl`, and what the trainer runs: the gradient w.r.t. one per-row
//! input slice of a dense layer, `dx[r, c] += sum_o dz[r, o] W[o, off + c]` (shapes as in
//! [`crate::cpu::dense_weight_grad`]). Every element is its starting value plus the products added one by one
//! in increasing `o`, as the shader adds them.

use crate::cpu::dense_weight_grad::SliceShape;
use crate::cpu::gemm::gemm_acc;

/// Accumulates into `dx` (`rows x width`) the gradient of the slice, given `dz` (`rows x out_dim`) and the
/// layer's weight (`out_dim x in_dim`, PyTorch layout). Panics when a slice is too short for `shape`.
pub fn dense_input_grad(shape: &SliceShape, dz: &[f32], weight: &[f32], dx: &mut [f32]) {
    let w = &weight[shape.offset..];
    gemm_acc(shape.rows, shape.width, shape.out_dim, dz, shape.out_dim, w, shape.in_dim, dx, shape.width);
}
