//! Per-kernel benchmarks: each GPU kernel against its CPU twin, at sizes realistic in shape but small enough
//! for lavapipe (software Vulkan, ~1 GFLOP/s) to finish in a few minutes; scale the `SIZES` up on real GPUs.
//!
//! What is timed: the GPU side is the slice API `gpu::k::run` (upload, one dispatch, readback, all
//! waited for), so small kernels are dominated by transfer and submission latency; the CPU side (`cpu/N`) is
//! the code `CpuBackend` runs: the twin `cpu::k` for every kernel but dense, where it is the vectorised
//! `cpu::gemm::dense` (bit-identical to the twin), and `cpu_bf16/N` the bf16 layer the CPU backend runs
//! instead where the CPU has AVX-512 BF16; the readable dense twin is timed as `cpu_twin/N` for comparison. Inputs are built once outside the timed closure. Benchmark ids are `cpu/N` and `gpu/N` with
//! N the problem size. Without a Vulkan adapter (or `DPR_GPU_BACKEND`/`WGPU_BACKEND`) only the CPU side runs.
//! CI builds these (`cargo bench --no-run`) but does not run them.

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use dpr_gpu::backend::{Backend, CpuBackend};
use dpr_gpu::cpu;
use dpr_gpu::cpu::dense::DenseShape;
use dpr_gpu::cpu::score_hypotheses::HypothesisScore;
use dpr_gpu::gpu::{self, Gpu, GpuBackend};
use dpr_gpu::model::config::PoseFrame;
use dpr_gpu::model::{Model, ModelConfig, Net, Weights};
use dpr_gpu::preprocess::GatheredPatches;
use dpr_gpu::rng::Rng;
use dpr_gpu::settings::MatchMode;
use std::hint::black_box;
use std::sync::{Arc, OnceLock};
use std::time::Duration;

/// Patches x points per patch of the feature and encoder benchmarks.
const PATCHES: (usize, usize) = (16, 64);
/// Rows x in x out of the dense benchmark (a 128 -> 256 encoder layer).
const DENSE: (usize, usize, usize) = (2048, 128, 256);
/// Keypoints per scan for matching (codeword 512), and correspondences for hypotheses / scoring.
const KEYPOINTS: usize = 256;

fn gpu() -> Option<Arc<Gpu>> {
    static GPU: OnceLock<Option<Arc<Gpu>>> = OnceLock::new();
    GPU.get_or_init(|| match gpu::testing::new_test_gpu() {
        Ok(g) => Some(Arc::new(g)),
        Err(e) => {
            eprintln!("=== GPU benchmarks SKIPPED (no GPU adapter): {e} ===");
            None
        }
    })
    .clone()
}

fn normals(rng: &mut Rng, n: usize) -> Vec<f32> {
    (0..n).map(|_| rng.normal() as f32).collect()
}

fn points(rng: &mut Rng, n: usize) -> Vec<[f32; 3]> {
    (0..n).map(|_| [0; 3].map(|_: i32| rng.uniform(-1.0, 1.0) as f32)).collect()
}

fn patch_features(c: &mut Criterion) {
    let (p, n) = PATCHES;
    let mut rng = Rng::new(1);
    let patches = GatheredPatches {
        centers: points(&mut rng, p),
        center_normals: points(&mut rng, p),
        points: points(&mut rng, p * n),
        normals: points(&mut rng, p * n),
    };
    let frame = PoseFrame::Normal;
    let mut g = c.benchmark_group("patch_features");
    g.bench_function(BenchmarkId::new("cpu", p * n), |b| b.iter(|| black_box(patches.features(n, 0.3, frame))));
    if let Some(dev) = gpu() {
        let (mut ppf, mut pc) = (vec![0.0; p * n * 4], vec![0.0; p * n * 3]);
        g.bench_function(BenchmarkId::new("gpu", p * n), |b| {
            b.iter(|| {
                dpr_gpu::block_on(gpu::patch_features::run(&dev, &patches, n, 0.3, frame, &mut ppf, &mut pc)).unwrap()
            })
        });
    }
    g.finish();
}

fn dense(c: &mut Criterion) {
    let (rows, i, o) = DENSE;
    let mut rng = Rng::new(2);
    let (x, w, bias) = (normals(&mut rng, rows * i), normals(&mut rng, i * o), normals(&mut rng, o));
    let shape = DenseShape { rows, in_dim: i, out_dim: o, rows_per_group: rows, accumulate: false, relu: true };
    let mut out = vec![0.0; rows * o];
    let mut g = c.benchmark_group("dense");
    // "elements" are floating-point operations: criterion's Gelem/s is GFLOP/s here.
    g.throughput(criterion::Throughput::Elements((2 * rows * i * o) as u64));
    // What CpuBackend runs (model::foldnet calls cpu::gemm::dense in f32, and cpu::gemm_bf16 with the packed
    // weight where the CPU has AVX-512 BF16), and the readable twin the f32 path reproduces.
    g.bench_function(BenchmarkId::new("cpu", rows), |b| b.iter(|| cpu::gemm::dense(&shape, &x, &w, &bias, &mut out)));
    if cpu::gemm_bf16::is_available() {
        let packed = cpu::gemm_bf16::pack_weight(&w, i, o);
        g.bench_function(BenchmarkId::new("cpu_bf16", rows), |b| {
            b.iter(|| cpu::gemm_bf16::dense_bf16_packed(&shape, &[(&x, i)], &packed, &bias, &mut out))
        });
    }
    g.bench_function(BenchmarkId::new("cpu_twin", rows), |b| {
        b.iter(|| cpu::dense::dense(&shape, &x, &w, &bias, &mut out))
    });
    if let Some(dev) = gpu() {
        g.bench_function(BenchmarkId::new("gpu", rows), |b| {
            b.iter(|| dpr_gpu::block_on(gpu::dense::run(&dev, &shape, &x, &w, &bias, &mut out)).unwrap())
        });
    }
    g.finish();
}

