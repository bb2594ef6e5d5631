//! `dpr-gpu bench --json` on the test adapter (lavapipe in CI; its timings are meaningless, the code path is
//! what is tested): the schema, finite non-negative times, GFLOP/s = flops / time, the peak fraction, and the
//! bytes moved, which must equal an independent count made from the buffer sizes of each call: per stage from
//! the sizes in the report, and per pair from a wrapper backend that adds up the sizes of every call one
//! `register` of the same pair makes. Without an adapter the report must say it is CPU-only.
//!
//! GPU tests print `SKIPPED (no GPU adapter)` and return without one (they fail instead with `CI=true` or
//! `DPR_GPU_REQUIRE_ADAPTER=1`).

use dpr_gpu::backend::{
    Backend, DescribedKeypoints, Lap, MatchedRows, PatchBatch, RotationInputs, RowMatch, ScanCloud, ScanRows,
    ScanSettings, Verified,
};
use dpr_gpu::cli::bench::{self, Args};
use dpr_gpu::cpu::gemm::Precision;
use dpr_gpu::cpu::hypotheses::Hypothesis;
use dpr_gpu::cpu::mutual_knn::Match;
use dpr_gpu::cpu::score_hypotheses::HypothesisScore;
use dpr_gpu::gpu::GpuBackend;
use dpr_gpu::gpu::gemm::GemmVariant;
use dpr_gpu::gpu::hypotheses::HYPOTHESIS_FLOATS;
use dpr_gpu::gpu::mutual_knn::K_MAX;
use dpr_gpu::gpu::testing::gpu_or_skip;
use dpr_gpu::model::{Model, ModelConfig, Net};
use dpr_gpu::preprocess::GatheredPatches;
use dpr_gpu::settings::MatchMode;
use serde_json::Value;
use std::collections::HashSet;
use std::process::Command;
use std::sync::{Arc, Mutex};

/// The small run every test makes: sizes lavapipe gets through in seconds.
fn small_args() -> Args {
    Args {
        keypoints: 48,
        points: Some(32),
        backend: "both".into(),
        weights: None,
        repeat: 1,
        seed: 3,
        json: true,
        peak_tflops: Some(2.5),
        pair_points: 3000,
        pose_graph: None,
        full_sizes: false,
        gemm_sweep: false,
        gemm_rows: None,
    }
}

/// `dpr-gpu bench` with `args` as the command line would pass them, plus `env`; (status, stdout, stderr).
fn run_bench(args: &Args, env: &[(&str, &str)]) -> (bool, String, String) {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_dpr-gpu"));
    cmd.args(["bench", "--json", "--backend", &args.backend]);
    for (flag, value) in [
        ("--keypoints", args.keypoints.to_string()),
        ("--points", args.points.expect("set").to_string()),
        ("--repeat", args.repeat.to_string()),
        ("--seed", args.seed.to_string()),
        ("--peak-tflops", args.peak_tflops.expect("set").to_string()),
        ("--pair-points", args.pair_points.to_string()),
    ] {
        cmd.args([flag, &value]);
    }
    for (k, v) in env {
        cmd.env(k, v);
    }
    let out = cmd.output().expect("runs dpr-gpu");
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}

fn parse(stdout: &str, stderr: &str) -> Value {
    serde_json::from_str(stdout)
        .unwrap_or_else(|e| panic!("stdout is not one JSON document ({e}):\n{stdout}\n{stderr}"))
}

fn num(v: &Value, what: &str) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("{what} is not a number: {v}"))
}

fn uint(v: &Value, what: &str) -> u64 {
    v.as_u64().unwrap_or_else(|| panic!("{what} is not an unsigned integer: {v}"))
}

/// A time in ms: finite and not negative.
fn time_ms(v: &Value, what: &str) -> f64 {
    let t = num(v, what);
    assert!(t.is_finite() && t >= 0.0, "{what} = {t}");
    t
}

fn assert_rel(a: f64, b: f64, what: &str) {
    assert!((a - b).abs() <= 1e-9 * b.abs().max(1e-300), "{what}: {a} vs {b}");
}

