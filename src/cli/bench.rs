//! `dpr-gpu bench`: times every learned or massively parallel stage on synthetic inputs of a realistic shape
//! (K keypoints x P points per patch), on the GPU backend and/or the CPU reference, the dense GEMM on its own
//! (every CPU micro-kernel, the readable twin, each WGSL GEMM variant) in GFLOP/s, and one synthetic pair registered
//! end to end: cold (a new `Registrar`'s first registration, measured before anything else, so on the GPU it
//! compiles its pipelines) and warm (the `Registrar` reused), beside the device's creation time; prints a table,
//! or with `--json` one JSON document ([`Report`], schema [`SCHEMA`]).
//!
//! GPU stages report the wall time of the backend call (upload, dispatches, readback) and the device time:
//! the GPU timestamps of the submissions' compute passes where the adapter has `TIMESTAMP_QUERY`
//! (`clock: gpu_timestamps`), else the host wall time (`clock: host_wall`), and the bytes moved between host
//! and device by one call (counted by the GPU context where buffers are written and read back). Each stage
//! runs once untimed (warm-up; its traffic is what is reported), then `--repeat` times; the fastest run is
//! reported. GFLOP/s = flops / time, with the device time on the GPU; `--peak-tflops` (the adapter does not
//! report its peak) adds `peak_fraction = gflops / (peak_tflops * 1000)` to GPU figures.

use crate::backend::{Backend, CpuBackend, RotationInputs};
use crate::cpu::dense::{DenseShape, dense as dense_twin};
use crate::cpu::gemm::{EncoderPrecision, GemmPath, Precision, dense_on};
use crate::cpu::gemm_bf16::Bf16Unit;
use crate::cpu::hypotheses::Hypothesis;
use crate::gpu::context::Transfers;
use crate::gpu::{Gpu, GpuBackend, buffer::GpuBuffer, dense as gpu_dense, gemm::GemmVariant, recorder::Recorder};
use crate::model::{FoldNet, Model, Net, Weights};
use crate::preprocess::GatheredPatches;
use crate::rng::Rng;
use crate::settings::MatchMode;
use crate::train::PairSample;
use crate::{PointCloud, Registrar, RegistrationSettings};
use anyhow::{Context, bail};
use rayon::prelude::*;
use serde::Serialize;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// The `schema` field of the JSON report; bumped when a field changes meaning or goes away.
pub const SCHEMA: &str = "dpr-gpu-bench/2";

/// Arguments of `dpr-gpu bench`.
#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    /// Keypoints (patches) per scan; also the number of correspondences and hypotheses [default: 1000; 16 on a
    /// software adapter, see --full-sizes].
    #[arg(long, default_value_t = DEFAULT_KEYPOINTS, hide_default_value = true)]
    pub keypoints: usize,
    /// Points per patch (default: the model's, 256 for the default configuration; 32 on a software adapter).
    #[arg(long)]
    pub points: Option<usize>,
    /// Backends to time: gpu, cpu or both.
    #[arg(long, default_value = "both")]
    pub backend: String,
    /// Weights file; default: seeded random weights of the built-in model's configuration (its pruned widths;
    /// times do not depend on the values).
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// Timed repetitions per stage (the fastest is reported) [default: 3; 1 on a software adapter].
    #[arg(long, default_value_t = DEFAULT_REPEAT, hide_default_value = true)]
    pub repeat: usize,
    /// Seed of the synthetic inputs.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Print one JSON document (schema `dpr-gpu-bench/2`, fields in docs/gpu.md) on stdout instead of the table.
    #[arg(long)]
    pub json: bool,
    /// The GPU's peak f32 throughput in TFLOP/s, from its datasheet (adapters do not report it): GPU GFLOP/s
    /// figures then also give the fraction of that peak.
    #[arg(long)]
    pub peak_tflops: Option<f64>,
    /// Points per scan of the synthetic pair registered end to end (per-pair bytes and times); 0 skips it
    /// [default: 20000; 2000 on a software adapter].
    #[arg(long, default_value_t = DEFAULT_PAIR_POINTS, hide_default_value = true)]
    pub pair_points: usize,
    /// On a software adapter (a CPU device such as llvmpipe/lavapipe), keep the hardware defaults: without it,
    /// each size left at its default is cut (keypoints, points per patch, the end-to-end pair, the training
    /// batch, the repetitions) so that the run takes seconds, not many minutes, and the cut is reported.
    #[arg(long)]
    pub full_sizes: bool,
    /// Time only the GEMM kernels: every variant the adapter runs and every tile shape of `fast`, on the
    /// encoders' 704 -> 512 and 512 -> 512 layers, and record the fastest for this adapter in the GEMM choice
    /// file, which GEMM auto then takes (docs/gpu.md, "Choosing the GEMM").
    #[arg(long)]
    pub gemm_sweep: bool,
    /// Rows of each `--gemm-sweep` layer [default: 32768; 512 on a software adapter].
    #[arg(long, value_name = "N")]
    pub gemm_rows: Option<usize>,
    /// Time the pose-graph optimiser on this g2o file instead (reading, chordal start, Levenberg-Marquardt).
    #[arg(long, value_name = "FILE")]
    pub pose_graph: Option<PathBuf>,
}

/// Which clock a device time comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Clock {
    /// GPU timestamps around the compute passes of each submission, summed over the call's submissions.
    GpuTimestamps,
    /// Host wall time of the whole call (the adapter has no `TIMESTAMP_QUERY`, or the figure is a CPU one).
    HostWall,
}

/// The whole report (`--json`).
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// [`SCHEMA`].
    pub schema: &'static str,
    /// What was measured.
    pub config: Config,
    /// The CPU side, when timed.
    pub cpu: Option<CpuInfo>,
    /// The GPU side: whether one was measured, and why not.
    pub gpu: GpuInfo,
    /// One entry per stage, in pipeline order.
    pub stages: Vec<StageReport>,
    /// The dense GEMM on its own, one entry per variant measured.
    pub gemm: Vec<GemmReport>,
    /// GPU GEMM variants not measured, with the reason (the adapter cannot run them, or no GPU).
    pub gemm_unavailable: Vec<GemmUnavailable>,
    /// One synthetic pair registered end to end, unless `--pair-points 0`.
    pub pair: Option<PairReport>,
}

/// The sizes and options of the run.
#[derive(Clone, Debug, Serialize)]
pub struct Config {
    /// Keypoints per scan (K): patches, correspondences.
    pub keypoints: usize,
    /// Points per patch (P).
    pub points_per_patch: usize,
    /// Codeword length.
    pub codeword: usize,
    /// Rotations per correspondence (hypotheses = K x candidates).
    pub candidates: usize,
    /// Timed repetitions per stage.
    pub repeat: usize,
    /// Seed of the synthetic inputs.
    pub seed: u64,
    /// The weights file, or `None` for seeded random weights.
    pub weights: Option<String>,
    /// `--peak-tflops`.
    pub peak_tflops: Option<f64>,
    /// Points per scan of the synthetic pair.
    pub pair_points: usize,
    /// Patches of the `encode_backward ppf` stage: `min(keypoints, 128)`, a training batch's size.
    pub backward_patches: usize,
    /// Pairs of the `train_step` batch: `clamp(keypoints / 2, 1, 32)` (32: the trainer's default batch; 2 on a
    /// software adapter at the default keypoints, unless `--full-sizes`).
    pub train_pairs: usize,
    /// Whether the sizes left at their defaults were cut for a software adapter (`--full-sizes` keeps them).
    pub sizes_cut: bool,
    /// Dense FLOPs of one PPF-FoldNet patch at `points_per_patch` points (what `encode ppf` divides).
    pub ppf_flops_per_patch: f64,
    /// Dense FLOPs of one PC-FoldNet patch.
    pub pc_flops_per_patch: f64,
}

