//! Every WGSL kernel against its CPU twin, and the networks end to end (GPU backend vs CPU reference).
//!
//! Inputs are seeded (`DPR_SEED` overrides; the seed is in every failure message) and adversarial: sizes
//! that miss the workgroup and tile sizes, dispatches past 65,535 workgroups in one dimension, degenerate
//! geometry, heavy ties, and outputs pre-filled with a NaN / 0xDEADBEEF sentinel so an element a kernel
//! never writes fails the comparison. This binary uses `dpr_gpu::gpu::testing::run_tests` as its harness
//! (`harness = false`): without a Vulkan adapter every test is reported `SKIPPED` and counted as skipped, never
//! as passed, unless `CI=true` or `DPR_GPU_REQUIRE_ADAPTER=1` (then each fails). Every test is listed in
//! `main` at the end of the file.
//!
//! Tolerances are named constants below, each with the reason it is not zero. Kernels whose result does not
//! depend on float rounding (max_pool, mutual_knn on a given matrix, inlier counts away from the threshold)
//! must match exactly.

use dpr_gpu::BackendKind;
use dpr_gpu::backend::{Backend, CpuBackend};
use dpr_gpu::backend::{RotationInputs, StepFuture};
use dpr_gpu::cpu::dense::DenseShape;
use dpr_gpu::cpu::hypotheses::{Hypothesis, hypotheses as cpu_hypotheses};
use dpr_gpu::cpu::score_hypotheses::{HypothesisScore, squared_residual};
use dpr_gpu::cpu::{self, mutual_knn::Match};
use dpr_gpu::gpu::codeword_distance::CodewordDistance;
use dpr_gpu::gpu::dense::Dense;
use dpr_gpu::gpu::dense_coop_f16::DenseCoopF16;
use dpr_gpu::gpu::dense_fast::DenseFast;
use dpr_gpu::gpu::gemm::GemmVariant;
use dpr_gpu::gpu::hypotheses::Hypotheses;
use dpr_gpu::gpu::kernel::GpuKernel;
use dpr_gpu::gpu::max_pool::MaxPool;
use dpr_gpu::gpu::mutual_knn::MutualKnn;
use dpr_gpu::gpu::patch_features::PatchFeatures;
use dpr_gpu::gpu::registry::KERNELS;
use dpr_gpu::gpu::rotation_head::RotationHead;
use dpr_gpu::gpu::score_hypotheses::ScoreHypotheses;
use dpr_gpu::gpu::testing::{gpu_or_skip as gpu, new_gpu_or_skip};
use dpr_gpu::gpu::{self, Gpu, GpuBackend, GpuContext};
use dpr_gpu::model::config::{PoseFrame, RotationOutput};
use dpr_gpu::model::{Model, ModelConfig, Net, Weights};
use dpr_gpu::preprocess::GatheredPatches;
use dpr_gpu::rng::Rng;
use dpr_gpu::settings::MatchMode;
use std::sync::Arc;

mod common;
mod gpu_icp;
mod gpu_preprocess;
mod gpu_train;

const EPS: f32 = f32::EPSILON;

/// codeword_distance: both sides sum the same terms in the same order, but a GPU may contract
/// `a * b + c` into an FMA and so round differently at each step; the sequential-sum error bound is
/// `n * eps * sum |terms|` for each side, so allow twice that (`n` = terms + 2).
const SUM_ERROR_FACTOR: f32 = 2.0;

/// patch_features angles (in units of pi): WGSL's `atan2` and `sqrt` are not correctly rounded (the
/// spec allows thousands of ulp for atan2); 2e-5 is ~2^-15.6 of the [0, 1] range, far below feature noise.
const PPF_ANGLE_ATOL: f32 = 2e-5;

/// patch_features distances and PC coordinates: one `sqrt` / division, each a few ulp on a GPU.
const PPF_LENGTH_RTOL: f32 = 8.0 * EPS;

/// patch_features PC coordinates in a normal frame: the frame costs a `sqrt`, two divisions and a few
/// products (each a few ulp on a GPU, FMA-contractible), then a 3-term dot product; relative to the row's
/// vector length.
const PC_FRAME_RTOL: f32 = 32.0 * EPS;

/// rotation_head: normalisation (`sqrt`, division), Gram-Schmidt or quaternion products, and with normal frames
/// two 3x3 products of unit-scale matrices; each step a few ulp on a GPU, so a few tens of ulp of 1 in all.
const ROTATION_ATOL: f32 = 64.0 * EPS;

/// rotation_head with angle bins: the angle's `sin` and `cos` on a GPU need only an absolute accuracy of 2^-11
/// on [-pi, pi] (Vulkan's precision rules), so the rotation entries get that bound.
const ROTATION_BINS_ATOL: f32 = 1.0 / 2048.0;

/// hypotheses: R copied, t = p_t - R p_s (FMA-contractible); errors are a few ulp of the largest term.
const HYPOTHESIS_ULPS: f32 = 16.0;

/// score_hypotheses: the GPU sums residuals in a tree, the twin sequentially; both within
/// `n * eps * sum` of the exact sum.
const RESIDUAL_SUM_ULPS_PER_TERM: f32 = 2.0;

/// score_hypotheses: each component of a residual `q - R p - t` is three products and four sums of terms up to
/// `3 max|p| + max|t| + max|q|`; a GPU may contract them into FMAs (naga emits no `NoContraction`) and round
/// each differently, a few ulp of that magnitude, not of the (possibly far smaller) residual.
const RESIDUAL_ULPS: f64 = 8.0;

/// score_hypotheses: a residual this close (relative) to the threshold may be classified differently when
/// the GPU rounds the residual differently; the count may differ by at most the number of such pairs.
const BORDERLINE_RTOL: f64 = 1e-5;

/// End to end (encode, decode, RelativeNet): several layers of the dense tolerance compound, and max-pool
/// may pick a different (nearly equal) maximum; relative to the largest output magnitude.
const NETWORK_RTOL: f32 = 1e-4;

/// End to end with the cooperative-matrix GEMM (f16 inputs): each dense layer is then off by up to about
/// `2 * 2^-11` of its `sum |terms|` (the f16 rounding of both inputs; `cpu::dense_coop_f16`), ~1e-3 of the output
/// scale where terms do not cancel; the deepest path (encoder, head) chains about six such layers, whose errors
/// add to first order: ~6e-3, so 1e-2 of the largest output magnitude.
const NETWORK_RTOL_F16: f32 = 1e-2;

/// The end-to-end tolerance for the GEMM variant the test device runs.
/// The shared device where its GEMM is f32, else a device of its own on the `fast` (f32) GEMM.
fn f32_gemm_gpu() -> Option<Arc<Gpu>> {
    let g = gpu()?;
    if g.gemm_variant().is_f32() {
        return Some(g);
    }
    let mut own = new_gpu_or_skip()?;
    own.set_gemm_variant(GemmVariant::Fast).unwrap();
    Some(Arc::new(own))
}

fn network_rtol() -> f32 {
    match gpu() {
        Some(g) if !g.gemm_variant().is_f32() => NETWORK_RTOL_F16,
        _ => NETWORK_RTOL,
    }
}

// ---------------------------------------------------------------------------------------------- helpers

/// Sentinel every float output is pre-filled with: an element the kernel never writes stays NaN and fails.
const SENTINEL: f32 = f32::NAN;

/// Sentinel for integer outputs.
const SENTINEL_U32: u32 = 0xDEAD_BEEF;

/// The test seed: `DPR_SEED` or `default`.
fn seed(default: u64) -> u64 {
    std::env::var("DPR_SEED").ok().and_then(|s| s.parse().ok()).unwrap_or(default)
}

/// `n` standard normal floats.
fn normals(rng: &mut Rng, n: usize) -> Vec<f32> {
    (0..n).map(|_| rng.normal() as f32).collect()
}

/// `n` points uniform in [-extent, extent]^3.
fn points(rng: &mut Rng, n: usize, extent: f64) -> Vec<[f32; 3]> {
    (0..n).map(|_| [0; 3].map(|_: i32| rng.uniform(-extent, extent) as f32)).collect()
}

/// Asserts `|a - e| <= tol(i)` elementwise (NaN equals NaN; infinities must match), naming the kernel, the
/// first bad index, both values, the tolerance, the seed and how many elements are off.
fn assert_close(kernel: &str, seed: u64, actual: &[f32], expected: &[f32], tol: impl Fn(usize) -> f32) {
    assert_eq!(actual.len(), expected.len(), "{kernel}: length differs (seed {seed})");
    let bad: Vec<usize> = (0..actual.len())
        .filter(|&i| {
            let (a, e) = (actual[i], expected[i]);
            if !a.is_finite() || !e.is_finite() {
                return !(a.is_nan() && e.is_nan() || a == e);
            }
            (a - e).abs() > tol(i)
        })
        .collect();
    if let Some(&i) = bad.first() {
        panic!(
            "{kernel}: {} of {} elements differ (seed {seed}); first at {i}: gpu {} vs cpu {} (diff {:e}, tol {:e})",
            bad.len(),
            actual.len(),
            actual[i],
            expected[i],
            (actual[i] - expected[i]).abs(),
            tol(i)
        );
    }
}

/// `sum |terms|` of each dense output, the scale of its rounding error.
fn dense_scale(s: &DenseShape, x: &[f32], w: &[f32], g: &[f32], init: &[f32]) -> Vec<f32> {
    (0..s.rows * s.out_dim)
        .map(|i| {
            let (r, o) = (i / s.out_dim, i % s.out_dim);
            let mut v = if s.accumulate { init[i].abs() } else { 0.0 };
            if !g.is_empty() {
                v += g[(r / s.rows_per_group) * s.out_dim + o].abs();
            }
            v + (0..s.in_dim).map(|k| (x[r * s.in_dim + k] * w[k * s.out_dim + o]).abs()).sum::<f32>()
        })
        .collect()
}

fn unit(rng: &mut Rng) -> [f32; 3] {
    loop {
        let v = [0; 3].map(|_: i32| rng.normal() as f32);
        let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if n > 1e-3 {
            return v.map(|c| c / n);
        }
    }
}

/// A small model (ragged widths, a 5 x 7 grid) with random weights and non-zero biases, so every group
/// term and concatenation slice is exercised.
fn small_model(seed: u64) -> Model {
    random_model(small_config(), seed)
}

fn small_config() -> ModelConfig {
    ModelConfig {
        radius: 0.3,
        points_per_patch: 32,
        encoder_widths: vec![16, 24, 40],
        head_widths: vec![48, 36],
        fold_widths: vec![32, 16],
        grid: [5, 7],
        grid_extent: 0.3,
        relative_widths: vec![40, 24],
        pose_frame: PoseFrame::Normal,
        rotation_output: RotationOutput::SixD,
    }
}

/// `config` with Xavier weights and random (non-zero) biases.
fn random_model(config: ModelConfig, seed: u64) -> Model {
    let mut w = Weights::init(&config, seed).expect("valid config");
    let mut rng = Rng::new(seed ^ 0xB1A5);
    for (name, t) in w.tensors.iter_mut() {
        if name.ends_with(".bias") {
            t.iter_mut().for_each(|v| *v = (rng.normal() * 0.1) as f32);
        }
    }
    Model::from_weights(&w).expect("model")
}

fn backends(g: Arc<Gpu>, seed: u64) -> (GpuBackend, CpuBackend) {
    backends_for(g, small_model(seed))
}

fn backends_for(g: Arc<Gpu>, model: Model) -> (GpuBackend, CpuBackend) {
    let gpu = GpuBackend::with_gpu(g, model.clone()).expect("GPU backend");
    gpu.set_poison(Some(SENTINEL)).unwrap();
    (gpu, CpuBackend::new(model))
}

fn max_abs(v: &[f32]) -> f32 {
    v.iter().fold(0f32, |m, x| m.max(x.abs()))
}

fn gathered(rng: &mut Rng, patches: usize, n: usize, radius: f32) -> GatheredPatches {
    let centers = points(rng, patches, 5.0);
    let mut pts = Vec::new();
    for c in &centers {
        for _ in 0..n {
            let d = unit(rng);
            let r = rng.uniform(0.0, radius as f64) as f32;
            pts.push([c[0] + d[0] * r, c[1] + d[1] * r, c[2] + d[2] * r]);
        }
    }
    GatheredPatches {
        center_normals: (0..patches).map(|_| unit(rng)).collect(),
        normals: (0..patches * n).map(|_| unit(rng)).collect(),
        centers,
        points: pts,
    }
}