/// (host to device, device to host) bytes each GPU stage of the report moves, counted from the sizes in
/// `config` and the buffer layouts of the kernels' host sides: inputs are uploaded once each, results read once.
fn expected_stage_bytes(stage: &str, config: &Value) -> (u64, u64) {
    let c = |k: &str| uint(&config[k], k);
    let (k, p, cw, cand) = (c("keypoints"), c("points_per_patch"), c("codeword"), c("candidates"));
    let hf = HYPOTHESIS_FLOATS as u64;
    match stage {
        // centres + centre normals + points + normals; PPF (4 floats) + PC (3 floats) per point.
        "patch_features" => (2 * 12 * k + 2 * 12 * k * p, (16 + 12) * k * p),
        "encode ppf" => (4 * 4 * k * p, 4 * k * cw),
        "encode pc" => (3 * 4 * k * p, 4 * k * cw),
        // Both codeword sets; three K_MAX lists per source row (distances, indices, mutual flags).
        "match_codewords" => (2 * 4 * k * cw, 3 * 4 * k * K_MAX as u64),
        // Source and target pose features and normals; candidates rotation matrices per row.
        "predict_rotations" => (2 * 4 * k * cw + 2 * 12 * k, 36 * k * cand),
        "hypotheses" => ((36 + 12 + 12) * k * cand, 4 * hf * k * cand),
        "score_hypotheses" => (2 * 12 * k * cand + 4 * hf * k * cand, 8 * k * cand),
        // Activations, weights and gradients are uploaded before timing and the gradients stay on the device.
        "encode_backward ppf" => (0, 0),
        // Per step: both networks' inputs and folding grids, the pose rows, the loss heads' gradients (PPF
        // codewords, raw rotation outputs) up; the per-patch reconstruction losses, the PPF codewords and the raw
        // outputs down. The default model's grid and rotation head (the bench's random weights).
        "train_step" => {
            let (b, m) = (c("train_pairs"), ModelConfig::default().grid_points() as u64);
            let width = ModelConfig::default().rotation_output.width() as u64;
            let up = 2 * b * p * 4 * (4 + 3) + 2 * (2 * b * m * 2 * 4) + 2 * b * 4 + 2 * b * cw * 4 + b * width * 4;
            (up, 2 * (2 * b * 4) + 2 * b * cw * 4 + b * width * 4)
        }
        other => panic!("unexpected stage {other}"),
    }
}

/// Wraps the GPU backend and adds up, for every call, the bytes its inputs and result buffers take: an
/// independent count of what one registration moves. The steps keep a scan's rows on the device: describing
/// uploads the gathered patches and reads nothing back; matching reads back three K_MAX lists per source row;
/// pose features upload the indices of the rows they compute (each row once per scan); verifying uploads the
/// matched normals and points (per rotation candidate for the hypotheses) and reads back a score per
/// hypothesis and the kept hypotheses. A scan stays on the device ([`CountingScan`]): its points (and file normals)
/// go up once, with two words of each cell table's state (one table, or two when normals are estimated), whose
/// grid words and status come back.
struct CountingBackend {
    inner: GpuBackend,
    /// The inner backend's device (ICP's traffic is checked against its counters).
    gpu: Arc<dpr_gpu::gpu::Gpu>,
    /// (host to device, device to host), shared with the test.
    bytes: Arc<Mutex<(u64, u64)>>,
    /// (scan rows, row) whose pose feature has been computed.
    computed: Mutex<HashSet<(usize, u32)>>,
}

/// A device scan, counted per call: sampling a round uploads its keypoint indices, then reads back the
/// candidate counts per keypoint and search-block cell (64 words each); with a kept patch it uploads the
/// per-cell offsets and the kept patches' table (16 bytes each, once to sample and once to describe) and reads
/// back the kept keypoints' positions and normals.
struct CountingScan {
    inner: Box<dyn ScanCloud>,
    bytes: Arc<Mutex<(u64, u64)>>,
}

impl ScanCloud for CountingScan {
    fn describe_keypoints<'a>(
        &'a mut self,
        backend: &'a dyn Backend,
        cloud: &'a mut dpr_gpu::PointCloud,
        keypoints: (&'a [usize], f32),
        seed: u64,
        rows: &'a dyn ScanRows,
        lap: Lap<'a>,
    ) -> dpr_gpu::backend::StepFuture<'a, DescribedKeypoints> {
        Box::pin(async move {
            let out = self.inner.describe_keypoints(backend, cloud, keypoints, seed, rows, lap).await?;
            let (k, p) = (keypoints.0.len() as u64, out.kept.len() as u64);
            let block = dpr_gpu::cpu::patch_sample::BLOCK_CELLS as u64;
            let offsets = if p > 0 { 4 * block * k } else { 0 };
            let mut b = self.bytes.lock().unwrap();
            b.0 += 4 * k + offsets + 2 * 16 * p;
            b.1 += 4 * block * k + 24 * p;
            Ok(out)
        })
    }

    fn farthest_points<'a>(
        &'a self,
        cloud: &'a dpr_gpu::PointCloud,
        count: usize,
        start: usize,
    ) -> dpr_gpu::backend::StepFuture<'a, Vec<usize>> {
        Box::pin(async move {
            let out = self.inner.farthest_points(cloud, count, start).await?;
            // The chosen indices: initialised up, read back.
            let mut b = self.bytes.lock().unwrap();
            b.0 += 4 * count as u64;
            b.1 += 4 * count as u64;
            Ok(out)
        })
    }

    fn complete_normals<'a>(&'a mut self, cloud: &'a mut dpr_gpu::PointCloud) -> dpr_gpu::backend::StepFuture<'a, ()> {
        Box::pin(async move {
            let before = self.inner.normals_complete();
            self.inner.complete_normals(cloud).await?;
            if !before && self.inner.normals_complete() {
                self.bytes.lock().unwrap().1 += 12 * cloud.len() as u64;
            }
            Ok(())
        })
    }

    fn normals_complete(&self) -> bool {
        self.inner.normals_complete()
    }

    fn held_points(&self) -> Option<Arc<dyn dpr_gpu::backend::HeldPoints>> {
        self.inner.held_points()
    }
}