/// The CPU the reference ran on.
#[derive(Clone, Debug, Serialize)]
pub struct CpuInfo {
    /// Rayon threads.
    pub threads: usize,
    /// The GEMM micro-kernel the CPU backend uses (`avx512`, `avx2`, `portable`).
    pub gemm_path: &'static str,
    /// The arithmetic of the encoders on the CPU (`EncoderPrecision::choose`: `bf16` on AMX tiles, `bf16,int8`
    /// (PPF-FoldNet bf16, PC-FoldNet int8) where the CPU has AVX-512 BF16 and VNNI, else `bf16`, `int8` or
    /// `f32`; `DPR_GPU_CPU_PRECISION` overrides it); the training stages take bf16 where PPF-FoldNet's is int8.
    pub precision: String,
    /// Where the bf16 multiplies run (`amx` tiles or the `vector` unit); `None` in f32.
    pub bf16_unit: Option<&'static str>,
}

/// The GPU the kernels ran on, or why none did.
#[derive(Clone, Debug, Serialize)]
pub struct GpuInfo {
    /// Whether GPU figures were measured.
    pub available: bool,
    /// Adapter name, backend, type and driver.
    pub adapter: Option<String>,
    /// Whether the adapter has `TIMESTAMP_QUERY`.
    pub timestamps: bool,
    /// The GPU GEMM variant the backend's dense layers run (`portable`, `fast`, `coop_f16`).
    pub gemm_variant: Option<&'static str>,
    /// The clock of the GPU device times (`None` without a GPU).
    pub clock: Option<Clock>,
    /// Bytes uploaded once for the model's weights (not part of any stage).
    pub weights_upload_bytes: Option<u64>,
    /// Wall time of creating the device (`Gpu::new`: adapter, device, pipeline cache; the pipelines are compiled
    /// on first use), ms.
    pub create_ms: Option<f64>,
    /// Why no GPU was measured (`None` when one was).
    pub note: Option<String>,
}

/// One stage on each backend.
#[derive(Clone, Debug, Serialize)]
pub struct StageReport {
    /// Stage name (`patch_features`, `encode ppf`, ...).
    pub stage: String,
    /// Floating-point operations of one call, for the stages that are GEMM-bound.
    pub flops: Option<f64>,
    /// The CPU reference, when timed.
    pub cpu: Option<CpuTiming>,
    /// The GPU backend, when timed.
    pub gpu: Option<GpuTiming>,
}

/// A CPU figure.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct CpuTiming {
    /// Fastest wall time of one call, ms.
    pub wall_ms: f64,
    /// `flops / wall`, GFLOP/s.
    pub gflops: Option<f64>,
}

/// A GPU figure.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct GpuTiming {
    /// Fastest wall time of one call (upload, dispatches, readback), ms.
    pub wall_ms: f64,
    /// Fastest device time of one call, ms, on `clock`.
    pub device_ms: f64,
    /// Where `device_ms` comes from.
    pub clock: Clock,
    /// Bytes moved by one call.
    #[serde(flatten)]
    pub transfers: Transfers,
    /// `flops / device time`, GFLOP/s.
    pub gflops: Option<f64>,
    /// `gflops / (peak_tflops * 1000)`.
    pub peak_fraction: Option<f64>,
}

/// One GEMM variant.
#[derive(Clone, Debug, Serialize)]
pub struct GemmReport {
    /// `cpu_gemm_<path>` (the CPU backend's kernel on each micro-kernel this CPU has), `cpu_twin` (the readable
    /// twin), `gpu_dense_<variant>` (each WGSL GEMM variant the adapter runs: `portable`, `fast`, `coop_f16`).
    pub variant: String,
    /// Input precision of the products: `f32`, or `f16` (f32 accumulation).
    pub precision: &'static str,
    /// `cpu` or `gpu`.
    pub device: &'static str,
    /// Whether this is the variant the backend runs.
    pub used_by_backend: bool,
    /// The layer and its time.
    #[serde(flatten)]
    pub timing: GemmTiming,
}

/// One dense layer's shape and fastest time: the fields every GEMM row shares (`bench` and `--gemm-sweep`).
#[derive(Clone, Debug, Serialize)]
pub struct GemmTiming {
    /// Rows of the layer.
    pub rows: usize,
    /// Input width.
    pub in_dim: usize,
    /// Output width.
    pub out_dim: usize,
    /// `2 x rows x in_dim x out_dim`.
    pub flops: f64,
    /// Fastest time, ms, on `clock`.
    pub time_ms: f64,
    /// Where `time_ms` comes from.
    pub clock: Clock,
    /// `flops / time`, GFLOP/s.
    pub gflops: f64,
    /// `gflops / (peak_tflops * 1000)` with `--peak-tflops` (GPU rows only).
    pub peak_fraction: Option<f64>,
}

impl GemmTiming {
    /// A `rows x in_dim -> out_dim` layer timed at `time_ms` on `clock`; the peak fraction where `peak_tflops`
    /// is given.
    pub fn new(
        (rows, in_dim, out_dim): (usize, usize, usize),
        time_ms: f64,
        clock: Clock,
        peak_tflops: Option<f64>,
    ) -> GemmTiming {
        let flops = 2.0 * (rows * in_dim * out_dim) as f64;
        let g = gflops(flops, time_ms);
        GemmTiming {
            rows,
            in_dim,
            out_dim,
            flops,
            time_ms,
            clock,
            gflops: g,
            peak_fraction: peak_fraction(Some(g), peak_tflops),
        }
    }
}

/// A GPU GEMM variant that was not measured.
#[derive(Clone, Debug, Serialize)]
pub struct GemmUnavailable {
    /// `gpu_dense_<variant>`.
    pub variant: String,
    /// Why it was not measured.
    pub reason: String,
}

/// One pair registered end to end (`Registrar::register`: preprocessing on the CPU, the stages on the backend).
#[derive(Clone, Debug, Serialize)]
pub struct PairReport {
    /// The backend's name.
    pub backend: String,
    /// Points per scan.
    pub points_per_scan: usize,
    /// Keypoints per scan.
    pub keypoints: usize,
    /// Correspondences found.
    pub correspondences: usize,
    /// Warm: the fastest wall time of the whole registration over `--repeat` registrations reusing the
    /// `Registrar` after the first, ms.
    pub wall_ms: f64,
    /// Cold: the wall time of the first registration of a new `Registrar`, ms. It is measured before any other
    /// stage, so on the GPU it includes compiling the pipelines the registration dispatches (through the
    /// driver's pipeline cache, where it has one).
    pub cold_wall_ms: f64,
    /// Pipelines the first registration compiled (`None` on the CPU).
    pub cold_pipelines_compiled: Option<usize>,
    /// Device time of the GPU stages, ms (`None` on the CPU).
    pub device_ms: Option<f64>,
    /// Where `device_ms` comes from.
    pub clock: Option<Clock>,
    /// Bytes from host to device for the pair (`None` on the CPU).
    pub host_to_device_bytes: Option<u64>,
    /// Bytes from device to host for the pair.
    pub device_to_host_bytes: Option<u64>,
    /// Uniform parameter bytes for the pair.
    pub uniform_bytes: Option<u64>,
}

