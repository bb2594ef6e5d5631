//! Host side of `shaders/dense_fast.wgsl`: the dense layer with 128 x 128 register-tiled, double-buffered
//! tiles (the [`super::gemm::GemmVariant::Fast`] GEMM). Same parameters and bindings as [`super::dense`], which
//! records it ([`super::dense::record_with`]). CPU twin: [`crate::cpu::dense_fast`].

use super::dense_params::DenseParams;
use crate::cpu::dense::DenseShape;
use crate::gpu::device::kernel::{BindKind, GpuKernel};

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 256;
/// Output rows per workgroup tile.
pub const TILE_M: usize = 128;
/// Output columns per workgroup tile.
pub const TILE_N: usize = 128;
/// Workgroup memory the shader declares: two buffers of 8 x 128 floats for each operand.
pub const WORKGROUP_STORAGE_BYTES: u32 = 2 * 2 * 8 * 128 * 4;

/// The `dense_fast` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct DenseFast;

impl GpuKernel for DenseFast {
    const NAME: &'static str = "dense_fast";
    const SOURCE: &'static str = include_str!("../../../shaders/dense_fast.wgsl");
    const BINDS: &'static [BindKind] =
        &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = DenseParams;
    type CpuTwin = fn(&DenseShape, &[f32], &[f32], &[f32], &mut [f32]);
    const CPU_TWIN: Self::CpuTwin = crate::cpu::dense_fast::dense_fast;
}