fn check_patch_features(kernel: &str, seed: u64, got: (&[f32], &[f32]), want: (&[f32], &[f32]), frame: PoseFrame) {
    assert_close(&format!("{kernel} ppf"), seed, got.0, want.0, |i| {
        if i % 4 == 3 { PPF_LENGTH_RTOL * want.0[i].abs() + 1e-30 } else { PPF_ANGLE_ATOL }
    });
    let row_len = |i: usize| want.1[i / 3 * 3..][..3].iter().map(|v| v * v).sum::<f32>().sqrt();
    assert_close(&format!("{kernel} pc ({frame:?} frame)"), seed, got.1, want.1, |i| match frame {
        PoseFrame::Fragment => PPF_LENGTH_RTOL * want.1[i].abs() + 1e-30,
        PoseFrame::Normal => PC_FRAME_RTOL * row_len(i) + 1e-30,
    });
}

/// The CPU twin of patch_features on `p`.
fn twin_patch_features(p: &GatheredPatches, n: usize, radius: f32, frame: PoseFrame) -> (Vec<f32>, Vec<f32>) {
    PatchFeatures::CPU_TWIN(&p.centers, &p.center_normals, &p.points, &p.normals, n, radius, frame)
}

/// The kernel on `p` in `frame`, outputs pre-filled with the sentinel.
fn gpu_patch_features(g: &Gpu, p: &GatheredPatches, n: usize, radius: f32, frame: PoseFrame) -> (Vec<f32>, Vec<f32>) {
    let (mut ppf, mut pc) = (vec![SENTINEL; p.points.len() * 4], vec![SENTINEL; p.points.len() * 3]);
    dpr_gpu::block_on(gpu::patch_features::run(g, p, n, radius, frame, &mut ppf, &mut pc)).unwrap();
    (ppf, pc)
}

// ----------------------------------------------------------------------------------------- patch_features

fn patch_features_matches_cpu_ragged() {
    let Some(g) = gpu() else { return };
    let s = seed(11);
    let mut rng = Rng::new(s);
    let (patches, n, radius) = (7, 37, 0.3); // 259 points: not a multiple of 64
    let mut p = gathered(&mut rng, patches, n, radius);
    // Normals on the frame's branch switch (z = +0, -0) and the poles.
    p.center_normals[..4].copy_from_slice(&[[1.0, 0.0, 0.0], [0.0, 0.6, -0.8], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]]);
    p.center_normals[4] = [0.0, 1.0, -0.0];
    for frame in [PoseFrame::Fragment, PoseFrame::Normal] {
        let (want_ppf, want_pc) = twin_patch_features(&p, n, radius, frame);
        let (ppf, pc) = gpu_patch_features(&g, &p, n, radius, frame);
        check_patch_features("patch_features", s, (&ppf, &pc), (&want_ppf, &want_pc), frame);
    }
}

fn patch_features_matches_cpu_degenerate() {
    let Some(g) = gpu() else { return };
    let s = seed(12);
    let mut rng = Rng::new(s);
    let c = [1.0e3, -2.0e3, 0.5];
    let n_c = [0.0, 0.0, 1.0];
    let up = [0.0, 0.0, 1.0];
    // (point, normal) per row; every row is a degenerate case of the angle or distance.
    let rows: Vec<([f32; 3], [f32; 3])> = vec![
        (c, up),                                          // coincident with the centre: d = 0
        (c, [0.0, 0.0, 0.0]),                             // coincident and zero normal
        ([c[0] + 0.1, c[1], c[2]], [0.0; 3]),             // zero neighbour normal
        ([c[0] + 0.1, c[1], c[2]], up),                   // normals parallel
        ([c[0] + 0.1, c[1], c[2]], [0.0, 0.0, -1.0]),     // normals antiparallel
        ([c[0], c[1], c[2] + 0.2], up),                   // d parallel to both normals
        ([c[0], c[1], c[2] - 0.2], [0.0, 0.0, -1.0]),     // d antiparallel to n_r
        ([c[0] + 0.3, c[1] - 0.3, c[2]], unit(&mut rng)), // on the radius
    ];
    let n = rows.len();
    let mut centers = vec![c, c];
    let mut center_normals = vec![n_c, [0.0; 3]]; // second patch: zero centre normal
    let mut pts: Vec<[f32; 3]> = rows.iter().map(|r| r.0).collect();
    let mut nrm: Vec<[f32; 3]> = rows.iter().map(|r| r.1).collect();
    pts.extend(pts.clone());
    nrm.extend(nrm.clone());
    centers.truncate(2);
    center_normals.truncate(2);
    let p = GatheredPatches { centers, center_normals, points: pts, normals: nrm };
    for frame in [PoseFrame::Normal, PoseFrame::Fragment] {
        let (want_ppf, want_pc) = twin_patch_features(&p, n, 0.3, frame);
        let (ppf, pc) = gpu_patch_features(&g, &p, n, 0.3, frame);
        assert!(want_ppf.iter().chain(&want_pc).all(|v| v.is_finite()), "finite features on degenerate input");
        check_patch_features("patch_features (degenerate)", s, (&ppf, &pc), (&want_ppf, &want_pc), frame);
    }
    let (want_ppf, _) = twin_patch_features(&p, n, 0.3, PoseFrame::Fragment);
    let (ppf, _) = gpu_patch_features(&g, &p, n, 0.3, PoseFrame::Fragment);
    // The zero-vector branch (atan2(0, 0) -> 0) must be taken identically: exact zeros where the twin has one
    // because a vector is exactly zero.
    for (i, (&a, &e)) in ppf.iter().zip(&want_ppf).enumerate() {
        let (row, comp) = (i / 4 % n, i % 4);
        let zero_vector = row <= 1 || (row == 2 && comp != 0) || i / 4 >= n && comp != 1;
        if zero_vector && comp < 3 {
            assert_eq!(a, e, "patch_features (degenerate): element {i} (row {row}, component {comp}) seed {s}");
        }
    }
}

// ------------------------------------------------------------------------------------------------- dense

/// One dense case: (rows, in_dim, out_dim, rows_per_group, accumulate, relu, group term, w_row_offset).
type DenseCase = (usize, usize, usize, usize, bool, bool, bool, usize);

/// Cases around the reference's 64 x 64 x 16 tiles: a single element, ragged edges, widths of the real layers,
/// and weight rows read from an offset (a slice of a concatenated input).
const DENSE_CASES: &[DenseCase] = &[
    (1, 1, 1, 1, false, false, true, 0),
    (1, 1, 1, 1, true, true, false, 3),
    (63, 3, 65, 63, false, true, true, 0),
    (65, 17, 64, 5, true, true, true, 7),
    (130, 70, 130, 13, true, false, false, 0),
    (257, 4, 3, 32, false, false, true, 2),
    (77, 129, 33, 77, true, true, true, 0),
    (128, 16, 128, 1, false, true, true, 16),
];

/// Cases around the fast kernel's 128 x 128 tiles and 8-deep double-buffered k-tiles: one k-tile, one more
/// than a k-tile, an odd number of k-tiles (the last one in the second buffer), tile edges +-1 on both axes.
const DENSE_FAST_CASES: &[DenseCase] = &[
    (127, 8, 129, 127, false, true, true, 0),
    (129, 9, 127, 43, true, false, true, 5),
    (128, 24, 128, 64, true, true, false, 0),
    (255, 33, 257, 85, false, false, true, 1),
    (3, 200, 2, 1, true, true, true, 11),
];

/// Cases around the cooperative kernel's 64 x 64 tiles, 32-deep k-tiles and 16 x 16 matrices.
const DENSE_COOP_CASES: &[DenseCase] = &[
    (15, 16, 17, 15, false, true, true, 0),
    (64, 32, 64, 8, true, false, true, 3),
    (65, 33, 63, 65, true, true, false, 0),
    (200, 100, 140, 50, false, false, true, 9),
];

/// Runs `cases` on `variant` through the recorded path (weights at `w_row_offset` of a larger weight buffer,
/// output pre-filled with the initial contents or the sentinel) and compares with `twin`, each element within
/// `tol(shape, x, w, group, init)[i]`.
fn check_dense_variant(
    g: &Gpu,
    variant: GemmVariant,
    seed: u64,
    cases: &[DenseCase],
    twin: <Dense as GpuKernel>::CpuTwin,
    tol: impl Fn(&DenseShape, &[f32], &[f32], &[f32], &[f32]) -> Vec<f32>,
) {
    use dpr_gpu::gpu::{buffer::GpuBuffer, recorder::Recorder};
    let mut rng = Rng::new(seed);
    for &(rows, in_dim, out_dim, rpg, accumulate, relu, group, offset) in cases {
        let shape = DenseShape { rows, in_dim, out_dim, rows_per_group: rpg, accumulate, relu };
        let x = normals(&mut rng, rows * in_dim);
        let w_all = normals(&mut rng, (offset + in_dim) * out_dim);
        let w = &w_all[offset * out_dim..];
        let gt = if group { normals(&mut rng, rows.div_ceil(rpg) * out_dim) } else { Vec::new() };
        // Without accumulation the initial contents must be ignored: use the sentinel.
        let init = if accumulate { normals(&mut rng, rows * out_dim) } else { vec![SENTINEL; rows * out_dim] };
        let mut want = init.clone();
        twin(&shape, &x, w, &gt, &mut want);
        let ctx = &g.context;
        let xb = GpuBuffer::from_slice(ctx, "x", &x).unwrap();
        let wb = GpuBuffer::from_slice(ctx, "w_t", &w_all).unwrap();
        let gb = GpuBuffer::from_slice(ctx, "group", if group { &gt[..] } else { &[0.0] }).unwrap();
        let ob = GpuBuffer::from_slice(ctx, "out", &init).unwrap();
        let params = gpu::dense::DenseParams::new(&shape, offset, group).unwrap();
        let mut rec = Recorder::new(g, "dense parity");
        let group_buf = group.then_some(gb.raw());
        gpu::dense::record_with(&mut rec, g, variant, &params, [xb.raw(), wb.raw()], group_buf, ob.raw()).unwrap();
        rec.read(ob.raw(), 0, (init.len() * 4) as u64);
        let got: Vec<f32> = bytemuck::pod_collect_to_vec(&dpr_gpu::block_on(rec.finish()).unwrap()[0]);
        let init_for_tol = if accumulate { init.clone() } else { vec![0.0; init.len()] };
        let tol = tol(&shape, &x, w, &gt, &init_for_tol);
        assert_close(&format!("{} {shape:?} w_row_offset {offset}", variant.kernel().name), seed, &got, &want, |i| {
            tol[i]
        });
    }
}

/// The f32 tolerance of a GEMM kernel against the twin: both sum the same `in_dim + 2` terms (start value, group
/// term, products) in the same order, but a GPU may contract `a * b + c` into an FMA and so round differently;
/// each side is within `gamma_{in_dim + 2} * sum |terms|` of the exact sum, so they differ by at most twice that.
fn f32_gemm_tolerance(s: &DenseShape, x: &[f32], w: &[f32], g: &[f32], init: &[f32]) -> Vec<f32> {
    let gamma = cpu::dense::gamma_f32(s.in_dim + 2) as f32;
    let scale = dense_scale(s, x, w, g, init);
    // `scale` is itself an f32 sum (within gamma of its exact value); MIN_POSITIVE covers an all-zero row.
    scale.iter().map(|&v| 2.0 * gamma * v * (1.0 + 2.0 * gamma) + f32::MIN_POSITIVE).collect()
}

/// The portable reference GEMM against the twin.
fn dense_matches_cpu_ragged() {
    let Some(g) = gpu() else { return };
    check_dense_variant(&g, GemmVariant::Portable, seed(21), DENSE_CASES, Dense::CPU_TWIN, f32_gemm_tolerance);
}

/// The fast portable GEMM against its twin, on its own edge cases and the reference's.
fn dense_fast_matches_cpu_ragged() {
    let Some(g) = gpu() else { return };
    if let Some(why) = GemmVariant::Fast.unavailable_reason(&g.context) {
        return dpr_gpu::gpu::testing::skip_test(format!("dense_fast cannot run on this adapter: {why}"));
    }
    let s = seed(22);
    check_dense_variant(&g, GemmVariant::Fast, s, DENSE_FAST_CASES, DenseFast::CPU_TWIN, f32_gemm_tolerance);
    check_dense_variant(&g, GemmVariant::Fast, s + 1, DENSE_CASES, DenseFast::CPU_TWIN, f32_gemm_tolerance);
}

/// The cooperative-matrix GEMM (f16 inputs, f32 accumulation) against its f16 twin, within the bound derived
/// in `cpu::dense_coop_f16` (the GPU's conversion and accumulation error plus the twin's). Runs only on an
/// adapter with a 16x16x16 f16 -> f32 cooperative matrix configuration; elsewhere it is reported SKIPPED.
fn dense_coop_f16_matches_cpu_within_the_f16_bound() {
    let Some(g) = gpu() else { return };
    if let Some(why) = GemmVariant::CoopF16.unavailable_reason(&g.context) {
        return dpr_gpu::gpu::testing::skip_test(format!("needs an adapter with cooperative matrices: {why}"));
    }
    let s = seed(23);
    let tol = cpu::dense_coop_f16::parity_tolerance;
    check_dense_variant(&g, GemmVariant::CoopF16, s, DENSE_COOP_CASES, DenseCoopF16::CPU_TWIN, tol);
    check_dense_variant(&g, GemmVariant::CoopF16, s + 1, DENSE_CASES, DenseCoopF16::CPU_TWIN, tol);
}