/// The best times of one measured call, and the traffic of one call.
#[derive(Clone, Copy, Debug)]
pub(super) struct Measured {
    /// The untimed first call's wall time (the cold one: what a first call pays once).
    first: Duration,
    wall: Duration,
    device: Option<Duration>,
    transfers: Option<Transfers>,
}

/// Runs `f` once untimed (warm-up; its GPU traffic is recorded), then `repeat` times: the fastest wall and
/// device times.
pub(super) fn measure<T>(
    repeat: usize,
    gpu: Option<&Gpu>,
    mut f: impl FnMut() -> anyhow::Result<T>,
) -> anyhow::Result<Measured> {
    let before = gpu.map(|g| g.context.transfers());
    let start = Instant::now();
    f()?;
    let first = start.elapsed();
    let transfers = gpu.zip(before).map(|(g, b)| g.context.transfers().since(b));
    let mut best = Measured { first, wall: Duration::MAX, device: None, transfers };
    for _ in 0..repeat.max(1) {
        if let Some(g) = gpu {
            g.take_gpu_time();
        }
        let start = Instant::now();
        f()?;
        best.wall = best.wall.min(start.elapsed());
        if let Some(d) = gpu.and_then(Gpu::take_gpu_time) {
            best.device = Some(best.device.map_or(d, |b| b.min(d)));
        }
    }
    Ok(best)
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// `flops / ms` in GFLOP/s (a zero time counts as 1 ns).
pub(super) fn gflops(flops: f64, ms: f64) -> f64 {
    flops / (ms * 1e-3).max(1e-9) / 1e9
}

pub(super) fn peak_fraction(gflops: Option<f64>, peak_tflops: Option<f64>) -> Option<f64> {
    Some(gflops? / (peak_tflops? * 1e3))
}

fn cpu_timing(m: Measured, flops: Option<f64>) -> CpuTiming {
    let wall_ms = ms(m.wall);
    CpuTiming { wall_ms, gflops: flops.map(|f| gflops(f, wall_ms)) }
}

pub(super) fn gpu_timing(m: Measured, flops: Option<f64>, peak_tflops: Option<f64>) -> GpuTiming {
    let (device_ms, clock) = match m.device {
        Some(d) => (ms(d), Clock::GpuTimestamps),
        None => (ms(m.wall), Clock::HostWall),
    };
    let g = flops.map(|f| gflops(f, device_ms));
    GpuTiming {
        wall_ms: ms(m.wall),
        device_ms,
        clock,
        transfers: m.transfers.unwrap_or_default(),
        gflops: g,
        peak_fraction: peak_fraction(g, peak_tflops),
    }
}

/// Dense FLOPs of one encoder pass over `patches` patches of `points` points (the per-patch global slice of
/// the first head layer counted per patch, as computed).
pub(super) fn encode_flops(f: &FoldNet, patches: usize, points: usize) -> f64 {
    let per_point: usize = f.encoder.iter().chain(&f.head[1..]).map(|l| l.in_dim * l.out_dim).sum::<usize>()
        + f.head.first().map_or(0, |h| (h.in_dim - f.encoder.last().map_or(0, |l| l.out_dim)) * h.out_dim);
    let per_patch = f.head.first().map_or(0, |h| f.encoder.last().map_or(0, |l| l.out_dim) * h.out_dim);
    2.0 * (per_point * points * patches + per_patch * patches) as f64
}

/// Synthetic gathered patches: K centres in a 5 m box, P neighbours within `radius`, random unit normals.
fn synthetic_patches(rng: &mut Rng, k: usize, p: usize, radius: f32) -> GatheredPatches {
    let unit = |rng: &mut Rng| {
        let v = [0; 3].map(|_: i32| rng.normal() as f32);
        let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().max(1e-6);
        v.map(|c| c / n)
    };
    let centers: Vec<[f32; 3]> = (0..k).map(|_| [0; 3].map(|_: i32| rng.uniform(-2.5, 2.5) as f32)).collect();
    let mut points = Vec::with_capacity(k * p);
    for c in &centers {
        for _ in 0..p {
            let d = unit(rng);
            let r = rng.uniform(0.0, f64::from(radius)) as f32;
            points.push([c[0] + d[0] * r, c[1] + d[1] * r, c[2] + d[2] * r]);
        }
    }
    GatheredPatches {
        center_normals: (0..k).map(|_| unit(rng)).collect(),
        normals: (0..k * p).map(|_| unit(rng)).collect(),
        centers,
        points,
    }
}

/// Two scans of a synthetic room corner (floor, two walls, a box, a sphere; about 4 m across), `points` each,
/// sampled independently; the target is moved by a seeded rigid pose. For the end-to-end pair of the benchmark.
pub fn synthetic_pair(seed: u64, points: usize) -> (PointCloud, PointCloud) {
    let scan = |rng: &mut Rng| -> Vec<[f32; 3]> {
        (0..points)
            .map(|i| {
                let (u, v) = (rng.unit_f64(), rng.unit_f64());
                let p = match i % 5 {
                    0 => [4.0 * u, 4.0 * v, 0.0],
                    1 => [4.0 * u, 0.0, 2.5 * v],
                    2 => [0.0, 4.0 * u, 2.5 * v],
                    3 => [1.5 + 0.8 * u, 1.2 + 0.6 * v, 0.9],
                    _ => {
                        let (th, z) = (std::f64::consts::TAU * u, 2.0 * v - 1.0);
                        let r = (1.0 - z * z).sqrt() * 0.4;
                        [1.0 + r * th.cos(), 2.6 + r * th.sin(), 0.4 + 0.4 * z]
                    }
                };
                p.map(|c| c as f32)
            })
            .collect()
    };
    let mut rng = Rng::new(seed ^ 0x5041_4952);
    let source = scan(&mut rng);
    let target = scan(&mut rng);
    let q = rng.unit_quaternion();
    let r = crate::pose::matrix_from_quaternion(q);
    let t = [0; 3].map(|_: i32| rng.uniform(-1.0, 1.0));
    let moved = target
        .iter()
        .map(|p| {
            let p = p.map(f64::from);
            [0, 1, 2].map(|a| (r[(a, 0)] * p[0] + r[(a, 1)] * p[1] + r[(a, 2)] * p[2] + t[a]) as f32)
        })
        .collect();
    (PointCloud::from_points(source), PointCloud::from_points(moved))
}

/// The model `args` describe: the weights file or seeded random weights, with `--points` applied.
pub fn bench_model(args: &Args) -> anyhow::Result<Model> {
    model_of(&bench_weights(args)?, args)
}

/// The weights `bench` times: `--weights`, or seeded random weights of the built-in model's configuration.
pub fn bench_weights(args: &Args) -> anyhow::Result<Weights> {
    Ok(match &args.weights {
        Some(path) => Weights::load(path).with_context(|| format!("loading {}", path.display()))?,
        None => Weights::init(&Weights::built_in_view()?.config, args.seed)?,
    })
}

/// The model of `weights`, with `--points` points per patch.
fn model_of(weights: &Weights, args: &Args) -> anyhow::Result<Model> {
    let mut model = Model::from_weights(weights)?;
    if let Some(p) = args.points {
        model.config.points_per_patch = p;
    }
    Ok(model)
}

/// The settings of the end-to-end pair: the defaults with `--keypoints` and `--seed`, every point kept (no
/// voxel downsampling, which the defaults apply to clouds without normals) so a scan has exactly the points the
/// report names.
pub fn pair_settings(args: &Args) -> RegistrationSettings {
    RegistrationSettings { keypoints: args.keypoints, seed: args.seed, voxel: Some(0.0), ..Default::default() }
}

/// Most timed repetitions.
pub const MAX_REPEAT: usize = 1_000;

/// Most points per scan of the end-to-end pair.
pub const MAX_PAIR_POINTS: usize = 2_000_000;

/// Checks the sizes against their bounds before anything is allocated: keypoints and points per patch as for
/// `register` (at most [`crate::settings::MAX_KEYPOINTS`], [`crate::model::config::MAX_POINTS_PER_PATCH`],
/// and [`crate::pipeline::MAX_PATCH_POINTS`] in all).
fn check_bounds(args: &Args) -> anyhow::Result<()> {
    use crate::model::config::MAX_POINTS_PER_PATCH;
    use crate::settings::MAX_KEYPOINTS;
    if !(1..=MAX_KEYPOINTS).contains(&args.keypoints) {
        bail!("--keypoints must be 1..={MAX_KEYPOINTS}, got {}", args.keypoints);
    }
    if let Some(p) = args.points
        && !(1..=MAX_POINTS_PER_PATCH).contains(&p)
    {
        bail!("--points must be 1..={MAX_POINTS_PER_PATCH}, got {p}");
    }
    let total = args.keypoints.saturating_mul(args.points.unwrap_or(2048));
    if total > crate::pipeline::MAX_PATCH_POINTS {
        bail!("--keypoints x --points = {total} patch points, over the limit of {}", crate::pipeline::MAX_PATCH_POINTS);
    }
    if args.repeat > MAX_REPEAT {
        bail!("--repeat must be at most {MAX_REPEAT}, got {}", args.repeat);
    }
    if let Some(p) = args.peak_tflops
        && !(p.is_finite() && p > 0.0)
    {
        bail!("--peak-tflops must be a positive number of TFLOP/s, got {p}");
    }
    if args.pair_points > MAX_PAIR_POINTS {
        bail!("--pair-points must be at most {MAX_PAIR_POINTS}, got {}", args.pair_points);
    }
    Ok(())
}

/// Runs `dpr-gpu bench`: the table, or with `--json` the [`Report`] on stdout (`--gemm-sweep` runs
/// [`super::bench_gemm_sweep::run`] instead; the command dispatch picks it, so this module need not import it).
pub fn run(args: Args) -> anyhow::Result<()> {
    if let Some(path) = &args.pose_graph {
        return super::bench_pose_graph::run(path, args.repeat, args.json);
    }
    let report = measure_all(&args)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print_report(&report);
    }
    Ok(())
}

