//! Parity cases of the training kernels (the backward passes, Adam, the Chamfer loss's kernels, the transpose)
//! against their CPU twins, which are what the CPU trainer runs.

use super::Outcome;
use super::inference::{EPS, SENTINEL, SUM_ERROR_FACTOR, assert_close, normals, seed};
use crate::cpu::adam_step::AdamStep as Step;
use crate::cpu::chamfer_grad::chamfer_grad;
use crate::cpu::chamfer_nearest::chamfer_nearest;
use crate::cpu::dense_weight_grad::SliceShape;
use crate::gpu::adam_step::AdamStep;
use crate::gpu::dense_input_grad::DenseInputGrad;
use crate::gpu::dense_weight_grad::DenseWeightGrad;
use crate::gpu::group_row_sums::GroupRowSums;
use crate::gpu::kernel::GpuKernel;
use crate::gpu::max_pool_backward::MaxPoolBackward;
use crate::gpu::relu_backward::ReluBackward;
use crate::gpu::{self, Gpu};
use crate::rng::Rng;

/// The transpose (a refreshed forward weight) against its twin, bit for bit, over ragged shapes past a
/// workgroup; every output element written (the sentinel never survives).
pub async fn transpose_matches_cpu_exactly(g: &Gpu) -> Outcome {
    let s = seed(154);
    let mut rng = Rng::new(s);
    for (rows, cols) in [(1, 1), (1, 70), (37, 67), (130, 9), (256, 4)] {
        let x = normals(&mut rng, rows * cols);
        let want = crate::cpu::transpose::transpose(&x, rows, cols);
        let mut got = vec![SENTINEL; x.len()];
        gpu::transpose::run(g, &x, rows, cols, &mut got).await.unwrap();
        assert_close(&format!("transpose {rows} x {cols}"), s, &got, &want, |_| 0.0);
    }
    Outcome::Passed
}

/// Slices of a layer: a full layer, the skip concatenation's second part, ragged sizes past a workgroup, one
/// row (the group sums of a single patch's shared input).
pub const SLICES: &[SliceShape] = &[
    SliceShape { rows: 1, out_dim: 1, in_dim: 1, width: 1, offset: 0 },
    SliceShape { rows: 37, out_dim: 67, in_dim: 5, width: 5, offset: 0 },
    SliceShape { rows: 200, out_dim: 33, in_dim: 100, width: 36, offset: 64 },
    SliceShape { rows: 1, out_dim: 20, in_dim: 70, width: 64, offset: 3 },
    SliceShape { rows: 45, out_dim: 9, in_dim: 130, width: 129, offset: 1 },
];

/// Both sides add the same terms in the same order, but a GPU may contract products and sums into FMAs: allow
/// the sequential-sum bound `n * eps * (|start| + sum |terms|)` for each side, `n` the terms plus 2.
pub fn sum_tolerance(terms: usize, start: f32, abs_terms: f32) -> f32 {
    SUM_ERROR_FACTOR * (terms + 2) as f32 * EPS * (start.abs() + abs_terms)
}

/// Positive, negative, zero and negative-zero outputs (only strictly positive ones pass the gradient), past
/// one workgroup: one comparison and a select, so the same bits.
pub async fn relu_backward_matches_cpu_at_zero_and_signed_zeros(g: &Gpu) -> Outcome {
    let s = seed(144);
    let mut rng = Rng::new(s);
    let mut out = normals(&mut rng, 1000);
    out[..4].copy_from_slice(&[0.0, -0.0, f32::MIN_POSITIVE, -f32::MIN_POSITIVE]);
    out.iter_mut().skip(4).step_by(7).for_each(|v| *v = 0.0);
    let d_out = normals(&mut rng, out.len());
    let want = ReluBackward::CPU_TWIN(&out, &d_out);
    let mut got = vec![SENTINEL; out.len()];
    gpu::relu_backward::run(g, &out, &d_out, &mut got).await.unwrap();
    assert_close("relu_backward", s, &got, &want, |_| 0.0);
    Outcome::Passed
}