// ---------------------------------------------------------------------------------------------- max_pool

fn max_pool_matches_cpu_ragged() {
    let Some(g) = gpu() else { return };
    let s = seed(31);
    let mut rng = Rng::new(s);
    for (groups, rows, channels) in [(1, 1, 1), (5, 37, 67), (3, 1, 130), (2, 300, 5)] {
        // All negative in one group: the -inf start value matters.
        let mut x = normals(&mut rng, groups * rows * channels);
        x[..rows * channels].iter_mut().for_each(|v| *v = -v.abs() - 1.0);
        let want = MaxPool::CPU_TWIN(&x, groups, rows, channels);
        let mut got = vec![SENTINEL; groups * channels];
        dpr_gpu::block_on(gpu::max_pool::run(&g, &x, groups, rows, channels, &mut got)).unwrap();
        assert_close(&format!("max_pool {groups}x{rows}x{channels}"), s, &got, &want, |_| 0.0);
    }
}

fn max_pool_matches_cpu_past_65535_workgroups() {
    let Some(g) = gpu() else { return };
    let s = seed(32);
    // 65,600 x 64 outputs: 65,600 workgroups of 64, folded into a 2-D grid; one row per group keeps it cheap.
    let groups = 65_600 * gpu::max_pool::WG_SIZE as usize + 17;
    let mut rng = Rng::new(s);
    let x: Vec<f32> = (0..groups).map(|_| rng.uniform(-1.0, 1.0) as f32).collect();
    let want = MaxPool::CPU_TWIN(&x, groups, 1, 1);
    let mut got = vec![SENTINEL; groups];
    dpr_gpu::block_on(gpu::max_pool::run(&g, &x, groups, 1, 1, &mut got)).unwrap();
    assert_close("max_pool (2-D dispatch)", s, &got, &want, |_| 0.0);
}

// ------------------------------------------------------------------------------ codeword_distance + knn

fn codeword_distance_matches_cpu_ragged() {
    let Some(g) = gpu() else { return };
    let s = seed(41);
    let mut rng = Rng::new(s);
    for (ns, nt, dim) in [(1, 1, 1), (37, 53, 70), (17, 16, 33), (5, 300, 4)] {
        let a = normals(&mut rng, ns * dim);
        let b = normals(&mut rng, nt * dim);
        let want = CodewordDistance::CPU_TWIN(&a, &b, dim);
        let mut got = vec![SENTINEL; ns * nt];
        dpr_gpu::block_on(gpu::codeword_distance::run(&g, &a, &b, dim, &mut got)).unwrap();
        // All terms are non-negative, so sum |terms| is the value itself.
        let tol = |i: usize| SUM_ERROR_FACTOR * (dim + 2) as f32 * EPS * want[i] + f32::MIN_POSITIVE;
        assert_close(&format!("codeword_distance {ns}x{nt}x{dim}"), s, &got, &want, tol);
    }
}

const MODES: [MatchMode; 5] =
    [MatchMode::Closest, MatchMode::Mutual(1), MatchMode::Mutual(2), MatchMode::Mutual(3), MatchMode::Mutual(4)];

fn check_knn(g: &Gpu, s: u64, d: &[f32], ns: usize, nt: usize, what: &str) {
    for mode in MODES {
        let want = MutualKnn::CPU_TWIN(d, ns, nt, mode);
        let got = dpr_gpu::block_on(gpu::mutual_knn::run(g, d, ns, nt, mode)).unwrap();
        assert_eq!(got, want, "mutual_knn {what} {ns}x{nt} {mode:?} (seed {s})");
    }
}

fn mutual_knn_matches_cpu_random() {
    let Some(g) = gpu() else { return };
    let s = seed(42);
    let mut rng = Rng::new(s);
    for (ns, nt) in [(1, 1), (1, 5), (5, 1), (2, 3), (67, 71), (130, 3)] {
        let d: Vec<f32> = (0..ns * nt).map(|_| rng.uniform(0.0, 10.0) as f32).collect();
        check_knn(&g, s, &d, ns, nt, "random");
    }
}

fn mutual_knn_matches_cpu_with_ties() {
    let Some(g) = gpu() else { return };
    let s = seed(43);
    let mut rng = Rng::new(s);
    // Few distinct values: most comparisons are ties, broken towards the lower index on both sides.
    for (ns, nt, levels) in [(4, 4, 1), (9, 13, 2), (65, 66, 3), (3, 2, 2)] {
        let d: Vec<f32> = (0..ns * nt).map(|_| rng.below(levels) as f32).collect();
        check_knn(&g, s, &d, ns, nt, "ties");
    }
}

// ----------------------------------------------------------------------- quaternions, hypotheses, scores

fn rotation_head_matches_cpu() {
    let Some(g) = gpu() else { return };
    let s = seed(51);
    let bins = RotationOutput::AngleBins { bins: 36, candidates: 3 };
    for output in [RotationOutput::Quaternion, RotationOutput::SixD, bins] {
        let mut rng = Rng::new(s);
        let w = output.width();
        let rows = 131;
        let mut raw: Vec<f32> = (0..rows * w)
            .map(|i| {
                let scale = 10f32.powi((i / w) as i32 % 7 - 3);
                rng.normal() as f32 * scale
            })
            .collect();
        // Degenerate rows: zero, below the minimum norm (identity), just above it, one-hot, NaN (not for angle
        // bins, whose NaN ordering WGSL leaves undefined), and for 6-D a second column parallel to the first.
        let mut extra: Vec<Vec<f32>> = vec![vec![0.0; w], vec![1e-13; w], vec![2e-12; w]];
        if !matches!(output, RotationOutput::AngleBins { .. }) {
            extra.push(vec![f32::NAN; w]);
        } else {
            // Ties everywhere, and a peak on the wrap-around.
            extra.push((0..w).map(|k| (k % 3) as f32).collect());
            extra.push((0..w).map(|k| if k == 0 || k == w - 1 { 2.0 } else { 0.0 }).collect());
        }
        let mut one_hot = vec![0.0; w];
        one_hot[1] = -3.0;
        extra.push(one_hot);
        if w == 6 {
            extra.push(vec![1.0, 2.0, 3.0, 2.0, 4.0, 6.0]);
        }
        for e in &extra {
            raw.extend(e);
        }
        let n = raw.len() / w;
        let mut ns: Vec<[f32; 3]> = (0..n).map(|_| unit(&mut rng)).collect();
        let nt: Vec<[f32; 3]> = (0..n).map(|_| unit(&mut rng)).collect();
        ns[..4].copy_from_slice(&[[0.0; 3], [0.0, 0.0, -1.0], [1.0, 0.0, -0.0], [f32::NAN; 3]]);
        for frame in [PoseFrame::Fragment, PoseFrame::Normal] {
            let want = RotationHead::CPU_TWIN(&raw, output, frame, &ns, &nt);
            assert_eq!(want.len(), n * output.candidates());
            let mut got = vec![[SENTINEL; 9]; want.len()];
            dpr_gpu::block_on(gpu::rotation_head::run(&g, &raw, output, frame, [&ns, &nt], &mut got)).unwrap();
            let name = format!("rotation_head ({output:?}, {frame:?})");
            let tol = if output == bins { ROTATION_BINS_ATOL } else { ROTATION_ATOL };
            assert_close(&name, s, got.as_flattened(), want.as_flattened(), |_| tol);
        }
    }
}

/// Rotations with source and target points, one per correspondence.
type RotationProblem = (Vec<[f32; 9]>, Vec<[f32; 3]>, Vec<[f32; 3]>);

fn random_hypotheses(rng: &mut Rng, n: usize, extent: f64) -> RotationProblem {
    let q: Vec<[f32; 4]> = (0..n).map(|_| rng.unit_quaternion().map(|v| v as f32)).collect();
    let r = q.iter().map(|&q| cpu::rotation_head::quaternion_rotation(q)).collect();
    (r, points(rng, n, extent), points(rng, n, extent))
}

fn hypotheses_matches_cpu() {
    let Some(g) = gpu() else { return };
    let s = seed(52);
    let mut rng = Rng::new(s);
    let (q, ps, pt) = random_hypotheses(&mut rng, 131, 20.0);
    let want = Hypotheses::CPU_TWIN(&q, &ps, &pt);
    let sentinel = Hypothesis { rotation: [SENTINEL; 9], translation: [SENTINEL; 3] };
    let mut got = vec![sentinel; q.len()];
    dpr_gpu::block_on(gpu::hypotheses::run(&g, &q, &ps, &pt, &mut got)).unwrap();
    let flat = |h: &[Hypothesis]| h.iter().flat_map(gpu::hypotheses::to_row).collect::<Vec<f32>>();
    let scale: Vec<f32> = (0..q.len())
        .flat_map(|i| {
            let p = ps[i].iter().chain(&pt[i]).fold(1f32, |m, v| m.max(v.abs()));
            [[1.0; 9].as_slice(), [p; 3].as_slice()].concat()
        })
        .collect();
    assert_close("hypotheses", s, &flat(&got), &flat(&want), |i| HYPOTHESIS_ULPS * EPS * scale[i]);
}

/// Correspondences with about 60% inliers of a random pose, and hypotheses near that pose.
fn scoring_problem(rng: &mut Rng, hyps: usize, corr: usize) -> (Vec<Hypothesis>, Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let (q, ps, _) = random_hypotheses(rng, 1, 1.0);
    let truth = cpu_hypotheses(&q, &ps, &points(rng, 1, 2.0))[0];
    let source = points(rng, corr, 3.0);
    let target = source
        .iter()
        .map(|&p| {
            let rp = dpr_gpu::cpu::hypotheses::rotate(&truth.rotation, p);
            let noise = if rng.unit_f64() < 0.6 { 0.05 } else { 2.0 };
            [0, 1, 2].map(|a| rp[a] + truth.translation[a] + (rng.normal() * noise) as f32)
        })
        .collect();
    // Small translations of the truth, and every fifth an unrelated pose.
    let (hq, hs, ht) = random_hypotheses(rng, hyps, 0.02);
    let hypotheses = (0..hyps)
        .map(|i| {
            if i % 5 == 4 {
                return cpu_hypotheses(&[hq[i]], &[hs[i]], &[ht[i]])[0];
            }
            let mut h = truth;
            for (a, v) in h.translation.iter_mut().enumerate() {
                *v += hs[i][a] + ht[i][a];
            }
            h
        })
        .collect();
    (hypotheses, source, target)
}

/// How far another rounding of a squared residual `r2` of `h` on `(p, q)` can move it: `(r + d)^2 - r^2` for a
/// shift of `d` per component (`RESIDUAL_ULPS` of the terms' magnitude), plus the squares' own rounding.
fn residual_slack(h: &Hypothesis, p: [f32; 3], q: [f32; 3], r2: f64) -> f64 {
    let max_abs3 = |v: [f32; 3]| f64::from(v.iter().fold(0f32, |m, x| m.max(x.abs())));
    let d = RESIDUAL_ULPS * f64::from(EPS) * (3.0 * max_abs3(p) + max_abs3(h.translation) + max_abs3(q));
    2.0 * 3f64.sqrt() * r2.sqrt() * d + 3.0 * d * d + 4.0 * f64::from(EPS) * r2
}

fn check_scores(s: u64, h: &[Hypothesis], src: &[[f32; 3]], tgt: &[[f32; 3]], thr: f32, got: &[HypothesisScore]) {
    let want = ScoreHypotheses::CPU_TWIN(h, src, tgt, thr);
    assert_eq!(got.len(), want.len());
    let t2 = f64::from(thr) * f64::from(thr);
    for (i, (a, e)) in got.iter().zip(&want).enumerate() {
        let r2: Vec<f64> = src.iter().zip(tgt).map(|(&p, &q)| f64::from(squared_residual(&h[i], p, q))).collect();
        let slack: Vec<f64> =
            src.iter().zip(tgt).zip(&r2).map(|((&p, &q), &r2)| residual_slack(&h[i], p, q, r2)).collect();
        let borderline = r2.iter().zip(&slack).filter(|&(&r, &d)| (r - t2).abs() <= d + BORDERLINE_RTOL * t2).count();
        let dc = a.inliers.abs_diff(e.inliers) as usize;
        assert!(
            dc <= borderline,
            "score_hypotheses[{i}] inliers gpu {} vs cpu {} ({borderline} borderline, seed {s})",
            a.inliers,
            e.inliers
        );
        let inlier_slack: f64 = r2.iter().zip(&slack).filter(|&(&r, _)| r < t2).map(|(_, &d)| d).sum();
        let tol = RESIDUAL_SUM_ULPS_PER_TERM * (e.inliers as f32 + 2.0) * EPS * e.residual_sum
            + inlier_slack as f32
            + borderline as f32 * thr * thr;
        assert!(
            (a.residual_sum - e.residual_sum).abs() <= tol,
            "score_hypotheses[{i}] residual sum gpu {} vs cpu {} (tol {tol:e}, seed {s})",
            a.residual_sum,
            e.residual_sum
        );
    }
}

