//! `dpr-gpu bench`: times every learned or massively parallel stage on synthetic inputs of a realistic shape
//! (K keypoints x P points per patch), on the GPU backend and/or the CPU reference, and reports the dense
//! GEMM throughput in GFLOP/s.
//!
//! GPU times are the wall time of the backend call (upload, dispatches, readback) and, where the adapter
//! supports `TIMESTAMP_QUERY`, the GPU time between the first and last dispatch of each submission. Each
//! stage runs once untimed (pipeline and buffer warm-up), then `--repeat` times; the fastest run is reported.

use crate::backend::{Backend, CpuBackend, RotationInputs};
use crate::cpu::dense::{DenseShape, dense};
use crate::gpu::{Gpu, GpuBackend, buffer::GpuBuffer, dense as gpu_dense, recorder::Recorder};
use crate::model::{Model, ModelConfig, Net, Weights};
use crate::preprocess::GatheredPatches;
use crate::rng::Rng;
use crate::settings::MatchMode;
use anyhow::{Context, bail};
use rayon::prelude::*;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Arguments of `dpr-gpu bench`.
#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    /// Keypoints (patches) per scan; also the number of correspondences and hypotheses.
    #[arg(long, default_value_t = 1000)]
    pub keypoints: usize,
    /// Points per patch (default: the model's, 256 for the default configuration).
    #[arg(long)]
    pub points: Option<usize>,
    /// Backends to time: gpu, cpu or both.
    #[arg(long, default_value = "both")]
    pub backend: String,
    /// Weights file; default: seeded random weights of the default configuration (times do not depend on
    /// the values).
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// Timed repetitions per stage (the fastest is reported).
    #[arg(long, default_value_t = 3)]
    pub repeat: usize,
    /// Seed of the synthetic inputs.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// Best times of one stage on one backend.
#[derive(Clone, Copy, Debug, Default)]
struct Timing {
    wall: Duration,
    kernels: Option<Duration>,
}

/// Runs `f` once to warm up, then `repeat` times; the fastest wall and GPU times.
fn time<T>(repeat: usize, gpu: Option<&Gpu>, mut f: impl FnMut() -> anyhow::Result<T>) -> anyhow::Result<Timing> {
    f()?;
    let mut best = Timing { wall: Duration::MAX, kernels: None };
    for _ in 0..repeat.max(1) {
        if let Some(g) = gpu {
            g.take_gpu_time();
        }
        let start = Instant::now();
        f()?;
        best.wall = best.wall.min(start.elapsed());
        if let Some(k) = gpu.and_then(Gpu::take_gpu_time) {
            best.kernels = Some(best.kernels.map_or(k, |b: Duration| b.min(k)));
        }
    }
    Ok(best)
}

fn ms(d: Duration) -> String {
    format!("{:10.2}", d.as_secs_f64() * 1e3)
}

fn gflops(flops: f64, d: Duration) -> String {
    format!("{:8.2}", flops / d.as_secs_f64().max(1e-12) / 1e9)
}

/// Dense FLOPs of one encoder pass over `patches` patches of `points` points (the per-patch global slice of
/// the first head layer counted per patch, as computed).
fn encode_flops(model: &Model, patches: usize, points: usize) -> f64 {
    let f = &model.ppf;
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

/// One stage's row of the report.
struct Row {
    stage: String,
    cpu: Option<Timing>,
    gpu: Option<Timing>,
    flops: Option<f64>,
}

/// Most timed repetitions.
pub const MAX_REPEAT: usize = 1_000;

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
    Ok(())
}