impl CountingBackend {
    fn add(&self, up: usize, down: usize) {
        let mut b = self.bytes.lock().unwrap();
        b.0 += up as u64;
        b.1 += down as u64;
    }

    /// Rows of `which` not computed before (now marked computed).
    fn newly_computed(&self, rows: &dyn ScanRows, which: &[u32]) -> usize {
        let scan = rows as *const dyn ScanRows as *const () as usize;
        let mut done = self.computed.lock().unwrap();
        which.iter().filter(|&&r| done.insert((scan, r))).count()
    }
}

impl Backend for CountingBackend {
    fn name(&self) -> String {
        self.inner.name()
    }

    fn model(&self) -> &Model {
        self.inner.model()
    }

    fn new_scan_rows(&self, capacity: usize) -> dpr_gpu::Result<Arc<dyn ScanRows>> {
        self.inner.new_scan_rows(capacity)
    }

    fn start_scan<'a>(
        &'a self,
        cloud: &'a dpr_gpu::PointCloud,
        settings: &'a ScanSettings,
        lap: Lap<'a>,
    ) -> dpr_gpu::backend::StepFuture<'a, (dpr_gpu::PointCloud, Box<dyn ScanCloud>)> {
        Box::pin(async move {
            assert!(settings.voxel.is_none(), "the count below is for scans that are not downsampled");
            let (host, inner) = self.inner.start_scan(cloud, settings, lap).await?;
            let n = host.len();
            // File normals go up with the points; estimated ones need a second cell table.
            let (normals, tables) = if host.normals.is_some() { (12 * n, 1) } else { (0, 2) };
            self.add(12 * n + normals + tables * (32 + 4), tables * (32 + 4));
            Ok((host, Box::new(CountingScan { inner, bytes: Arc::clone(&self.bytes) }) as Box<dyn ScanCloud>))
        })
    }

    fn describe<'a>(&'a self, batch: PatchBatch<'a>, rows: &'a dyn ScanRows) -> dpr_gpu::backend::StepFuture<'a, ()> {
        Box::pin(async move {
            self.inner.describe(batch, rows).await?;
            let p = batch.patches();
            self.add(24 * p.centers.len() + 24 * p.points.len(), 0);
            Ok(())
        })
    }

    fn correspond<'a>(&'a self, request: RowMatch<'a>) -> dpr_gpu::backend::StepFuture<'a, Vec<Match>> {
        Box::pin(async move {
            let out = self.inner.correspond(request).await?;
            let ((_, ns), (_, nt)) = (request.source(), request.target());
            if ns > 0 && nt > 0 {
                self.add(0, 3 * 4 * K_MAX * ns);
            }
            Ok(out)
        })
    }

    fn prepare_pose_features<'a>(
        &'a self,
        rows: &'a dyn ScanRows,
        which: &'a [u32],
    ) -> dpr_gpu::backend::StepFuture<'a, ()> {
        Box::pin(async move {
            self.inner.prepare_pose_features(rows, which).await?;
            self.add(4 * self.newly_computed(rows, which), 0);
            Ok(())
        })
    }

    fn verify<'a>(&'a self, request: MatchedRows<'a>) -> dpr_gpu::backend::StepFuture<'a, Verified> {
        Box::pin(async move {
            let out = self.inner.verify(request).await?;
            let (s, t) = (request.source(), request.target());
            let missing = self.newly_computed(s.scan, s.rows) + self.newly_computed(t.scan, t.rows);
            let (c, m) = (request.len(), self.inner.model().config.rotation_output.candidates());
            let rotations = if request.wants_rotations() { 36 * c * m } else { 0 };
            self.add(
                4 * missing + 12 * 2 * c * (2 + m),
                8 * c * m + 4 * HYPOTHESIS_FLOATS * out.best.len() + rotations,
            );
            Ok(out)
        })
    }

    /// ICP on the device: up, the grid words of two cell tables (the target's voxel copy and its ICP grid);
    /// down, the same words and the 28 sums of each iteration, whose count only the loop knows: checked to be
    /// that shape, at most `max_iterations` sums, and counted.
    fn refine_icp<'a>(
        &'a self,
        source: &'a dpr_gpu::pipeline::ScanFeatures,
        target: &'a dpr_gpu::pipeline::ScanFeatures,
        initial: nalgebra::Matrix4<f64>,
        problem: &'a dpr_gpu::estimate::icp::IcpProblem,
    ) -> dpr_gpu::backend::StepFuture<'a, nalgebra::Matrix4<f64>> {
        Box::pin(async move {
            let before = self.gpu.context.transfers();
            let out = self.inner.refine_icp(source, target, initial, problem).await?;
            let moved = self.gpu.context.transfers().since(before);
            let (tables, sums) = (2 * (32 + 4), 28 * 4);
            assert_eq!(moved.host_to_device_bytes, tables, "ICP uploads only grid words (the points are held)");
            let per_iteration = moved.device_to_host_bytes - tables;
            assert!(
                per_iteration.is_multiple_of(sums) && per_iteration / sums <= problem.max_iterations as u64,
                "ICP read back {} bytes",
                moved.device_to_host_bytes
            );
            self.add(tables as usize, moved.device_to_host_bytes as usize);
            Ok(out)
        })
    }

    fn patch_features<'a>(
        &'a self,
        patches: &'a GatheredPatches,
        radius: f32,
    ) -> dpr_gpu::backend::StepFuture<'a, (Vec<f32>, Vec<f32>)> {
        Box::pin(async move {
            let out = self.inner.patch_features(patches, radius).await?;
            self.add(24 * patches.centers.len() + 24 * patches.points.len(), 4 * (out.0.len() + out.1.len()));
            Ok(out)
        })
    }

    fn encode<'a>(&'a self, net: Net, input: &'a [f32], patches: usize) -> dpr_gpu::backend::StepFuture<'a, Vec<f32>> {
        Box::pin(async move {
            let out = self.inner.encode(net, input, patches).await?;
            self.add(4 * input.len(), 4 * out.len());
            Ok(out)
        })
    }

    fn match_codewords<'a>(
        &'a self,
        s: &'a [f32],
        t: &'a [f32],
        dim: usize,
        mode: MatchMode,
    ) -> dpr_gpu::backend::StepFuture<'a, Vec<Match>> {
        Box::pin(async move {
            let out = self.inner.match_codewords(s, t, dim, mode).await?;
            if !s.is_empty() && !t.is_empty() {
                self.add(4 * (s.len() + t.len()), 3 * 4 * K_MAX * (s.len() / dim));
            }
            Ok(out)
        })
    }

    fn predict_rotations<'a>(&'a self, pose: RotationInputs<'a>) -> dpr_gpu::backend::StepFuture<'a, Vec<[f32; 9]>> {
        Box::pin(async move {
            let out = self.inner.predict_rotations(pose).await?;
            let up = 4 * (pose.source.len() + pose.target.len())
                + 12 * (pose.source_normals.len() + pose.target_normals.len());
            self.add(up, 36 * out.len());
            Ok(out)
        })
    }

    fn hypotheses<'a>(
        &'a self,
        r: &'a [[f32; 9]],
        s: &'a [[f32; 3]],
        t: &'a [[f32; 3]],
    ) -> dpr_gpu::backend::StepFuture<'a, Vec<Hypothesis>> {
        Box::pin(async move {
            let out = self.inner.hypotheses(r, s, t).await?;
            self.add(36 * r.len() + 12 * (s.len() + t.len()), 4 * HYPOTHESIS_FLOATS * out.len());
            Ok(out)
        })
    }

    fn score_hypotheses<'a>(
        &'a self,
        h: &'a [Hypothesis],
        s: &'a [[f32; 3]],
        t: &'a [[f32; 3]],
        threshold: f32,
    ) -> dpr_gpu::backend::StepFuture<'a, Vec<HypothesisScore>> {
        Box::pin(async move {
            let out = self.inner.score_hypotheses(h, s, t, threshold).await?;
            self.add(12 * (s.len() + t.len()) + 4 * HYPOTHESIS_FLOATS * h.len(), 8 * out.len());
            Ok(out)
        })
    }
}