fn score_hypotheses_matches_cpu() {
    let Some(g) = gpu() else { return };
    let s = seed(53);
    let mut rng = Rng::new(s);
    for (hyps, corr) in [(1, 1), (37, 200), (5, 64), (3, 65), (70, 0)] {
        let (h, src, tgt) = scoring_problem(&mut rng, hyps, corr);
        let mut got = vec![HypothesisScore { inliers: SENTINEL_U32, residual_sum: SENTINEL }; h.len()];
        dpr_gpu::block_on(gpu::score_hypotheses::run(&g, &h, &src, &tgt, 0.1, &mut got)).unwrap();
        check_scores(s, &h, &src, &tgt, 0.1, &got);
    }
}

fn score_hypotheses_matches_cpu_past_65535_workgroups() {
    let Some(g) = gpu() else { return };
    let s = seed(54);
    let mut rng = Rng::new(s);
    // One workgroup per hypothesis: 65,600 of them need a 2-D grid; two correspondences keep it cheap.
    let (h, src, tgt) = scoring_problem(&mut rng, 65_600, 2);
    let mut got = vec![HypothesisScore { inliers: SENTINEL_U32, residual_sum: SENTINEL }; h.len()];
    dpr_gpu::block_on(gpu::score_hypotheses::run(&g, &h, &src, &tgt, 0.5, &mut got)).unwrap();
    check_scores(s, &h, &src, &tgt, 0.5, &got);
}

fn inlier_mask_matches_cpu() {
    let Some(g) = gpu() else { return };
    let s = seed(55);
    let mut rng = Rng::new(s);
    let (h, src, tgt) = scoring_problem(&mut rng, 1, 333);
    let mut mask = vec![SENTINEL_U32; src.len()];
    dpr_gpu::block_on(gpu::score_hypotheses::inlier_mask(&g, &h[0], &src, &tgt, 0.1, &mut mask)).unwrap();
    let t2 = 0.1f32 * 0.1;
    for (c, (&p, &q)) in src.iter().zip(&tgt).enumerate() {
        let r2 = squared_residual(&h[0], p, q);
        let slack = residual_slack(&h[0], p, q, f64::from(r2));
        let borderline = (f64::from(r2) - f64::from(t2)).abs() <= slack + BORDERLINE_RTOL * f64::from(t2);
        assert!(mask[c] <= 1, "inlier_mask[{c}] = {:#x} was not written (seed {s})", mask[c]);
        if !borderline {
            assert_eq!(mask[c] == 1, r2 < t2, "inlier_mask[{c}] (r2 {r2}, seed {s})");
        }
    }
}

// ---------------------------------------------------------------------------------- the backend, e2e

fn backend_patch_features_and_encode_match_cpu() {
    let Some(g) = gpu() else { return };
    let s = seed(61);
    let (gpu_b, cpu_b) = backends(g, s);
    let n = cpu_b.model().config.points_per_patch;
    let mut rng = Rng::new(s);
    let p = gathered(&mut rng, 13, n, 0.3);
    let want = dpr_gpu::block_on(cpu_b.patch_features(&p, 0.3)).unwrap();
    let got = dpr_gpu::block_on(gpu_b.patch_features(&p, 0.3)).unwrap();
    let frame = cpu_b.model().config.pose_frame;
    check_patch_features("backend patch_features", s, (&got.0, &got.1), (&want.0, &want.1), frame);
    for (net, input) in [(Net::Ppf, &want.0), (Net::Pc, &want.1)] {
        let want_cw = dpr_gpu::block_on(cpu_b.encode(net, input, 13)).unwrap();
        let got_cw = dpr_gpu::block_on(gpu_b.encode(net, input, 13)).unwrap();
        let tol = network_rtol() * max_abs(&want_cw);
        assert_close(&format!("encode {net:?}"), s, &got_cw, &want_cw, |_| tol);
    }
}

fn networks_match_cpu_at_default_widths() {
    let Some(g) = gpu() else { return };
    let s = seed(66);
    // The shipped widths (full 64-wide tiles, 704-wide concatenation, 512-wide codewords), few points.
    let config = ModelConfig { points_per_patch: 48, grid: [6, 6], ..ModelConfig::default() };
    let (gpu_b, cpu_b) = backends_for(g, random_model(config, s));
    let n = cpu_b.model().config.points_per_patch;
    let mut rng = Rng::new(s);
    let p = gathered(&mut rng, 3, n, 0.3);
    let (ppf, pc) = dpr_gpu::block_on(cpu_b.patch_features(&p, 0.3)).unwrap();
    let mut codewords = Vec::new();
    for (net, input) in [(Net::Ppf, &ppf), (Net::Pc, &pc)] {
        let want = dpr_gpu::block_on(cpu_b.encode(net, input, 3)).unwrap();
        let got = dpr_gpu::block_on(gpu_b.encode(net, input, 3)).unwrap();
        let tol = network_rtol() * max_abs(&want);
        assert_close(&format!("encode {net:?} (default widths)"), s, &got, &want, |_| tol);
        let f = if net == Net::Ppf { &cpu_b.model().ppf } else { &cpu_b.model().pc };
        let want_rec = f.decode(&want, 3);
        let got_rec = dpr_gpu::block_on(gpu_b.decode(net, &want, 3)).unwrap();
        let tol = network_rtol() * max_abs(&want_rec);
        assert_close(&format!("decode {net:?} (default widths)"), s, &got_rec, &want_rec, |_| tol);
        codewords.push(want);
    }
    let pose = dpr_gpu::model::pose_feature(&codewords[1], &codewords[0]);
    let inputs = RotationInputs {
        source: &pose,
        target: &pose,
        source_normals: &p.center_normals,
        target_normals: &p.center_normals[..3],
        rows: 3,
    };
    let want = dpr_gpu::block_on(cpu_b.predict_rotations(inputs)).unwrap();
    let got = dpr_gpu::block_on(gpu_b.predict_rotations(inputs)).unwrap();
    let tol = if cpu_b.model().config.rotation_output.candidates() > 1 {
        ROTATION_BINS_ATOL.max(network_rtol())
    } else {
        network_rtol()
    };
    assert_close("predict_rotations (default widths)", s, got.as_flattened(), want.as_flattened(), |_| tol);
}

fn encode_and_matching_match_cpu_when_chunked() {
    // A device of its own: the buffer cap is shrunk so encode and matching run in many chunks.
    let Some(g) = new_gpu_or_skip().map(Arc::new) else { return };
    let s = seed(62);
    let (gpu_b, cpu_b) = backends(Arc::clone(&g), s);
    let n = cpu_b.model().config.points_per_patch;
    let mut rng = Rng::new(s);
    let input: Vec<f32> = (0..11 * n * 4).map(|_| rng.unit_f64() as f32).collect();
    g.context.set_max_buffer_bytes(8 << 10); // one 32-point patch x 48 channels per chunk
    let want = dpr_gpu::block_on(cpu_b.encode(Net::Ppf, &input, 11)).unwrap();
    let got = dpr_gpu::block_on(gpu_b.encode(Net::Ppf, &input, 11)).unwrap();
    let tol = network_rtol() * max_abs(&want);
    assert_close("encode (chunked)", s, &got, &want, |_| tol);

    let (ns, nt, dim) = (120, 37, 16); // 55 distance rows per 8 KiB chunk: 3 chunks
    let a = normals(&mut rng, ns * dim);
    let b = normals(&mut rng, nt * dim);
    for mode in MODES {
        let want = dpr_gpu::block_on(cpu_b.match_codewords(&a, &b, dim, mode)).unwrap();
        let got = dpr_gpu::block_on(gpu_b.match_codewords(&a, &b, dim, mode)).unwrap();
        let pairs = |m: &[Match]| m.iter().map(|m| (m.source, m.target)).collect::<Vec<_>>();
        assert_eq!(pairs(&got), pairs(&want), "match_codewords (chunked) {mode:?} seed {s}");
        let (gd, wd): (Vec<f32>, Vec<f32>) =
            (got.iter().map(|m| m.distance).collect(), want.iter().map(|m| m.distance).collect());
        assert_close("match_codewords distances", s, &gd, &wd, |i| SUM_ERROR_FACTOR * (dim + 2) as f32 * EPS * wd[i]);
    }
    assert!(gpu_b.workspace_bytes().unwrap() <= 40 * (8 << 10), "workspace stays within the chunk sizes");
}

fn decode_matches_cpu() {
    let Some(g) = gpu() else { return };
    let s = seed(63);
    let (gpu_b, cpu_b) = backends(g, s);
    let model = cpu_b.model();
    let cw = model.config.codeword();
    let mut rng = Rng::new(s);
    let codewords: Vec<f32> = (0..9 * cw).map(|_| rng.unit_f64() as f32).collect();
    for (net, f) in [(Net::Ppf, &model.ppf), (Net::Pc, &model.pc)] {
        let want = f.decode(&codewords, 9);
        let got = dpr_gpu::block_on(gpu_b.decode(net, &codewords, 9)).unwrap();
        let tol = network_rtol() * max_abs(&want);
        assert_close(&format!("decode {net:?}"), s, &got, &want, |_| tol);
    }
}

fn relativenet_hypotheses_and_scores_match_cpu() {
    let Some(g) = gpu() else { return };
    let s = seed(64);
    let heads = [
        (PoseFrame::Normal, RotationOutput::AngleBins { bins: 12, candidates: 2 }),
        (PoseFrame::Normal, RotationOutput::SixD),
        (PoseFrame::Fragment, RotationOutput::Quaternion),
        (PoseFrame::Normal, RotationOutput::Quaternion),
        (PoseFrame::Fragment, RotationOutput::SixD),
    ];
    for (pose_frame, rotation_output) in heads {
        let config = ModelConfig { pose_frame, rotation_output, ..small_config() };
        let (gpu_b, cpu_b) = backends_for(Arc::clone(&g), random_model(config, s));
        relativenet_matches_cpu(s, &gpu_b, &cpu_b);
    }
}

fn relativenet_matches_cpu(s: u64, gpu_b: &GpuBackend, cpu_b: &CpuBackend) {
    let config = &cpu_b.model().config;
    let cw = config.codeword();
    let rows = 77;
    let mut rng = Rng::new(s);
    let (src, tgt) = (normals(&mut rng, rows * cw), normals(&mut rng, rows * cw));
    let ns: Vec<[f32; 3]> = (0..rows).map(|_| unit(&mut rng)).collect();
    let nt: Vec<[f32; 3]> = (0..rows).map(|_| unit(&mut rng)).collect();
    let inputs = RotationInputs { source: &src, target: &tgt, source_normals: &ns, target_normals: &nt, rows };
    let want = dpr_gpu::block_on(cpu_b.predict_rotations(inputs)).unwrap();
    let got = dpr_gpu::block_on(gpu_b.predict_rotations(inputs)).unwrap();
    let name = format!("predict_rotations ({:?}, {:?})", config.pose_frame, config.rotation_output);
    assert_eq!(want.len(), rows * config.rotation_output.candidates());
    let tol =
        if config.rotation_output.candidates() > 1 { ROTATION_BINS_ATOL.max(network_rtol()) } else { network_rtol() };
    assert_close(&name, s, got.as_flattened(), want.as_flattened(), |_| tol);
    // Wrong lengths are errors on both backends.
    let short = RotationInputs { source_normals: &ns[1..], ..inputs };
    assert!(
        dpr_gpu::block_on(cpu_b.predict_rotations(short)).is_err()
            && dpr_gpu::block_on(gpu_b.predict_rotations(short)).is_err()
    );

    let (ps, pt) = (points(&mut rng, want.len(), 2.0), points(&mut rng, want.len(), 2.0));
    let want_h = dpr_gpu::block_on(cpu_b.hypotheses(&want, &ps, &pt)).unwrap();
    let got_h = dpr_gpu::block_on(gpu_b.hypotheses(&want, &ps, &pt)).unwrap();
    let flat = |h: &[Hypothesis]| h.iter().flat_map(gpu::hypotheses::to_row).collect::<Vec<f32>>();
    assert_close("backend hypotheses", s, &flat(&got_h), &flat(&want_h), |_| HYPOTHESIS_ULPS * EPS * 4.0);
    let got_s = dpr_gpu::block_on(gpu_b.score_hypotheses(&want_h, &ps, &pt, 0.5)).unwrap();
    check_scores(s, &want_h, &ps, &pt, 0.5, &got_s);
}