/// Measures everything `args` ask for (what `dpr-gpu bench` prints). With `--json`, progress notes go to
/// stderr (the table repeats them otherwise).
pub fn measure_all(args: &Args) -> anyhow::Result<Report> {
    let note = |text: String| {
        if args.json {
            eprintln!("{text}");
        }
    };
    let (use_cpu, use_gpu) = requested_backends(args)?;
    check_bounds(args)?;
    if args.points == Some(0) {
        bail!("--points must be at least 1");
    }
    let started = Instant::now();
    let device = open_device((use_cpu, use_gpu))?;
    let create_ms = device.is_ok().then(|| ms(started.elapsed()));
    let sizes = Sizes::for_device(args, &device);
    if let Some(cut) = &sizes.cut {
        eprintln!("{cut}");
    }
    let args = &sizes.args;
    let weights = bench_weights(args)?;
    let model = model_of(&weights, args)?;
    let (k, p) = (args.keypoints, model.config.points_per_patch);
    let cw = model.config.codeword();
    let peak = args.peak_tflops;
    note(format!(
        "dpr-gpu bench: {k} keypoints x {p} points per patch, codeword {cw}, best of {} runs",
        args.repeat.max(1)
    ));

    let (precision, _) = EncoderPrecision::from_env()?;
    let cpu = use_cpu.then(|| CpuBackend::with_precision(model.clone(), precision)).transpose()?;
    let (gpu, mut info) = open_gpu(&model, device, &note)?;
    info.create_ms = create_ms;
    // The pair first, so that its first registration is a process's cold one (it compiles its pipelines).
    let pair = if args.pair_points == 0 {
        None
    } else {
        let backend: Box<dyn Backend> = match &gpu {
            Some(g) => Box::new(GpuBackend::with_gpu(Arc::clone(g.gpu_arc()), model.clone())?),
            None => Box::new(CpuBackend::with_precision(model.clone(), precision)?),
        };
        Some(measure_pair(args, backend, gpu.as_ref().map(GpuBackend::gpu))?)
    };
    let cpu_info = cpu.as_ref().map(|_| CpuInfo {
        threads: rayon::current_num_threads(),
        gemm_path: GemmPath::selected().name(),
        precision: precision.name(),
        bf16_unit: precision.uses(Precision::Bf16).then(|| match Bf16Unit::default().effective() {
            Bf16Unit::Tiles => "amx",
            Bf16Unit::Vector => "vector",
        }),
    });

    let reference: &dyn Backend = match (&gpu, &cpu) {
        (Some(g), _) => g,
        (None, Some(c)) => c,
        (None, None) => unreachable!("at least one backend"),
    };
    let inputs = BenchInputs::new(args.seed, reference, &model, k)?;
    let (ppf, pc) = (&inputs.ppf, &inputs.pc);
    let mut stages = measure_stages(args, &model, &inputs, cpu.as_ref(), gpu.as_ref())?;
    let backward_patches = k.min(BACKWARD_PATCHES);
    // The training stages at the trainer's precision (int8 is for inference).
    let cpu_precision = cpu.is_some().then_some(precision.for_training());
    stages.push(measure_encode_backward(args, &weights, &model, ppf, backward_patches, cpu_precision, gpu.as_ref())?);
    let train_pairs = (k / 2).clamp(1, sizes.train_pairs);
    let batch = train_batch(args.seed, &model, [ppf, pc], k, train_pairs);
    // The weights as the model runs them (`--points` changes no tensor).
    let train_weights = Weights { config: model.config.clone(), ..weights.clone() };
    stages.push(measure_train_step(args, &train_weights, &batch, cpu_precision, gpu.as_ref())?);
    let (gemm, gemm_unavailable) =
        gemm_variants(args, gpu.as_ref().map(GpuBackend::gpu), use_cpu.then_some(precision), k * p)?;
    let config = Config {
        keypoints: k,
        points_per_patch: p,
        codeword: cw,
        candidates: inputs.candidates,
        repeat: args.repeat.max(1),
        seed: args.seed,
        weights: args.weights.as_ref().map(|w| w.display().to_string()),
        peak_tflops: peak,
        pair_points: args.pair_points,
        backward_patches,
        train_pairs,
        sizes_cut: sizes.cut.is_some(),
        ppf_flops_per_patch: encode_flops(&model.ppf, 1, p),
        pc_flops_per_patch: encode_flops(&model.pc, 1, p),
    };
    Ok(Report { schema: SCHEMA, config, cpu: cpu_info, gpu: info, stages, gemm, gemm_unavailable, pair })
}

/// Which backends `--backend` asks for: (cpu, gpu).
fn requested_backends(args: &Args) -> anyhow::Result<(bool, bool)> {
    Ok(match args.backend.as_str() {
        "cpu" => (true, false),
        "gpu" => (false, true),
        "both" => (true, true),
        other => bail!("--backend must be cpu, gpu or both, got '{other}'"),
    })
}

