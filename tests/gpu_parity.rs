//! Every WGSL kernel against its CPU twin, and the networks end to end (GPU backend vs CPU reference).
//!
//! The per-kernel cases live in the library (`dpr_gpu::gpu::parity`, so that a browser runs the same cases on
//! WebGPU: `web/parity.html`); this binary runs them (`parity::CASES`) beside its own tests of the backend, the
//! steps and whole registrations. Inputs are seeded (`DPR_SEED` overrides; the seed is in every failure message)
//! and adversarial: sizes that miss the workgroup and tile sizes, dispatches past 65,535 workgroups in one
//! dimension, degenerate geometry, heavy ties, and outputs pre-filled with a NaN / 0xDEADBEEF sentinel so an
//! element a kernel never writes fails the comparison. This binary uses `dpr_gpu::gpu::testing::run_tests` as its
//! harness (`harness = false`): without a Vulkan adapter every test is reported `SKIPPED` and counted as skipped,
//! never as passed, unless `CI=true` or `DPR_GPU_REQUIRE_ADAPTER=1` (then each fails). Every test is listed in
//! `main` at the end of the file.
//!
//! Tolerances are named constants (here and in `dpr_gpu::gpu::parity`), each with the reason it is not zero.

use dpr_gpu::BackendKind;
use dpr_gpu::backend::{Backend, CpuBackend};
use dpr_gpu::backend::{RotationInputs, StepFuture};
use dpr_gpu::cpu::dense::DenseShape;
use dpr_gpu::cpu::hypotheses::Hypothesis;
use dpr_gpu::cpu::mutual_knn::Match;
use dpr_gpu::cpu::score_hypotheses::{HypothesisScore, squared_residual};
use dpr_gpu::gpu::gemm::GemmVariant;
use dpr_gpu::gpu::registry::KERNELS;
use dpr_gpu::gpu::testing::{gpu_or_skip as gpu, new_gpu_or_skip};
use dpr_gpu::gpu::{self, Gpu, GpuBackend, GpuContext};
use dpr_gpu::model::config::{PoseFrame, RotationOutput};
use dpr_gpu::model::{Model, ModelConfig, Net, Weights};
use dpr_gpu::preprocess::GatheredPatches;
use dpr_gpu::rng::Rng;
use dpr_gpu::settings::MatchMode;
use std::sync::Arc;

use dpr_gpu::gpu::parity::{self, inference::*};

mod common;
mod gpu_icp;
mod gpu_train;

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
        // PC-FoldNet at its own ragged widths, as in a pruned model.
        pc_widths: Some(dpr_gpu::model::config::NetWidths { encoder: vec![8, 20, 28], head: vec![44, 36] }),
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

// ----------------------------------------------------------------------------------------- patch_features

// ------------------------------------------------------------------------------------------------- dense

// ---------------------------------------------------------------------------------------------- max_pool

// ------------------------------------------------------------------------------ codeword_distance + knn

// ----------------------------------------------------------------------- quaternions, hypotheses, scores

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
                .chain(gpu_icp::TESTS)
                .chain(gpu_train::TESTS)
                .map(|(name, _)| *name)
                .chain(parity::CASES.iter().map(|c| c.name))
                .any(|name| name.starts_with(&prefix)),
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
    let tests = [TESTS, gpu_icp::TESTS, gpu_train::TESTS].concat();
    dpr_gpu::gpu::testing::run_tests(&tests, parity::CASES)
}

/// Every test of this binary.
const TESTS: &[dpr_gpu::gpu::testing::GpuTest] = &[
    ("every_registered_kernel_has_a_parity_test", every_registered_kernel_has_a_parity_test),
    ("device_voxel_scan_is_described_in_place", device_voxel_scan_is_described_in_place),
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
