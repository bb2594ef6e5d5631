//! The bf16 forms of the trainer's two backward multiplies, [`crate::cpu::dense_weight_grad`] and
//! [`crate::cpu::dense_input_grad`]: the same sums with both factors rounded to bfloat16 and the products added
//! in f32 on AMX tiles or by `vdpbf16ps` ([`crate::cpu::gemm_bf16::gemm_acc_packed`] on a [`Bf16Unit`]), onto
//! the f32 gradients. Not twins of a
//! shader: the trainer runs them for its wide layers when it trains in bf16 (`train::grad::dense_backward_at`),
//! and each output is within [`crate::cpu::gemm_bf16::bf16_dense_bound`] of the f32 form (the tests below).
//!
//! A layer's output gradient `dz` is rounded and packed once for all the slices of its input
//! ([`PackedOutputGrad`]), in the two layouts the two multiplies read.

use crate::cpu::dense_weight_grad::SliceShape;
use crate::cpu::gemm_bf16::{Bf16Unit, gemm_acc_packed, pack_column_pairs, pack_row_pairs, pack_rows_of};

/// A layer's output gradient `dz` (`rows x out_dim`) as bf16 pairs, packed for both backward multiplies.
pub struct PackedOutputGrad {
    rows: usize,
    out_dim: usize,
    /// `rows x out_dim.div_ceil(2)` words: pairs along the outputs (the input gradient's left factor).
    by_row: Vec<u32>,
    /// `out_dim x rows.div_ceil(2)` words: pairs along the rows (the weight gradient's left factor, `dz^T`).
    by_column: Vec<u32>,
}

impl PackedOutputGrad {
    /// Packs `dz` (`rows x out_dim`). Panics when it is too short.
    pub fn new(dz: &[f32], rows: usize, out_dim: usize) -> PackedOutputGrad {
        PackedOutputGrad {
            rows,
            out_dim,
            by_row: pack_rows_of(dz, rows, out_dim),
            by_column: pack_column_pairs(dz, rows, out_dim, out_dim),
        }
    }
}

/// [`crate::cpu::dense_weight_grad::dense_weight_grad`] without the bias, in bf16: accumulates
/// `dW[o, offset + c] += sum_r dz[r, o] x[r, c]` into `weight_grad` (`out_dim x in_dim`). `x` is the slice
/// (`rows x width`). Panics when the CPU lacks AVX-512 BF16, or a size disagrees with `shape`.
pub fn dense_weight_grad_bf16(
    unit: Bf16Unit,
    shape: &SliceShape,
    dz: &PackedOutputGrad,
    x: &[f32],
    weight_grad: &mut [f32],
) {
    assert!(dz.rows == shape.rows && dz.out_dim == shape.out_dim, "dense_weight_grad_bf16: dz has another shape");
    let x_pairs = pack_row_pairs(x, shape.rows, shape.width, shape.width);
    let sizes = (shape.out_dim, shape.width, shape.rows.div_ceil(2));
    gemm_acc_packed(unit, sizes, &dz.by_column, &x_pairs, &mut weight_grad[shape.offset..], shape.in_dim);
}

