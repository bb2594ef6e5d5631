//! CPU twin of `shaders/dense_weight_grad.wgsl`, and what the trainer runs: the weight (and bias) gradient of
//! one input slice of a dense layer.
//!
//! A dense layer computes `out[r] = act(b + sum_s W[:, off_s..off_s + w_s] · x_s[r / rows_per_group_s])`: each
//! slice `x_s` is a per-row input (`rows_per_group = 1`) or a per-group one shared by `rows_per_group`
//! consecutive rows (the broadcast global feature, the codeword of the folding decoder). Given `dz`, the gradient
//! w.r.t. the layer's pre-activation (`rows x out_dim`, ReLU's mask already applied), the slice's weight
//! columns get `dW[o, off + c] += sum_g dz_g[g, o] x[g, c]`, where `dz_g` sums `dz` over each group's rows
//! ([`group_row_sums`]; `dz` itself for a per-row slice). Every element is its starting value plus the products
//! added one by one in increasing `g` ([`crate::cpu::gemm`]'s order), as the shader adds them.

use crate::cpu::gemm::gemm_acc_at;

/// One input slice of a dense layer, as its backward kernels see it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SliceShape {
    /// Output rows of the layer.
    pub rows: usize,
    /// Consecutive output rows sharing one row of the slice: 1 for a per-row input.
    pub rows_per_group: usize,
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
    /// Rows of the slice: `rows / rows_per_group` (`rows` for a per-row slice).
    pub fn groups(&self) -> usize {
        self.rows / self.rows_per_group.max(1)
    }

    /// Whether the slice and the weight columns it multiplies lie inside the layer.
    pub fn is_valid(&self) -> bool {
        self.rows_per_group >= 1
            && self.rows.is_multiple_of(self.rows_per_group)
            && self.width >= 1
            && self.offset.checked_add(self.width).is_some_and(|end| end <= self.in_dim)
    }
}

/// `dz` (`rows x out_dim`) summed over each group of `rows_per_group` consecutive rows, in row order from zero:
/// `groups x out_dim`.
pub fn group_row_sums(dz: &[f32], rows_per_group: usize, out_dim: usize) -> Vec<f32> {
    let rpg = rows_per_group.max(1);
    let groups = dz.len() / out_dim.max(1) / rpg;
    let mut sums = vec![0.0f32; groups * out_dim];
    for (r, row) in dz.chunks_exact(out_dim).take(groups * rpg).enumerate() {
        for (s, &v) in sums[(r / rpg) * out_dim..][..out_dim].iter_mut().zip(row) {
            *s += v;
        }
    }
    sums
}

/// `bias[o] += sum_r dz[r, o]` over the first `rows` rows of `dz` (`rows x out_dim`), rows in order.
pub fn bias_grad(rows: usize, out_dim: usize, dz: &[f32], bias: &mut [f32]) {
    for row in dz[..rows * out_dim].chunks_exact(out_dim) {
        bias.iter_mut().zip(row).for_each(|(b, &g)| *b += g);
    }
}

/// Accumulates the slice's weight gradient into `weight_grad` (`out_dim x in_dim`, its columns
/// `offset..offset + width`) and, when given, the bias gradient `bias_grad[o] += sum_r dz[r, o]` (rows in order).
/// `x` is the slice (`groups x width`). Panics when a slice is too short for `shape`.
pub fn dense_weight_grad(
    shape: &SliceShape,
    dz: &[f32],
    x: &[f32],
    weight_grad: &mut [f32],
    bias_grad: Option<&mut [f32]>,
) {
    let (out_dim, width) = (shape.out_dim, shape.width);
    if let Some(bias) = bias_grad {
        self::bias_grad(shape.rows, out_dim, dz, bias);
    }
    let dst = &mut weight_grad[shape.offset..];
    if shape.rows_per_group <= 1 {
        gemm_acc_at(out_dim, width, shape.rows, dz, out_dim, x, width, dst, shape.in_dim);
    } else {
        let sums = group_row_sums(&dz[..shape.rows * out_dim], shape.rows_per_group, out_dim);
        gemm_acc_at(out_dim, width, shape.groups(), &sums, out_dim, x, width, dst, shape.in_dim);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cpu::dense_input_grad::dense_input_grad;
    use crate::rng::Rng;

    /// Both gradients of a per-group slice against the definition, summed in f64 row by row (no group sums).
    #[test]
    fn per_group_gradients_match_the_definition() {
        let shape = SliceShape { rows: 12, rows_per_group: 4, out_dim: 5, in_dim: 9, width: 3, offset: 2 };
        let mut rng = Rng::new(3);
        let mut normals = |n: usize| (0..n).map(|_| rng.normal() as f32).collect::<Vec<f32>>();
        let (dz, x, weight) = (normals(60), normals(9), normals(45));
        let (mut dw, mut db, mut dx) = (vec![0.0; 45], vec![0.0; 5], vec![0.0; 9]);
        dense_weight_grad(&shape, &dz, &x, &mut dw, Some(&mut db));
        dense_input_grad(&shape, &dz, &weight, &mut dx);
        for o in 0..5 {
            let want: f64 = (0..12).map(|r| dz[r * 5 + o] as f64).sum();
            assert!((db[o] as f64 - want).abs() < 1e-5, "bias {o}");
            for col in 0..9usize {
                let want: f64 = match col.checked_sub(2).filter(|&c| c < 3) {
                    Some(c) => (0..12).map(|r| dz[r * 5 + o] as f64 * x[(r / 4) * 3 + c] as f64).sum(),
                    None => 0.0,
                };
                assert!((dw[o * 9 + col] as f64 - want).abs() < 1e-5, "weight ({o}, {col})");
            }
        }
        for (i, &got) in dx.iter().enumerate() {
            let (g, c) = (i / 3, i % 3);
            let want: f64 = (g * 4..g * 4 + 4)
                .flat_map(|r| (0..5).map(move |o| (r, o)))
                .map(|(r, o)| dz[r * 5 + o] as f64 * weight[o * 9 + 2 + c] as f64)
                .sum();
            assert!((got as f64 - want).abs() < 1e-5, "input ({g}, {c})");
        }
    }
}
