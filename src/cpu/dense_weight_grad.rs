//! CPU twin of `shaders/dense_weight_grad.wgsl`, and what the trainer runs: the weight (and bias) gradient of
//! one input slice of a dense layer.
//!
//! A dense layer computes `out[r] = act(b + sum_s W[:, off_s..off_s + w_s] · x_s[r])`. Given `dz`, the gradient
//! w.r.t. the layer's pre-activation (`rows x out_dim`, ReLU's mask applied: [`crate::cpu::relu_backward`]), a
//! slice's weight columns get `dW[o, off + c] += sum_r dz[r, o] x[r, c]`. A slice shared by a group of rows
//! (the broadcast global feature) is a per-row slice of the group sums of `dz`
//! ([`crate::cpu::group_row_sums`]). Every element is its starting value plus the products added one by one in
//! increasing `r` ([`crate::cpu::gemm`]'s order), as the shader adds them.

use crate::cpu::gemm::gemm_acc_at;

/// One per-row input slice of a dense layer, as its backward kernels see it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SliceShape {
    /// Rows (of `dz` and of the slice).
    pub rows: usize,
    /// Output width of the layer.
    pub out_dim: usize,
    /// Full input width of the layer (the weight's row length).
    pub in_dim: usize,
    /// The slice's width.
    pub width: usize,
    /// First weight column the slice multiplies.
    pub offset: usize,
}

impl SliceShape {
    /// Whether the weight columns the slice multiplies lie inside the layer.
    pub fn is_valid(&self) -> bool {
        self.width >= 1 && self.offset.checked_add(self.width).is_some_and(|end| end <= self.in_dim)
    }
}

/// `bias[o] += sum_r dz[r, o]` over the first `rows` rows of `dz` (`rows x out_dim`), rows in order.
pub fn bias_grad(rows: usize, out_dim: usize, dz: &[f32], bias: &mut [f32]) {
    for row in dz[..rows * out_dim].chunks_exact(out_dim) {
        bias.iter_mut().zip(row).for_each(|(b, &g)| *b += g);
    }
}

/// Accumulates the slice's weight gradient into `weight_grad` (`out_dim x in_dim`, its columns
/// `offset..offset + width`) and, when given, the bias gradient ([`bias_grad`]). `x` is the slice
/// (`rows x width`). Panics when a slice is too short for `shape`.
pub fn dense_weight_grad(shape: &SliceShape, dz: &[f32], x: &[f32], weight_grad: &mut [f32], bias: Option<&mut [f32]>) {
    if let Some(bias) = bias {
        bias_grad(shape.rows, shape.out_dim, dz, bias);
    }
    let dst = &mut weight_grad[shape.offset..];
    gemm_acc_at(shape.out_dim, shape.width, shape.rows, dz, shape.out_dim, x, shape.width, dst, shape.in_dim);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cpu::dense_input_grad::dense_input_grad;
    use crate::rng::Rng;

    /// Both gradients of a slice against the definition, summed in f64.
    #[test]
    fn slice_gradients_match_the_definition() {
        let shape = SliceShape { rows: 12, out_dim: 5, in_dim: 9, width: 3, offset: 2 };
        let mut rng = Rng::new(3);
        let mut normals = |n: usize| (0..n).map(|_| rng.normal() as f32).collect::<Vec<f32>>();
        let (dz, x, weight) = (normals(60), normals(36), normals(45));
        let (mut dw, mut db, mut dx) = (vec![0.0; 45], vec![0.0; 5], vec![0.0; 36]);
        dense_weight_grad(&shape, &dz, &x, &mut dw, Some(&mut db));
        dense_input_grad(&shape, &dz, &weight, &mut dx);
        for o in 0..5 {
            let want: f64 = (0..12).map(|r| dz[r * 5 + o] as f64).sum();
            assert!((db[o] as f64 - want).abs() < 1e-5, "bias {o}");
            for col in 0..9usize {
                let want: f64 = match col.checked_sub(2).filter(|&c| c < 3) {
                    Some(c) => (0..12).map(|r| dz[r * 5 + o] as f64 * x[r * 3 + c] as f64).sum(),
                    None => 0.0,
                };
                assert!((dw[o * 9 + col] as f64 - want).abs() < 1e-5, "weight ({o}, {col})");
            }
        }
        for (i, &got) in dx.iter().enumerate() {
            let (r, c) = (i / 3, i % 3);
            let want: f64 = (0..5).map(|o| dz[r * 5 + o] as f64 * weight[o * 9 + 2 + c] as f64).sum();
            assert!((got as f64 - want).abs() < 1e-5, "input ({r}, {c})");
        }
    }
}