#[test]
fn bench_json_on_the_test_adapter_is_consistent() {
    let Some(gpu) = gpu_or_skip() else { return };
    let args = small_args();
    let backend_env = std::env::var("WGPU_BACKEND").unwrap_or_else(|_| "vulkan".into());
    let (ok, stdout, stderr) = run_bench(&args, &[("WGPU_BACKEND", &backend_env)]);
    assert!(ok, "bench failed:\n{stderr}");
    let r = parse(&stdout, &stderr);
    assert_eq!(r["schema"], bench::SCHEMA);
    let config = &r["config"];
    assert_eq!(uint(&config["keypoints"], "keypoints"), 48);
    assert_eq!(uint(&config["points_per_patch"], "points"), 32);
    assert_eq!(num(&config["peak_tflops"], "peak"), 2.5);
    let peak_gflops = 2.5 * 1000.0;

    let g = &r["gpu"];
    assert_eq!(g["available"], true, "{g}");
    assert!(g["note"].is_null());
    let timestamps = g["timestamps"].as_bool().expect("bool");
    assert_eq!(timestamps, gpu.context.has_timestamps(), "the test adapter's TIMESTAMP_QUERY");
    let clock = if timestamps { "gpu_timestamps" } else { "host_wall" };
    assert_eq!(g["clock"], clock);
    assert!(uint(&g["weights_upload_bytes"], "weights bytes") > 0);
    assert!(uint(&r["cpu"]["threads"], "threads") >= 1);

    let stages = r["stages"].as_array().expect("stages");
    let names: Vec<&str> = stages.iter().map(|s| s["stage"].as_str().expect("name")).collect();
    assert_eq!(
        names,
        [
            "patch_features",
            "encode ppf",
            "encode pc",
            "match_codewords",
            "predict_rotations",
            "hypotheses",
            "score_hypotheses",
            "encode_backward ppf",
            "train_step"
        ]
    );
    assert_eq!(uint(&config["backward_patches"], "backward patches"), 48, "min(keypoints, 128)");
    assert_eq!(uint(&config["train_pairs"], "train pairs"), 24, "clamp(keypoints / 2, 1, 32)");
    for s in stages {
        let name = s["stage"].as_str().unwrap();
        let flops = s["flops"].as_f64();
        let cpu_t = &s["cpu"];
        let cpu_wall = time_ms(&cpu_t["wall_ms"], &format!("{name} cpu wall_ms"));
        match flops {
            Some(f) => assert_rel(num(&cpu_t["gflops"], "cpu gflops"), f / (cpu_wall * 1e-3) / 1e9, name),
            None => assert!(cpu_t["gflops"].is_null(), "{name}"),
        }
        let gt = &s["gpu"];
        time_ms(&gt["wall_ms"], &format!("{name} gpu wall_ms"));
        let device = time_ms(&gt["device_ms"], &format!("{name} device_ms"));
        assert_eq!(gt["clock"], clock, "{name}");
        let (up, down) = expected_stage_bytes(name, config);
        assert_eq!(uint(&gt["host_to_device_bytes"], "up"), up, "{name}: bytes uploaded");
        assert_eq!(uint(&gt["device_to_host_bytes"], "down"), down, "{name}: bytes read back");
        assert!(uint(&gt["uniform_bytes"], "uniform") > 0, "{name}: every stage dispatches with parameters");
        match flops {
            Some(f) => {
                let gf = num(&gt["gflops"], "gpu gflops");
                assert_rel(gf, f / (device * 1e-3) / 1e9, &format!("{name} gpu GFLOP/s"));
                assert_rel(num(&gt["peak_fraction"], "peak"), gf / peak_gflops, &format!("{name} peak fraction"));
            }
            None => assert!(gt["gflops"].is_null() && gt["peak_fraction"].is_null(), "{name}"),
        }
    }

    let gemm = r["gemm"].as_array().expect("gemm");
    let variants: Vec<&str> = gemm.iter().map(|v| v["variant"].as_str().unwrap()).collect();
    // The CPU layers the backend runs: the bf16 one for an encoder at bf16, the int8 one for an encoder at int8,
    // else the f32 micro-kernel (`bf16,int8`: both of the first two).
    let cpu_precision = r["cpu"]["precision"].as_str().expect("cpu.precision");
    let want_precision = dpr_gpu::cpu::gemm::EncoderPrecision::from_env().unwrap().0;
    assert_eq!(cpu_precision, want_precision.name(), "the bench times the precision the CPU backend picks");
    // bf16 runs on AMX tiles where the CPU has them (the bench says which unit in `cpu.bf16_unit`).
    let amx = dpr_gpu::cpu::gemm_amx::is_available();
    let selected: Vec<String> = [want_precision.ppf, want_precision.pc]
        .map(|p| match p {
            Precision::Bf16 if amx => "cpu_gemm_bf16_amx".to_string(),
            Precision::Bf16 => "cpu_gemm_bf16".to_string(),
            Precision::Int8 => "cpu_gemm_int8".to_string(),
            Precision::F32 => format!("cpu_gemm_{}", r["cpu"]["gemm_path"].as_str().unwrap()),
        })
        .into();
    let want_unit = want_precision.uses(Precision::Bf16).then_some(if amx { "amx" } else { "vector" });
    assert_eq!(r["cpu"]["bf16_unit"].as_str(), want_unit);
    // The FLOPs of one patch, from the built-in model's widths, each network's own (the bench's random weights
    // have its config): per point every encoder layer and the head's per-point part, per patch the global
    // slice of head 0.
    use dpr_gpu::model::params::{concat_width, encoder_widths, head_widths};
    let c = dpr_gpu::model::Weights::built_in_view().unwrap().config;
    let p = uint(&r["config"]["points_per_patch"], "points") as usize;
    let widths = |first: usize, w: &[usize]| -> usize {
        let mut dims = vec![first];
        dims.extend_from_slice(w);
        dims.windows(2).map(|d| d[0] * d[1]).sum()
    };
    for (key, net) in [("ppf_flops_per_patch", Net::Ppf), ("pc_flops_per_patch", Net::Pc)] {
        let (enc, head) = (encoder_widths(&c, net), head_widths(&c, net));
        let last = *enc.last().unwrap();
        let head_in = concat_width(&c, net) - last;
        let per_point = widths(net.io_width(), enc) + widths(head_in, head);
        let want = 2 * (per_point * p + last * head[0]);
        assert_eq!(num(&r["config"][key], key), want as f64, "{key}");
    }
    // The GPU GEMM the backend runs is the device's (the same selection in this process and the bench's).
    assert_eq!(g["gemm_variant"], gpu.gemm_variant().name());
    let gpu_selected = format!("gpu_dense_{}", gpu.gemm_variant());
    let f32_selected = format!("cpu_gemm_{}", r["cpu"]["gemm_path"].as_str().unwrap());
    for want in [
        selected[0].as_str(),
        selected[1].as_str(),
        f32_selected.as_str(),
        "cpu_gemm_portable",
        "cpu_twin",
        "gpu_dense_portable",
        gpu_selected.as_str(),
    ] {
        assert!(variants.contains(&want), "{want} missing from {variants:?}");
    }
    // Every GPU variant is either measured or listed as unavailable with the adapter's reason, never both.
    let unavailable = r["gemm_unavailable"].as_array().expect("gemm_unavailable");
    for v in GemmVariant::ALL {
        let name = format!("gpu_dense_{v}");
        let listed: Vec<&Value> = unavailable.iter().filter(|u| u["variant"] == name.as_str()).collect();
        match v.unavailable_reason(&gpu.context) {
            None => assert!(variants.contains(&name.as_str()) && listed.is_empty(), "{name} runs here: {variants:?}"),
            Some(reason) => {
                assert!(!variants.contains(&name.as_str()), "{name} cannot run here but was measured");
                assert_eq!(listed.len(), 1, "{name} listed once as unavailable");
                assert_eq!(listed[0]["reason"], reason.as_str(), "{name}");
            }
        }
    }
    for v in gemm {
        let name = v["variant"].as_str().unwrap();
        let (rows, i, o) = (uint(&v["rows"], "rows"), uint(&v["in_dim"], "in"), uint(&v["out_dim"], "out"));
        let flops = num(&v["flops"], "flops");
        assert_eq!(flops, 2.0 * (rows * i * o) as f64, "{name}");
        let t = time_ms(&v["time_ms"], name);
        let gf = num(&v["gflops"], "gflops");
        assert_rel(gf, flops / (t * 1e-3) / 1e9, name);
        let on_gpu = v["device"] == "gpu";
        assert_eq!(v["clock"], if on_gpu { clock } else { "host_wall" }, "{name}");
        assert_eq!(v["used_by_backend"], selected.iter().any(|s| s == name) || name == gpu_selected, "{name}");
        let precision = match name {
            "gpu_dense_coop_f16" => "f16",
            "cpu_gemm_bf16" | "cpu_gemm_bf16_amx" => "bf16",
            "cpu_gemm_int8" => "int8",
            _ => "f32",
        };
        assert_eq!(v["precision"], precision, "{name}");
        if on_gpu {
            assert_rel(num(&v["peak_fraction"], "peak"), gf / peak_gflops, name);
        } else {
            assert!(v["peak_fraction"].is_null(), "{name}: no CPU peak was given");
        }
    }

    // The pair: the same registration in this process through the counting wrapper, on the test adapter.
    let pair = &r["pair"];
    let model = bench::bench_model(&args).unwrap();
    let counted = Arc::new(Mutex::new((0u64, 0u64)));
    let counting = CountingBackend {
        inner: GpuBackend::with_gpu(Arc::clone(&gpu), model).unwrap(),
        gpu: Arc::clone(&gpu),
        bytes: Arc::clone(&counted),
        computed: Mutex::new(HashSet::new()),
    };
    let (source, target) = bench::synthetic_pair(args.seed, args.pair_points);
    let registrar = dpr_gpu::Registrar::with_backend(&bench::pair_settings(&args), Box::new(counting)).unwrap();
    let before = gpu.context.transfers();
    let result = registrar.register(&source, &target).unwrap();
    let moved = gpu.context.transfers().since(before);
    let (up, down) = *counted.lock().unwrap();
    assert!(up > 0 && down > 0, "the registration ran on the GPU");
    assert_eq!(moved.host_to_device_bytes, up, "bytes uploaded by one register call");
    assert_eq!(moved.device_to_host_bytes, down, "bytes read back by one register call");
    // The report's pair is the same registration in the bench process: the same sizes, so the same bytes.
    assert_eq!(uint(&pair["correspondences"], "correspondences"), result.correspondences as u64);
    assert_eq!(uint(&pair["host_to_device_bytes"], "pair up"), up, "{pair}");
    assert_eq!(uint(&pair["device_to_host_bytes"], "pair down"), down, "{pair}");
    assert!(uint(&pair["uniform_bytes"], "pair uniform") > 0);
    assert_eq!(uint(&pair["points_per_scan"], "points"), args.pair_points as u64);
    assert_eq!(pair["clock"], clock);
    let wall = time_ms(&pair["wall_ms"], "pair wall_ms");
    // Start-up, reported apart from the warm figure: the cold first registration (it compiled pipelines: it ran
    // before any other stage) and the device's creation.
    time_ms(&pair["cold_wall_ms"], "pair cold_wall_ms");
    assert!(uint(&pair["cold_pipelines_compiled"], "pipelines compiled by the cold pair") > 0, "{pair}");
    time_ms(&r["gpu"]["create_ms"], "gpu create_ms");
    let device = time_ms(&pair["device_ms"], "pair device_ms");
    if timestamps {
        assert!(device <= wall, "the device time of a pair ({device} ms) fits in its wall time ({wall} ms)");
    }
}