fn invalid_calls_are_errors_not_panics() {
    let Some(g) = gpu() else { return };
    let (gpu_b, _) = backends(Arc::clone(&g), seed(65));
    assert!(dpr_gpu::block_on(gpu_b.match_codewords(&[0.0; 8], &[0.0; 8], 4, MatchMode::Mutual(5))).is_err());
    assert!(dpr_gpu::block_on(gpu_b.encode(Net::Ppf, &[0.0; 7], 1)).is_err());
    let shape = DenseShape { rows: 2, in_dim: 2, out_dim: 2, rows_per_group: 1, accumulate: false, relu: false };
    assert!(dpr_gpu::block_on(gpu::dense::run(&g, &shape, &[0.0; 3], &[0.0; 4], &[], &mut [0.0; 4])).is_err());
    // Larger than the buffer cap: a clear Error::Gpu naming the limit.
    let big = vec![0.0f32; (g.context.max_buffer_bytes() / 4 + 1) as usize];
    let err = dpr_gpu::block_on(gpu::max_pool::run(&g, &big, 1, big.len(), 1, &mut [0.0])).unwrap_err().to_string();
    assert!(err.contains("max_storage_buffer_binding_size"), "{err}");
}

/// End to end: `register` on a generated pair with the GPU backend (on the device's default GEMM variant:
/// `fast` on lavapipe) and with the CPU reference. With an f32 GEMM the codewords agree to `NETWORK_RTOL`, far
/// below the distance gaps mutual matching decides on, so the correspondences must be identical; RANSAC then
/// sees identical inputs, so the poses must agree to `POSE_ATOL`. With the f16 cooperative-matrix GEMM the
/// codewords agree to `NETWORK_RTOL_F16`, which can flip a near tie: most correspondences must be shared, and
/// the CPU estimator on the GPU's correspondences must give the GPU's pose (on an H200 the random weights' RANSAC
/// pose moved 150 degrees with a few flipped correspondences). RelativeNet's estimate is compared in `register_with_relativenet_matches_cpu_on_a_generated_pair`.
fn register_matches_cpu_on_a_generated_pair() {
    let Some(g) = gpu() else { return };
    register_matches_cpu_with(g, seed(70));
}

/// The same end-to-end comparison on the reference GEMM (`portable`), on a device of its own.
fn register_matches_cpu_with_the_reference_gemm() {
    let Some(mut g) = new_gpu_or_skip() else { return };
    g.set_gemm_variant(GemmVariant::Portable).unwrap();
    register_matches_cpu_with(Arc::new(g), seed(70));
}

fn register_matches_cpu_with(g: Arc<Gpu>, s: u64) {
    /// Identical correspondences and seed give the identical RANSAC sample sequence; only the printing of
    /// f64 sums could differ, so allow a hair above f64 noise.
    const POSE_ATOL: f64 = 1e-9;
    /// f16 GEMM: share of the CPU's correspondences the GPU must also find (near ties may flip).
    const F16_SHARED_FRACTION: f64 = 0.9;
    let variant = g.gemm_variant();
    let s_msg = format!("seed {s}, GEMM {variant}");
    let (gpu_b, cpu_b) = backends_for(g, small_model(s));
    // ICP off: RANSAC's poses are compared to f64 noise here; ICP runs on the device with f32 sums, compared
    // with the host's in `device_icp_converges_like_the_host` and end to end in `device_register_matches_cpu_register`.
    let settings = dpr_gpu::RegistrationSettings {
        keypoints: 120,
        estimator: dpr_gpu::Estimator::Ransac,
        icp: None,
        seed: s,
        ..Default::default()
    };
    // Normals from the "file" (the CPU path's estimates): both backends then sample and featurise the same
    // patches, so only the networks' rounding differs. Estimated normals: `device_register_matches_cpu_register`.
    let (source, target, _) = common::room_pair(s, 4_000);
    let (source, target) = (with_host_normals(&source), with_host_normals(&target));
    let on_gpu = dpr_gpu::Registrar::with_backend(&settings, Box::new(gpu_b)).unwrap();
    let on_cpu = dpr_gpu::Registrar::with_backend(&settings, Box::new(cpu_b)).unwrap();
    let (gs, gt) = (on_gpu.describe(&source, 0).unwrap(), on_gpu.describe(&target, 1).unwrap());
    let (cs, ct) = (on_cpu.describe(&source, 0).unwrap(), on_cpu.describe(&target, 1).unwrap());
    assert_eq!(gs.keypoints, cs.keypoints, "{s_msg}");
    let rtol = if variant.is_f32() { NETWORK_RTOL } else { NETWORK_RTOL_F16 };
    let (g_cw, c_cw) = (gs.read_codewords().unwrap(), cs.read_codewords().unwrap());
    let tol = rtol * max_abs(&c_cw);
    assert_close(&format!("register ppf codewords ({s_msg})"), s, &g_cw, &c_cw, |_| tol);
    let g_corr = on_gpu.correspond(&gs, &gt).unwrap();
    let c_corr = on_cpu.correspond(&cs, &ct).unwrap();
    let pairs = |c: &[dpr_gpu::Correspondence]| c.iter().map(|c| (c.source_index, c.target_index)).collect::<Vec<_>>();
    assert!(c_corr.len() >= 3, "the generated pair gives correspondences ({})", c_corr.len());
    let g_pose = on_gpu.estimate(&gs, &gt, &g_corr, dpr_gpu::Estimator::Ransac).unwrap();
    let c_pose = on_cpu.estimate(&cs, &ct, &c_corr, dpr_gpu::Estimator::Ransac).unwrap();
    if variant.is_f32() {
        assert_eq!(pairs(&g_corr), pairs(&c_corr), "correspondences, {s_msg}");
        assert!((g_pose.target_from_source - c_pose.target_from_source).abs().max() < POSE_ATOL, "{s_msg}");
        assert_eq!(g_pose.inliers, c_pose.inliers, "{s_msg}");
    } else {
        let cpu_pairs: std::collections::HashSet<_> = pairs(&c_corr).into_iter().collect();
        let shared = pairs(&g_corr).iter().filter(|p| cpu_pairs.contains(p)).count();
        assert!(
            shared as f64 >= F16_SHARED_FRACTION * c_corr.len() as f64,
            "{shared} of {} correspondences shared, {s_msg}",
            c_corr.len()
        );
        // The seeded random weights give few right correspondences, so RANSAC's pose hangs on which ones flipped;
        // on the GPU's own correspondences the CPU estimator must land where the GPU's did.
        let c_on_g = on_cpu.estimate(&cs, &ct, &g_corr, dpr_gpu::Estimator::Ransac).unwrap();
        let diff = (g_pose.target_from_source - c_on_g.target_from_source).abs().max();
        assert!(diff < POSE_ATOL, "pose on the GPU's correspondences {diff:e} from the CPU's, {s_msg}");
        assert_eq!(g_pose.inliers, c_on_g.inliers, "{s_msg}");
    }
}

/// Poison inputs: a NaN point in one patch and an infinite normal in another. Each backend must either refuse
/// the input with an error or confine the poison to those patches: every other patch's codewords are exactly
/// what a clean run gives (CPU) and match the CPU's to the network tolerance (GPU). No panic, no hang.
fn poison_inputs_stay_in_their_patches() {
    let Some(g) = gpu() else { return };
    let s = seed(80);
    let (gpu_b, cpu_b) = backends(g, s);
    let n = cpu_b.model().config.points_per_patch;
    let clean = gathered(&mut Rng::new(s), 6, n, 0.3);
    let mut poisoned = gathered(&mut Rng::new(s), 6, n, 0.3);
    poisoned.points[n + 3] = [f32::NAN, 0.0, 0.0];
    poisoned.normals[3 * n + 1] = [f32::INFINITY, 0.0, 0.0];
    poisoned.points[4 * n] = [f32::NEG_INFINITY, 1.0, 1.0];
    let (cpu_ppf, _) = dpr_gpu::block_on(cpu_b.patch_features(&clean, 0.3)).unwrap();
    let want = dpr_gpu::block_on(cpu_b.encode(Net::Ppf, &cpu_ppf, 6)).unwrap();
    let dim = want.len() / 6;
    let tol = network_rtol() * max_abs(&want);
    for (name, backend) in [("cpu", &cpu_b as &dyn Backend), ("gpu", &gpu_b as &dyn Backend)] {
        let Ok((ppf, _)) = dpr_gpu::block_on(backend.patch_features(&poisoned, 0.3)) else { continue };
        let Ok(got) = dpr_gpu::block_on(backend.encode(Net::Ppf, &ppf, 6)) else { continue };
        assert_eq!(got.len(), want.len(), "{name}, seed {s}");
        for patch in [0, 2, 5] {
            let range = patch * dim..(patch + 1) * dim;
            assert_close(
                &format!("{name} clean patch {patch} beside poison"),
                s,
                &got[range.clone()],
                &want[range],
                |_| tol,
            );
        }
    }
    // Poisoned correspondences: a NaN keypoint must not be counted as an inlier by either scorer.
    let src = vec![[0.0, 0.0, 0.0], [f32::NAN, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, f32::INFINITY, 0.0]];
    let tgt = vec![[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let hyps = [Hypothesis { rotation: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], translation: [0.0; 3] }];
    let want = dpr_gpu::block_on(cpu_b.score_hypotheses(&hyps, &src, &tgt, 0.1)).unwrap();
    assert_eq!(want[0].inliers, 2, "cpu counts only the finite pairs");
    if let Ok(got) = dpr_gpu::block_on(gpu_b.score_hypotheses(&hyps, &src, &tgt, 0.1)) {
        assert_eq!(got[0].inliers, want[0].inliers, "gpu inliers with poisoned correspondences, seed {s}");
    }
}

/// End to end with the RelativeNet estimator (the learned path that the RANSAC parity case does not cover):
/// identical correspondences (as in the RANSAC case), then each backend's RelativeNet rotations, hypotheses
/// and scoring. Rotations agree only to the network tolerance, so two hypotheses whose scores tie up to rounding
/// may be ranked differently and the winner refined on a slightly different inlier set: the poses must agree to
/// `ROTATION_DEG_TOL` / `TRANSLATION_TOL` and the inlier counts to `INLIER_SLACK`.
fn register_with_relativenet_matches_cpu_on_a_generated_pair() {
    /// A refinement on an inlier set that differs by a pair or two moves the pose by hundredths of a degree.
    const ROTATION_DEG_TOL: f64 = 0.25;
    /// Same reasoning, in cloud units (metres), for a 2 m scene.
    const TRANSLATION_TOL: f64 = 0.01;
    /// Correspondences whose residual is within rounding of the threshold may count on one side only.
    const INLIER_SLACK: usize = 2;
    let Some(g) = gpu() else { return };
    let s = seed(71);
    // The shipped (trained) weights: with random ones RelativeNet's rotations are noise, every hypothesis has
    // one inlier and the comparison would only exercise tie-breaking.
    let weights = Weights::built_in().unwrap();
    let (gpu_b, cpu_b) = backends_for(g, Model::from_weights(&weights).unwrap());
    let settings = dpr_gpu::RegistrationSettings {
        keypoints: 120,
        estimator: dpr_gpu::Estimator::RelativeNet,
        seed: s,
        ..Default::default()
    };
    // The shipped example pair (synthetic scans the weights register), with 500 keypoints to keep lavapipe quick.
    let pair = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/pair");
    let load = |name: &str| dpr_gpu::io::read_cloud(&pair.join(name), &Default::default()).unwrap().0;
    let (source, target) = (load("cloud_bin_1.ply"), load("cloud_bin_0.ply"));
    let settings = dpr_gpu::RegistrationSettings { keypoints: 500, ..settings };
    let on_gpu = dpr_gpu::Registrar::with_backend(&settings, Box::new(gpu_b)).unwrap();
    let on_cpu = dpr_gpu::Registrar::with_backend(&settings, Box::new(cpu_b)).unwrap();
    let g_res = on_gpu.register(&source, &target).unwrap();
    let c_res = on_cpu.register(&source, &target).unwrap();
    assert_eq!(g_res.correspondences, c_res.correspondences, "seed {s}");
    let (gp, cp) = (&g_res.estimate, &c_res.estimate);
    let angle = dpr_gpu::pose::rotation_error_deg(&gp.target_from_source, &cp.target_from_source);
    assert!(angle < ROTATION_DEG_TOL, "RelativeNet poses differ by {angle} degrees, seed {s}");
    let shift = dpr_gpu::pose::translation_error(&gp.target_from_source, &cp.target_from_source);
    assert!(shift < TRANSLATION_TOL, "RelativeNet translations differ by {shift}, seed {s}");
    assert!(gp.inliers.abs_diff(cp.inliers) <= INLIER_SLACK, "inliers {} vs {}, seed {s}", gp.inliers, cp.inliers);
    assert!(cp.inliers >= 10, "the CPU reference registers the pair ({} inliers), seed {s}", cp.inliers);
}

/// unit_rows: each block is its rows at unit length times the weight, in its columns of the wider rows; the
/// other columns keep the sentinel. The length's in-order sum may be FMA-contracted on a GPU (the
/// codeword_distance bound), and its `sqrt` and the division cost a few ulp each.
fn unit_rows_matches_cpu_ragged() {
    use dpr_gpu::gpu::unit_rows::{Block, UnitRows};
    let Some(g) = gpu() else { return };
    let s = seed(74);
    let mut rng = Rng::new(s);
    for (rows, width, out_width, column, weight) in
        [(1, 1, 1, 0, 1.0), (37, 13, 40, 13, 0.7), (70, 33, 99, 66, 2.5), (130, 4, 9, 0, 1.0)]
    {
        let mut input = normals(&mut rng, rows * width);
        input[..width].fill(0.0); // a zero row stays zero
        let block = Block { width, out_width, column, weight };
        let mut want = vec![SENTINEL; rows * out_width];
        UnitRows::CPU_TWIN(&input, width, weight, column, out_width, &mut want);
        let mut got = vec![SENTINEL; rows * out_width];
        dpr_gpu::block_on(gpu::unit_rows::run(&g, &input, block, &mut got)).unwrap();
        let tol = |i: usize| (SUM_ERROR_FACTOR * (width + 2) as f32 + 8.0) * EPS * want[i].abs() + f32::MIN_POSITIVE;
        assert_close(&format!("unit_rows {rows}x{width} into {out_width} at {column}"), s, &got, &want, tol);
        let written = want.iter().filter(|x| !x.is_nan()).count();
        assert_eq!(written, rows * width, "only the block's columns are written (seed {s})");
        for row in want.chunks_exact(out_width).skip(1) {
            let length = row[column..column + width].iter().map(|x| x * x).sum::<f32>().sqrt();
            assert!((length - weight).abs() < 1e-4 * weight, "rows at unit length times the weight (seed {s})");
        }
    }
    let bad = Block { width: 4, out_width: 6, column: 3, weight: 1.0 };
    assert!(dpr_gpu::block_on(gpu::unit_rows::run(&g, &[0.0; 4], bad, &mut [0.0; 6])).is_err(), "a block past the row");
}

/// pose_feature: a subtraction per value, exact on both sides; rows not named keep their contents.
fn pose_feature_matches_cpu_scattered() {
    let Some(g) = gpu() else { return };
    let s = seed(72);
    let mut rng = Rng::new(s);
    let (rows, width) = (37, 13);
    let ppf = normals(&mut rng, rows * width);
    // Rows 3, 5, ... in scrambled order.
    let mut picked: Vec<u32> = (0..rows as u32).filter(|r| r % 2 == 1).collect();
    picked.reverse();
    picked.swap(1, 7);
    let pc = normals(&mut rng, picked.len() * width);
    let mut want = vec![SENTINEL; rows * width];
    gpu::pose_feature::PoseFeature::CPU_TWIN(&pc, &ppf, &picked, width, &mut want);
    let mut got = vec![SENTINEL; rows * width];
    dpr_gpu::block_on(gpu::pose_feature::run(&g, &pc, &ppf, &picked, width, &mut got)).unwrap();
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&got), bits(&want), "pose_feature (seed {s})");
    assert!(want.iter().filter(|x| x.is_nan()).count() == (rows - picked.len()) * width, "unnamed rows untouched");
    assert!(
        dpr_gpu::block_on(gpu::pose_feature::run(&g, &pc, &ppf, &[rows as u32], width, &mut got)).is_err(),
        "row out of range"
    );
}

