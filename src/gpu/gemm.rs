//! Which GEMM kernel runs the dense layers: [`GemmVariant`], chosen once per device from the adapter's features
//! and limits ([`select`]), overridable with [`GEMM_ENV`] (`DPR_GPU_GEMM=portable|fast|coop|auto`) for tests and
//! benchmarks.
//!
//! - [`GemmVariant::Portable`] (`shaders/dense.wgsl`): the reference kernel, 64 x 64 tiles; runs everywhere.
//! - [`GemmVariant::Fast`] (`shaders/dense_fast.wgsl`): 128 x 128 tiles, 8 x 8 outputs per invocation, vec4
//!   workgroup-memory reads, double-buffered k-tiles; the same f32 function in the same summation order. Needs
//!   16 KiB of workgroup memory (every Vulkan, Metal and DX12 device has it).
//! - [`GemmVariant::CoopF16`] (`shaders/dense_coop_f16.wgsl`): tensor cores through wgpu's
//!   `EXPERIMENTAL_COOPERATIVE_MATRIX`, f16 inputs and f32 accumulation, 16 x 16 x 16 matrices. Chosen only when
//!   the adapter reports that configuration ([`coop_f16_support`]); its precision has its own twin
//!   ([`crate::cpu::dense_coop_f16`]).
//!
//! Automatic choice: `coop_f16` where supported, else `fast`, else `portable`. The portable kernel stays the
//! reference every other variant is tested against, and the fallback.

use super::context::GpuContext;
use super::dense::Dense;
use super::dense_coop_f16::{self, DenseCoopF16};
use super::dense_fast::{self, DenseFast};
use super::kernel::{GpuKernel, KernelSpec};
use crate::error::{Error, Result};

/// Environment variable overriding the GEMM variant: `portable`, `fast`, `coop` (or `coop_f16`), `auto`.
pub const GEMM_ENV: &str = "DPR_GPU_GEMM";

/// One GEMM kernel behind the dense layers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum GemmVariant {
    /// `dense`: the portable f32 reference (64 x 64 tiles).
    Portable,
    /// `dense_fast`: the portable f32 kernel with 128 x 128 register-tiled, double-buffered tiles.
    Fast,
    /// `dense_coop_f16`: cooperative matrices (tensor cores), f16 inputs, f32 accumulation.
    CoopF16,
}

impl GemmVariant {
    /// Every variant, reference first.
    pub const ALL: [GemmVariant; 3] = [GemmVariant::Portable, GemmVariant::Fast, GemmVariant::CoopF16];

    /// Short name (`portable`, `fast`, `coop_f16`), as in [`GEMM_ENV`] and the bench report.
    pub fn name(self) -> &'static str {
        match self {
            GemmVariant::Portable => "portable",
            GemmVariant::Fast => "fast",
            GemmVariant::CoopF16 => "coop_f16",
        }
    }

    /// The value of [`GEMM_ENV`]: `Some(variant)`, or `None` for `auto` / empty.
    pub fn parse(text: &str) -> Result<Option<GemmVariant>> {
        match text.trim().to_ascii_lowercase().as_str() {
            "" | "auto" => Ok(None),
            "portable" | "reference" => Ok(Some(GemmVariant::Portable)),
            "fast" => Ok(Some(GemmVariant::Fast)),
            "coop" | "coop_f16" => Ok(Some(GemmVariant::CoopF16)),
            other => Err(Error::Gpu(format!(
                "{GEMM_ENV}={other} is not a GEMM variant (expected portable, fast, coop or auto)"
            ))),
        }
    }

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
            GemmVariant::Portable => (super::dense::TILE_M, super::dense::TILE_N),
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