/// Groups of one row, of many rows, and wide rows past a workgroup. Each sum adds its rows in order from zero on
/// both sides, with no products to contract: the same bits.
pub async fn group_row_sums_matches_cpu_ragged(g: &Gpu) -> Outcome {
    let s = seed(145);
    let mut rng = Rng::new(s);
    for (groups, rows_per_group, width) in [(1, 1, 1), (3, 1, 70), (4, 45, 9), (2, 300, 130)] {
        let x = normals(&mut rng, groups * rows_per_group * width);
        let want = GroupRowSums::CPU_TWIN(&x, rows_per_group, width);
        let mut got = vec![SENTINEL; groups * width];
        gpu::group_row_sums::run(g, &x, rows_per_group, width, &mut got).await.unwrap();
        assert_close(&format!("group_row_sums {groups}x{rows_per_group}x{width}"), s, &got, &want, |_| 0.0);
    }
    Outcome::Passed
}

/// Ties (equal values in a channel, where the lowest row must win), a group of one row, negative inputs, and
/// a gradient added to a nonzero `dx`.
pub async fn max_pool_backward_matches_cpu_with_ties_and_accumulation(g: &Gpu) -> Outcome {
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
        gpu::max_pool_backward::run(g, &x, groups, rows, channels, &d_out, &mut got).await.unwrap();
        // One addition per element at most, in the same order: the same bits.
        assert_close(&format!("max_pool_backward {groups}x{rows}x{channels}"), s, &got, &want, |_| 0.0);
    }
    Outcome::Passed
}

/// With and without the bias gradient, added to nonzero gradients; columns outside the slice stay as they were.
pub async fn dense_weight_grad_matches_cpu_ragged(g: &Gpu) -> Outcome {
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
            gpu::dense_weight_grad::run(g, shape, &dz, &x, &mut got_w, bias.then_some(&mut got_b[..])).await.unwrap();
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
    Outcome::Passed
}

/// Added to a nonzero `dx`.
pub async fn dense_input_grad_matches_cpu_ragged(g: &Gpu) -> Outcome {
    let s = seed(143);
    let mut rng = Rng::new(s);
    for shape in SLICES {
        let dz = normals(&mut rng, shape.rows * shape.out_dim);
        let weight = normals(&mut rng, shape.out_dim * shape.in_dim);
        let start = normals(&mut rng, shape.rows * shape.width);
        let mut want = start.clone();
        DenseInputGrad::CPU_TWIN(shape, &dz, &weight, &mut want);
        let mut got = start.clone();
        gpu::dense_input_grad::run(g, shape, &dz, &weight, &mut got).await.unwrap();
        let tol = |i: usize| {
            let (r, c) = (i / shape.width, i % shape.width);
            let terms: f32 = (0..shape.out_dim)
                .map(|o| (dz[r * shape.out_dim + o] * weight[o * shape.in_dim + shape.offset + c]).abs())
                .sum();
            sum_tolerance(shape.out_dim, start[i], terms)
        };
        assert_close(&format!("dense_input_grad {shape:?}"), s, &got, &want, tol);
    }
    Outcome::Passed
}