/// The step seam on the device: scans described on the GPU give the CPU's codewords; a CPU scan adopted by the
/// GPU backend reads back bit for bit; `verify` on matched rows gives the CPU's rotations (asked for) and the
/// same number of hypotheses, and its best hypothesis scores like the CPU's.
///
/// On an f32 GEMM (a device of its own where the default is the f16 cooperative-matrix one): what is checked
/// here is where the data lives, not the GEMM's precision (`networks_match_cpu_at_default_widths`), and f16
/// codewords move the RelativeNet rotations past the f32 tolerances used here.
fn device_steps_match_cpu_steps() {
    use dpr_gpu::backend::{MatchedRows, MatchedSide};
    let Some(g) = f32_gemm_gpu() else { return };
    let s = seed(73);
    let (gpu_b, cpu_b) = backends_for(g, small_model(s));
    let settings = dpr_gpu::RegistrationSettings { keypoints: 80, seed: s, ..Default::default() };
    let (source, target, _) = common::room_pair(s, 3_000);
    let on_gpu = dpr_gpu::Registrar::with_backend(&settings, Box::new(gpu_b)).unwrap();
    let on_cpu = dpr_gpu::Registrar::with_backend(&settings, Box::new(cpu_b)).unwrap();
    let (cs, ct) = (on_cpu.describe(&source, 0).unwrap(), on_cpu.describe(&target, 1).unwrap());
    let (gs, gt) = (on_gpu.adopt(&cs).unwrap(), on_gpu.adopt(&ct).unwrap());
    assert_eq!(gs.read_codewords().unwrap(), cs.read_codewords().unwrap(), "adopted codewords, seed {s}");
    let c_corr = on_cpu.correspond(&cs, &ct).unwrap();
    let g_corr = on_gpu.correspond(&gs, &gt).unwrap();
    let pairs = |c: &[dpr_gpu::Correspondence]| c.iter().map(|c| (c.source_index, c.target_index)).collect::<Vec<_>>();
    assert_eq!(pairs(&g_corr), pairs(&c_corr), "correspondences of adopted rows, seed {s}");
    assert!(c_corr.len() >= 3, "the pair gives correspondences ({})", c_corr.len());
    let rows = |f: fn(&dpr_gpu::Correspondence) -> u32| c_corr.iter().map(f).collect::<Vec<u32>>();
    let (sr, tr) = (rows(|c| c.source_index), rows(|c| c.target_index));
    let (sp, tp): (Vec<_>, Vec<_>) = c_corr.iter().map(|c| (c.source_point, c.target_point)).unzip();
    let ns: Vec<[f32; 3]> = sr.iter().map(|&r| cs.keypoint_normals[r as usize]).collect();
    let nt: Vec<[f32; 3]> = tr.iter().map(|&r| ct.keypoint_normals[r as usize]).collect();
    let verify = |r: &dpr_gpu::Registrar, a: &dpr_gpu::pipeline::ScanFeatures, b: &dpr_gpu::pipeline::ScanFeatures| {
        let request = MatchedRows::new(
            MatchedSide { scan: a.rows.as_ref(), rows: &sr, points: &sp, normals: &ns },
            MatchedSide { scan: b.rows.as_ref(), rows: &tr, points: &tp, normals: &nt },
            0.1,
            3,
        )
        .unwrap()
        .with_rotations();
        dpr_gpu::block_on(r.backend().verify(request)).unwrap()
    };
    let (want, got) = (verify(&on_cpu, &cs, &ct), verify(&on_gpu, &gs, &gt));
    assert_eq!(got.hypotheses, want.hypotheses, "seed {s}");
    let (wr, gr) = (want.rotations.unwrap(), got.rotations.unwrap());
    assert_close("verify rotations", s, gr.as_flattened(), wr.as_flattened(), |_| ROTATION_ATOL.max(NETWORK_RTOL));
    assert_eq!(got.best.len(), 3.min(want.hypotheses));
    let (gb, wb) = (got.best[0].score, want.best[0].score);
    assert!(gb.inliers.abs_diff(wb.inliers) <= 1, "best inliers {} vs {}, seed {s}", gb.inliers, wb.inliers);
    assert!(got.best.windows(2).all(|w| w[0].score.inliers >= w[1].score.inliers), "best first, seed {s}");
    // Pose features read back after verify: what the CPU computed.
    let (gf, wf) = (on_gpu.pose_features(&gs, &sr).unwrap(), on_cpu.pose_features(&cs, &sr).unwrap());
    assert_close("pose features", s, &gf, &wf, |_| NETWORK_RTOL * max_abs(&wf).max(1.0));
}

/// After describing, a pair's correspond + estimate on the GPU moves only small results: no codeword or pose
/// feature crosses the bus. The bound is counted from the step's inputs and outputs, independently of the
/// counters: up, the pose rows' indices, the matched normals and points (repeated per rotation candidate for the
/// hypotheses); down, the matcher's per-row lists (3 x K_MAX words per source row), a score (8 bytes) per
/// hypothesis and the kept best hypotheses (12 floats each, one per pose candidate).
fn pair_steps_read_back_only_small_results() {
    let Some(g) = gpu() else { return };
    let s = seed(74);
    let model = small_model(s);
    let config = model.config.clone();
    let backend = GpuBackend::with_gpu(Arc::clone(&g), model.clone()).unwrap();
    let settings = dpr_gpu::RegistrationSettings {
        keypoints: 80,
        estimator: dpr_gpu::Estimator::RelativeNet,
        icp: None,
        seed: s,
        ..Default::default()
    };
    // File normals: the device and host descriptions (compared below) then see the same patches.
    let (source, target, _) = common::room_pair(s, 3_000);
    let (source, target) = (with_host_normals(&source), with_host_normals(&target));
    let r = dpr_gpu::Registrar::with_backend(&settings, Box::new(backend)).unwrap();
    let (fs, ft) = (r.describe(&source, 0).unwrap(), r.describe(&target, 1).unwrap());
    let before = g.context.transfers();
    let corr = r.correspond(&fs, &ft).unwrap();
    let estimate = r.estimate(&fs, &ft, &corr, dpr_gpu::Estimator::RelativeNet).unwrap();
    let moved = g.context.transfers().since(before);
    let (c, m, cw) = (corr.len() as u64, config.rotation_output.candidates() as u64, config.codeword() as u64);
    let (ns, nt) = (fs.keypoints.len() as u64, ft.keypoints.len() as u64);
    let k_max = dpr_gpu::gpu::mutual_knn::K_MAX as u64;
    let up_bound = 4 * 2 * c + 12 * 2 * c + 12 * 2 * c * m + 12 * 2 * c;
    let down_bound = 3 * 4 * k_max * ns + 8 * c * m + 4 * 12 * settings.pose_candidates as u64;
    assert!(c >= 3 && estimate.hypotheses_scored == (c * m) as usize, "{c} correspondences, seed {s}");
    assert!(moved.host_to_device_bytes <= up_bound, "{} bytes up, bound {up_bound}", moved.host_to_device_bytes);
    assert!(moved.device_to_host_bytes <= down_bound, "{} bytes down, bound {down_bound}", moved.device_to_host_bytes);
    // What the host-vector seam moved for matching alone: both scans' codewords up.
    let codewords_up = 4 * cw * (ns + nt);
    assert!(moved.host_to_device_bytes + moved.device_to_host_bytes < codewords_up, "{moved:?} vs {codewords_up}");
    // The same pair through the stage methods only (the seam before: host vectors in and out of every stage):
    // the same correspondences and pose, more bytes.
    let old = dpr_gpu::Registrar::with_backend(
        &settings,
        Box::new(HostSteps(GpuBackend::with_gpu(Arc::clone(&g), model).unwrap())),
    )
    .unwrap();
    let (os, ot) = (old.describe(&source, 0).unwrap(), old.describe(&target, 1).unwrap());
    let before_old = g.context.transfers();
    let old_corr = old.correspond(&os, &ot).unwrap();
    let old_estimate = old.estimate(&os, &ot, &old_corr, dpr_gpu::Estimator::RelativeNet).unwrap();
    let moved_old = g.context.transfers().since(before_old);
    let pairs = |c: &[dpr_gpu::Correspondence]| c.iter().map(|c| (c.source_index, c.target_index)).collect::<Vec<_>>();
    assert_eq!(pairs(&old_corr), pairs(&corr), "seed {s}");
    assert_eq!(old_estimate.hypotheses_scored, estimate.hypotheses_scored);
    let total = |t: dpr_gpu::gpu::context::Transfers| t.host_to_device_bytes + t.device_to_host_bytes;
    assert!(total(moved) < total(moved_old), "steps {moved:?} vs stages {moved_old:?}");
    // Whole registrations (description included), for the record.
    let t0 = g.context.transfers();
    r.register(&source, &target).unwrap();
    let t1 = g.context.transfers();
    old.register(&source, &target).unwrap();
    let t2 = g.context.transfers();
    eprintln!(
        "pair after description ({c} correspondences, {ns}+{nt} rows, codeword {cw}): steps {} up / {} down, \
         stages {} up / {} down; whole registration: steps {} up / {} down, stages {} up / {} down (bytes)",
        moved.host_to_device_bytes,
        moved.device_to_host_bytes,
        moved_old.host_to_device_bytes,
        moved_old.device_to_host_bytes,
        t1.since(t0).host_to_device_bytes,
        t1.since(t0).device_to_host_bytes,
        t2.since(t1).host_to_device_bytes,
        t2.since(t1).device_to_host_bytes,
    );
}

