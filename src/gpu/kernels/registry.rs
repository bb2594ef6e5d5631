//! The kernel registry: the one list of every WGSL kernel ([`KERNELS`], in pipeline order) and the pipelines
//! compiled from it once per device ([`Kernels`]).
//!
//! Adding a kernel: `shaders/k.wgsl`, a unit type implementing [`GpuKernel`] in `gpu/kernels/k.rs` (source,
//! bindings, workgroup size, params type, CPU twin), the twin in `cpu/k.rs`, and its `SPEC` here.
//! `tests/shaders.rs` then validates it and `tests/gpu_parity.rs` insists on a parity case for it
//! (`gpu::parity`: run natively by that test and in a browser by `web/parity.html`). Host code
//! dispatches through the type (`Recorder::dispatch::<K>`), which looks the compiled pipeline up by name.

use super::adam_step::AdamStep;
use super::bitonic_sort::BitonicSort;
use super::cell_bounds::CellBounds;
use super::cell_keys::CellKeys;
use super::chamfer_grad::ChamferGrad;
use super::chamfer_nearest::ChamferNearest;
use super::codeword_distance::CodewordDistance;
use super::dense::Dense;
use super::dense_coop_f16::DenseCoopF16;
use super::dense_fast::{DenseFast, FastTile};
use super::dense_input_grad::DenseInputGrad;
use super::dense_weight_grad::DenseWeightGrad;
use super::farthest_point::FarthestPoint;
use super::grid_knn::GridKnn;
use super::group_row_sums::GroupRowSums;
use super::hypotheses::Hypotheses;
use super::icp_normal_equations::IcpNormalEquations;
use super::max_pool::MaxPool;
use super::max_pool_backward::MaxPoolBackward;
use super::mutual_knn::MutualKnn;
use super::patch_features::PatchFeatures;
use super::patch_gather::PatchGather;
use super::patch_sample::PatchSample;
use super::pca_normals::PcaNormals;
use super::pose_feature::PoseFeature;
use super::prefix_scan::PrefixScan;
use super::relu_backward::ReluBackward;
use super::rotation_head::RotationHead;
use super::score_hypotheses::ScoreHypotheses;
use super::segments::SegmentsKernel;
use super::transpose::Transpose;
use super::unit_rows::UnitRows;
use super::voxel_average::VoxelAverage;
use crate::error::{Error, Result};
use crate::gpu::device::context::GpuContext;
use crate::gpu::device::kernel::{GpuKernel, Kernel, KernelSpec};

/// Every kernel, in pipeline order (inference, then training).
pub const KERNELS: &[KernelSpec] = &[
    CellBounds::SPEC,
    CellKeys::SPEC,
    BitonicSort::SPEC,
    PrefixScan::SPEC,
    SegmentsKernel::SPEC,
    VoxelAverage::SPEC,
    GridKnn::SPEC,
    PcaNormals::SPEC,
    FarthestPoint::SPEC,
    PatchSample::SPEC,
    PatchGather::SPEC,
    PatchFeatures::SPEC,
    Dense::SPEC,
    DenseFast::SPEC,
    DenseCoopF16::SPEC,
    MaxPool::SPEC,
    UnitRows::SPEC,
    CodewordDistance::SPEC,
    MutualKnn::SPEC,
    PoseFeature::SPEC,
    RotationHead::SPEC,
    Hypotheses::SPEC,
    ScoreHypotheses::SPEC,
    IcpNormalEquations::SPEC,
    // Training: the backward passes.
    ReluBackward::SPEC,
    GroupRowSums::SPEC,
    MaxPoolBackward::SPEC,
    DenseWeightGrad::SPEC,
    DenseInputGrad::SPEC,
    AdamStep::SPEC,
    ChamferNearest::SPEC,
    ChamferGrad::SPEC,
    Transpose::SPEC,
];

/// Every pipeline of [`KERNELS`] the device can run, compiled once per device.
#[derive(Debug)]
pub struct Kernels {
    compiled: Vec<Kernel>,
    /// The fast GEMM's other tile shapes ([`FastTile::ALL`] after the default), compiled on first use.
    fast_tiles: [std::sync::OnceLock<Kernel>; FastTile::ALL.len()],
    /// Kernels not compiled because the device lacks features they need, with those features.
    skipped: Vec<(&'static str, wgpu::Features)>,
}

impl Kernels {
    /// Compiles every kernel of [`KERNELS`] whose [`KernelSpec::features`] the device has (the others are
    /// optional variants: see [`super::gemm`]).
    pub fn new(ctx: &GpuContext) -> Result<Kernels> {
        let (usable, skipped): (Vec<&'static KernelSpec>, Vec<&'static KernelSpec>) =
            KERNELS.iter().partition(|spec| ctx.features.contains(spec.features));
        Ok(Kernels {
            compiled: usable.into_iter().map(|spec| Kernel::new(ctx, spec)).collect::<Result<_>>()?,
            fast_tiles: Default::default(),
            skipped: skipped.into_iter().map(|spec| (spec.name, spec.features - ctx.features)).collect(),
        })
    }

    /// The compiled pipeline of `K`, or an error when `K` is not in [`KERNELS`].
    pub fn get<K: GpuKernel>(&self) -> Result<&Kernel> {
        self.by_name(K::NAME)
    }

    /// The compiled pipeline named `name`.
    pub fn by_name(&self, name: &str) -> Result<&Kernel> {
        if let Some(k) = self.compiled.iter().find(|k| k.spec.name == name) {
            return Ok(k);
        }
        Err(Error::Gpu(match self.skipped.iter().find(|(n, _)| *n == name) {
            Some((_, missing)) => format!("kernel '{name}' needs device features this device lacks: {missing}"),
            None => format!("kernel '{name}' is not registered in gpu::registry::KERNELS"),
        }))
    }

    /// The fast GEMM's pipeline for `tile`: the registry's for [`FastTile::DEFAULT`], else the shape's
    /// generated source ([`FastTile::source`]), compiled on `ctx` the first time it is asked for.
    pub fn fast_tile(&self, ctx: &GpuContext, tile: FastTile) -> Result<&Kernel> {
        if tile == FastTile::DEFAULT {
            return self.get::<DenseFast>();
        }
        let slot = tile
            .index()
            .and_then(|i| self.fast_tiles.get(i))
            .ok_or_else(|| Error::Gpu(format!("dense_fast: {tile} is not one of the swept tile shapes")))?;
        if slot.get().is_none() {
            let label = format!("dense_fast {tile}");
            let kernel = Kernel::with_source(ctx, &DenseFast::SPEC, &tile.source()?, &label)?;
            // Another thread may have compiled it meanwhile: either pipeline is the same.
            let _ = slot.set(kernel);
        }
        slot.get().ok_or_else(|| Error::Gpu(format!("dense_fast {tile}: the pipeline was not kept")))
    }

    /// The compiled kernels, in [`KERNELS`] order.
    pub fn iter(&self) -> impl Iterator<Item = &Kernel> {
        self.compiled.iter()
    }
}
