//! Start-up of the GPU path: pipelines compiled on first use (a registration compiles only the kernels it
//! dispatches, no training kernel), every usable kernel still compiles ([`Kernels::compile_all`]), and the
//! driver's pipeline cache kept across runs (`gpu::device::pipeline_cache`): its file is written when a device is
//! dropped, verified and used by the next device, refused (and replaced) when damaged, truncated, oversized or
//! foreign, and a registration gives the same pose bit for bit with the cache, without it and after each refusal.
//!
//! This binary sets `DPR_GPU_CACHE_DIR` and `DPR_GPU_PIPELINE_CACHE` for its own devices, so it runs its tests
//! one at a time on one thread (`dpr_gpu::gpu::testing::run_tests`, `harness = false`); without a Vulkan adapter
//! each is reported SKIPPED unless `CI=true` or `DPR_GPU_REQUIRE_ADAPTER=1`. The file format's own checks (every
//! flipped bit, truncation, size cap, special files) are unit tests of the module, without a device.
//!
//! [`Kernels::compile_all`]: dpr_gpu::gpu::registry::Kernels::compile_all

use dpr_gpu::gpu::device::pipeline_cache::{self, MAX_FILE_BYTES, PIPELINE_CACHE_ENV};
use dpr_gpu::gpu::gemm_choice::CACHE_DIR_ENV;
use dpr_gpu::gpu::registry::KERNELS;
use dpr_gpu::gpu::testing::{new_gpu_or_skip, skip_test};
use dpr_gpu::gpu::{Gpu, GpuBackend};
use dpr_gpu::model::{Model, Weights};
use dpr_gpu::{Matrix4, Registrar, RegistrationSettings};
use std::path::{Path, PathBuf};
use std::sync::Arc;

mod common;

/// The kernels only training dispatches (the backward passes, Adam, the Chamfer loss, the transpose).
const TRAINING_KERNELS: &[&str] = &[
    "relu_backward",
    "group_row_sums",
    "max_pool_backward",
    "dense_weight_grad",
    "dense_input_grad",
    "adam_step",
    "chamfer_nearest",
    "chamfer_grad",
    "transpose",
];

/// A registration on `gpu`: a tiny random network on a small generated room pair, fixed seed (deterministic
/// on one device: the same pose bit for bit every time).
fn register_on(gpu: Arc<Gpu>) -> Matrix4<f64> {
    let model = Model::from_weights(&Weights::init(&common::tiny_config(), 7).unwrap()).unwrap();
    let backend = GpuBackend::with_gpu(gpu, model).expect("GPU backend");
    let settings = RegistrationSettings { keypoints: 48, seed: 7, ..Default::default() };
    let (source, target, _) = common::room_pair(7, 1_500);
    let registrar = Registrar::with_backend(&settings, Box::new(backend)).expect("registrar");
    registrar.register(&source, &target).expect("registration").estimate.target_from_source
}

/// Sets (or with `None` removes) an environment variable.
fn set_env(name: &str, value: Option<&Path>) {
    // SAFETY: this binary runs its tests one at a time on the main thread; no other thread reads the environment.
    unsafe {
        match value {
            Some(v) => std::env::set_var(name, v),
            None => std::env::remove_var(name),
        }
    }
}

/// A fresh device with its pipeline cache in `dir` (`None`: the cache turned off), or `None` when skipped.
fn device_with_cache(dir: &Path, on: bool) -> Option<Gpu> {
    set_env(CACHE_DIR_ENV, Some(dir));
    set_env(PIPELINE_CACHE_ENV, (!on).then_some(Path::new("0")));
    let gpu = new_gpu_or_skip();
    set_env(PIPELINE_CACHE_ENV, None);
    set_env(CACHE_DIR_ENV, None);
    gpu
}

/// A new device compiles nothing; a registration compiles some kernels but no training kernel; `compile_all`
/// then compiles every kernel the device can run (the others need features it lacks), each once.
fn a_registration_compiles_only_the_kernels_it_dispatches() {
    let dir = common::temp_dir("lazy");
    let Some(gpu) = device_with_cache(&dir, false) else { return };
    let gpu = Arc::new(gpu);
    assert_eq!(gpu.kernels.iter().count(), 0, "nothing is compiled before it is used");
    register_on(Arc::clone(&gpu));
    let compiled: Vec<&str> = gpu.kernels.iter().map(|k| k.spec.name).collect();
    assert!(!compiled.is_empty());
    for name in TRAINING_KERNELS {
        assert!(KERNELS.iter().any(|k| k.name == *name), "{name} is registered");
        assert!(!compiled.contains(name), "a registration compiled the training kernel {name}: {compiled:?}");
    }
    assert!(compiled.len() < KERNELS.len() - TRAINING_KERNELS.len(), "{compiled:?}");
    let usable = KERNELS.iter().filter(|k| gpu.context.features.contains(k.features)).count();
    assert_eq!(gpu.kernels.compile_all(&gpu.context).unwrap(), usable);
    let again: Vec<*const wgpu::ComputePipeline> = gpu.kernels.iter().map(|k| &k.pipeline as *const _).collect();
    assert_eq!(gpu.kernels.compile_all(&gpu.context).unwrap(), usable);
    let same: Vec<*const wgpu::ComputePipeline> = gpu.kernels.iter().map(|k| &k.pipeline as *const _).collect();
    assert_eq!(again, same, "a compiled kernel is kept, not compiled again");
    // A kernel the device lacks features for is refused by name, not compiled.
    for spec in KERNELS.iter().filter(|k| !gpu.context.features.contains(k.features)) {
        let err = gpu.kernels.by_name(&gpu.context, spec.name).unwrap_err().to_string();
        assert!(err.contains(spec.name) && err.contains("lacks"), "{err}");
    }
    let err = gpu.kernels.by_name(&gpu.context, "no_such_kernel").unwrap_err().to_string();
    assert!(err.contains("no_such_kernel"), "{err}");
}

