//! Host side of `shaders/max_pool.wgsl`: per-group, per-channel maximum. CPU twin: [`crate::cpu::max_pool`].

use crate::error::{Error, Result};
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};

gpu_params! {
    /// Mirrors `struct MaxPoolParams` in shaders/max_pool.wgsl.
    pub struct MaxPoolParams {
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

/// The `max_pool` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct MaxPool;

impl GpuKernel for MaxPool {
    const NAME: &'static str = "max_pool";
    const SOURCE: &'static str = include_str!("../../../shaders/max_pool.wgsl");
    const BINDS: &'static [BindKind] = &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = MaxPoolParams;
    type CpuTwin = fn(&[f32], usize, usize, usize) -> Vec<f32>;
    const CPU_TWIN: Self::CpuTwin = crate::cpu::max_pool::max_pool;
}

impl MaxPoolParams {
    /// Parameters for `groups x rows_per_group x channels`.
    pub fn new(groups: usize, rows_per_group: usize, channels: usize) -> Result<MaxPoolParams> {
        to_u32(groups * channels, "max_pool outputs")?;
        Ok(MaxPoolParams {
            groups: to_u32(groups, "max_pool groups")?,
            rows_per_group: to_u32(rows_per_group, "max_pool rows per group")?,
            channels: to_u32(channels, "max_pool channels")?,
            _pad: 0,
        })
    }
}

/// Records the pooling of `x` into `out` (`groups x channels`).
pub fn record<'a>(rec: &mut Recorder<'a>, params: &MaxPoolParams, x: &wgpu::Buffer, out: &wgpu::Buffer) -> Result<()> {
    let n = params.groups as usize * params.channels as usize;
    rec.dispatch::<MaxPool>(params, &[x, out], workgroups(n, WG_SIZE))
}

/// Runs the kernel on slices; `out` (`groups x channels`) holds the initial contents (a sentinel in tests)
/// and receives the result.
pub async fn run(
    gpu: &Gpu,
    x: &[f32],
    groups: usize,
    rows_per_group: usize,
    channels: usize,
    out: &mut [f32],
) -> Result<()> {
    if x.len() != groups * rows_per_group * channels || out.len() != groups * channels {
        return Err(Error::invalid("max_pool: slice lengths do not match the shape"));
    }
    let ctx = &gpu.context;
    let xb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "x", x)?;
    let ob = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "out", out)?;
    let mut rec = Recorder::new(gpu, "max_pool");
    record(&mut rec, &MaxPoolParams::new(groups, rows_per_group, channels)?, xb.raw(), ob.raw())?;
    let r = rec.read(ob.raw(), 0, (out.len() * 4) as u64);
    let bytes = rec.finish().await?;
    out.copy_from_slice(bytemuck::cast_slice(&bytes[r]));
    Ok(())
}
