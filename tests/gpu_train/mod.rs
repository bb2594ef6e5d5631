//! The training kernels (the backward passes) against their CPU twins, which are what the CPU trainer runs.
//! Part of the `gpu_parity` binary (its `main` runs [`TESTS`] too).

use super::{EPS, SENTINEL, SUM_ERROR_FACTOR, assert_close, normals, seed};
use dpr_gpu::cpu::dense_weight_grad::SliceShape;
use dpr_gpu::gpu;
use dpr_gpu::gpu::dense_input_grad::DenseInputGrad;
use dpr_gpu::gpu::dense_weight_grad::DenseWeightGrad;
use dpr_gpu::gpu::kernel::GpuKernel;
use dpr_gpu::gpu::max_pool_backward::MaxPoolBackward;
use dpr_gpu::gpu::testing::gpu_or_skip as gpu;
use dpr_gpu::rng::Rng;

/// The training kernels' parity tests, run by `gpu_parity`'s `main`.
pub const TESTS: &[(&str, fn())] = &[
    (
        "max_pool_backward_matches_cpu_with_ties_and_accumulation",
        max_pool_backward_matches_cpu_with_ties_and_accumulation,
    ),
    ("dense_weight_grad_matches_cpu_per_row_and_per_group", dense_weight_grad_matches_cpu_per_row_and_per_group),
    ("dense_input_grad_matches_cpu_per_row_and_per_group", dense_input_grad_matches_cpu_per_row_and_per_group),
];

/// Slices of a layer: per-row inputs of several widths and offsets (a full layer, the skip concatenation's
/// second part, ragged sizes past a workgroup) and per-group inputs (the broadcast global feature, a codeword
/// shared by a folding grid).
const SLICES: &[SliceShape] = &[
    SliceShape { rows: 1, rows_per_group: 1, out_dim: 1, in_dim: 1, width: 1, offset: 0 },
    SliceShape { rows: 37, rows_per_group: 1, out_dim: 67, in_dim: 5, width: 5, offset: 0 },
    SliceShape { rows: 200, rows_per_group: 1, out_dim: 33, in_dim: 100, width: 36, offset: 64 },
    SliceShape { rows: 96, rows_per_group: 32, out_dim: 20, in_dim: 70, width: 64, offset: 3 },
    SliceShape { rows: 45, rows_per_group: 45, out_dim: 9, in_dim: 130, width: 129, offset: 1 },
];

/// The elements of `dz` (`rows x out_dim`) summed over each slice row's group, as absolute values: with the
/// slice's magnitudes they bound each gradient element's terms.
fn abs_group_sums(shape: &SliceShape, dz: &[f32]) -> Vec<f32> {
    let abs: Vec<f32> = dz.iter().map(|v| v.abs()).collect();
    dpr_gpu::cpu::dense_weight_grad::group_row_sums(&abs, shape.rows_per_group, shape.out_dim)
}

/// Both sides add the same terms in the same order, but a GPU may contract products and sums into FMAs: allow
/// the sequential-sum bound `n * eps * (|start| + sum |terms|)` for each side, `n` the terms (group sums
/// included) plus 2.
fn sum_tolerance(terms: usize, start: f32, abs_terms: f32) -> f32 {
    SUM_ERROR_FACTOR * (terms + 2) as f32 * EPS * (start.abs() + abs_terms)
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

fn dense_weight_grad_matches_cpu_per_row_and_per_group() {
    let Some(g) = gpu() else { return };
    let s = seed(142);
    let mut rng = Rng::new(s);
    for shape in SLICES {
        let dz = normals(&mut rng, shape.rows * shape.out_dim);
        let x = normals(&mut rng, shape.groups() * shape.width);
        let (w_start, b_start) = (normals(&mut rng, shape.out_dim * shape.in_dim), normals(&mut rng, shape.out_dim));
        for bias in [true, false] {
            let (mut want_w, mut want_b) = (w_start.clone(), b_start.clone());
            DenseWeightGrad::CPU_TWIN(shape, &dz, &x, &mut want_w, bias.then_some(&mut want_b[..]));
            let (mut got_w, mut got_b) = (w_start.clone(), vec![SENTINEL; shape.out_dim]);
            if bias {
                got_b.copy_from_slice(&b_start);
            }
            gpu::dense_weight_grad::run(&g, shape, &dz, &x, &mut got_w, bias.then_some(&mut got_b[..])).unwrap();
            let sums = abs_group_sums(shape, &dz);
            let tol_w = |i: usize| {
                let (o, col) = (i / shape.in_dim, i % shape.in_dim);
                let Some(c) = col.checked_sub(shape.offset).filter(|&c| c < shape.width) else { return 0.0 };
                let terms: f32 =
                    (0..shape.groups()).map(|r| sums[r * shape.out_dim + o] * x[r * shape.width + c].abs()).sum();
                sum_tolerance(shape.rows, w_start[i], terms)
            };
            assert_close(&format!("dense_weight_grad weights {shape:?}"), s, &got_w, &want_w, tol_w);
            // Columns outside the slice are left as they were.
            let outside =
                (0..want_w.len()).filter(|i| !(shape.offset..shape.offset + shape.width).contains(&(i % shape.in_dim)));
            assert!(
                outside.into_iter().all(|i| got_w[i] == w_start[i]),
                "dense_weight_grad wrote outside its slice {shape:?}"
            );
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

fn dense_input_grad_matches_cpu_per_row_and_per_group() {
    let Some(g) = gpu() else { return };
    let s = seed(143);
    let mut rng = Rng::new(s);
    for shape in SLICES {
        let dz = normals(&mut rng, shape.rows * shape.out_dim);
        let weight = normals(&mut rng, shape.out_dim * shape.in_dim);
        let start = normals(&mut rng, shape.groups() * shape.width);
        let mut want = start.clone();
        DenseInputGrad::CPU_TWIN(shape, &dz, &weight, &mut want);
        let mut got = start.clone();
        gpu::dense_input_grad::run(&g, shape, &dz, &weight, &mut got).unwrap();
        let sums = abs_group_sums(shape, &dz);
        let tol = |i: usize| {
            let (r, c) = (i / shape.width, i % shape.width);
            let terms: f32 = (0..shape.out_dim)
                .map(|o| sums[r * shape.out_dim + o] * weight[o * shape.in_dim + shape.offset + c].abs())
                .sum();
            sum_tolerance(shape.out_dim + shape.rows_per_group, start[i], terms)
        };
        assert_close(&format!("dense_input_grad {shape:?}"), s, &got, &want, tol);
    }
}