/// The cache file of the adapter in `dir`.
fn cache_file_in(dir: &Path, gpu: &Gpu) -> PathBuf {
    dir.join(wgpu::util::pipeline_cache_key(&gpu.context.info).expect("a Vulkan adapter has a cache key"))
}

/// The first device writes the file when dropped; the next reads it (its header and checksum verify) and gives
/// the same pose bit for bit, as does a device without a cache; every kind of unusable file is refused, the
/// registration's pose unchanged, and the file replaced by a good one.
fn the_pipeline_cache_round_trips_and_bad_files_change_no_result() {
    let dir = common::temp_dir("pipeline-cache");
    let Some(first) = device_with_cache(&dir, true) else { return };
    if !first.context.features.contains(wgpu::Features::PIPELINE_CACHE) {
        return skip_test("the adapter has no PIPELINE_CACHE");
    }
    let path = cache_file_in(&dir, &first);
    assert_eq!(first.context.pipeline_cache().map(|c| c.path()), Some(path.as_path()));
    assert!(!path.exists(), "nothing is written before pipelines are compiled");
    let first = Arc::new(first);
    let pose = register_on(Arc::clone(&first));
    drop(first);
    let data = pipeline_cache::read(&path).expect("a valid file").expect("written when the device was dropped");
    assert!(!data.is_empty());

    let Some(uncached) = device_with_cache(&dir, false) else { return };
    assert!(uncached.context.pipeline_cache().is_none(), "{PIPELINE_CACHE_ENV}=0 turns the cache off");
    assert!(!uncached.context.features.contains(wgpu::Features::PIPELINE_CACHE));
    assert_eq!(register_on(Arc::new(uncached)), pose, "without the cache");

    let Some(cached) = device_with_cache(&dir, true) else { return };
    assert_eq!(register_on(Arc::new(cached)), pose, "with the cache read back");
    assert_eq!(pipeline_cache::read(&path).unwrap().as_deref(), Some(&data[..]), "unchanged data are kept");

    let good = std::fs::read(&path).unwrap();
    let mut flipped = good.clone();
    let last = flipped.len() - 1;
    flipped[last] ^= 1;
    let oversized = |path: &Path| std::fs::File::create(path).unwrap().set_len(MAX_FILE_BYTES + 1).unwrap();
    type Spoil<'a> = &'a dyn Fn(&Path);
    let bad: [(&str, Spoil); 4] = [
        ("a flipped bit", &|p| std::fs::write(p, &flipped).unwrap()),
        ("a truncated file", &|p| std::fs::write(p, &good[..good.len() / 2]).unwrap()),
        ("an oversized file", &oversized),
        ("the driver's data without our header", &|p| std::fs::write(p, &data).unwrap()),
    ];
    for (what, spoil) in bad {
        spoil(&path);
        assert!(pipeline_cache::read(&path).is_err(), "{what} is refused");
        let Some(gpu) = device_with_cache(&dir, true) else { return };
        assert!(gpu.context.pipeline_cache().is_some(), "{what}: the device starts with an empty cache");
        assert_eq!(register_on(Arc::new(gpu)), pose, "after {what}");
        let back = pipeline_cache::read(&path).unwrap_or_else(|e| panic!("after {what}: {e}"));
        assert!(back.is_some_and(|d| !d.is_empty()), "{what} is replaced by a good file");
    }
}

fn main() -> std::process::ExitCode {
    dpr_gpu::gpu::testing::run_tests(TESTS, &[])
}

/// Every test of this binary, run in this order.
const TESTS: &[dpr_gpu::gpu::testing::GpuTest] = &[
    ("a_registration_compiles_only_the_kernels_it_dispatches", a_registration_compiles_only_the_kernels_it_dispatches),
    (
        "the_pipeline_cache_round_trips_and_bad_files_change_no_result",
        the_pipeline_cache_round_trips_and_bad_files_change_no_result,
    ),
];