#[test]
fn bench_json_without_an_adapter_says_it_is_cpu_only() {
    let mut args = small_args();
    args.pair_points = 600;
    // No Metal adapter exists on Linux or Windows: the default `--backend both` then times the CPU only.
    let (ok, stdout, stderr) = run_bench(&args, &[("DPR_GPU_BACKEND", "metal")]);
    if cfg!(target_os = "macos") {
        return;
    }
    assert!(ok, "bench failed:\n{stderr}");
    let r = parse(&stdout, &stderr);
    assert_eq!(r["gpu"]["available"], false);
    assert!(r["gpu"]["note"].as_str().expect("a note").contains("CPU only"), "{}", r["gpu"]);
    assert!(r["gpu"]["adapter"].is_null() && r["gpu"]["clock"].is_null());
    for s in r["stages"].as_array().unwrap() {
        assert!(s["gpu"].is_null(), "{s}");
        time_ms(&s["cpu"]["wall_ms"], "cpu wall");
    }
    assert!(r["gemm"].as_array().unwrap().iter().all(|v| v["device"] == "cpu"));
    assert!(r["gpu"]["gemm_variant"].is_null());
    let unavailable: Vec<&str> =
        r["gemm_unavailable"].as_array().unwrap().iter().map(|u| u["variant"].as_str().unwrap()).collect();
    assert_eq!(unavailable, ["gpu_dense_portable", "gpu_dense_fast", "gpu_dense_coop_f16"]);
    let pair = &r["pair"];
    assert!(pair["backend"].as_str().unwrap().starts_with("cpu"), "{pair}");
    assert!(pair["host_to_device_bytes"].is_null() && pair["device_ms"].is_null());
    time_ms(&pair["wall_ms"], "pair wall");
}

