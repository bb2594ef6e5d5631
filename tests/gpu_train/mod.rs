//! The training kernels (the backward passes) against their CPU twins, which are what the CPU trainer runs.
//! Part of the `gpu_parity` binary (its `main` runs [`TESTS`] too).

use super::{EPS, SENTINEL, SUM_ERROR_FACTOR, assert_close, normals, seed};
use dpr_gpu::cpu::dense_weight_grad::SliceShape;
use dpr_gpu::gpu;
use dpr_gpu::gpu::dense_input_grad::DenseInputGrad;
use dpr_gpu::gpu::dense_weight_grad::DenseWeightGrad;
use dpr_gpu::gpu::group_row_sums::GroupRowSums;
use dpr_gpu::gpu::kernel::GpuKernel;
use dpr_gpu::gpu::max_pool_backward::MaxPoolBackward;
use dpr_gpu::gpu::relu_backward::ReluBackward;
use dpr_gpu::gpu::testing::gpu_or_skip as gpu;
use dpr_gpu::rng::Rng;

/// The training kernels' parity tests, run by `gpu_parity`'s `main`.
pub const TESTS: &[(&str, fn())] = &[
    ("relu_backward_matches_cpu_at_zero_and_signed_zeros", relu_backward_matches_cpu_at_zero_and_signed_zeros),
    ("group_row_sums_matches_cpu_ragged", group_row_sums_matches_cpu_ragged),
    (
        "max_pool_backward_matches_cpu_with_ties_and_accumulation",
        max_pool_backward_matches_cpu_with_ties_and_accumulation,
    ),
    ("dense_weight_grad_matches_cpu_ragged", dense_weight_grad_matches_cpu_ragged),
    ("dense_input_grad_matches_cpu_ragged", dense_input_grad_matches_cpu_ragged),
];

/// Slices of a layer: a full layer, the skip concatenation's second part, ragged sizes past a workgroup, one
/// row (the group sums of a single patch's shared input).
const SLICES: &[SliceShape] = &[
    SliceShape { rows: 1, out_dim: 1, in_dim: 1, width: 1, offset: 0 },
    SliceShape { rows: 37, out_dim: 67, in_dim: 5, width: 5, offset: 0 },
    SliceShape { rows: 200, out_dim: 33, in_dim: 100, width: 36, offset: 64 },
    SliceShape { rows: 1, out_dim: 20, in_dim: 70, width: 64, offset: 3 },
    SliceShape { rows: 45, out_dim: 9, in_dim: 130, width: 129, offset: 1 },
];

/// Both sides add the same terms in the same order, but a GPU may contract products and sums into FMAs: allow
/// the sequential-sum bound `n * eps * (|start| + sum |terms|)` for each side, `n` the terms plus 2.
fn sum_tolerance(terms: usize, start: f32, abs_terms: f32) -> f32 {
    SUM_ERROR_FACTOR * (terms + 2) as f32 * EPS * (start.abs() + abs_terms)
}

/// Positive, negative, zero and negative-zero outputs (only strictly positive ones pass the gradient), past
/// one workgroup: one comparison and a select, so the same bits.
fn relu_backward_matches_cpu_at_zero_and_signed_zeros() {
    let Some(g) = gpu() else { return };
    let s = seed(144);
    let mut rng = Rng::new(s);
    let mut out = normals(&mut rng, 1000);
    out[..4].copy_from_slice(&[0.0, -0.0, f32::MIN_POSITIVE, -f32::MIN_POSITIVE]);
    out.iter_mut().skip(4).step_by(7).for_each(|v| *v = 0.0);
    let d_out = normals(&mut rng, out.len());
    let want = ReluBackward::CPU_TWIN(&out, &d_out);
    let mut got = vec![SENTINEL; out.len()];
    gpu::relu_backward::run(&g, &out, &d_out, &mut got).unwrap();
    assert_close("relu_backward", s, &got, &want, |_| 0.0);
}

/// Groups of one row, of many rows, and wide rows past a workgroup. Each sum adds its rows in order from zero on
/// both sides, with no products to contract: the same bits.
fn group_row_sums_matches_cpu_ragged() {
    let Some(g) = gpu() else { return };
    let s = seed(145);
    let mut rng = Rng::new(s);
    for (groups, rows_per_group, width) in [(1, 1, 1), (3, 1, 70), (4, 45, 9), (2, 300, 130)] {
        let x = normals(&mut rng, groups * rows_per_group * width);
        let want = GroupRowSums::CPU_TWIN(&x, rows_per_group, width);
        let mut got = vec![SENTINEL; groups * width];
        gpu::group_row_sums::run(&g, &x, rows_per_group, width, &mut got).unwrap();
        assert_close(&format!("group_row_sums {groups}x{rows_per_group}x{width}"), s, &got, &want, |_| 0.0);
    }
}

