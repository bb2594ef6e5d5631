//! The kernel registry: the one list of every WGSL kernel ([`KERNELS`], in pipeline order) and the pipelines
//! compiled from it once per device, each on first use ([`Kernels`]).
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
use super::dense_coop_f16::{CoopTile, DenseCoopF16};
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
use std::sync::OnceLock;

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

/// The pipelines of [`KERNELS`] on one device, each compiled the first time it is asked for ([`Kernels::get`]),
/// so a run compiles only the kernels it dispatches (inference never compiles the training kernels);
/// [`Kernels::compile_all`] compiles every one the device can run.
#[derive(Debug)]
pub struct Kernels {
    /// One slot per entry of [`KERNELS`], in its order, filled on first use.
    slots: Vec<OnceLock<Kernel>>,
    /// The fast GEMM's tile shapes (slots of [`FastTile::ALL`]; the default's stays empty: it is the
    /// registry's), compiled on first use.
    fast_tiles: [OnceLock<Kernel>; FastTile::ALL.len()],
    /// The cooperative-matrix GEMM's tile shapes (slots of [`CoopTile::ALL`], the same way).
    coop_tiles: [OnceLock<Kernel>; CoopTile::ALL.len()],
    /// The device's features: a kernel needing others is never compiled.
    features: wgpu::Features,
}

impl Kernels {
    /// The registry on `ctx`, nothing compiled yet.
    pub fn new(ctx: &GpuContext) -> Kernels {
        Kernels {
            slots: KERNELS.iter().map(|_| OnceLock::new()).collect(),
            fast_tiles: Default::default(),
            coop_tiles: Default::default(),
            features: ctx.features,
        }
    }

    /// The pipeline of `K`, compiled on `ctx` (the device these kernels were made for) the first time; an error
    /// when `K` is not in [`KERNELS`], the device lacks a feature it needs, or it does not compile.
    pub fn get<K: GpuKernel>(&self, ctx: &GpuContext) -> Result<&Kernel> {
        self.by_name(ctx, K::NAME)
    }

    /// The pipeline named `name`, compiled on `ctx` the first time (see [`Kernels::get`]).
    pub fn by_name(&self, ctx: &GpuContext, name: &str) -> Result<&Kernel> {
        let Some(index) = KERNELS.iter().position(|spec| spec.name == name) else {
            return Err(Error::Gpu(format!("kernel '{name}' is not registered in gpu::registry::KERNELS")));
        };
        let spec = &KERNELS[index];
        self.runnable(spec)?;
        compiled(&self.slots[index], || Kernel::new(ctx, spec), name)
    }

    /// The fast GEMM's pipeline for `tile`: the registry's for [`FastTile::DEFAULT`], else the shape's
    /// generated source ([`FastTile::source`]), compiled on `ctx` the first time it is asked for.
    pub fn fast_tile(&self, ctx: &GpuContext, tile: FastTile) -> Result<&Kernel> {
        if tile == FastTile::DEFAULT {
            return self.get::<DenseFast>(ctx);
        }
        let slot = tile.index().and_then(|i| self.fast_tiles.get(i));
        self.generated(ctx, &DenseFast::SPEC, slot, &tile.to_string(), || tile.source())
    }

    /// The cooperative-matrix GEMM's pipeline for `tile`: an error naming the limit when the device's
    /// `max_compute_workgroup_storage_size` cannot hold the shape ([`CoopTile::unavailable_reason`]), else the
    /// registry's for [`CoopTile::DEFAULT`] or the shape's generated source ([`CoopTile::source`]), compiled on
    /// `ctx` the first time it is asked for.
    pub fn coop_tile(&self, ctx: &GpuContext, tile: CoopTile) -> Result<&Kernel> {
        if let Some(why) = tile.unavailable_reason(&ctx.limits) {
            return Err(Error::Gpu(why));
        }
        if tile == CoopTile::DEFAULT {
            return self.get::<DenseCoopF16>(ctx);
        }
        let slot = tile.index().and_then(|i| self.coop_tiles.get(i));
        self.generated(ctx, &DenseCoopF16::SPEC, slot, &tile.to_string(), || tile.source())
    }

    /// A generated tile shape `tile` of `spec` in `slot` (`None`: not a swept shape), compiled from `source()`
    /// the first time; an error when the device lacks `spec`'s features.
    fn generated<'a>(
        &'a self,
        ctx: &GpuContext,
        spec: &'static KernelSpec,
        slot: Option<&'a OnceLock<Kernel>>,
        tile: &str,
        source: impl FnOnce() -> Result<String>,
    ) -> Result<&'a Kernel> {
        let name = spec.name;
        let slot = slot.ok_or_else(|| Error::Gpu(format!("{name}: {tile} is not one of the swept tile shapes")))?;
        self.runnable(spec)?;
        let label = format!("{name} {tile}");
        compiled(slot, || Kernel::with_source(ctx, spec, &source()?, &label), &label)
    }

    /// An error naming `spec` and the features it needs that the device lacks, if any.
    fn runnable(&self, spec: &KernelSpec) -> Result<()> {
        let missing = spec.features - self.features;
        if missing.is_empty() {
            return Ok(());
        }
        Err(Error::Gpu(format!("kernel '{}' needs device features this device lacks: {missing}", spec.name)))
    }

    /// Compiles every kernel of [`KERNELS`] whose [`KernelSpec::features`] the device has (the others are
    /// optional variants: see [`super::gemm`]) that is not compiled yet; the number compiled then.
    pub fn compile_all(&self, ctx: &GpuContext) -> Result<usize> {
        for spec in KERNELS.iter().filter(|spec| self.features.contains(spec.features)) {
            self.by_name(ctx, spec.name)?;
        }
        Ok(self.iter().count())
    }

    /// The kernels compiled so far, in [`KERNELS`] order (the GEMMs' generated tile shapes not included).
    pub fn iter(&self) -> impl Iterator<Item = &Kernel> {
        self.slots.iter().filter_map(OnceLock::get)
    }
}

/// The kernel in `slot`, compiled by `compile` when it is empty. Two threads may both compile it; either
/// pipeline is the same, and one is kept.
fn compiled<'a>(
    slot: &'a OnceLock<Kernel>,
    compile: impl FnOnce() -> Result<Kernel>,
    name: &str,
) -> Result<&'a Kernel> {
    if slot.get().is_none() {
        let _ = slot.set(compile()?);
    }
    slot.get().ok_or_else(|| Error::Gpu(format!("{name}: the pipeline was not kept")))
}