/// A GPU backend seen only through its stage methods: the steps run on host rows, as every pair did before
/// the step seam.
struct HostSteps(GpuBackend);

impl Backend for HostSteps {
    fn name(&self) -> String {
        self.0.name()
    }
    fn model(&self) -> &Model {
        self.0.model()
    }
    fn patch_features<'a>(&'a self, p: &'a GatheredPatches, radius: f32) -> StepFuture<'a, (Vec<f32>, Vec<f32>)> {
        self.0.patch_features(p, radius)
    }
    fn encode<'a>(&'a self, net: Net, input: &'a [f32], patches: usize) -> StepFuture<'a, Vec<f32>> {
        self.0.encode(net, input, patches)
    }
    fn match_codewords<'a>(
        &'a self,
        s: &'a [f32],
        t: &'a [f32],
        dim: usize,
        mode: MatchMode,
    ) -> StepFuture<'a, Vec<Match>> {
        self.0.match_codewords(s, t, dim, mode)
    }
    fn predict_rotations<'a>(&'a self, pose: RotationInputs<'a>) -> StepFuture<'a, Vec<[f32; 9]>> {
        self.0.predict_rotations(pose)
    }
    fn hypotheses<'a>(
        &'a self,
        r: &'a [[f32; 9]],
        s: &'a [[f32; 3]],
        t: &'a [[f32; 3]],
    ) -> StepFuture<'a, Vec<Hypothesis>> {
        self.0.hypotheses(r, s, t)
    }
    fn score_hypotheses<'a>(
        &'a self,
        h: &'a [Hypothesis],
        s: &'a [[f32; 3]],
        t: &'a [[f32; 3]],
        threshold: f32,
    ) -> StepFuture<'a, Vec<HypothesisScore>> {
        self.0.score_hypotheses(h, s, t, threshold)
    }
}

/// `--backend auto` never takes a software rasteriser on its own: on a CPU-type adapter (lavapipe in CI) the
/// hardware-only policy finds nothing and names what it skipped, and the registrar falls back to the CPU and says
/// why; `DPR_GPU_ALLOW_SOFTWARE=1` lets it take the adapter. On a hardware adapter it takes a hardware one.
fn auto_backend_skips_software_adapters() {
    use dpr_gpu::gpu::context::{ALLOW_SOFTWARE_ENV, AdapterPolicy};
    let Some(g) = gpu() else { return };
    let backends = dpr_gpu::gpu::testing::test_backends().unwrap();
    let hardware = GpuContext::with_policy(backends, AdapterPolicy::HardwareOnly);
    if g.context.info.device_type != wgpu::DeviceType::Cpu {
        assert_ne!(hardware.expect("a hardware adapter exists").info.device_type, wgpu::DeviceType::Cpu);
        return;
    }
    let Err(message) = hardware.map(|_| ()).map_err(|e| e.to_string()) else {
        panic!("a software adapter must not be taken automatically")
    };
    assert!(message.contains("no hardware GPU adapter") && message.contains(&g.context.info.name), "{message}");
    let model = Model::from_weights(
        &Weights::init(&ModelConfig { points_per_patch: 16, ..ModelConfig::default() }, 1).unwrap(),
    )
    .unwrap();
    let (backend, reason) = dpr_gpu::pipeline::choose_backend(BackendKind::Auto, model).unwrap();
    assert!(backend.name().starts_with("cpu") && reason.contains("software"), "{} / {reason}", backend.name());
    // SAFETY: the GPU harness runs its tests one at a time on this thread; nothing else reads the environment now.
    unsafe { std::env::set_var(ALLOW_SOFTWARE_ENV, "1") };
    let allowed = GpuContext::with_policy(backends, AdapterPolicy::HardwareOnly);
    unsafe { std::env::remove_var(ALLOW_SOFTWARE_ENV) };
    assert_eq!(allowed.expect("allowed by the environment").info.name, g.context.info.name);
}

/// Every kernel in the registry has a parity test against its twin here: a test named `{kernel}_matches_cpu...`.
fn every_registered_kernel_has_a_parity_test() {
    for spec in KERNELS {
        let prefix = format!("{}_matches_cpu", spec.name);
        assert!(
            TESTS
                .iter()
                .chain(gpu_preprocess::TESTS)
                .chain(gpu_icp::TESTS)
                .chain(gpu_train::TESTS)
                .any(|(name, _)| name.starts_with(&prefix)),
            "kernel '{}' is registered in gpu::registry::KERNELS but has no parity test named {prefix}*",
            spec.name
        );
    }
}

/// `cloud` with the CPU path's normals (facing a viewpoint inside the room of `common::room_pair`), as if
/// read from its file.
fn with_host_normals(cloud: &dpr_gpu::PointCloud) -> dpr_gpu::PointCloud {
    let index = dpr_gpu::spatial::PointIndex::new(&cloud.points).unwrap();
    let normals = dpr_gpu::preprocess::estimate_normals(&cloud.points, &index, 16, ROOM_VIEWPOINT);
    dpr_gpu::PointCloud { points: cloud.points.clone(), normals: Some(normals) }
}

/// A viewpoint inside `common::room_pair`'s room, off its walls (the default viewpoint, the origin, lies in
/// all three wall planes: the orientation of their normals would be decided by rounding).
const ROOM_VIEWPOINT: [f32; 3] = [1.0, 0.9, 0.7];

/// A GPU `register` keeps each scan on the device: normals estimated there, patches sampled, gathered and
/// described there. Against the CPU `register` on the shipped example pair with its normals dropped (so both
/// estimate them, facing each scan's sensor at its origin: the same neighbourhoods, PCA in f32 Jacobi sweeps
/// vs nalgebra f64, equal to rounding where well conditioned, possibly not on edges, which changes a few
/// patches): the same keypoints are kept (same order, same patch rule), both register the pair (against its
/// exact ground truth), and the poses agree within what two fits to inlier sets of residual <= tau (the inlier
/// threshold) can differ by: 2 tau in translation and 2 tau / L radians in rotation, L the scene's half
/// extent.
fn device_register_matches_cpu_register() {
    let Some(g) = gpu() else { return };
    let s = seed(75);
    let weights = Weights::built_in().unwrap();
    let (gpu_b, cpu_b) = backends_for(g, Model::from_weights(&weights).unwrap());
    let settings = dpr_gpu::RegistrationSettings {
        keypoints: 250,
        estimator: dpr_gpu::Estimator::Ransac,
        seed: s,
        ..Default::default()
    };
    let pair = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/pair");
    let load = |name: &str| {
        let cloud = dpr_gpu::io::read_cloud(&pair.join(name), &Default::default()).unwrap().0;
        dpr_gpu::PointCloud::from_points(cloud.points)
    };
    let (source, target) = (load("cloud_bin_1.ply"), load("cloud_bin_0.ply"));
    let truth = nalgebra::Matrix4::from_row_slice(&[
        0.8249374759465605,
        0.021196035911689073,
        -0.5648264236387563,
        0.5109733910578623,
        -0.16826266813936608,
        0.9631996801883057,
        -0.20960450996046517,
        -0.27075264472254146,
        0.5395978458903807,
        0.2679498164708749,
        0.7981460145635543,
        0.9388456291136249,
        0.0,
        0.0,
        0.0,
        1.0,
    ]);
    let on_gpu = dpr_gpu::Registrar::with_backend(&settings, Box::new(gpu_b)).unwrap();
    let on_cpu = dpr_gpu::Registrar::with_backend(&settings, Box::new(cpu_b)).unwrap();
    let tau = f64::from(on_cpu.inlier_threshold());
    let g_res = on_gpu.register_detailed(&source, &target).unwrap();
    let c_res = on_cpu.register_detailed(&source, &target).unwrap();
    assert_eq!(g_res.source.keypoints, c_res.source.keypoints, "seed {s}");
    assert_eq!(g_res.target.keypoint_ranks, c_res.target.keypoint_ranks, "seed {s}");
    let (lo, hi) = source.points.iter().fold(([f32::MAX; 3], [f32::MIN; 3]), |(lo, hi), p| {
        ([0, 1, 2].map(|a| lo[a].min(p[a])), [0, 1, 2].map(|a| hi[a].max(p[a])))
    });
    let half_extent = 0.5 * f64::from((0..3).map(|a| (hi[a] - lo[a]).powi(2)).sum::<f32>().sqrt());
    let (rot_tol, shift_tol) = ((2.0 * tau / half_extent).to_degrees(), 2.0 * tau);
    for (name, r) in [("gpu", &g_res), ("cpu", &c_res)] {
        let t = &r.result.estimate.target_from_source;
        let angle = dpr_gpu::pose::rotation_error_deg(t, &truth);
        let shift = dpr_gpu::pose::translation_error(t, &truth);
        assert!(angle < rot_tol && shift < shift_tol, "{name} misses the known pose: {angle} deg, {shift} (seed {s})");
    }
    let (gp, cp) = (&g_res.result.estimate.target_from_source, &c_res.result.estimate.target_from_source);
    let angle = dpr_gpu::pose::rotation_error_deg(gp, cp);
    let shift = dpr_gpu::pose::translation_error(gp, cp);
    assert!(angle < rot_tol && shift < shift_tol, "poses differ by {angle} deg and {shift} (seed {s})");
    eprintln!(
        "device register: {} vs {} correspondences, poses {angle:.3} deg / {shift:.4} apart (tolerances {rot_tol:.2} \
         deg / {shift_tol:.3}; seed {s})",
        g_res.result.correspondences, c_res.result.correspondences
    );
}

/// A GPU `register` reads back no per-point data: per scan and round only per-keypoint arrays (the candidate
/// counts per keypoint and search-block cell, the kept keypoints' positions and normals) and the grid words,
/// then the pair steps' small results, and ICP (on, the default) per round the grid words of the target's
/// two tables and the 28-term normal equations per iteration. The bound below is counted from those sizes,
/// with no term in the cloud size, and the clouds are large enough that one readback of a cloud's points or
/// normals would exceed it. Up, each cloud's points cross once (normals are estimated on the device, ICP
/// reads the points the scans left there), plus per-keypoint arrays and grid words. Checked for one round on
/// the main radius alone, and for an untrusted pair's two (the main radius's, then the context round, whose
/// patches are described from the points already on the device): twice the per-round terms.
fn device_register_reads_back_no_per_point_data() {
    let Some(g) = gpu() else { return };
    let s = seed(76);
    let (k, n_points) = (40u64, 12_000);
    // Every point kept: by default a cloud without normals is voxel-downsampled, and the downsampled cloud is
    // read back once as part of the result (`device_voxel_scan_is_described_in_place` counts that case).
    let main_only = dpr_gpu::RegistrationSettings {
        keypoints: k as usize,
        first_keypoints: None,
        context_radii: Vec::new(),
        voxel: Some(0.0),
        estimator: dpr_gpu::Estimator::Ransac,
        viewpoint: ROOM_VIEWPOINT,
        seed: s,
        ..Default::default()
    };
    // The default context radius, and a verdict nothing passes: the context round runs.
    let untrusted = dpr_gpu::RegistrationSettings {
        context_radii: dpr_gpu::settings::DEFAULT_CONTEXT_RADII.to_vec(),
        context_when: dpr_gpu::settings::ContextWhen::Untrusted,
        verdict: dpr_gpu::verdict::VerdictSettings { min_inliers: usize::MAX, ..Default::default() },
        ..main_only.clone()
    };
    let (source, target, _) = common::room_pair(s, n_points);
    for (settings, rounds) in [(main_only, 1u64), (untrusted, 2)] {
        let icp = settings.icp.expect("ICP is on by default");
        let backend = GpuBackend::with_gpu(Arc::clone(&g), small_model(s)).unwrap();
        let r = dpr_gpu::Registrar::with_backend(&settings, Box::new(backend)).unwrap();
        let before = g.context.transfers();
        let result = r.register_detailed(&source, &target).unwrap();
        let moved = g.context.transfers().since(before);
        let context_described = result.source.context.first().map_or(0, |c| c.rows.rows());
        assert_eq!(context_described > 0, rounds == 2, "the context round ran only when asked (seed {s})");
        let n = (source.len() + target.len()) as u64;
        let block = dpr_gpu::cpu::patch_sample::BLOCK_CELLS as u64;
        let k_max = dpr_gpu::gpu::mutual_knn::K_MAX as u64;
        // Per scan: grid words and status of two cell tables (radius cells; kNN cells for the normals).
        let meta = 2 * (32 + 4);
        // ICP, per round: grid words of the target's two tables, then 28 f32 sums per iteration; twice when the
        // estimator's choice is not trusted and another pose candidate replaces it.
        let icps = if settings.pose_candidates > 1 { 2 } else { 1 };
        let (icp_down, icp_up) = (icps * (meta + 4 * 28 * icp.max_iterations as u64), icps * 2 * (32 + 4));
        let down_bound = rounds * (2 * (meta + k * (4 * block + 24)) + 3 * 4 * k_max * k + icp_down);
        let up_bound = 12 * n + rounds * (2 * (2 * (32 + 4) + k * (4 + 4 * block + 2 * 16)) + icp_up);
        assert!(result.result.correspondences >= 3, "seed {s}");
        let down = moved.device_to_host_bytes;
        assert!(down <= down_bound, "{rounds} round(s): {down} bytes down, bound {down_bound}");
        assert!(down_bound < 12 * source.len().min(target.len()) as u64, "the clouds are too small to tell");
        let up = moved.host_to_device_bytes;
        assert!(up <= up_bound, "{rounds} round(s): {up} bytes up, bound {up_bound}");
        eprintln!(
            "device register of {n} points, {k} keypoints per scan, {rounds} round(s): {up} bytes up (points: {}), \
             {down} bytes down",
            12 * n
        );
    }
}