/// Ties (equal values in a channel, where the lowest row must win), a group of one row, negative inputs, and
/// a gradient added to a nonzero `dx`.
fn max_pool_backward_matches_cpu_with_ties_and_accumulation() {
    let Some(g) = gpu() else { return };
    let s = seed(141);
    let mut rng = Rng::new(s);
    for (groups, rows, channels) in [(1, 1, 1), (5, 37, 67), (3, 1, 130), (2, 300, 5)] {
        let mut x = normals(&mut rng, groups * rows * channels);
        x[..rows * channels].iter_mut().for_each(|v| *v = -v.abs() - 1.0);
        // Round to quarters so channels hold many exact ties.
        x.iter_mut().skip(rows * channels).step_by(2).for_each(|v| *v = (*v * 4.0).round() / 4.0);
        let d_out = normals(&mut rng, groups * channels);
        let start = normals(&mut rng, x.len());
        let mut want = start.clone();
        MaxPoolBackward::CPU_TWIN(&x, groups, rows, channels, &d_out, &mut want);
        let mut got = start.clone();
        gpu::max_pool_backward::run(&g, &x, groups, rows, channels, &d_out, &mut got).unwrap();
        // One addition per element at most, in the same order: the same bits.
        assert_close(&format!("max_pool_backward {groups}x{rows}x{channels}"), s, &got, &want, |_| 0.0);
    }
}

/// With and without the bias gradient, added to nonzero gradients; columns outside the slice stay as they were.
fn dense_weight_grad_matches_cpu_ragged() {
    let Some(g) = gpu() else { return };
    let s = seed(142);
    let mut rng = Rng::new(s);
    for shape in SLICES {
        let dz = normals(&mut rng, shape.rows * shape.out_dim);
        let x = normals(&mut rng, shape.rows * shape.width);
        let (w_start, b_start) = (normals(&mut rng, shape.out_dim * shape.in_dim), normals(&mut rng, shape.out_dim));
        for bias in [true, false] {
            let (mut want_w, mut want_b) = (w_start.clone(), b_start.clone());
            DenseWeightGrad::CPU_TWIN(shape, &dz, &x, &mut want_w, bias.then_some(&mut want_b[..]));
            let mut got_w = w_start.clone();
            let mut got_b = if bias { b_start.clone() } else { vec![SENTINEL; shape.out_dim] };
            gpu::dense_weight_grad::run(&g, shape, &dz, &x, &mut got_w, bias.then_some(&mut got_b[..])).unwrap();
            let tol_w = |i: usize| {
                let (o, col) = (i / shape.in_dim, i % shape.in_dim);
                let Some(c) = col.checked_sub(shape.offset).filter(|&c| c < shape.width) else { return 0.0 };
                let terms: f32 =
                    (0..shape.rows).map(|r| (dz[r * shape.out_dim + o] * x[r * shape.width + c]).abs()).sum();
                sum_tolerance(shape.rows, w_start[i], terms)
            };
            // tol_w is 0 outside the slice: those columns must keep their starting bits.
            assert_close(&format!("dense_weight_grad weights {shape:?}"), s, &got_w, &want_w, tol_w);
            if bias {
                let tol_b = |o: usize| {
                    let terms: f32 = (0..shape.rows).map(|r| dz[r * shape.out_dim + o].abs()).sum();
                    sum_tolerance(shape.rows, b_start[o], terms)
                };
                assert_close(&format!("dense_weight_grad bias {shape:?}"), s, &got_b, &want_b, tol_b);
            }
        }
    }
}

/// Added to a nonzero `dx`.
fn dense_input_grad_matches_cpu_ragged() {
    let Some(g) = gpu() else { return };
    let s = seed(143);
    let mut rng = Rng::new(s);
    for shape in SLICES {
        let dz = normals(&mut rng, shape.rows * shape.out_dim);
        let weight = normals(&mut rng, shape.out_dim * shape.in_dim);
        let start = normals(&mut rng, shape.rows * shape.width);
        let mut want = start.clone();
        DenseInputGrad::CPU_TWIN(shape, &dz, &weight, &mut want);
        let mut got = start.clone();
        gpu::dense_input_grad::run(&g, shape, &dz, &weight, &mut got).unwrap();
        let tol = |i: usize| {
            let (r, c) = (i / shape.width, i % shape.width);
            let terms: f32 = (0..shape.out_dim)
                .map(|o| (dz[r * shape.out_dim + o] * weight[o * shape.in_dim + shape.offset + c]).abs())
                .sum();
            sum_tolerance(shape.out_dim, start[i], terms)
        };
        assert_close(&format!("dense_input_grad {shape:?}"), s, &got, &want, tol);
    }
}