/// [`crate::cpu::dense_input_grad::dense_input_grad`] in bf16: accumulates
/// `dx[r, c] += sum_o dz[r, o] W[o, offset + c]` into `dx` (`rows x width`), given the layer's weight
/// (`out_dim x in_dim`, PyTorch layout). Panics when the CPU lacks AVX-512 BF16, or a size disagrees with
/// `shape`.
pub fn dense_input_grad_bf16(
    unit: Bf16Unit,
    shape: &SliceShape,
    dz: &PackedOutputGrad,
    weight: &[f32],
    dx: &mut [f32],
) {
    assert!(dz.rows == shape.rows && dz.out_dim == shape.out_dim, "dense_input_grad_bf16: dz has another shape");
    let w_pairs = pack_row_pairs(&weight[shape.offset..], shape.out_dim, shape.width, shape.in_dim);
    let sizes = (shape.rows, shape.width, shape.out_dim.div_ceil(2));
    gemm_acc_packed(unit, sizes, &dz.by_row, &w_pairs, dx, shape.width);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cpu::dense_input_grad::dense_input_grad;
    use crate::cpu::dense_weight_grad::dense_weight_grad;
    use crate::cpu::gemm_bf16::{bf16_dense_bound, is_available};
    use crate::rng::Rng;

    /// Both multiplies against the f32 forms, element by element within the bf16 bound of each sum (its
    /// magnitude: the sum of `|products|` plus the starting value), on ragged sizes (odd rows and outputs,
    /// partial tiles, a slice in the middle of the weight's columns).
    #[test]
    fn both_multiplies_stay_within_the_bf16_bound_of_the_f32_forms() {
        if !is_available() {
            eprintln!("SKIPPED: this CPU has no AVX-512 BF16 (the bf16 trainer is never selected here)");
            return;
        }
        let mut rng = Rng::new(17);
        for &(rows, out_dim, in_dim, width, offset) in
            &[(64, 48, 100, 40, 30), (37, 33, 70, 70, 0), (512, 64, 64, 64, 0), (9, 5, 12, 3, 9)]
        {
            let shape = SliceShape { rows, out_dim, in_dim, width, offset };
            let mut v = |n: usize| (0..n).map(|_| rng.normal() as f32).collect::<Vec<f32>>();
            let (dz, x, weight) = (v(rows * out_dim), v(rows * width), v(out_dim * in_dim));
            let (dw0, dx0) = (v(out_dim * in_dim), v(rows * width));
            let packed = PackedOutputGrad::new(&dz, rows, out_dim);
            let (mut dw_f32, mut dx_f32) = (dw0.clone(), dx0.clone());
            dense_weight_grad(&shape, &dz, &x, &mut dw_f32, None);
            dense_input_grad(&shape, &dz, &weight, &mut dx_f32);
            for unit in [Bf16Unit::Vector, Bf16Unit::Tiles] {
                let (mut dw, mut dx) = (dw0.clone(), dx0.clone());
                dense_weight_grad_bf16(unit, &shape, &packed, &x, &mut dw);
                dense_input_grad_bf16(unit, &shape, &packed, &weight, &mut dx);
                let what = format!("{shape:?} on {:?}", unit.effective());
                check_within_bound(
                    &what,
                    (&dw, &dw_f32, &dw0),
                    |o, col| {
                        let c = col.checked_sub(offset).filter(|&c| c < width)?;
                        Some((rows, (0..rows).map(|r| f64::from((dz[r * out_dim + o] * x[r * width + c]).abs())).sum()))
                    },
                    in_dim,
                );
                check_within_bound(
                    &what,
                    (&dx, &dx_f32, &dx0),
                    |r, c| {
                        let products = (0..out_dim)
                            .map(|o| f64::from((dz[r * out_dim + o] * weight[o * in_dim + offset + c]).abs()));
                        Some((out_dim, products.sum()))
                    },
                    width,
                );
            }
        }
    }

    /// Each element of `got` (a matrix with rows of `cols`) against `want` (the f32 form, both started from
    /// `start`): within the bf16 bound of its sum, whose length and sum of `|products|` `sum(row, col)` gives
    /// (`None`: an element the multiply must leave as it was). The rounding must show somewhere (worst error
    /// over 1 % of its bound), or the bf16 path did not run.
    fn check_within_bound(
        what: &str,
        (got, want, start): (&[f32], &[f32], &[f32]),
        sum: impl Fn(usize, usize) -> Option<(usize, f64)>,
        cols: usize,
    ) {
        let mut worst = 0.0f64;
        for (i, (&g, &w)) in got.iter().zip(want).enumerate() {
            let Some((len, products)) = sum(i / cols, i % cols) else {
                assert_eq!(g, start[i], "{what}: element {i} outside the slice changed");
                continue;
            };
            let bound = bf16_dense_bound(len, f64::from(start[i].abs()) + products);
            let d = f64::from((g - w).abs());
            assert!(d <= bound, "{what}: element {i} {g} vs f32 {w} (bound {bound})");
            worst = worst.max(d / bound);
        }
        assert!(worst > 0.01, "{what}: worst error only {worst} of the bound");
    }
}