/// `--voxel` on the device: the scan is described from the downsampling's output buffer in place, bit for bit
/// as if its read-back copy were uploaded and described without `--voxel` (the same keypoints, normals and
/// codewords), and the input's points cross the bus once: the downsampled points are not uploaded again.
fn device_voxel_scan_is_described_in_place() {
    let Some(g) = gpu() else { return };
    let s = seed(78);
    let model = small_model(s);
    let settings = |voxel| dpr_gpu::RegistrationSettings {
        keypoints: 40,
        first_keypoints: None,
        voxel,
        viewpoint: ROOM_VIEWPOINT,
        seed: s,
        ..Default::default()
    };
    let (source, _, _) = common::room_pair(s, 12_000);
    let backend = || Box::new(GpuBackend::with_gpu(Arc::clone(&g), model.clone()).unwrap());
    let in_place = dpr_gpu::Registrar::with_backend(&settings(Some(0.05)), backend()).unwrap();
    let before = g.context.transfers();
    let a = in_place.describe(&source, 0).unwrap();
    let up = g.context.transfers().since(before).host_to_device_bytes;
    assert!(a.cloud.len() < source.len() / 2, "the voxel must thin the cloud ({} of {})", a.cloud.len(), source.len());
    let again = dpr_gpu::Registrar::with_backend(&settings(Some(0.0)), backend()).unwrap();
    // Its points only: the described cloud also carries the normals the device estimated.
    let b = again.describe(&dpr_gpu::PointCloud::from_points(a.cloud.points.clone()), 0).unwrap();
    assert_eq!(a.keypoints, b.keypoints, "seed {s}");
    assert_eq!(a.keypoint_normals, b.keypoint_normals, "seed {s}");
    assert_eq!(a.read_codewords().unwrap(), b.read_codewords().unwrap(), "seed {s}");
    // Up: the input once, then per-keypoint arrays and grid words, far less than a second copy of the
    // downsampled points.
    let input = 12 * source.len() as u64;
    assert!(up < input + 12 * a.cloud.len() as u64 / 2, "{up} bytes up for {input} bytes of input points");
}

/// Uniform keypoints (farthest-point sampling) drawn on the device: the same keypoint order as the CPU path,
/// hence the same kept keypoints and ranks.
fn device_uniform_keypoints_match_cpu() {
    let Some(g) = gpu() else { return };
    let s = seed(77);
    let (gpu_b, cpu_b) = backends(g, s);
    let settings = dpr_gpu::RegistrationSettings {
        keypoints: 60,
        keypoint_mode: dpr_gpu::settings::KeypointMode::Uniform,
        viewpoint: ROOM_VIEWPOINT,
        seed: s,
        ..Default::default()
    };
    let (source, _, _) = common::room_pair(s, 3_000);
    let source = with_host_normals(&source);
    let on_gpu = dpr_gpu::Registrar::with_backend(&settings, Box::new(gpu_b)).unwrap();
    let on_cpu = dpr_gpu::Registrar::with_backend(&settings, Box::new(cpu_b)).unwrap();
    let (gs, cs) = (on_gpu.describe(&source, 0).unwrap(), on_cpu.describe(&source, 0).unwrap());
    assert_eq!(gs.keypoints, cs.keypoints, "seed {s}");
    assert_eq!(gs.keypoint_ranks, cs.keypoint_ranks, "seed {s}");
    assert_eq!(gs.cloud.normals, cs.cloud.normals, "file normals, normalised alike (seed {s})");
}

/// Context radii on the device: the cloud's cell table is built for the largest radius and patches of the main
/// radius are drawn from it, so the kept keypoints are the CPU's; the context rows' codewords are the CPU's,
/// and matching on the unit codewords side by side (`unit_rows`) gives the CPU's correspondences, exactly for
/// the same rows (a CPU scan adopted by the GPU backend) and nearly for rows described on each side.
fn device_context_radii_match_cpu() {
    use dpr_gpu::settings::ContextRadius;
    let Some(g) = gpu() else { return };
    let s = seed(78);
    let (gpu_b, cpu_b) = backends_for(Arc::clone(&g), small_model(s));
    let settings = dpr_gpu::RegistrationSettings {
        keypoints: 70,
        radius: Some(0.3),
        viewpoint: ROOM_VIEWPOINT,
        context_radii: vec![ContextRadius { factor: 2.5, weight: 0.8 }],
        seed: s,
        ..Default::default()
    };
    let (source, target, _) = common::room_pair(s, 3_000);
    let (source, target) = (with_host_normals(&source), with_host_normals(&target));
    let on_gpu = dpr_gpu::Registrar::with_backend(&settings, Box::new(gpu_b)).unwrap();
    let on_cpu = dpr_gpu::Registrar::with_backend(&settings, Box::new(cpu_b)).unwrap();
    let (gs, cs) = (on_gpu.describe(&source, 0).unwrap(), on_cpu.describe(&source, 0).unwrap());
    let (gt, ct) = (on_gpu.describe(&target, 1).unwrap(), on_cpu.describe(&target, 1).unwrap());
    let rtol = network_rtol();
    for (g_scan, c_scan) in [(&gs, &cs), (&gt, &ct)] {
        assert_eq!(g_scan.keypoint_ranks, c_scan.keypoint_ranks, "seed {s}");
        let (gm, cm) = (g_scan.read_codewords().unwrap(), c_scan.read_codewords().unwrap());
        assert_close("main codewords", s, &gm, &cm, |_| rtol * max_abs(&cm).max(1.0));
        let (gc, cc) = (
            dpr_gpu::block_on(g_scan.context[0].rows.read_codewords()).unwrap(),
            dpr_gpu::block_on(c_scan.context[0].rows.read_codewords()).unwrap(),
        );
        assert_eq!(gc.len(), cm.len(), "a context row per kept keypoint (seed {s})");
        assert_close("context codewords", s, &gc, &cc, |_| rtol * max_abs(&cc).max(1.0));
        assert!(gc.iter().zip(&gm).any(|(a, b)| a != b), "context rows are another radius's (seed {s})");
    }
    let pairs = |c: &[dpr_gpu::Correspondence]| {
        c.iter().map(|c| (c.source_index, c.target_index)).collect::<std::collections::HashSet<_>>()
    };
    let want = pairs(&on_cpu.correspond(&cs, &ct).unwrap());
    assert!(want.len() >= 5, "the pair gives correspondences ({}), seed {s}", want.len());
    let (ags, agt) = (on_gpu.adopt(&cs).unwrap(), on_gpu.adopt(&ct).unwrap());
    assert_eq!(pairs(&on_gpu.correspond(&ags, &agt).unwrap()), want, "adopted rows, seed {s}");
    let got = pairs(&on_gpu.correspond(&gs, &gt).unwrap());
    let shared = got.intersection(&want).count();
    assert!(
        shared * 10 >= 9 * want.len().max(got.len()),
        "{shared} shared of {} / {}, seed {s}",
        got.len(),
        want.len()
    );
    // Described only for a last round (`ContextWhen::Untrusted`, a verdict nothing passes, three rounds
    // before it): the same keypoints and context rows as describing them with the main patches.
    let lazy = dpr_gpu::RegistrationSettings {
        context_when: dpr_gpu::settings::ContextWhen::Untrusted,
        first_keypoints: Some(20),
        verdict: dpr_gpu::verdict::VerdictSettings { min_inliers: usize::MAX, ..Default::default() },
        ..settings.clone()
    };
    let (gpu_b, _) = backends_for(g, small_model(s));
    let registered =
        dpr_gpu::Registrar::with_backend(&lazy, Box::new(gpu_b)).unwrap().register_detailed(&source, &target).unwrap();
    for (g_scan, c_scan) in [(&registered.source, &cs), (&registered.target, &ct)] {
        assert_eq!(g_scan.keypoint_ranks, c_scan.keypoint_ranks, "lazy context, seed {s}");
        let (gc, cc) = (
            dpr_gpu::block_on(g_scan.context[0].rows.read_codewords()).unwrap(),
            dpr_gpu::block_on(c_scan.context[0].rows.read_codewords()).unwrap(),
        );
        assert_close("lazily described context codewords", s, &gc, &cc, |_| rtol * max_abs(&cc).max(1.0));
    }
}

fn main() -> std::process::ExitCode {
    dpr_gpu::gpu::testing::run_tests(&[TESTS, gpu_preprocess::TESTS, gpu_icp::TESTS, gpu_train::TESTS].concat())
}

/// Every test of this binary.
const TESTS: &[dpr_gpu::gpu::testing::GpuTest] = &[
    ("every_registered_kernel_has_a_parity_test", every_registered_kernel_has_a_parity_test),
    ("patch_features_matches_cpu_ragged", patch_features_matches_cpu_ragged),
    ("device_voxel_scan_is_described_in_place", device_voxel_scan_is_described_in_place),
    ("patch_features_matches_cpu_degenerate", patch_features_matches_cpu_degenerate),
    ("dense_matches_cpu_ragged", dense_matches_cpu_ragged),
    ("dense_fast_matches_cpu_ragged", dense_fast_matches_cpu_ragged),
    ("dense_coop_f16_matches_cpu_within_the_f16_bound", dense_coop_f16_matches_cpu_within_the_f16_bound),
    ("max_pool_matches_cpu_ragged", max_pool_matches_cpu_ragged),
    ("max_pool_matches_cpu_past_65535_workgroups", max_pool_matches_cpu_past_65535_workgroups),
    ("codeword_distance_matches_cpu_ragged", codeword_distance_matches_cpu_ragged),
    ("mutual_knn_matches_cpu_random", mutual_knn_matches_cpu_random),
    ("mutual_knn_matches_cpu_with_ties", mutual_knn_matches_cpu_with_ties),
    ("rotation_head_matches_cpu", rotation_head_matches_cpu),
    ("hypotheses_matches_cpu", hypotheses_matches_cpu),
    ("score_hypotheses_matches_cpu", score_hypotheses_matches_cpu),
    ("score_hypotheses_matches_cpu_past_65535_workgroups", score_hypotheses_matches_cpu_past_65535_workgroups),
    ("inlier_mask_matches_cpu", inlier_mask_matches_cpu),
    ("backend_patch_features_and_encode_match_cpu", backend_patch_features_and_encode_match_cpu),
    ("networks_match_cpu_at_default_widths", networks_match_cpu_at_default_widths),
    ("encode_and_matching_match_cpu_when_chunked", encode_and_matching_match_cpu_when_chunked),
    ("decode_matches_cpu", decode_matches_cpu),
    ("relativenet_hypotheses_and_scores_match_cpu", relativenet_hypotheses_and_scores_match_cpu),
    ("invalid_calls_are_errors_not_panics", invalid_calls_are_errors_not_panics),
    ("register_matches_cpu_on_a_generated_pair", register_matches_cpu_on_a_generated_pair),
    ("register_matches_cpu_with_the_reference_gemm", register_matches_cpu_with_the_reference_gemm),
    ("poison_inputs_stay_in_their_patches", poison_inputs_stay_in_their_patches),
    ("auto_backend_skips_software_adapters", auto_backend_skips_software_adapters),
    ("pose_feature_matches_cpu_scattered", pose_feature_matches_cpu_scattered),
    ("unit_rows_matches_cpu_ragged", unit_rows_matches_cpu_ragged),
    ("device_steps_match_cpu_steps", device_steps_match_cpu_steps),
    ("pair_steps_read_back_only_small_results", pair_steps_read_back_only_small_results),
    ("device_register_matches_cpu_register", device_register_matches_cpu_register),
    ("device_register_reads_back_no_per_point_data", device_register_reads_back_no_per_point_data),
    ("device_uniform_keypoints_match_cpu", device_uniform_keypoints_match_cpu),
    ("device_context_radii_match_cpu", device_context_radii_match_cpu),
    (
        "register_with_relativenet_matches_cpu_on_a_generated_pair",
        register_with_relativenet_matches_cpu_on_a_generated_pair,
    ),
];
