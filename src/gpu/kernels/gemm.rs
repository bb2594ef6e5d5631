//! Which GEMM kernel runs the dense layers: [`GemmVariant`], chosen once per device from the adapter's features
//! and limits ([`select`]), overridable with [`GEMM_ENV`] (`DPR_GPU_GEMM=portable|fast|coop|auto`) for tests and
//! benchmarks.
//!
//! - [`GemmVariant::Portable`] (`shaders/dense.wgsl`): the reference kernel, 64 x 64 tiles; runs everywhere.
//! - [`GemmVariant::Fast`] (`shaders/dense_fast.wgsl`): 128 x 128 tiles, 8 x 8 outputs per invocation, vec4
//!   workgroup-memory reads, double-buffered k-tiles; the same f32 function in the same summation order. Needs
//!   16 KiB of workgroup memory (every Vulkan, Metal and DX12 device has it).
//! - [`GemmVariant::CoopF16`] (`shaders/dense_coop_f16.wgsl`): tensor cores through wgpu's
//!   `EXPERIMENTAL_COOPERATIVE_MATRIX`, f16 inputs and f32 accumulation, 16 x 16 x 16 matrices, tiles from
//!   64 x 64 to 128 x 128 ([`dense_coop_f16::CoopTile`]). Chosen only when the adapter reports that
//!   configuration ([`coop_f16_support`]); its precision has its own twin ([`crate::cpu::dense_coop_f16`]).
//!
//! Automatic choice: the choice `dpr-gpu bench --gemm-sweep` recorded for the adapter ([`gemm_choice`]: variant
//! and tile shape) when the device can run it, else `coop_f16` where supported, else `fast`, else `portable`. The portable kernel stays the
//! reference every other variant is tested against, and the fallback.

use super::dense::Dense;
use super::dense_coop_f16::{self, DenseCoopF16};
use super::dense_fast::{self, DenseFast};
pub use super::gemm_choice::{self, GemmChoice};
use crate::error::{Error, Result};
use crate::gpu::device::context::GpuContext;
pub use crate::gpu::device::features::{GEMM_ENV, GemmVariant, coop_f16_support, requested};
use crate::gpu::device::kernel::{GpuKernel, KernelSpec};

impl GemmVariant {
    /// The kernel that implements it.
    pub fn kernel(self) -> &'static KernelSpec {
        match self {
            GemmVariant::Portable => &Dense::SPEC,
            GemmVariant::Fast => &DenseFast::SPEC,
            GemmVariant::CoopF16 => &DenseCoopF16::SPEC,
        }
    }

    /// Output rows and columns one workgroup computes.
    pub fn tile(self) -> (usize, usize) {
        match self {
            GemmVariant::Portable => (super::dense_params::TILE_M, super::dense_params::TILE_N),
            GemmVariant::Fast => (dense_fast::TILE_M, dense_fast::TILE_N),
            GemmVariant::CoopF16 => (dense_coop_f16::TILE_M, dense_coop_f16::TILE_N),
        }
    }

    /// Whether the products are formed from f32 inputs (`false`: f16 inputs, f32 accumulation).
    pub fn is_f32(self) -> bool {
        self != GemmVariant::CoopF16
    }

    /// Why the variant cannot run on `ctx`'s device, or `None` when it can.
    pub fn unavailable_reason(self, ctx: &GpuContext) -> Option<String> {
        let missing = self.kernel().features - ctx.features;
        if !missing.is_empty() {
            let why = match self {
                GemmVariant::CoopF16 => coop_f16_support(&ctx.adapter).err().unwrap_or_default(),
                _ => String::new(),
            };
            let sep = if why.is_empty() { "" } else { ": " };
            return Some(format!("the device was created without {missing}{sep}{why}"));
        }
        match self {
            GemmVariant::Portable => None,
            GemmVariant::Fast => {
                let have = ctx.limits.max_compute_workgroup_storage_size;
                (have < dense_fast::WORKGROUP_STORAGE_BYTES).then(|| {
                    format!(
                        "max_compute_workgroup_storage_size is {have} bytes; it needs {}",
                        dense_fast::WORKGROUP_STORAGE_BYTES
                    )
                })
            }
            GemmVariant::CoopF16 => coop_f16_support(&ctx.adapter).err(),
        }
    }
}

impl GemmChoice {
    /// Why the choice cannot run on `ctx`'s device (its variant cannot, or its cooperative tile needs more
    /// workgroup memory than the device has), or `None` when it can.
    pub fn unavailable_reason(&self, ctx: &GpuContext) -> Option<String> {
        self.variant.unavailable_reason(ctx).or_else(|| match self.variant {
            GemmVariant::CoopF16 => self.coop.unavailable_reason(&ctx.limits),
            _ => None,
        })
    }
}