impl std::fmt::Display for GemmVariant {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The variant [`GEMM_ENV`] asks for (`None`: automatic), or an error for an unknown value.
pub fn requested() -> Result<Option<GemmVariant>> {
    match std::env::var(GEMM_ENV) {
        Ok(v) => GemmVariant::parse(&v),
        Err(_) => Ok(None),
    }
}

/// Whether `adapter` can run the cooperative-matrix kernel: it has `SHADER_F16`, `SUBGROUP` and
/// `EXPERIMENTAL_COOPERATIVE_MATRIX`, reports a 16 x 16 x 16 configuration with f16 A/B and f32 C/result,
/// runs subgroups of exactly 32 invocations (the kernel's four subgroups each own a 32 x 32 quarter of the
/// tile), and has the kernel's workgroup memory. `Err` says what is missing.
pub fn coop_f16_support(adapter: &wgpu::Adapter) -> std::result::Result<(), String> {
    let missing = DenseCoopF16::FEATURES - adapter.features();
    if !missing.is_empty() {
        return Err(format!("the adapter lacks {missing}"));
    }
    let configs = adapter.cooperative_matrix_properties();
    let suitable = configs.iter().any(|p| {
        p.m_size == dense_coop_f16::MATRIX
            && p.n_size == dense_coop_f16::MATRIX
            && p.k_size == dense_coop_f16::MATRIX
            && p.ab_type == wgpu::CooperativeScalarType::F16
            && p.cr_type == wgpu::CooperativeScalarType::F32
    });
    if !suitable {
        let list: Vec<String> = configs
            .iter()
            .map(|p| format!("{}x{}x{} {:?}->{:?}", p.m_size, p.n_size, p.k_size, p.ab_type, p.cr_type))
            .collect();
        return Err(format!(
            "no 16x16x16 f16->f32 cooperative matrix configuration (the adapter reports [{}])",
            list.join(", ")
        ));
    }
    let info = adapter.get_info();
    if info.subgroup_min_size != dense_coop_f16::SUBGROUP_SIZE
        || info.subgroup_max_size != dense_coop_f16::SUBGROUP_SIZE
    {
        return Err(format!(
            "subgroups of {}..={} invocations; the kernel needs exactly {}",
            info.subgroup_min_size,
            info.subgroup_max_size,
            dense_coop_f16::SUBGROUP_SIZE
        ));
    }
    let have = adapter.limits().max_compute_workgroup_storage_size;
    if have < dense_coop_f16::WORKGROUP_STORAGE_BYTES {
        return Err(format!(
            "max_compute_workgroup_storage_size is {have} bytes; it needs {}",
            dense_coop_f16::WORKGROUP_STORAGE_BYTES
        ));
    }
    Ok(())
}

/// Optional device features the GEMM variants want from `adapter`: the cooperative-matrix kernel's, when the
/// adapter supports it and [`GEMM_ENV`] does not exclude it (an experimental feature is requested only when it
/// will be used).
pub fn device_features(adapter: &wgpu::Adapter) -> wgpu::Features {
    let wanted = matches!(requested(), Ok(None | Some(GemmVariant::CoopF16)));
    if wanted && coop_f16_support(adapter).is_ok() { DenseCoopF16::FEATURES } else { wgpu::Features::empty() }
}

/// The variant a new device runs: [`GEMM_ENV`]'s when set (an error naming the reason when the device cannot
/// run it), else the first of `coop_f16`, `fast`, `portable` the device can run.
pub fn select(ctx: &GpuContext) -> Result<GemmVariant> {
    if let Some(v) = requested()? {
        return match v.unavailable_reason(ctx) {
            None => Ok(v),
            Some(why) => Err(Error::Gpu(format!("{GEMM_ENV}={v}: this adapter cannot run it: {why}"))),
        };
    }
    let order = [GemmVariant::CoopF16, GemmVariant::Fast, GemmVariant::Portable];
    Ok(order.into_iter().find(|v| v.unavailable_reason(ctx).is_none()).unwrap_or(GemmVariant::Portable))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parse_accepts_the_documented_names_and_rejects_others() {
        assert_eq!(GemmVariant::parse("auto").unwrap(), None);
        assert_eq!(GemmVariant::parse(" ").unwrap(), None);
        assert_eq!(GemmVariant::parse("Portable").unwrap(), Some(GemmVariant::Portable));
        assert_eq!(GemmVariant::parse("fast").unwrap(), Some(GemmVariant::Fast));
        assert_eq!(GemmVariant::parse("coop").unwrap(), Some(GemmVariant::CoopF16));
        assert_eq!(GemmVariant::parse("coop_f16").unwrap(), Some(GemmVariant::CoopF16));
        let err = GemmVariant::parse("tensor").unwrap_err().to_string();
        assert!(err.contains(GEMM_ENV) && err.contains("tensor"), "{err}");
        for v in GemmVariant::ALL {
            assert_eq!(GemmVariant::parse(v.name()).unwrap(), Some(v));
        }
    }

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
}