#[test]
fn bench_rejects_a_bad_peak() {
    for bad in ["--peak-tflops=-1", "--peak-tflops=0", "--peak-tflops=NaN"] {
        let out = Command::new(env!("CARGO_BIN_EXE_dpr-gpu"))
            .args(["bench", "--json", "--backend", "cpu", "--keypoints", "8", bad])
            .output()
            .unwrap();
        assert!(!out.status.success(), "{bad} accepted");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(stderr.contains("--peak-tflops must be a positive number"), "{bad}: {stderr}");
        assert!(out.stdout.is_empty(), "{bad}: no report on stdout");
    }
}

/// `dpr-gpu bench --gemm-sweep --json --gemm-rows 64` with `cache` as the cache directory, plus `env`.
fn run_sweep(cache: &std::path::Path, env: &[(&str, &str)]) -> (bool, String, String) {
    let backend_env = std::env::var("WGPU_BACKEND").unwrap_or_else(|_| "vulkan".into());
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_dpr-gpu"));
    cmd.args(["bench", "--gemm-sweep", "--json", "--gemm-rows", "64", "--peak-tflops", "2.5"]);
    cmd.env("WGPU_BACKEND", backend_env).env("DPR_GPU_CACHE_DIR", cache).env_remove("DPR_GPU_GEMM");
    for (k, v) in env {
        cmd.env(k, v);
    }
    let out = cmd.output().expect("runs dpr-gpu");
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}

