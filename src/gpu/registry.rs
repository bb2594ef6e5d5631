//! The kernel registry: the one list of every WGSL kernel ([`KERNELS`], in pipeline order) and the pipelines
//! compiled from it once per device ([`Kernels`]).
//!
//! Adding a kernel: `shaders/k.wgsl`, a unit type implementing [`GpuKernel`] in `gpu/k.rs` (source,
//! bindings, workgroup size, params type, CPU twin), the twin in `cpu/k.rs`, and its `SPEC` here.
//! `tests/shaders.rs` then validates it and `tests/gpu_parity.rs` insists on a parity test for it. Host code
//! dispatches through the type (`Recorder::dispatch::<K>`), which looks the compiled pipeline up by name.

use super::codeword_distance::CodewordDistance;
use super::context::GpuContext;
use super::dense::Dense;
use super::hypotheses::Hypotheses;
use super::kernel::{GpuKernel, Kernel, KernelSpec};
use super::max_pool::MaxPool;
use super::mutual_knn::MutualKnn;
use super::patch_features::PatchFeatures;
use super::pose_feature::PoseFeature;
use super::rotation_head::RotationHead;
use super::score_hypotheses::ScoreHypotheses;
use crate::error::{Error, Result};

/// Every kernel, in pipeline order.
pub const KERNELS: &[KernelSpec] = &[
    PatchFeatures::SPEC,
    Dense::SPEC,
    MaxPool::SPEC,
    CodewordDistance::SPEC,
    MutualKnn::SPEC,
    PoseFeature::SPEC,
    RotationHead::SPEC,
    Hypotheses::SPEC,
    ScoreHypotheses::SPEC,
];

/// Every pipeline of [`KERNELS`], compiled once per device.
#[derive(Debug)]
pub struct Kernels {
    compiled: Vec<Kernel>,
}

impl Kernels {
    /// Compiles every kernel of [`KERNELS`].
    pub fn new(ctx: &GpuContext) -> Result<Kernels> {
        Ok(Kernels { compiled: KERNELS.iter().map(|spec| Kernel::new(ctx, spec)).collect::<Result<_>>()? })
    }

    /// The compiled pipeline of `K`, or an error when `K` is not in [`KERNELS`].
    pub fn get<K: GpuKernel>(&self) -> Result<&Kernel> {
        self.by_name(K::NAME)
    }

    /// The compiled pipeline named `name`.
    pub fn by_name(&self, name: &str) -> Result<&Kernel> {
        self.compiled
            .iter()
            .find(|k| k.spec.name == name)
            .ok_or_else(|| Error::Gpu(format!("kernel '{name}' is not registered in gpu::registry::KERNELS")))
    }

    /// The compiled kernels, in [`KERNELS`] order.
    pub fn iter(&self) -> impl Iterator<Item = &Kernel> {
        self.compiled.iter()
    }
}