/// AdamW on the device (f32) against its twin (f64 per element): at the first step (large bias corrections)
/// and a late one, with and without weight decay, over gradients with zeros and tiny values. Each result within
/// a few f32 roundings of its terms: 4 eps of the moments' terms, and of `x` plus 1e-5 of the step.
pub async fn adam_step_matches_cpu_within_f32_rounding(g: &Gpu) -> Outcome {
    let s = seed(150);
    let mut rng = Rng::new(s);
    let n = 1000;
    for (t, decay) in [(1, true), (1000, false), (37, true)] {
        let (beta1, beta2): (f64, f64) = (0.9, 0.999);
        let step = Step {
            lr: 3e-4,
            beta1,
            beta2,
            eps: 1e-8,
            weight_decay: 1e-2,
            c1: 1.0 - beta1.powi(t),
            c2: 1.0 - beta2.powi(t),
        };
        let value = normals(&mut rng, n);
        let mut grad = normals(&mut rng, n);
        grad[..10].fill(0.0);
        grad[10..20].iter_mut().for_each(|v| *v *= 1e-6);
        let m: Vec<f32> = normals(&mut rng, n).iter().map(|v| v * 0.1).collect();
        let v: Vec<f32> = normals(&mut rng, n).iter().map(|v| v.abs() * 0.01).collect();
        let (mut want_x, mut want_m, mut want_v) = (value.clone(), m.clone(), v.clone());
        AdamStep::CPU_TWIN(&step, decay, &mut want_x, &grad, &mut want_m, &mut want_v);
        let (mut got_x, mut got_m, mut got_v) = (value.clone(), m.clone(), v.clone());
        gpu::adam_step::run(g, &step, decay, &mut got_x, &grad, &mut got_m, &mut got_v).await.unwrap();
        let what = |part: &str| format!("adam_step t={t} decay={decay}: {part}");
        let b = |x: f64| x as f32;
        let tol_m = |i: usize| 4.0 * EPS * (b(beta1) * m[i].abs() + b(1.0 - beta1) * grad[i].abs());
        let tol_v = |i: usize| 4.0 * EPS * (b(beta2) * v[i] + b(1.0 - beta2) * grad[i] * grad[i]);
        let wd = if decay { step.weight_decay } else { 0.0 };
        let tol_x = |i: usize| {
            let adam = (want_m[i] as f64 / step.c1) / ((want_v[i] as f64 / step.c2).sqrt() + step.eps);
            let size = step.lr * (adam.abs() + (wd * value[i] as f64).abs());
            4.0 * EPS * value[i].abs() + 1e-5 * size as f32
        };
        assert_close(&what("first moment"), s, &got_m, &want_m, tol_m);
        assert_close(&what("second moment"), s, &got_v, &want_v, tol_v);
        assert_close(&what("value"), s, &got_x, &want_x, tol_x);
        assert!(got_x.iter().zip(&value).filter(|(a, b)| a != b).count() > n / 2, "{}", what("the step moved nothing"));
    }
    Outcome::Passed
}

// ----------------------------------------------------------------------------- the Chamfer loss's kernels

/// Three patch pairs of ragged sizes: plain clouds, one with far input points (so `a > b`: the gradient gathers
/// over the input points) and one with far reconstructed points (`b > a`: each reconstructed point's own nearest).
fn clouds(rng: &mut Rng, (n, m): (usize, usize), dim: usize) -> (Vec<f32>, Vec<f32>) {
    let (mut x, mut y) = (normals(rng, 3 * n * dim), normals(rng, 3 * m * dim));
    for c in 0..dim {
        x[(n + 2) * dim + c] += 40.0;
        x[(n + 5) * dim + c] -= 30.0;
        y[(2 * m + 1) * dim + c] += 50.0;
        y[(2 * m + 7) * dim + c] -= 35.0;
    }
    (x, y)
}

