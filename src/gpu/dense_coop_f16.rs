//! Host side of `shaders/dense_coop_f16.wgsl`: the dense layer on cooperative matrices (tensor cores), f16
//! inputs and f32 accumulation (the [`super::gemm::GemmVariant::CoopF16`] GEMM). Same parameters and bindings
//! as [`super::dense`], which records it ([`super::dense::record_with`]). Compiled only on devices created with
//! [`DenseCoopF16::FEATURES`], which [`super::gemm::device_features`] requests only when the adapter reports a
//! suitable configuration ([`super::gemm::coop_f16_support`]). CPU twin: [`crate::cpu::dense_coop_f16`].

use super::dense::DenseParams;
use super::kernel::{BindKind, GpuKernel};
use crate::cpu::dense::DenseShape;

/// Invocations per workgroup (`WG_SIZE` in the shader): four subgroups of [`SUBGROUP_SIZE`].
pub const WG_SIZE: u32 = 128;
/// The subgroup width the kernel's layout assumes (four subgroups, each owning a 32 x 32 quarter).
pub const SUBGROUP_SIZE: u32 = 32;
/// Output rows per workgroup tile.
pub const TILE_M: usize = 64;
/// Output columns per workgroup tile.
pub const TILE_N: usize = 64;
/// The cooperative matrix size M = N = K the kernel uses (`coop_mat16x16`).
pub const MATRIX: u32 = 16;
/// Workgroup memory the shader declares: 64 x 32 and 32 x 64 f16 operand tiles and the 64 x 64 f32 product.
pub const WORKGROUP_STORAGE_BYTES: u32 = 2 * 64 * 32 * 2 + 64 * 64 * 4;

/// The `dense_coop_f16` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct DenseCoopF16;

impl GpuKernel for DenseCoopF16 {
    const NAME: &'static str = "dense_coop_f16";
    const SOURCE: &'static str = include_str!("../../shaders/dense_coop_f16.wgsl");
    const BINDS: &'static [BindKind] =
        &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = DenseParams;
    type CpuTwin = fn(&DenseShape, &[f32], &[f32], &[f32], &mut [f32]);
    const CPU_TWIN: Self::CpuTwin = crate::cpu::dense_coop_f16::dense_coop_f16;
    const FEATURES: wgpu::Features = wgpu::Features::SHADER_F16
        .union(wgpu::Features::SUBGROUP)
        .union(wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX);
}
