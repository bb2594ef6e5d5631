//! Parity cases of the inference kernels (patch features, the dense layers, max-pool, codeword distances and
//! mutual kNN, RelativeNet's rotation head, hypotheses and their scores, unit rows, pose features) and the
//! helpers the cases share with `tests/gpu_parity.rs`. Tolerances are named constants, each with the reason it is
//! not zero; kernels whose result does not depend on float rounding must match exactly.

use super::Outcome;
use crate::cpu;
use crate::cpu::dense::DenseShape;
use crate::cpu::hypotheses::{Hypothesis, hypotheses as cpu_hypotheses};
use crate::cpu::score_hypotheses::{HypothesisScore, squared_residual};
use crate::gpu::codeword_distance::CodewordDistance;
use crate::gpu::dense::Dense;
use crate::gpu::dense_coop_f16::{CoopTile, DenseCoopF16};
use crate::gpu::dense_fast::{DenseFast, FastTile};
use crate::gpu::gemm::GemmVariant;
use crate::gpu::gemm_choice::GemmChoice;
use crate::gpu::hypotheses::Hypotheses;
use crate::gpu::kernel::GpuKernel;
use crate::gpu::max_pool::MaxPool;
use crate::gpu::mutual_knn::MutualKnn;
use crate::gpu::patch_features::PatchFeatures;
use crate::gpu::rotation_head::RotationHead;
use crate::gpu::score_hypotheses::ScoreHypotheses;
use crate::gpu::{self, Gpu};
use crate::model::config::{PoseFrame, RotationOutput};
use crate::preprocess::GatheredPatches;
use crate::rng::Rng;
use crate::settings::MatchMode;

/// One ulp of 1 in f32: the unit the tolerances are written in.
pub const EPS: f32 = f32::EPSILON;

/// codeword_distance: both sides sum the same terms in the same order, but a GPU may contract
/// `a * b + c` into an FMA and so round differently at each step; the sequential-sum error bound is
/// `n * eps * sum |terms|` for each side, so allow twice that (`n` = terms + 2).
pub const SUM_ERROR_FACTOR: f32 = 2.0;

/// patch_features angles (in units of pi): WGSL's `atan2` and `sqrt` are not correctly rounded (the
/// spec allows thousands of ulp for atan2); 2e-5 is ~2^-15.6 of the [0, 1] range, far below feature noise.
pub const PPF_ANGLE_ATOL: f32 = 2e-5;

/// patch_features distances and PC coordinates: one `sqrt` / division, each a few ulp on a GPU.
pub const PPF_LENGTH_RTOL: f32 = 8.0 * EPS;

/// patch_features PC coordinates in a normal frame: the frame costs a `sqrt`, two divisions and a few
/// products (each a few ulp on a GPU, FMA-contractible), then a 3-term dot product; relative to the row's
/// vector length.
pub const PC_FRAME_RTOL: f32 = 32.0 * EPS;

/// rotation_head: normalisation (`sqrt`, division), Gram-Schmidt or quaternion products, and with normal frames
/// two 3x3 products of unit-scale matrices; each step a few ulp on a GPU, so a few tens of ulp of 1 in all.
pub const ROTATION_ATOL: f32 = 64.0 * EPS;

/// rotation_head with angle bins: the angle's `sin` and `cos` on a GPU need only an absolute accuracy of 2^-11
/// on [-pi, pi] (Vulkan's precision rules), so the rotation entries get that bound.
pub const ROTATION_BINS_ATOL: f32 = 1.0 / 2048.0;

/// hypotheses: R copied, t = p_t - R p_s (FMA-contractible); errors are a few ulp of the largest term.
pub const HYPOTHESIS_ULPS: f32 = 16.0;

/// score_hypotheses: the GPU sums residuals in a tree, the twin sequentially; both within
/// `n * eps * sum` of the exact sum.
pub const RESIDUAL_SUM_ULPS_PER_TERM: f32 = 2.0;