/// Runs `dpr-gpu bench`.
pub fn run(args: Args) -> anyhow::Result<()> {
    let (use_cpu, use_gpu) = match args.backend.as_str() {
        "cpu" => (true, false),
        "gpu" => (false, true),
        "both" => (true, true),
        other => bail!("--backend must be cpu, gpu or both, got '{other}'"),
    };
    check_bounds(&args)?;
    if args.keypoints == 0 {
        bail!("--keypoints must be at least 1");
    }
    let weights = match &args.weights {
        Some(path) => Weights::load(path).with_context(|| format!("loading {}", path.display()))?,
        None => Weights::init(&ModelConfig::default(), args.seed)?,
    };
    let mut model = Model::from_weights(&weights)?;
    if let Some(p) = args.points {
        if p == 0 {
            bail!("--points must be at least 1");
        }
        model.config.points_per_patch = p;
    }
    let (k, p) = (args.keypoints, model.config.points_per_patch);
    let cw = model.config.codeword();
    let radius = model.config.radius;
    println!("dpr-gpu bench: {k} keypoints x {p} points per patch, codeword {cw}, best of {} runs", args.repeat.max(1));

    let cpu = use_cpu.then(|| CpuBackend::new(model.clone()));
    let gpu = match (use_gpu, use_cpu) {
        (false, _) => None,
        (true, false) => Some(GpuBackend::new(model.clone()).context("creating the GPU backend")?),
        // The default (`both`): without an adapter, time what exists and say what was not measured.
        (true, true) => match GpuBackend::new(model.clone()) {
            Ok(g) => Some(g),
            Err(e) => {
                println!("gpu: not measured ({e}); timing the CPU reference only");
                None
            }
        },
    };
    if let Some(g) = &gpu {
        g.gpu().set_profiling(true);
        let ts = if g.gpu().context.has_timestamps() { "GPU timestamps" } else { "no TIMESTAMP_QUERY: wall time only" };
        println!("gpu: {} ({ts})", g.adapter_info());
    }
    if cpu.is_some() {
        println!("cpu: {} threads", rayon::current_num_threads());
    }

    let mut rng = Rng::new(args.seed);
    let patches = synthetic_patches(&mut rng, k, p, radius);
    let (ppf, pc) = patches.features(p, radius, model.config.pose_frame);
    let reference: &dyn Backend = match (&gpu, &cpu) {
        (Some(g), _) => g,
        (None, Some(c)) => c,
        (None, None) => unreachable!("at least one backend"),
    };
    let source_cw = reference.encode(Net::Ppf, &ppf, k)?;
    let target_cw: Vec<f32> = source_cw.iter().map(|v| v + 0.01 * rng.normal() as f32).collect();
    let pose: Vec<f32> = crate::model::pose_feature(&reference.encode(Net::Pc, &pc, k)?, &source_cw);
    let normals = patches.center_normals.clone();
    let rotation_inputs =
        RotationInputs { source: &pose, target: &pose, source_normals: &normals, target_normals: &normals, rows: k };
    let rotations = reference.predict_rotations(rotation_inputs)?;
    // One hypothesis per predicted rotation: each correspondence's points repeat once per candidate rotation.
    let candidates = rotations.len() / k.max(1);
    let centers = patches.centers.iter().flat_map(|&c| std::iter::repeat_n(c, candidates));
    let src_pts: Vec<[f32; 3]> = centers.collect();
    let tgt_pts: Vec<[f32; 3]> = src_pts.iter().map(|q| q.map(|c| c + 0.05 * rng.normal() as f32)).collect();
    let hyps = reference.hypotheses(&rotations, &src_pts, &tgt_pts)?;

    let stages: Vec<(&str, Option<f64>)> = vec![
        ("patch_features", None),
        ("encode ppf", Some(encode_flops(&model, k, p))),
        ("encode pc", Some(encode_flops(&model, k, p))),
        ("match_codewords", Some(3.0 * (k * k * cw) as f64)),
        ("predict_rotations", None),
        ("hypotheses", None),
        ("score_hypotheses", None),
    ];
    let mut rows = Vec::new();
    for (stage, flops) in stages {
        let mut row = Row { stage: stage.to_string(), cpu: None, gpu: None, flops };
        let backends: [(Option<&dyn Backend>, Option<&Gpu>, bool); 2] = [
            (cpu.as_ref().map(|c| c as &dyn Backend), None, false),
            (gpu.as_ref().map(|g| g as &dyn Backend), gpu.as_ref().map(GpuBackend::gpu), true),
        ];
        for (backend, device, is_gpu) in backends {
            let Some(b) = backend else { continue };
            let t = time(args.repeat, device, || -> anyhow::Result<()> {
                match stage {
                    "patch_features" => drop(b.patch_features(&patches, radius)?),
                    "encode ppf" => drop(b.encode(Net::Ppf, &ppf, k)?),
                    "encode pc" => drop(b.encode(Net::Pc, &pc, k)?),
                    "match_codewords" => drop(b.match_codewords(&source_cw, &target_cw, cw, MatchMode::Mutual(1))?),
                    "predict_rotations" => drop(b.predict_rotations(rotation_inputs)?),
                    "hypotheses" => drop(b.hypotheses(&rotations, &src_pts, &tgt_pts)?),
                    _ => drop(b.score_hypotheses(&hyps, &src_pts, &tgt_pts, radius / 3.0)?),
                }
                Ok(())
            })
            .with_context(|| format!("stage {stage}"))?;
            if is_gpu { row.gpu = Some(t) } else { row.cpu = Some(t) }
        }
        rows.push(row);
    }
    rows.push(dense_row(&args, gpu.as_ref().map(GpuBackend::gpu), use_cpu, k * p)?);
    print_report(&rows);
    Ok(())
}