/// Both sets' nearest points on the device, checked against the twin: the device's choice is a nearest one (its
/// f64 distance within f32 rounding of the twin's best, so a near-tie may go either way), its distances within
/// f32 rounding of the twin's. Returns the clouds, the device's choices and their exact (f64) distances.
async fn nearest_checked(g: &crate::gpu::Gpu, s: u64, rng: &mut Rng, dim: usize) -> Clouds {
    let (n, m) = SIZES;
    let (x, y) = clouds(rng, (n, m), dim);
    let (cpu_nearest, cpu_distance) = chamfer_nearest(&x, &y, dim, (n, m));
    let (nearest, distance) = gpu::chamfer_nearest::run(g, &x, &y, dim, (n, m)).await.unwrap();
    assert_eq!(nearest.len(), cpu_nearest.len());
    let d64 = |p: usize, r: usize, k: usize| {
        let (xi, yj) = if r < n { (p * n + r, p * m + k) } else { (p * n + k, p * m + r - n) };
        let (a, b) = (&x[xi * dim..][..dim], &y[yj * dim..][..dim]);
        a.iter().zip(b).map(|(&u, &v)| (u as f64 - v as f64).powi(2)).sum::<f64>().sqrt()
    };
    let mut exact = Vec::with_capacity(nearest.len());
    for (i, (&k, &best)) in nearest.iter().zip(&cpu_distance).enumerate() {
        let (p, r) = (i / (n + m), i % (n + m));
        let set = if r < n { m } else { n };
        assert!((k as usize) < set, "chamfer_nearest dim {dim}: row {i} index {k} out of 0..{set} (seed {s})");
        let chosen = d64(p, r, k as usize);
        let slack = 8.0 * EPS as f64 * (best * best + 1.0);
        assert!(
            chosen * chosen <= best * best + slack,
            "chamfer_nearest dim {dim}: row {i} chose {k} at {chosen}, the nearest ({}) is at {best} (seed {s})",
            cpu_nearest[i]
        );
        exact.push(chosen);
    }
    let want: Vec<f32> = exact.iter().map(|&d| d as f32).collect();
    assert_close(&format!("chamfer_nearest dim {dim} distances"), s, &distance, &want, |i| {
        4.0 * EPS * (want[i] + 1e-3)
    });
    Clouds { x, y, nearest, distance, exact }
}

/// Patch sizes: ragged, past a workgroup.
const SIZES: (usize, usize) = (37, 45);

/// Clouds of [`clouds`] with the device's nearest points and their distances (f32 from the device, f64 exact).
struct Clouds {
    x: Vec<f32>,
    y: Vec<f32>,
    nearest: Vec<u32>,
    distance: Vec<f32>,
    exact: Vec<f64>,
}

/// The nearest-point search against its twin, points of 3 and 4 values ([`nearest_checked`]).
pub async fn chamfer_nearest_matches_cpu_up_to_near_ties(g: &Gpu) -> Outcome {
    let s = seed(153);
    let mut rng = Rng::new(s);
    for dim in [3, 4] {
        nearest_checked(g, s, &mut rng, dim).await;
    }
    Outcome::Passed
}

/// The device's `chamfer_grad` on the device's nearest points against the twin on those same points (f64
/// distances), for both branches of the max and points of 3 and 4 values; the losses within f32 rounding.
pub async fn chamfer_grad_matches_cpu_on_both_branches(g: &Gpu) -> Outcome {
    let s = seed(158);
    let mut rng = Rng::new(s);
    let (n, m) = SIZES;
    for dim in [3, 4] {
        let Clouds { x, y, nearest, distance, exact } = nearest_checked(g, s, &mut rng, dim).await;
        let scale = 0.3f32;
        let (want_loss, want_grad) = chamfer_grad(&x, &y, dim, (n, m), (&nearest, &exact), scale);
        let (loss, grad) =
            gpu::chamfer_grad::run(g, [&x, &y], dim, (n, m), (&nearest, &distance), scale).await.unwrap();
        // Both branches of the max occur: patch 1 gathers over its input points, patch 2 does not.
        let mean =
            |p: usize, r: std::ops::Range<usize>| exact[p * (n + m)..][r.clone()].iter().sum::<f64>() / r.len() as f64;
        assert!(mean(1, 0..n) > mean(1, n..n + m) && mean(2, 0..n) < mean(2, n..n + m), "test clouds lost a branch");
        let want_loss32: Vec<f32> = want_loss.iter().map(|&v| v as f32).collect();
        assert_close(&format!("chamfer_grad dim {dim} losses"), s, &loss, &want_loss32, |i| {
            (n + m) as f32 * EPS * want_loss32[i]
        });
        assert!(want_grad.iter().filter(|v| **v != 0.0).count() > m, "a mostly zero gradient tests little");
        // Each element sums at most n terms of magnitude scale / n (unit vectors' components, weighted).
        assert_close(&format!("chamfer_grad dim {dim} gradient"), s, &grad, &want_grad, |_| {
            (n as f32 + 4.0) * EPS * scale
        });
    }
    Outcome::Passed
}