/// score_hypotheses: each component of a residual `q - R p - t` is three products and four sums of terms up to
/// `3 max|p| + max|t| + max|q|`; a GPU may contract them into FMAs (naga emits no `NoContraction`) and round
/// each differently, a few ulp of that magnitude, not of the (possibly far smaller) residual.
pub const RESIDUAL_ULPS: f64 = 8.0;

/// score_hypotheses: a residual this close (relative) to the threshold may be classified differently when
/// the GPU rounds the residual differently; the count may differ by at most the number of such pairs.
pub const BORDERLINE_RTOL: f64 = 1e-5;

/// Sentinel every float output is pre-filled with: an element the kernel never writes stays NaN and fails.
pub const SENTINEL: f32 = f32::NAN;

/// Sentinel for integer outputs.
pub const SENTINEL_U32: u32 = 0xDEAD_BEEF;

/// The test seed: `DPR_SEED` or `default`.
pub fn seed(default: u64) -> u64 {
    std::env::var("DPR_SEED").ok().and_then(|s| s.parse().ok()).unwrap_or(default)
}

/// `n` standard normal floats.
pub fn normals(rng: &mut Rng, n: usize) -> Vec<f32> {
    (0..n).map(|_| rng.normal() as f32).collect()
}

/// `n` points uniform in [-extent, extent]^3.
pub fn points(rng: &mut Rng, n: usize, extent: f64) -> Vec<[f32; 3]> {
    (0..n).map(|_| [0; 3].map(|_: i32| rng.uniform(-extent, extent) as f32)).collect()
}