/// The dense GEMM on its own: a 512 -> 512 layer over min(K x P, 32768) rows.
fn dense_row(args: &Args, gpu: Option<&Gpu>, use_cpu: bool, rows: usize) -> anyhow::Result<Row> {
    let rows = rows.clamp(1, 32_768);
    let (in_dim, out_dim) = (512, 512);
    let mut rng = Rng::new(args.seed ^ 0xD5);
    let mut v = |n: usize| (0..n).map(|_| rng.normal() as f32).collect::<Vec<f32>>();
    let (x, w, b) = (v(rows * in_dim), v(in_dim * out_dim), v(out_dim));
    let shape = DenseShape { rows, in_dim, out_dim, rows_per_group: rows, accumulate: false, relu: true };
    let mut row = Row {
        stage: format!("dense {in_dim}->{out_dim} x {rows} rows"),
        cpu: None,
        gpu: None,
        flops: Some(2.0 * (rows * in_dim * out_dim) as f64),
    };
    if use_cpu {
        let mut out = vec![0.0f32; rows * out_dim];
        row.cpu = Some(time(args.repeat, None, || {
            // Parallel over row blocks, as the CPU encoder runs it.
            out.par_chunks_mut(2048 * out_dim).zip(x.par_chunks(2048 * in_dim)).for_each(|(o, xc)| {
                let s = DenseShape { rows: xc.len() / in_dim, rows_per_group: xc.len() / in_dim, ..shape };
                dense(&s, xc, &w, &b, o);
            });
            Ok(())
        })?);
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
        row.gpu = Some(time(args.repeat, Some(g), || {
            let mut rec = Recorder::new(g, "bench dense");
            gpu_dense::record(&mut rec, g, &params, xb.raw(), wb.raw(), Some(bb.raw()), ob.raw())?;
            rec.finish()?;
            Ok(())
        })?);
    }
    Ok(row)
}

fn print_report(rows: &[Row]) {
    println!();
    println!(
        "{:<34} {:>10} {:>10} {:>10} {:>8} {:>8} {:>8}",
        "stage", "cpu ms", "gpu ms", "kernel ms", "speedup", "cpu GF/s", "gpu GF/s"
    );
    let blank = format!("{:>10}", "-");
    for r in rows {
        let cpu = r.cpu.map_or(blank.clone(), |t| ms(t.wall));
        let gpu = r.gpu.map_or(blank.clone(), |t| ms(t.wall));
        let kern = r.gpu.and_then(|t| t.kernels).map_or(blank.clone(), ms);
        let speedup = match (r.cpu, r.gpu) {
            (Some(c), Some(g)) => format!("{:7.1}x", c.wall.as_secs_f64() / g.wall.as_secs_f64().max(1e-12)),
            _ => format!("{:>8}", "-"),
        };
        let gf = |t: Option<Timing>, kernel: bool| match (r.flops, t) {
            (Some(f), Some(t)) => gflops(f, if kernel { t.kernels.unwrap_or(t.wall) } else { t.wall }),
            _ => format!("{:>8}", "-"),
        };
        println!("{:<34} {cpu} {gpu} {kern} {speedup} {} {}", r.stage, gf(r.cpu, false), gf(r.gpu, true));
    }
    println!("\n(gpu GF/s uses the kernel time where timestamps exist, else the wall time)");
}