/// The GPU device when `(use_cpu, use_gpu)` asks for it: with both, its absence is the reason it was not
/// measured (the CPU side still runs), not an error.
fn open_device((use_cpu, use_gpu): (bool, bool)) -> anyhow::Result<Result<Arc<Gpu>, String>> {
    Ok(match (use_gpu, use_cpu) {
        (false, _) => Err("not requested (--backend cpu)".to_string()),
        (true, false) => Ok(Arc::new(Gpu::new().context("creating the GPU backend")?)),
        // The default (`both`): without an adapter, time what exists and say what was not measured.
        (true, true) => Gpu::new().map(Arc::new).map_err(|e| format!("no GPU adapter ({e}); CPU only")),
    })
}

/// The hardware defaults of the sizes a software adapter cuts (`--full-sizes` keeps them).
const DEFAULT_KEYPOINTS: usize = 1000;
pub(super) const DEFAULT_REPEAT: usize = 3;
const DEFAULT_PAIR_POINTS: usize = 20_000;

/// What a software adapter runs instead of each default (a minute or less on two CPU cores; the hardware
/// defaults took over 7 minutes on llvmpipe even at 64 keypoints, most of it the training stages).
const SOFTWARE_KEYPOINTS: usize = 16;
const SOFTWARE_POINTS: usize = 32;
const SOFTWARE_REPEAT: usize = 1;
const SOFTWARE_PAIR_POINTS: usize = 2_000;
const SOFTWARE_TRAIN_PAIRS: usize = 2;

/// The sizes a run measures: the arguments, with the defaults cut on a software adapter.
struct Sizes {
    /// The arguments as measured.
    args: Args,
    /// Most pairs of the `train_step` batch.
    train_pairs: usize,
    /// What was cut and how to keep it, when anything was.
    cut: Option<String>,
}

impl Sizes {
    /// On a software adapter (device type CPU: llvmpipe, lavapipe, WARP) without `--full-sizes`, every size
    /// left at its default is cut to its small value; elsewhere the arguments as given.
    fn for_device(args: &Args, device: &Result<Arc<Gpu>, String>) -> Sizes {
        let mut sized = Sizes { args: args.clone(), train_pairs: TRAIN_PAIRS, cut: None };
        let software = device.as_ref().is_ok_and(|g| g.context.info.device_type == wgpu::DeviceType::Cpu);
        if !software || args.full_sizes {
            return sized;
        }
        let a = &mut sized.args;
        let mut cuts = Vec::new();
        if a.keypoints == DEFAULT_KEYPOINTS {
            // The training batch follows the keypoints (half of them, at most 32 pairs) unless they are given.
            cuts.push(format!("a training batch of {SOFTWARE_TRAIN_PAIRS} pairs"));
            sized.train_pairs = SOFTWARE_TRAIN_PAIRS;
        }
        let mut cut = |name: &str, at_default: bool, small: usize, field: &mut usize| {
            if at_default {
                cuts.push(format!("{name} {small}"));
                *field = small;
            }
        };
        cut("--keypoints", a.keypoints == DEFAULT_KEYPOINTS, SOFTWARE_KEYPOINTS, &mut a.keypoints);
        let mut points = a.points.unwrap_or(SOFTWARE_POINTS);
        cut("--points", a.points.is_none(), SOFTWARE_POINTS, &mut points);
        a.points = Some(points);
        cut("--pair-points", a.pair_points == DEFAULT_PAIR_POINTS, SOFTWARE_PAIR_POINTS, &mut a.pair_points);
        cut("--repeat", a.repeat == DEFAULT_REPEAT, SOFTWARE_REPEAT, &mut a.repeat);
        if cuts.is_empty() {
            return sized;
        }
        sized.cut = Some(format!(
            "bench: a software adapter: the large sizes are skipped, cut to {} (the hardware defaults take many \
             minutes here; --full-sizes keeps them)",
            cuts.join(", ")
        ));
        sized
    }
}

/// The GPU backend on `device` when there is one, and what the report says about the device.
fn open_gpu(
    model: &Model,
    device: Result<Arc<Gpu>, String>,
    note: &dyn Fn(String),
) -> anyhow::Result<(Option<GpuBackend>, GpuInfo)> {
    let mut info = GpuInfo {
        available: false,
        adapter: None,
        timestamps: false,
        gemm_variant: None,
        clock: None,
        weights_upload_bytes: None,
        create_ms: None,
        note: None,
    };
    let gpu = match device {
        Ok(dev) => {
            dev.set_profiling(true);
            let before = dev.context.transfers();
            let backend = GpuBackend::with_gpu(Arc::clone(&dev), model.clone()).context("uploading the weights")?;
            info.weights_upload_bytes = Some(dev.context.transfers().since(before).host_to_device_bytes);
            info.available = true;
            info.adapter = Some(backend.adapter_info());
            info.timestamps = dev.context.has_timestamps();
            info.gemm_variant = Some(dev.gemm_variant().name());
            info.clock = Some(if info.timestamps { Clock::GpuTimestamps } else { Clock::HostWall });
            let clock = if info.timestamps { "GPU timestamps" } else { "host wall time, no TIMESTAMP_QUERY" };
            note(format!("gpu: {} (device times: {clock})", backend.adapter_info()));
            Some(backend)
        }
        Err(reason) => {
            note(format!("gpu: not measured: {reason}"));
            info.note = Some(reason);
            None
        }
    };
    Ok((gpu, info))
}

/// The synthetic inputs of the stages: K patches, their features and codewords (PPF codewords as the source,
/// perturbed copies as the target), pose features, the predicted rotations and one hypothesis per rotation.
struct BenchInputs {
    patches: GatheredPatches,
    ppf: Vec<f32>,
    pc: Vec<f32>,
    source_cw: Vec<f32>,
    target_cw: Vec<f32>,
    pose: Vec<f32>,
    normals: Vec<[f32; 3]>,
    rotations: Vec<[f32; 9]>,
    /// Candidate rotations per correspondence.
    candidates: usize,
    src_pts: Vec<[f32; 3]>,
    tgt_pts: Vec<[f32; 3]>,
    hyps: Vec<Hypothesis>,
}

impl BenchInputs {
    /// The inputs for `k` keypoints from `seed`, encoded by `reference`.
    fn new(seed: u64, reference: &dyn Backend, model: &Model, k: usize) -> anyhow::Result<BenchInputs> {
        let (p, radius) = (model.config.points_per_patch, model.config.radius);
        let mut rng = Rng::new(seed);
        let patches = synthetic_patches(&mut rng, k, p, radius);
        let (ppf, pc) = patches.features(p, radius, model.config.pose_frame);
        let source_cw = crate::block_on(reference.encode(Net::Ppf, &ppf, k))?;
        let target_cw: Vec<f32> = source_cw.iter().map(|v| v + 0.01 * rng.normal() as f32).collect();
        let pose: Vec<f32> =
            crate::model::pose_feature(&crate::block_on(reference.encode(Net::Pc, &pc, k))?, &source_cw);
        let normals = patches.center_normals.clone();
        let rotation_inputs = RotationInputs {
            source: &pose,
            target: &pose,
            source_normals: &normals,
            target_normals: &normals,
            rows: k,
        };
        let rotations = crate::block_on(reference.predict_rotations(rotation_inputs))?;
        // One hypothesis per predicted rotation: each correspondence's points repeat once per candidate rotation.
        let candidates = rotations.len() / k.max(1);
        let centers = patches.centers.iter().flat_map(|&c| std::iter::repeat_n(c, candidates));
        let src_pts: Vec<[f32; 3]> = centers.collect();
        let tgt_pts: Vec<[f32; 3]> = src_pts.iter().map(|q| q.map(|c| c + 0.05 * rng.normal() as f32)).collect();
        let hyps = crate::block_on(reference.hypotheses(&rotations, &src_pts, &tgt_pts))?;
        Ok(BenchInputs {
            patches,
            ppf,
            pc,
            source_cw,
            target_cw,
            pose,
            normals,
            rotations,
            candidates,
            src_pts,
            tgt_pts,
            hyps,
        })
    }
}