/// The variant a new device runs: [`GEMM_ENV`]'s when set (at the default tiles; an error naming the reason
/// when the device cannot run it), else the choice `dpr-gpu bench --gemm-sweep` recorded for this adapter
/// ([`gemm_choice`]: variant and tile) when the device can run it, else the first of `coop_f16`, `fast`,
/// `portable` the device can run, at the default tiles.
pub fn select(ctx: &GpuContext) -> Result<GemmChoice> {
    let requested = requested()?;
    let recorded = match (requested, gemm_choice::choice_file()) {
        (None, Some(path)) => gemm_choice::lookup(&path, &gemm_choice::adapter_key(&ctx.info)),
        _ => None,
    };
    resolve(requested, recorded, |c| c.unavailable_reason(ctx))
}

/// [`select`]'s rule on `requested` ([`GEMM_ENV`]) and `recorded` (the sweep's choice for the adapter), with
/// `unavailable` saying why the device cannot run a choice.
pub fn resolve(
    requested: Option<GemmVariant>,
    recorded: Option<GemmChoice>,
    unavailable: impl Fn(&GemmChoice) -> Option<String>,
) -> Result<GemmChoice> {
    if let Some(v) = requested {
        let choice = GemmChoice::of(v);
        return match unavailable(&choice) {
            None => Ok(choice),
            Some(why) => Err(Error::Gpu(format!("{GEMM_ENV}={v}: this adapter cannot run it: {why}"))),
        };
    }
    if let Some(choice) = recorded.filter(|c| unavailable(c).is_none()) {
        return Ok(choice);
    }
    let order = [GemmVariant::CoopF16, GemmVariant::Fast, GemmVariant::Portable].map(GemmChoice::of);
    Ok(order.into_iter().find(|c| unavailable(c).is_none()).unwrap_or(GemmChoice::of(GemmVariant::Portable)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_variant_has_its_own_kernel_and_tile() {
        let names: std::collections::BTreeSet<&str> = GemmVariant::ALL.iter().map(|v| v.kernel().name).collect();
        assert_eq!(names.len(), GemmVariant::ALL.len());
        for v in GemmVariant::ALL {
            let (m, n) = v.tile();
            assert!(m >= 64 && n >= 64, "{v}");
        }
        assert!(GemmVariant::Portable.kernel().features.is_empty(), "the reference needs no feature");
        assert!(GemmVariant::Fast.kernel().features.is_empty(), "the fast kernel needs no feature");
    }

    #[test]
    fn the_environment_wins_then_a_runnable_recorded_choice_then_the_fixed_order() {
        use super::super::dense_coop_f16::CoopTile;
        use super::super::dense_fast::FastTile;
        let all = |_: &GemmChoice| None;
        let no_coop = |c: &GemmChoice| (c.variant == GemmVariant::CoopF16).then(|| "no coop".to_string());
        let small = GemmChoice::fast(FastTile { bm: 1, bn: 1 });
        // No record: today's rule.
        assert_eq!(resolve(None, None, all).unwrap(), GemmChoice::of(GemmVariant::CoopF16));
        assert_eq!(resolve(None, None, no_coop).unwrap(), GemmChoice::of(GemmVariant::Fast));
        // A record the device can run is taken, tile and all.
        assert_eq!(resolve(None, Some(small), all).unwrap(), small);
        let portable = GemmChoice::of(GemmVariant::Portable);
        assert_eq!(resolve(None, Some(portable), all).unwrap(), portable);
        // One it cannot run is not.
        let coop = GemmChoice::of(GemmVariant::CoopF16);
        assert_eq!(resolve(None, Some(coop), no_coop).unwrap(), GemmChoice::of(GemmVariant::Fast));
        // The environment wins over the record, with the default tile.
        assert_eq!(resolve(Some(GemmVariant::Portable), Some(small), all).unwrap(), portable);
        assert_eq!(resolve(Some(GemmVariant::Fast), Some(small), all).unwrap(), GemmChoice::of(GemmVariant::Fast));
        let err = resolve(Some(GemmVariant::CoopF16), Some(small), no_coop).unwrap_err().to_string();
        assert!(err.contains(GEMM_ENV) && err.contains("no coop"), "{err}");
        // A recorded cooperative tile is taken; one the device cannot hold is not (the default tile is, first
        // in the fixed order), and the environment's `coop` runs the default tile.
        let big = GemmChoice::coop(CoopTile::ALL[4]);
        assert_eq!(resolve(None, Some(big), all).unwrap(), big);
        let small_memory = |c: &GemmChoice| (c.coop != CoopTile::DEFAULT).then(|| "too big".to_string());
        assert_eq!(resolve(None, Some(big), small_memory).unwrap(), GemmChoice::of(GemmVariant::CoopF16));
        assert_eq!(resolve(Some(GemmVariant::CoopF16), Some(big), all).unwrap(), GemmChoice::of(GemmVariant::CoopF16));
    }
}