/// Asserts `|a - e| <= tol(i)` elementwise (NaN equals NaN; infinities must match), naming the kernel, the
/// first bad index, both values, the tolerance, the seed and how many elements are off.
pub fn assert_close(kernel: &str, seed: u64, actual: &[f32], expected: &[f32], tol: impl Fn(usize) -> f32) {
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
pub fn dense_scale(s: &DenseShape, x: &[f32], w: &[f32], g: &[f32], init: &[f32]) -> Vec<f32> {
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

/// A random unit vector.
pub fn unit(rng: &mut Rng) -> [f32; 3] {
    loop {
        let v = [0; 3].map(|_: i32| rng.normal() as f32);
        let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if n > 1e-3 {
            return v.map(|c| c / n);
        }
    }
}

/// `patches` gathered patches of `n` points within `radius` of random centres, with random unit normals.
pub fn gathered(rng: &mut Rng, patches: usize, n: usize, radius: f32) -> GatheredPatches {
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

/// Asserts patch features (PPF, PC) against the twin's within the patch_features tolerances.
pub fn check_patch_features(kernel: &str, seed: u64, got: (&[f32], &[f32]), want: (&[f32], &[f32]), frame: PoseFrame) {
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
pub fn twin_patch_features(p: &GatheredPatches, n: usize, radius: f32, frame: PoseFrame) -> (Vec<f32>, Vec<f32>) {
    PatchFeatures::CPU_TWIN(&p.centers, &p.center_normals, &p.points, &p.normals, n, radius, frame)
}

/// The kernel on `p` in `frame`, outputs pre-filled with the sentinel.
pub(crate) async fn gpu_patch_features(
    g: &Gpu,
    p: &GatheredPatches,
    n: usize,
    radius: f32,
    frame: PoseFrame,
) -> (Vec<f32>, Vec<f32>) {
    let (mut ppf, mut pc) = (vec![SENTINEL; p.points.len() * 4], vec![SENTINEL; p.points.len() * 3]);
    gpu::patch_features::run(g, p, n, radius, frame, &mut ppf, &mut pc).await.unwrap();
    (ppf, pc)
}

/// `patch_features` against its CPU twin (ragged).
pub async fn patch_features_matches_cpu_ragged(g: &Gpu) -> Outcome {
    let s = seed(11);
    let mut rng = Rng::new(s);
    let (patches, n, radius) = (7, 37, 0.3); // 259 points: not a multiple of 64
    let mut p = gathered(&mut rng, patches, n, radius);
    // Normals on the frame's branch switch (z = +0, -0) and the poles.
    p.center_normals[..4].copy_from_slice(&[[1.0, 0.0, 0.0], [0.0, 0.6, -0.8], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]]);
    p.center_normals[4] = [0.0, 1.0, -0.0];
    for frame in [PoseFrame::Fragment, PoseFrame::Normal] {
        let (want_ppf, want_pc) = twin_patch_features(&p, n, radius, frame);
        let (ppf, pc) = gpu_patch_features(g, &p, n, radius, frame).await;
        check_patch_features("patch_features", s, (&ppf, &pc), (&want_ppf, &want_pc), frame);
    }
    Outcome::Passed
}

/// `patch_features` against its CPU twin (degenerate).
pub async fn patch_features_matches_cpu_degenerate(g: &Gpu) -> Outcome {
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
        let (ppf, pc) = gpu_patch_features(g, &p, n, 0.3, frame).await;
        assert!(want_ppf.iter().chain(&want_pc).all(|v| v.is_finite()), "finite features on degenerate input");
        check_patch_features("patch_features (degenerate)", s, (&ppf, &pc), (&want_ppf, &want_pc), frame);
    }
    let (want_ppf, _) = twin_patch_features(&p, n, 0.3, PoseFrame::Fragment);
    let (ppf, _) = gpu_patch_features(g, &p, n, 0.3, PoseFrame::Fragment).await;
    // The zero-vector branch (atan2(0, 0) -> 0) must be taken identically: exact zeros where the twin has one
    // because a vector is exactly zero.
    for (i, (&a, &e)) in ppf.iter().zip(&want_ppf).enumerate() {
        let (row, comp) = (i / 4 % n, i % 4);
        let zero_vector = row <= 1 || (row == 2 && comp != 0) || i / 4 >= n && comp != 1;
        if zero_vector && comp < 3 {
            assert_eq!(a, e, "patch_features (degenerate): element {i} (row {row}, component {comp}) seed {s}");
        }
    }
    Outcome::Passed
}

/// One dense case: (rows, in_dim, out_dim, rows_per_group, accumulate, relu, group term, w_row_offset).
pub type DenseCase = (usize, usize, usize, usize, bool, bool, bool, usize);

/// Cases around the reference's 64 x 64 x 16 tiles: a single element, ragged edges, widths of the real layers,
/// and weight rows read from an offset (a slice of a concatenated input).
pub const DENSE_CASES: &[DenseCase] = &[
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
pub const DENSE_FAST_CASES: &[DenseCase] = &[
    (127, 8, 129, 127, false, true, true, 0),
    (129, 9, 127, 43, true, false, true, 5),
    (128, 24, 128, 64, true, true, false, 0),
    (255, 33, 257, 85, false, false, true, 1),
    (3, 200, 2, 1, true, true, true, 11),
];

/// Cases around the cooperative kernel's 64 x 64 tiles, 32-deep k-tiles and 16 x 16 matrices.
pub const DENSE_COOP_CASES: &[DenseCase] = &[
    (15, 16, 17, 15, false, true, true, 0),
    (64, 32, 64, 8, true, false, true, 3),
    (65, 33, 63, 65, true, true, false, 0),
    (200, 100, 140, 50, false, false, true, 9),
];

/// Cases around the cooperative kernel's larger tiles (128 rows or columns, eight subgroups) and its
/// four-element loads: rows and columns one off 128, input widths not a multiple of 4 (a partial group at the
/// end of each row of x) or of a 32-deep k-tile, an output width not a multiple of 4 (partial groups at the end of
/// each row of the weight), a single k-tile and an odd number of them (the last in the second buffer).
pub const DENSE_COOP_TILE_CASES: &[DenseCase] = &[
    (127, 32, 129, 127, false, true, true, 0),
    (129, 70, 127, 43, true, false, true, 5),
    (257, 97, 130, 64, true, true, false, 0),
    (1, 3, 1, 1, false, false, false, 2),
];

/// Runs `cases` on `variant` through the recorded path (weights at `w_row_offset` of a larger weight buffer,
/// output pre-filled with the initial contents or the sentinel) and compares with `twin`, each element within
/// `tol(shape, x, w, group, init)[i]`.
pub(crate) async fn check_dense_variant(
    g: &Gpu,
    variant: GemmVariant,
    seed: u64,
    cases: &[DenseCase],
    twin: <Dense as GpuKernel>::CpuTwin,
    tol: impl Fn(&DenseShape, &[f32], &[f32], &[f32], &[f32]) -> Vec<f32>,
) {
    check_dense_choice(g, GemmChoice { variant, ..g.gemm_choice() }, seed, cases, twin, tol).await;
}

/// [`check_dense_variant`] on explicit tile shapes too.
pub(crate) async fn check_dense_choice(
    g: &Gpu,
    choice: GemmChoice,
    seed: u64,
    cases: &[DenseCase],
    twin: <Dense as GpuKernel>::CpuTwin,
    tol: impl Fn(&DenseShape, &[f32], &[f32], &[f32], &[f32]) -> Vec<f32>,
) {
    use crate::gpu::{buffer::GpuBuffer, recorder::Recorder};
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
        gpu::dense::record_choice(&mut rec, g, choice, &params, [xb.raw(), wb.raw()], group_buf, ob.raw()).unwrap();
        rec.read(ob.raw(), 0, (init.len() * 4) as u64);
        let got: Vec<f32> = bytemuck::pod_collect_to_vec(&rec.finish().await.unwrap()[0]);
        let init_for_tol = if accumulate { init.clone() } else { vec![0.0; init.len()] };
        let tol = tol(&shape, &x, w, &gt, &init_for_tol);
        let what = format!("{} {shape:?} w_row_offset {offset}", choice.name());
        assert_close(&what, seed, &got, &want, |i| tol[i]);
    }
}

/// The f32 tolerance of a GEMM kernel against the twin: both sum the same `in_dim + 2` terms (start value, group
/// term, products) in the same order, but a GPU may contract `a * b + c` into an FMA and so round differently;
/// each side is within `gamma_{in_dim + 2} * sum |terms|` of the exact sum, so they differ by at most twice that.
pub fn f32_gemm_tolerance(s: &DenseShape, x: &[f32], w: &[f32], g: &[f32], init: &[f32]) -> Vec<f32> {
    let gamma = cpu::dense::gamma_f32(s.in_dim + 2) as f32;
    let scale = dense_scale(s, x, w, g, init);
    // `scale` is itself an f32 sum (within gamma of its exact value); MIN_POSITIVE covers an all-zero row.
    scale.iter().map(|&v| 2.0 * gamma * v * (1.0 + 2.0 * gamma) + f32::MIN_POSITIVE).collect()
}

/// The portable reference GEMM against the twin.
pub async fn dense_matches_cpu_ragged(g: &Gpu) -> Outcome {
    check_dense_variant(g, GemmVariant::Portable, seed(21), DENSE_CASES, Dense::CPU_TWIN, f32_gemm_tolerance).await;
    Outcome::Passed
}

/// The fast portable GEMM against its twin, on its own edge cases and the reference's.
pub async fn dense_fast_matches_cpu_ragged(g: &Gpu) -> Outcome {
    if let Some(why) = GemmVariant::Fast.unavailable_reason(&g.context) {
        return Outcome::Skipped(format!("dense_fast cannot run on this adapter: {why}"));
    }
    let s = seed(22);
    check_dense_variant(g, GemmVariant::Fast, s, DENSE_FAST_CASES, DenseFast::CPU_TWIN, f32_gemm_tolerance).await;
    check_dense_variant(g, GemmVariant::Fast, s + 1, DENSE_CASES, DenseFast::CPU_TWIN, f32_gemm_tolerance).await;
    Outcome::Passed
}

/// Every tile shape of the fast GEMM that `dpr-gpu bench --gemm-sweep` times ([`FastTile::ALL`], each a
/// generated variant of `shaders/dense_fast.wgsl`) against the twin, on the fast kernel's edge cases (ragged
/// around 64 and 128) and the reference's.
pub async fn dense_fast_tiles_match_cpu_ragged(g: &Gpu) -> Outcome {
    if let Some(why) = GemmVariant::Fast.unavailable_reason(&g.context) {
        return Outcome::Skipped(format!("dense_fast cannot run on this adapter: {why}"));
    }
    let s = seed(24);
    for tile in FastTile::ALL {
        let choice = GemmChoice::fast(tile);
        check_dense_choice(g, choice, s, DENSE_FAST_CASES, DenseFast::CPU_TWIN, f32_gemm_tolerance).await;
        check_dense_choice(g, choice, s + 1, DENSE_CASES, DenseFast::CPU_TWIN, f32_gemm_tolerance).await;
    }
    Outcome::Passed
}

/// The cooperative-matrix GEMM (f16 inputs, f32 accumulation) against its f16 twin, within the bound derived
/// in `cpu::dense_coop_f16` (the GPU's conversion and accumulation error plus the twin's). Runs only on an
/// adapter with a 16x16x16 f16 -> f32 cooperative matrix configuration; elsewhere it is reported SKIPPED.
pub async fn dense_coop_f16_matches_cpu_within_the_f16_bound(g: &Gpu) -> Outcome {
    if let Some(why) = GemmVariant::CoopF16.unavailable_reason(&g.context) {
        return Outcome::Skipped(format!("needs an adapter with cooperative matrices: {why}"));
    }
    let s = seed(23);
    let tol = cpu::dense_coop_f16::parity_tolerance;
    check_dense_variant(g, GemmVariant::CoopF16, s, DENSE_COOP_CASES, DenseCoopF16::CPU_TWIN, tol).await;
    check_dense_variant(g, GemmVariant::CoopF16, s + 1, DENSE_CASES, DenseCoopF16::CPU_TWIN, tol).await;
    Outcome::Passed
}

/// Every tile shape of the cooperative-matrix GEMM that `dpr-gpu bench --gemm-sweep` times ([`CoopTile::ALL`],
/// the default `shaders/dense_coop_f16.wgsl`, the others generated from `shaders/tiles/dense_coop_f16.wgsl`) against the f16 twin within its bound, on the
/// larger tiles' edge cases and the default tile's. SKIPPED without cooperative matrices; when the device's
/// workgroup memory cannot hold some shapes (the host refuses them: [`CoopTile::unavailable_reason`]), the
/// others are checked and the case is SKIPPED naming those.
pub async fn dense_coop_f16_tiles_match_cpu_within_the_f16_bound(g: &Gpu) -> Outcome {
    if let Some(why) = GemmVariant::CoopF16.unavailable_reason(&g.context) {
        return Outcome::Skipped(format!("needs an adapter with cooperative matrices: {why}"));
    }
    let s = seed(25);
    let tol = cpu::dense_coop_f16::parity_tolerance;
    let mut refused = Vec::new();
    for tile in CoopTile::ALL {
        if let Some(why) = tile.unavailable_reason(&g.context.limits) {
            refused.push(why);
            continue;
        }
        let choice = GemmChoice::coop(tile);
        check_dense_choice(g, choice, s, DENSE_COOP_TILE_CASES, DenseCoopF16::CPU_TWIN, tol).await;
        check_dense_choice(g, choice, s + 1, DENSE_COOP_CASES, DenseCoopF16::CPU_TWIN, tol).await;
    }
    match refused.len() {
        0 => Outcome::Passed,
        n => {
            Outcome::Skipped(format!("{} shapes passed, {n} not run: {}", CoopTile::ALL.len() - n, refused.join("; ")))
        }
    }
}

/// `max_pool` against its CPU twin (ragged).
pub async fn max_pool_matches_cpu_ragged(g: &Gpu) -> Outcome {
    let s = seed(31);
    let mut rng = Rng::new(s);
    for (groups, rows, channels) in [(1, 1, 1), (5, 37, 67), (3, 1, 130), (2, 300, 5)] {
        // All negative in one group: the -inf start value matters.
        let mut x = normals(&mut rng, groups * rows * channels);
        x[..rows * channels].iter_mut().for_each(|v| *v = -v.abs() - 1.0);
        let want = MaxPool::CPU_TWIN(&x, groups, rows, channels);
        let mut got = vec![SENTINEL; groups * channels];
        gpu::max_pool::run(g, &x, groups, rows, channels, &mut got).await.unwrap();
        assert_close(&format!("max_pool {groups}x{rows}x{channels}"), s, &got, &want, |_| 0.0);
    }
    Outcome::Passed
}

/// `max_pool` against its CPU twin (past 65535 workgroups).
pub async fn max_pool_matches_cpu_past_65535_workgroups(g: &Gpu) -> Outcome {
    let s = seed(32);
    // 65,600 x 64 outputs: 65,600 workgroups of 64, folded into a 2-D grid; one row per group keeps it cheap.
    let groups = 65_600 * gpu::max_pool::WG_SIZE as usize + 17;
    let mut rng = Rng::new(s);
    let x: Vec<f32> = (0..groups).map(|_| rng.uniform(-1.0, 1.0) as f32).collect();
    let want = MaxPool::CPU_TWIN(&x, groups, 1, 1);
    let mut got = vec![SENTINEL; groups];
    gpu::max_pool::run(g, &x, groups, 1, 1, &mut got).await.unwrap();
    assert_close("max_pool (2-D dispatch)", s, &got, &want, |_| 0.0);
    Outcome::Passed
}

/// `codeword_distance` against its CPU twin (ragged).
pub async fn codeword_distance_matches_cpu_ragged(g: &Gpu) -> Outcome {
    let s = seed(41);
    let mut rng = Rng::new(s);
    for (ns, nt, dim) in [(1, 1, 1), (37, 53, 70), (17, 16, 33), (5, 300, 4)] {
        let a = normals(&mut rng, ns * dim);
        let b = normals(&mut rng, nt * dim);
        let want = CodewordDistance::CPU_TWIN(&a, &b, dim);
        let mut got = vec![SENTINEL; ns * nt];
        gpu::codeword_distance::run(g, &a, &b, dim, &mut got).await.unwrap();
        // All terms are non-negative, so sum |terms| is the value itself.
        let tol = |i: usize| SUM_ERROR_FACTOR * (dim + 2) as f32 * EPS * want[i] + f32::MIN_POSITIVE;
        assert_close(&format!("codeword_distance {ns}x{nt}x{dim}"), s, &got, &want, tol);
    }
    Outcome::Passed
}

/// The matching rules the kNN cases run.
pub const MODES: [MatchMode; 5] =
    [MatchMode::Closest, MatchMode::Mutual(1), MatchMode::Mutual(2), MatchMode::Mutual(3), MatchMode::Mutual(4)];

pub(crate) async fn check_knn(g: &Gpu, s: u64, d: &[f32], ns: usize, nt: usize, what: &str) {
    for mode in MODES {
        let want = MutualKnn::CPU_TWIN(d, ns, nt, mode);
        let got = gpu::mutual_knn::run(g, d, ns, nt, mode).await.unwrap();
        assert_eq!(got, want, "mutual_knn {what} {ns}x{nt} {mode:?} (seed {s})");
    }
}

/// `mutual_knn` against its CPU twin (random).
pub async fn mutual_knn_matches_cpu_random(g: &Gpu) -> Outcome {
    let s = seed(42);
    let mut rng = Rng::new(s);
    for (ns, nt) in [(1, 1), (1, 5), (5, 1), (2, 3), (67, 71), (130, 3)] {
        let d: Vec<f32> = (0..ns * nt).map(|_| rng.uniform(0.0, 10.0) as f32).collect();
        check_knn(g, s, &d, ns, nt, "random").await;
    }
    Outcome::Passed
}

/// `mutual_knn` against its CPU twin (with ties).
pub async fn mutual_knn_matches_cpu_with_ties(g: &Gpu) -> Outcome {
    let s = seed(43);
    let mut rng = Rng::new(s);
    // Few distinct values: most comparisons are ties, broken towards the lower index on both sides.
    for (ns, nt, levels) in [(4, 4, 1), (9, 13, 2), (65, 66, 3), (3, 2, 2)] {
        let d: Vec<f32> = (0..ns * nt).map(|_| rng.below(levels) as f32).collect();
        check_knn(g, s, &d, ns, nt, "ties").await;
    }
    Outcome::Passed
}

/// `rotation_head` against its CPU twin.
pub async fn rotation_head_matches_cpu(g: &Gpu) -> Outcome {
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
            gpu::rotation_head::run(g, &raw, output, frame, [&ns, &nt], &mut got).await.unwrap();
            let name = format!("rotation_head ({output:?}, {frame:?})");
            let tol = if output == bins { ROTATION_BINS_ATOL } else { ROTATION_ATOL };
            assert_close(&name, s, got.as_flattened(), want.as_flattened(), |_| tol);
        }
    }
    Outcome::Passed
}

