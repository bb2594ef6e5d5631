//! Host side of `shaders/max_pool_backward.wgsl`: the gradient of the per-group, per-channel maximum, added to
//! the input gradient. CPU twin: [`crate::cpu::max_pool_backward`].

use crate::error::{Error, Result};
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};

gpu_params! {
    /// Mirrors `struct MaxPoolBackwardParams` in shaders/max_pool_backward.wgsl.
    pub struct MaxPoolBackwardParams {
        /// Groups (patches).
        pub groups: u32,
        /// Rows per group (points per patch).
        pub rows_per_group: u32,
        /// Channels (row width).
        pub channels: u32,
        /// Padding.
        pub _pad: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 64;

/// The `max_pool_backward` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct MaxPoolBackward;

impl GpuKernel for MaxPoolBackward {
    const NAME: &'static str = "max_pool_backward";
    const SOURCE: &'static str = include_str!("../../../shaders/max_pool_backward.wgsl");
    const BINDS: &'static [BindKind] =
        &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = MaxPoolBackwardParams;
    type CpuTwin = fn(&[f32], usize, usize, usize, &[f32], &mut [f32]);
    const CPU_TWIN: Self::CpuTwin = crate::cpu::max_pool_backward::max_pool_backward_acc;
}

impl MaxPoolBackwardParams {
    /// Parameters for `groups x rows_per_group x channels`.
    pub fn new(groups: usize, rows_per_group: usize, channels: usize) -> Result<MaxPoolBackwardParams> {
        to_u32(groups * rows_per_group * channels, "max_pool_backward inputs")?;
        Ok(MaxPoolBackwardParams {
            groups: to_u32(groups, "max_pool_backward groups")?,
            rows_per_group: to_u32(rows_per_group, "max_pool_backward rows per group")?,
            channels: to_u32(channels, "max_pool_backward channels")?,
            _pad: 0,
        })
    }
}

/// Records the backward pass: `x` is the pooled input, `d_out` the pooled output's gradient, `dx` the input
/// gradient it is added to.
pub fn record<'a>(
    rec: &mut Recorder<'a>,
    params: &MaxPoolBackwardParams,
    x: &wgpu::Buffer,
    d_out: &wgpu::Buffer,
    dx: &wgpu::Buffer,
) -> Result<()> {
    let n = params.groups as usize * params.channels as usize;
    rec.dispatch::<MaxPoolBackward>(params, &[x, d_out, dx], workgroups(n, WG_SIZE))
}

/// Runs the kernel on slices; `dx` (the shape of `x`) holds what the gradient is added to and receives the sum.
pub async fn run(
    gpu: &Gpu,
    x: &[f32],
    groups: usize,
    rows_per_group: usize,
    channels: usize,
    d_out: &[f32],
    dx: &mut [f32],
) -> Result<()> {
    if x.len() != groups * rows_per_group * channels || dx.len() != x.len() || d_out.len() != groups * channels {
        return Err(Error::invalid("max_pool_backward: slice lengths do not match the shape"));
    }
    let ctx = &gpu.context;
    let xb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "x", x)?;
    let db = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "d_out", d_out)?;
    let dxb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "dx", dx)?;
    let mut rec = Recorder::new(gpu, "max_pool_backward");
    record(&mut rec, &MaxPoolBackwardParams::new(groups, rows_per_group, channels)?, xb.raw(), db.raw(), dxb.raw())?;
    let r = rec.read(dxb.raw(), 0, (dx.len() * 4) as u64);
    let bytes = rec.finish().await?;
    dx.copy_from_slice(bytemuck::cast_slice(&bytes[r]));
    Ok(())
}
