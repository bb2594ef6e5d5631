//! Host side of `shaders/dense_coop_f16.wgsl`: the dense layer on cooperative matrices (tensor cores), f16
//! inputs and f32 accumulation (the [`super::gemm::GemmVariant::CoopF16`] GEMM). Same parameters and bindings
//! as [`super::dense`], which records it ([`super::dense::record_with`]). Compiled only on devices created with
//! [`DenseCoopF16::FEATURES`], which [`crate::gpu::device::features::device_features`] requests only when the adapter reports a
//! suitable configuration ([`crate::gpu::device::features::coop_f16_support`]). CPU twin: [`crate::cpu::dense_coop_f16`].

use super::dense_params::DenseParams;
use crate::cpu::dense::DenseShape;
pub use crate::gpu::device::features::coop_f16::{MATRIX, SUBGROUP_SIZE, WORKGROUP_STORAGE_BYTES};
use crate::gpu::device::kernel::{BindKind, GpuKernel};

/// Invocations per workgroup (`WG_SIZE` in the shader): four subgroups of [`SUBGROUP_SIZE`].
pub const WG_SIZE: u32 = 128;
/// Output rows per workgroup tile.
pub const TILE_M: usize = 64;
/// Output columns per workgroup tile.
pub const TILE_N: usize = 64;

/// The `dense_coop_f16` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct DenseCoopF16;

impl GpuKernel for DenseCoopF16 {
    const NAME: &'static str = "dense_coop_f16";
    const SOURCE: &'static str = include_str!("../../../shaders/dense_coop_f16.wgsl");
    const BINDS: &'static [BindKind] =
        &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = DenseParams;
    type CpuTwin = fn(&DenseShape, &[f32], &[f32], &[f32], &mut [f32]);
    const CPU_TWIN: Self::CpuTwin = crate::cpu::dense_coop_f16::dense_coop_f16;
    const FEATURES: wgpu::Features = crate::gpu::device::features::coop_f16::FEATURES;
}