/// The per-stage timings on each backend present (the stages `Backend` runs for a pair).
fn measure_stages(
    args: &Args,
    model: &Model,
    inputs: &BenchInputs,
    cpu: Option<&CpuBackend>,
    gpu: Option<&GpuBackend>,
) -> anyhow::Result<Vec<StageReport>> {
    let (k, p, cw) = (args.keypoints, model.config.points_per_patch, model.config.codeword());
    let (radius, peak) = (model.config.radius, args.peak_tflops);
    let BenchInputs {
        patches, ppf, pc, source_cw, target_cw, normals, pose, rotations, src_pts, tgt_pts, hyps, ..
    } = inputs;
    let rotation_inputs =
        RotationInputs { source: pose, target: pose, source_normals: normals, target_normals: normals, rows: k };
    let stage_list: Vec<(&str, Option<f64>)> = vec![
        ("patch_features", None),
        ("encode ppf", Some(encode_flops(&model.ppf, k, p))),
        ("encode pc", Some(encode_flops(&model.pc, k, p))),
        ("match_codewords", Some(3.0 * (k * k * cw) as f64)),
        ("predict_rotations", None),
        ("hypotheses", None),
        ("score_hypotheses", None),
    ];
    let mut stages = Vec::new();
    for (stage, flops) in stage_list {
        let mut row = StageReport { stage: stage.to_string(), flops, cpu: None, gpu: None };
        let backends: [(Option<&dyn Backend>, Option<&Gpu>); 2] =
            [(cpu.map(|c| c as &dyn Backend), None), (gpu.map(|g| g as &dyn Backend), gpu.map(GpuBackend::gpu))];
        for (backend, device) in backends {
            let Some(b) = backend else { continue };
            let m = measure(args.repeat, device, || -> anyhow::Result<()> {
                match stage {
                    "patch_features" => drop(crate::block_on(b.patch_features(patches, radius))?),
                    "encode ppf" => drop(crate::block_on(b.encode(Net::Ppf, ppf, k))?),
                    "encode pc" => drop(crate::block_on(b.encode(Net::Pc, pc, k))?),
                    "match_codewords" => {
                        drop(crate::block_on(b.match_codewords(source_cw, target_cw, cw, MatchMode::Mutual(1)))?)
                    }
                    "predict_rotations" => drop(crate::block_on(b.predict_rotations(rotation_inputs))?),
                    "hypotheses" => drop(crate::block_on(b.hypotheses(rotations, src_pts, tgt_pts))?),
                    _ => drop(crate::block_on(b.score_hypotheses(hyps, src_pts, tgt_pts, radius / 3.0))?),
                }
                Ok(())
            })
            .with_context(|| format!("stage {stage}"))?;
            match device {
                Some(_) => row.gpu = Some(gpu_timing(m, flops, peak)),
                None => row.cpu = Some(cpu_timing(m, flops)),
            }
        }
        stages.push(row);
    }
    Ok(stages)
}

/// Patches of the training stage at most: a training batch (32 pairs x 2 scans x 2 samples) rather than K, so the
/// forward activations it reads fit the smallest storage-binding limit (128 MiB) at 256 points per patch.
const BACKWARD_PATCHES: usize = 128;

/// The training stage `encode_backward ppf`: PPF-FoldNet's encoder backward pass over `patches` of the
/// synthetic patches, from a codeword gradient, on the CPU trainer (`train::backward::encode_backward`, at the
/// CPU's precision `cpu` when it is timed) and on
/// the device (`gpu::backward::record_encode_backward`, activations and weights uploaded before timing, so a
/// call moves no bytes: gradients stay there). Flops: twice the forward's (weight and input gradients).
fn measure_encode_backward(
    args: &Args,
    weights: &Weights,
    model: &Model,
    ppf: &[f32],
    patches: usize,
    cpu: Option<Precision>,
    gpu: Option<&GpuBackend>,
) -> anyhow::Result<StageReport> {
    use crate::gpu::backward::{DeviceEncodeTapeBuffers, DeviceLayerBuffers, record_encode_backward};
    use crate::train::backward::{Gradients, LayerWeights, encode_backward};
    let p = model.config.points_per_patch;
    let net = &model.ppf;
    let input = &ppf[..patches * p * net.encoder[0].in_dim];
    let tape = net.encode_tape(input, patches, p);
    let mut rng = Rng::new(args.seed ^ 0x6261_636b);
    let d_codeword: Vec<f32> = (0..patches * net.codeword_len()).map(|_| rng.normal() as f32).collect();
    let layer_weights = LayerWeights::new(weights)?;
    let flops = Some(2.0 * encode_flops(&model.ppf, patches, p));
    let mut row = StageReport { stage: "encode_backward ppf".into(), flops, cpu: None, gpu: None };
    if let Some(precision) = cpu {
        let cpu_weights = LayerWeights::with_precision(weights, precision)?;
        let m = measure(args.repeat, None, || -> anyhow::Result<()> {
            let mut grads = Gradients::zeros(&weights.config);
            encode_backward(net, &cpu_weights, 0, input, &tape, &d_codeword, &mut grads);
            Ok(())
        })?;
        row.cpu = Some(cpu_timing(m, flops));
    }
    if let Some(backend) = gpu {
        let g = backend.gpu();
        let layer_buffers = DeviceLayerBuffers::upload(&g.context, &layer_weights)?;
        let tape_buffers = DeviceEncodeTapeBuffers::upload(&g.context, input, &tape)?;
        let (layers, device_tape) = (layer_buffers.view(), tape_buffers.view());
        let d_cw = GpuBuffer::from_slice(&g.context, "d codeword", &d_codeword)?;
        let m = measure(args.repeat, Some(g), || -> anyhow::Result<()> {
            let mut rec = Recorder::new(g, "encode backward bench");
            record_encode_backward(&mut rec, net, &layers, 0, &device_tape, d_cw.raw())?;
            crate::block_on(rec.finish())?;
            Ok(())
        })?;
        row.gpu = Some(gpu_timing(m, flops, args.peak_tflops));
    }
    Ok(row)
}

/// Pairs of the `train_step` stage at most: the trainer's default batch.
const TRAIN_PAIRS: usize = 32;

/// A training batch of `pairs` pairs from the synthetic patches (pair i: patches 2i and 2i + 1, mod K), each
/// labelled with a seeded rotation about z (the angle-bin loss is defined for every pair).
fn train_batch(seed: u64, model: &Model, [ppf, pc]: [&[f32]; 2], k: usize, pairs: usize) -> Vec<PairSample> {
    let p = model.config.points_per_patch;
    let mut rng = Rng::new(seed ^ 0x0074_7261_696e);
    let patch = |x: &[f32], width: usize, i: usize| x[(i % k) * p * width..][..p * width].to_vec();
    (0..pairs)
        .map(|i| {
            let a = rng.uniform(-std::f64::consts::PI, std::f64::consts::PI);
            let (c, s) = (a.cos(), a.sin());
            PairSample {
                ppf: [patch(ppf, 4, 2 * i), patch(ppf, 4, 2 * i + 1)].concat(),
                pc: [patch(pc, 3, 2 * i), patch(pc, 3, 2 * i + 1)].concat(),
                label: [c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0],
            }
        })
        .collect()
}