/// The sweep times every variant the adapter runs (every tile of `fast`, every tile of `coop_f16` the workgroup
/// memory holds) on both encoder shapes with consistent figures, records the fastest for the adapter, and a new device then runs the recorded choice unless
/// `DPR_GPU_GEMM` says otherwise; a corrupt choice file is ignored with a warning and replaced.
#[test]
fn gemm_sweep_times_every_variant_and_tile_and_auto_takes_the_recorded_choice() {
    use dpr_gpu::gpu::dense_coop_f16::CoopTile;
    use dpr_gpu::gpu::dense_fast::FastTile;
    use dpr_gpu::gpu::gemm::{GemmChoice, gemm_choice};
    let Some(gpu) = gpu_or_skip() else { return };
    let cache = std::env::temp_dir().join(format!("dpr-gpu-sweep-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&cache);
    let (ok, stdout, stderr) = run_sweep(&cache, &[]);
    assert!(ok, "sweep failed:\n{stderr}");
    let r = parse(&stdout, &stderr);
    assert_eq!(r["schema"], "dpr-gpu-gemm-sweep/1");
    assert_eq!(uint(&r["rows"], "rows"), 64);
    let entries = r["gemm_sweep"].as_array().expect("gemm_sweep");
    let mut want = Vec::new();
    for v in GemmVariant::ALL {
        if v.unavailable_reason(&gpu.context).is_some() {
            assert!(r["unavailable"].as_array().unwrap().iter().any(|u| u["variant"] == v.name()), "{v}");
            continue;
        }
        let tiles: Vec<String> = match v {
            GemmVariant::Fast => FastTile::ALL.iter().map(|t| t.name()).collect(),
            GemmVariant::CoopF16 => CoopTile::ALL
                .iter()
                .filter(|t| t.unavailable_reason(&gpu.context.limits).is_none())
                .map(|t| t.name())
                .collect(),
            GemmVariant::Portable => vec![GemmChoice::of(v).tile_name()],
        };
        for tile in tiles {
            for (i, o) in [(704, 512), (512, 512)] {
                want.push((v.name().to_string(), tile.clone(), i as u64, o as u64));
            }
        }
    }
    let got: Vec<(String, String, u64, u64)> = entries
        .iter()
        .map(|e| {
            let s = |k: &str| e[k].as_str().unwrap().to_string();
            (s("variant"), s("tile"), uint(&e["in_dim"], "in"), uint(&e["out_dim"], "out"))
        })
        .collect();
    assert_eq!(got, want);
    // Per candidate: consistent figures; the best is the smallest total over the shapes.
    let mut totals: Vec<(String, String, f64)> = Vec::new();
    for e in entries {
        let flops = num(&e["flops"], "flops");
        assert_eq!(flops, 2.0 * 64.0 * num(&e["in_dim"], "in") * num(&e["out_dim"], "out"));
        let t = time_ms(&e["time_ms"], "time");
        assert_rel(num(&e["gflops"], "gflops"), flops / (t * 1e-3).max(1e-9) / 1e9, "gflops");
        assert_rel(num(&e["peak_fraction"], "peak"), num(&e["gflops"], "gflops") / 2500.0, "peak fraction");
        let (v, tile) = (e["variant"].as_str().unwrap().to_string(), e["tile"].as_str().unwrap().to_string());
        match totals.iter_mut().find(|(a, b, _)| *a == v && *b == tile) {
            Some(x) => x.2 += t,
            None => totals.push((v, tile, t)),
        }
    }
    let min = totals.iter().map(|x| x.2).fold(f64::INFINITY, f64::min);
    let best = &r["best"];
    let best_total = totals.iter().find(|x| x.0 == best["variant"] && x.1 == best["tile"]).expect("best is swept").2;
    assert_eq!(best_total, min, "the best is the fastest in all");
    // Recorded for this adapter.
    let file = cache.join(gemm_choice::FILE_NAME);
    assert_eq!(r["choice_file"].as_str(), Some(file.to_str().unwrap()));
    assert_eq!(r["recorded"], true);
    let key = r["adapter_key"].as_str().unwrap().to_string();
    assert_eq!(key, gemm_choice::adapter_key(&gpu.context.info));
    let recorded = gemm_choice::read(&file).unwrap().unwrap();
    assert_eq!(recorded.adapters[&key].variant, best["variant"].as_str().unwrap());
    assert_eq!(recorded.adapters[&key].tile, best["tile"].as_str().unwrap());

    // A new device takes the recorded choice: record one the fixed order never picks.
    let small = GemmChoice::fast(FastTile { bm: 1, bn: 1 });
    gemm_choice::record(&file, &key, small, 1.0).unwrap();
    let (ok, stdout, stderr) = run_sweep(&cache, &[]);
    assert!(ok, "{stderr}");
    assert_eq!(parse(&stdout, &stderr)["selected_before"], "fast 64x64");
    // The environment wins over the record.
    gemm_choice::record(&file, &key, small, 1.0).unwrap();
    let (ok, stdout, stderr) = run_sweep(&cache, &[("DPR_GPU_GEMM", "portable")]);
    assert!(ok, "{stderr}");
    assert_eq!(parse(&stdout, &stderr)["selected_before"], "portable");
    // A corrupt file: a warning naming it, the fixed order, and the file replaced by the new record.
    std::fs::write(&file, b"{ not json").unwrap();
    let (ok, stdout, stderr) = run_sweep(&cache, &[]);
    assert!(ok, "{stderr}");
    assert!(stderr.contains("warning") && stderr.contains(gemm_choice::FILE_NAME), "{stderr}");
    let r = parse(&stdout, &stderr);
    let fixed = if GemmVariant::CoopF16.unavailable_reason(&gpu.context).is_none() {
        "coop_f16 64x64/4sg"
    } else {
        "fast 128x128"
    };
    assert_eq!(r["selected_before"], fixed);
    assert!(gemm_choice::read(&file).unwrap().unwrap().adapters.contains_key(&key));
    let _ = std::fs::remove_dir_all(&cache);
}