/// Rotations with source and target points, one per correspondence.
pub type RotationProblem = (Vec<[f32; 9]>, Vec<[f32; 3]>, Vec<[f32; 3]>);

/// `n` random rotations with source and target points within `extent`.
pub fn random_hypotheses(rng: &mut Rng, n: usize, extent: f64) -> RotationProblem {
    let q: Vec<[f32; 4]> = (0..n).map(|_| rng.unit_quaternion().map(|v| v as f32)).collect();
    let r = q.iter().map(|&q| cpu::rotation_head::quaternion_rotation(q)).collect();
    (r, points(rng, n, extent), points(rng, n, extent))
}

/// `hypotheses` against its CPU twin.
pub async fn hypotheses_matches_cpu(g: &Gpu) -> Outcome {
    let s = seed(52);
    let mut rng = Rng::new(s);
    let (q, ps, pt) = random_hypotheses(&mut rng, 131, 20.0);
    let want = Hypotheses::CPU_TWIN(&q, &ps, &pt);
    let sentinel = Hypothesis { rotation: [SENTINEL; 9], translation: [SENTINEL; 3] };
    let mut got = vec![sentinel; q.len()];
    gpu::hypotheses::run(g, &q, &ps, &pt, &mut got).await.unwrap();
    let flat = |h: &[Hypothesis]| h.iter().flat_map(gpu::hypotheses::to_row).collect::<Vec<f32>>();
    let scale: Vec<f32> = (0..q.len())
        .flat_map(|i| {
            let p = ps[i].iter().chain(&pt[i]).fold(1f32, |m, v| m.max(v.abs()));
            [[1.0; 9].as_slice(), [p; 3].as_slice()].concat()
        })
        .collect();
    assert_close("hypotheses", s, &flat(&got), &flat(&want), |i| HYPOTHESIS_ULPS * EPS * scale[i]);
    Outcome::Passed
}