/// The training stage `train_step`: one whole step (every loss term of the recipe, contrastive included; the
/// gradient; AdamW) on `batch`, on the CPU trainer (`batch_objective_at` the CPU's precision `cpu` +
/// `apply_gradients`, as `dpr-gpu train` runs it) and on the device
/// (`gpu::train::DeviceTrainer::step`, on an f32 GEMM: a device of its own where the backend's GEMM is not).
/// Each repetition continues from the last one's weights. The device moves the batch's inputs and the loss
/// heads' values and gradients per step.
fn measure_train_step(
    args: &Args,
    weights: &Weights,
    batch: &[PairSample],
    cpu: Option<Precision>,
    gpu: Option<&GpuBackend>,
) -> anyhow::Result<StageReport> {
    use crate::train::trainer::{apply_gradients, tensor_order};
    use crate::train::{Adam, AdamSettings, LossSettings, batch_objective_at};
    let loss = LossSettings { contrast: true, ..LossSettings::default() };
    let sizes: Vec<usize> = tensor_order(&weights.config).iter().map(|t| t.1).collect();
    let adam = Adam::new(AdamSettings::default(), &sizes);
    let mut row = StageReport { stage: "train_step".into(), flops: None, cpu: None, gpu: None };
    if let Some(precision) = cpu {
        let (mut w, mut a) = (weights.clone(), adam.clone());
        let m = measure(args.repeat, None, || -> anyhow::Result<()> {
            let (_, grads) = batch_objective_at(precision, &w, batch, &loss)?;
            apply_gradients(&mut w, &mut a, &grads)?;
            Ok(())
        })?;
        row.cpu = Some(cpu_timing(m, None));
    }
    if let Some(backend) = gpu {
        let own;
        let g = if backend.gpu().gemm_variant().is_f32() {
            backend.gpu()
        } else {
            own = crate::gpu::train::training_gpu().context("train_step: a device on an f32 GEMM")?;
            &own
        };
        let mut trainer = crate::gpu::train::DeviceTrainer::new(g, weights, loss, &adam)?;
        let m =
            measure(args.repeat, Some(g), || crate::block_on(trainer.step(g, batch)).map(drop).map_err(Into::into))?;
        row.gpu = Some(gpu_timing(m, None, args.peak_tflops));
    }
    Ok(row)
}

/// Registers the synthetic pair with `backend` (on `gpu` when given): fastest wall and device times, and the
/// traffic of one registration.
fn measure_pair(args: &Args, backend: Box<dyn Backend>, gpu: Option<&Gpu>) -> anyhow::Result<PairReport> {
    let (source, target) = synthetic_pair(args.seed, args.pair_points);
    let name = backend.name();
    let registrar = Registrar::with_backend(&pair_settings(args), backend)?;
    let compiled = || gpu.map(|g| g.kernels.iter().count());
    let compiled_before = compiled();
    let mut correspondences = 0;
    let m = measure(args.repeat, gpu, || {
        correspondences = registrar.register(&source, &target)?.correspondences;
        Ok(())
    })
    .context("registering the synthetic pair")?;
    let timing = gpu.map(|_| gpu_timing(m, None, None));
    Ok(PairReport {
        backend: name,
        points_per_scan: args.pair_points,
        keypoints: args.keypoints,
        correspondences,
        wall_ms: ms(m.wall),
        cold_wall_ms: ms(m.first),
        cold_pipelines_compiled: compiled().zip(compiled_before).map(|(after, before)| after - before),
        device_ms: timing.map(|t| t.device_ms),
        clock: timing.map(|t| t.clock),
        host_to_device_bytes: timing.map(|t| t.transfers.host_to_device_bytes),
        device_to_host_bytes: timing.map(|t| t.transfers.device_to_host_bytes),
        uniform_bytes: timing.map(|t| t.transfers.uniform_bytes),
    })
}

/// One dense layer call on a block of rows: (shape of the block, its inputs, its outputs).
type DenseLayer<'a> = dyn Fn(&DenseShape, &[f32], &mut [f32]) + Sync + 'a;

/// The dense GEMM on its own, a 512 -> 512 layer over min(K x P, 32768) rows: the CPU backend's kernel on
/// every micro-kernel this CPU has, the readable twin, and every WGSL GEMM variant the adapter runs; the
/// variants it cannot run (or all of them, without a GPU) are listed with the reason.
fn gemm_variants(
    args: &Args,
    gpu: Option<&Gpu>,
    cpu_precision: Option<EncoderPrecision>,
    rows: usize,
) -> anyhow::Result<(Vec<GemmReport>, Vec<GemmUnavailable>)> {
    let rows = rows.clamp(1, 32_768);
    let (in_dim, out_dim) = (512, 512);
    let mut rng = Rng::new(args.seed ^ 0xD5);
    let mut v = |n: usize| (0..n).map(|_| rng.normal() as f32).collect::<Vec<f32>>();
    let (x, w, b) = (v(rows * in_dim), v(in_dim * out_dim), v(out_dim));
    let shape = DenseShape { rows, in_dim, out_dim, rows_per_group: rows, accumulate: false, relu: true };
    let flops = 2.0 * (rows * in_dim * out_dim) as f64;
    let report = |variant: String, device: &'static str, used: bool, time_ms: f64, clock: Clock| {
        let peak = if device == "gpu" { args.peak_tflops } else { None };
        GemmReport {
            precision: match variant.as_str() {
                "gpu_dense_coop_f16" => "f16",
                "cpu_gemm_bf16" | "cpu_gemm_bf16_amx" => "bf16",
                "cpu_gemm_int8" => "int8",
                _ => "f32",
            },
            variant,
            device,
            used_by_backend: used,
            timing: GemmTiming::new((rows, in_dim, out_dim), time_ms, clock, peak),
        }
    };
    let (mut out, mut unavailable) = (Vec::new(), Vec::new());
    if let Some(precision) = cpu_precision {
        let mut y = vec![0.0f32; rows * out_dim];
        // Parallel over row blocks, as the CPU encoder runs it.
        let mut time_cpu = |layer: &DenseLayer<'_>| {
            measure(args.repeat, None, || {
                y.par_chunks_mut(2048 * out_dim).zip(x.par_chunks(2048 * in_dim)).for_each(|(o, xc)| {
                    let s = DenseShape { rows: xc.len() / in_dim, rows_per_group: xc.len() / in_dim, ..shape };
                    layer(&s, xc, o);
                });
                Ok(())
            })
        };
        let selected = GemmPath::selected();
        let f32_used = precision.uses(Precision::F32);
        for path in GemmPath::available() {
            let m = time_cpu(&|s, xc, o| dense_on(path, s, xc, &w, &b, o))?;
            let used = f32_used && path == selected;
            out.push(report(format!("cpu_gemm_{}", path.name()), "cpu", used, ms(m.wall), Clock::HostWall));
        }
        if Precision::Bf16.is_available() {
            use crate::cpu::gemm_bf16::{dense_bf16_packed_on, pack_weight};
            let packed = pack_weight(&w, in_dim, out_dim);
            let amx = Bf16Unit::Tiles.effective() == Bf16Unit::Tiles;
            let units = [("cpu_gemm_bf16", Bf16Unit::Vector), ("cpu_gemm_bf16_amx", Bf16Unit::Tiles)];
            for (name, unit) in units.into_iter().filter(|u| u.1 == Bf16Unit::Vector || amx) {
                let m = time_cpu(&|s, xc, o| dense_bf16_packed_on(unit, s, &[(xc, in_dim)], &packed, &b, o))?;
                let used = precision.uses(Precision::Bf16) && (unit == Bf16Unit::Tiles) == amx;
                out.push(report(name.into(), "cpu", used, ms(m.wall), Clock::HostWall));
            }
        }
        if Precision::Int8.is_available() {
            let quantized = crate::cpu::gemm_int8::quantize_weight(&w, in_dim, out_dim);
            let m = time_cpu(&|s, xc, o| crate::cpu::gemm_int8::dense_int8(s, &[(xc, in_dim)], &quantized, &b, o))?;
            let used = precision.uses(Precision::Int8);
            out.push(report("cpu_gemm_int8".into(), "cpu", used, ms(m.wall), Clock::HostWall));
        }
        let m = time_cpu(&|s, xc, o| dense_twin(s, xc, &w, &b, o))?;
        out.push(report("cpu_twin".into(), "cpu", false, ms(m.wall), Clock::HostWall));
    }
    if let Some(g) = gpu {
        let ctx = &g.context;
        let (xb, wb, bb) = (
            GpuBuffer::from_slice(ctx, "x", &x)?,
            GpuBuffer::from_slice(ctx, "w", &w)?,
            GpuBuffer::from_slice(ctx, "b", &b)?,
        );
        let ob = GpuBuffer::from_slice(ctx, "out", &vec![0.0f32; rows * out_dim])?;
        let params = gpu_dense::DenseParams::new(&shape, 0, true)?;
        for variant in GemmVariant::ALL {
            let name = format!("gpu_dense_{variant}");
            if let Some(reason) = variant.unavailable_reason(ctx) {
                unavailable.push(GemmUnavailable { variant: name, reason });
                continue;
            }
            let m = measure(args.repeat, Some(g), || {
                let mut rec = Recorder::new(g, "bench dense");
                gpu_dense::record_with(&mut rec, g, variant, &params, [xb.raw(), wb.raw()], Some(bb.raw()), ob.raw())?;
                crate::block_on(rec.finish())?;
                Ok(())
            })?;
            let t = gpu_timing(m, Some(flops), args.peak_tflops);
            out.push(report(name, "gpu", variant == g.gemm_variant(), t.device_ms, t.clock));
        }
    } else {
        for variant in GemmVariant::ALL {
            unavailable.push(GemmUnavailable { variant: format!("gpu_dense_{variant}"), reason: "no GPU".into() });
        }
    }
    Ok((out, unavailable))
}