fn max_pool(c: &mut Criterion) {
    let (p, n) = PATCHES;
    let ch = 512;
    let x = normals(&mut Rng::new(3), p * n * ch);
    let mut out = vec![0.0; p * ch];
    let mut g = c.benchmark_group("max_pool");
    g.bench_function(BenchmarkId::new("cpu", p * n * ch), |b| {
        b.iter(|| black_box(cpu::max_pool::max_pool(&x, p, n, ch)))
    });
    if let Some(dev) = gpu() {
        g.bench_function(BenchmarkId::new("gpu", p * n * ch), |b| {
            b.iter(|| dpr_gpu::block_on(gpu::max_pool::run(&dev, &x, p, n, ch, &mut out)).unwrap())
        });
    }
    g.finish();
}

fn matching(c: &mut Criterion) {
    let (k, dim) = (KEYPOINTS, 512);
    let mut rng = Rng::new(4);
    let (s, t) = (normals(&mut rng, k * dim), normals(&mut rng, k * dim));
    let d = cpu::codeword_distance::codeword_distance(&s, &t, dim);
    let mut out = vec![0.0; k * k];
    let mut g = c.benchmark_group("codeword_distance");
    g.bench_function(BenchmarkId::new("cpu", k), |b| {
        b.iter(|| black_box(cpu::codeword_distance::codeword_distance(&s, &t, dim)))
    });
    if let Some(dev) = gpu() {
        g.bench_function(BenchmarkId::new("gpu", k), |b| {
            b.iter(|| dpr_gpu::block_on(gpu::codeword_distance::run(&dev, &s, &t, dim, &mut out)).unwrap())
        });
    }
    g.finish();
    let mut g = c.benchmark_group("mutual_knn");
    let mode = MatchMode::Mutual(2);
    g.bench_function(BenchmarkId::new("cpu", k), |b| b.iter(|| black_box(cpu::mutual_knn::mutual_knn(&d, k, k, mode))));
    if let Some(dev) = gpu() {
        g.bench_function(BenchmarkId::new("gpu", k), |b| {
            b.iter(|| dpr_gpu::block_on(gpu::mutual_knn::run(&dev, &d, k, k, mode)).unwrap())
        });
    }
    g.finish();
}

fn hypotheses_and_scores(c: &mut Criterion) {
    let k = KEYPOINTS * 4;
    let mut rng = Rng::new(5);
    let q: Vec<[f32; 9]> =
        (0..k).map(|_| cpu::rotation_head::quaternion_rotation(rng.unit_quaternion().map(|v| v as f32))).collect();
    let (ps, pt) = (points(&mut rng, k), points(&mut rng, k));
    let hyps = cpu::hypotheses::hypotheses(&q, &ps, &pt);
    let mut g = c.benchmark_group("hypotheses");
    g.bench_function(BenchmarkId::new("cpu", k), |b| b.iter(|| black_box(cpu::hypotheses::hypotheses(&q, &ps, &pt))));
    if let Some(dev) = gpu() {
        let mut out = hyps.clone();
        g.bench_function(BenchmarkId::new("gpu", k), |b| {
            b.iter(|| dpr_gpu::block_on(gpu::hypotheses::run(&dev, &q, &ps, &pt, &mut out)).unwrap())
        });
    }
    g.finish();
    let mut g = c.benchmark_group("score_hypotheses");
    g.bench_function(BenchmarkId::new("cpu", k), |b| {
        b.iter(|| black_box(cpu::score_hypotheses::score_hypotheses(&hyps, &ps, &pt, 0.1)))
    });
    if let Some(dev) = gpu() {
        let mut out = vec![HypothesisScore::default(); k];
        g.bench_function(BenchmarkId::new("gpu", k), |b| {
            b.iter(|| dpr_gpu::block_on(gpu::score_hypotheses::run(&dev, &hyps, &ps, &pt, 0.1, &mut out)).unwrap())
        });
    }
    g.finish();
}

fn encode(c: &mut Criterion) {
    let (p, n) = (4, 64);
    let config_ = ModelConfig { points_per_patch: n, ..ModelConfig::default() };
    let model = Model::from_weights(&Weights::init(&config_, 6).unwrap()).unwrap();
    let input: Vec<f32> = {
        let mut rng = Rng::new(6);
        (0..p * n * 4).map(|_| rng.unit_f64() as f32).collect()
    };
    let cpu_b = CpuBackend::new(model.clone());
    let mut g = c.benchmark_group("encode");
    g.bench_function(BenchmarkId::new("cpu", p * n), |b| {
        b.iter(|| black_box(dpr_gpu::block_on(cpu_b.encode(Net::Ppf, &input, p)).unwrap()))
    });
    if let Some(dev) = gpu() {
        let gpu_b = GpuBackend::with_gpu(dev, model).unwrap();
        g.bench_function(BenchmarkId::new("gpu", p * n), |b| {
            b.iter(|| black_box(dpr_gpu::block_on(gpu_b.encode(Net::Ppf, &input, p)).unwrap()))
        });
    }
    g.finish();
}

fn criterion() -> Criterion {
    Criterion::default()
        .sample_size(10)
        .warm_up_time(Duration::from_millis(300))
        .measurement_time(Duration::from_secs(2))
}

criterion_group! {
    name = kernels;
    config = criterion();
    targets = patch_features, dense, max_pool, matching, hypotheses_and_scores, encode
}
criterion_main!(kernels);
