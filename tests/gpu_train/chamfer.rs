//! The reconstruction loss's kernels (`chamfer_nearest`, `chamfer_grad`) against their twins, which are what the
//! CPU trainer's `train::loss::chamfer` runs (in f64).

use crate::{EPS, assert_close, normals, seed};
use dpr_gpu::cpu::chamfer_grad::chamfer_grad;
use dpr_gpu::cpu::chamfer_nearest::chamfer_nearest;
use dpr_gpu::gpu;
use dpr_gpu::gpu::testing::gpu_or_skip as gpu;
use dpr_gpu::rng::Rng;

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
fn nearest_checked(g: &dpr_gpu::gpu::Gpu, s: u64, rng: &mut Rng, dim: usize) -> Clouds {
    let (n, m) = SIZES;
    let (x, y) = clouds(rng, (n, m), dim);
    let (cpu_nearest, cpu_distance) = chamfer_nearest(&x, &y, dim, (n, m));
    let (nearest, distance) = dpr_gpu::block_on(gpu::chamfer_nearest::run(g, &x, &y, dim, (n, m))).unwrap();
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
pub fn chamfer_nearest_matches_cpu_up_to_near_ties() {
    let Some(g) = gpu() else { return };
    let s = seed(153);
    let mut rng = Rng::new(s);
    for dim in [3, 4] {
        nearest_checked(&g, s, &mut rng, dim);
    }
}

/// The device's `chamfer_grad` on the device's nearest points against the twin on those same points (f64
/// distances), for both branches of the max and points of 3 and 4 values; the losses within f32 rounding.
pub fn chamfer_grad_matches_cpu_on_both_branches() {
    let Some(g) = gpu() else { return };
    let s = seed(158);
    let mut rng = Rng::new(s);
    let (n, m) = SIZES;
    for dim in [3, 4] {
        let Clouds { x, y, nearest, distance, exact } = nearest_checked(&g, s, &mut rng, dim);
        let scale = 0.3f32;
        let (want_loss, want_grad) = chamfer_grad(&x, &y, dim, (n, m), (&nearest, &exact), scale);
        let (loss, grad) =
            dpr_gpu::block_on(gpu::chamfer_grad::run(&g, [&x, &y], dim, (n, m), (&nearest, &distance), scale)).unwrap();
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
}