fn print_report(r: &Report) {
    let c = &r.config;
    println!(
        "dpr-gpu bench: {} keypoints x {} points per patch, codeword {}, best of {} runs",
        c.keypoints, c.points_per_patch, c.codeword, c.repeat
    );
    match (&r.gpu.adapter, &r.gpu.note) {
        (Some(a), _) => {
            let clock = if r.gpu.timestamps { "GPU timestamps" } else { "host wall time, no TIMESTAMP_QUERY" };
            let gemm = r.gpu.gemm_variant.unwrap_or("-");
            let created = r.gpu.create_ms.map_or(String::new(), |t| format!("; created in {t:.1} ms"));
            println!("gpu: {a} (device times: {clock}; GEMM {gemm}{created})")
        }
        (None, Some(note)) => println!("gpu: not measured: {note}"),
        (None, None) => {}
    }
    println!(
        "model: {:.1} MFLOP per patch (PPF-FoldNet), {:.1} (PC-FoldNet)",
        c.ppf_flops_per_patch / 1e6,
        c.pc_flops_per_patch / 1e6
    );
    if let Some(cpu) = &r.cpu {
        let unit = cpu.bf16_unit.map_or(String::new(), |u| format!(" on {u}"));
        println!("cpu: {} threads, GEMM micro-kernel {}, {} encoders{unit}", cpu.threads, cpu.gemm_path, cpu.precision);
    }
    println!();
    println!(
        "{:<20} {:>10} {:>10} {:>10} {:>8} {:>8} {:>8} {:>10} {:>10}",
        "stage", "cpu ms", "gpu ms", "device ms", "speedup", "cpu GF/s", "gpu GF/s", "up KiB", "down KiB"
    );
    let num = |v: Option<f64>, w: usize, prec: usize| v.map_or(format!("{:>w$}", "-"), |v| format!("{v:>w$.prec$}"));
    for s in &r.stages {
        let speedup = s.cpu.zip(s.gpu).map(|(c, g)| c.wall_ms / g.wall_ms.max(1e-9));
        let kib = |b: Option<u64>| b.map(|b| b as f64 / 1024.0);
        println!(
            "{:<20} {} {} {} {} {} {} {} {}",
            s.stage,
            num(s.cpu.map(|t| t.wall_ms), 10, 2),
            num(s.gpu.map(|t| t.wall_ms), 10, 2),
            num(s.gpu.map(|t| t.device_ms), 10, 2),
            speedup.map_or(format!("{:>8}", "-"), |x| format!("{x:>7.1}x")),
            num(s.cpu.and_then(|t| t.gflops), 8, 2),
            num(s.gpu.and_then(|t| t.gflops), 8, 2),
            num(kib(s.gpu.map(|t| t.transfers.host_to_device_bytes)), 10, 1),
            num(kib(s.gpu.map(|t| t.transfers.device_to_host_bytes)), 10, 1),
        );
    }
    println!();
    for g in &r.gemm {
        let peak = g.timing.peak_fraction.map_or(String::new(), |f| format!(" ({:.1}% of peak)", 100.0 * f));
        let used = if g.used_by_backend { " [backend]" } else { "" };
        println!(
            "gemm {:<20} {}x{}x{}: {:10.3} ms {:9.2} GFLOP/s{peak}{used}",
            g.variant, g.timing.rows, g.timing.in_dim, g.timing.out_dim, g.timing.time_ms, g.timing.gflops
        );
    }
    for u in &r.gemm_unavailable {
        println!("gemm {:<20} not available: {}", u.variant, u.reason);
    }
    if let Some(p) = &r.pair {
        let bytes = match (p.host_to_device_bytes, p.device_to_host_bytes) {
            (Some(up), Some(down)) => {
                format!(", {:.1} KiB up, {:.1} KiB down", up as f64 / 1024.0, down as f64 / 1024.0)
            }
            _ => String::new(),
        };
        println!(
            "\npair ({} points per scan, {} correspondences) on {}: warm (Registrar reused) {:.2} ms{}{bytes}",
            p.points_per_scan,
            p.correspondences,
            p.backend,
            p.wall_ms,
            p.device_ms.map_or(String::new(), |d| format!(", {d:.2} ms on the device")),
        );
        let compiled = p.cold_pipelines_compiled.map_or(String::new(), |n| format!(", compiling {n} pipelines"));
        println!("pair cold (a new Registrar's first registration): {:.2} ms{compiled}", p.cold_wall_ms);
    }
    println!("\n(gpu GF/s uses the device time: GPU timestamps where the adapter has them, else the wall time)");
}