/// Correspondences with about 60% inliers of a random pose, and hypotheses near that pose.
pub fn scoring_problem(rng: &mut Rng, hyps: usize, corr: usize) -> (Vec<Hypothesis>, Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let (q, ps, _) = random_hypotheses(rng, 1, 1.0);
    let truth = cpu_hypotheses(&q, &ps, &points(rng, 1, 2.0))[0];
    let source = points(rng, corr, 3.0);
    let target = source
        .iter()
        .map(|&p| {
            let rp = crate::cpu::hypotheses::rotate(&truth.rotation, p);
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
pub fn residual_slack(h: &Hypothesis, p: [f32; 3], q: [f32; 3], r2: f64) -> f64 {
    let max_abs3 = |v: [f32; 3]| f64::from(v.iter().fold(0f32, |m, x| m.max(x.abs())));
    let d = RESIDUAL_ULPS * f64::from(EPS) * (3.0 * max_abs3(p) + max_abs3(h.translation) + max_abs3(q));
    2.0 * 3f64.sqrt() * r2.sqrt() * d + 3.0 * d * d + 4.0 * f64::from(EPS) * r2
}

/// Asserts hypothesis scores against the twin's: inliers may differ only by the pairs near the threshold.
pub fn check_scores(s: u64, h: &[Hypothesis], src: &[[f32; 3]], tgt: &[[f32; 3]], thr: f32, got: &[HypothesisScore]) {
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

/// `score_hypotheses` against its CPU twin.
pub async fn score_hypotheses_matches_cpu(g: &Gpu) -> Outcome {
    let s = seed(53);
    let mut rng = Rng::new(s);
    for (hyps, corr) in [(1, 1), (37, 200), (5, 64), (3, 65), (70, 0)] {
        let (h, src, tgt) = scoring_problem(&mut rng, hyps, corr);
        let mut got = vec![HypothesisScore { inliers: SENTINEL_U32, residual_sum: SENTINEL }; h.len()];
        gpu::score_hypotheses::run(g, &h, &src, &tgt, 0.1, &mut got).await.unwrap();
        check_scores(s, &h, &src, &tgt, 0.1, &got);
    }
    Outcome::Passed
}

/// `score_hypotheses` against its CPU twin (past 65535 workgroups).
pub async fn score_hypotheses_matches_cpu_past_65535_workgroups(g: &Gpu) -> Outcome {
    let s = seed(54);
    let mut rng = Rng::new(s);
    // One workgroup per hypothesis: 65,600 of them need a 2-D grid; two correspondences keep it cheap.
    let (h, src, tgt) = scoring_problem(&mut rng, 65_600, 2);
    let mut got = vec![HypothesisScore { inliers: SENTINEL_U32, residual_sum: SENTINEL }; h.len()];
    gpu::score_hypotheses::run(g, &h, &src, &tgt, 0.5, &mut got).await.unwrap();
    check_scores(s, &h, &src, &tgt, 0.5, &got);
    Outcome::Passed
}

/// unit_rows: each block is its rows at unit length times the weight, in its columns of the wider rows; the
/// other columns keep the sentinel. The length's in-order sum may be FMA-contracted on a GPU (the
/// codeword_distance bound), and its `sqrt` and the division cost a few ulp each.
pub async fn unit_rows_matches_cpu_ragged(g: &Gpu) -> Outcome {
    use crate::gpu::unit_rows::{Block, UnitRows};
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
        gpu::unit_rows::run(g, &input, block, &mut got).await.unwrap();
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
    assert!(gpu::unit_rows::run(g, &[0.0; 4], bad, &mut [0.0; 6]).await.is_err(), "a block past the row");
    Outcome::Passed
}

/// pose_feature: a subtraction per value, exact on both sides; rows not named keep their contents.
pub async fn pose_feature_matches_cpu_scattered(g: &Gpu) -> Outcome {
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
    gpu::pose_feature::run(g, &pc, &ppf, &picked, width, &mut got).await.unwrap();
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&got), bits(&want), "pose_feature (seed {s})");
    assert!(want.iter().filter(|x| x.is_nan()).count() == (rows - picked.len()) * width, "unnamed rows untouched");
    assert!(gpu::pose_feature::run(g, &pc, &ppf, &[rows as u32], width, &mut got).await.is_err(), "row out of range");
    Outcome::Passed
}
