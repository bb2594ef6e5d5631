//! Host side of `shaders/relu_backward.wgsl`: a gradient masked by ReLU's derivative. CPU twin:
//! [`crate::cpu::relu_backward`].

use crate::error::{Error, Result};
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};

gpu_params! {
    /// Mirrors `struct ReluBackwardParams` in shaders/relu_backward.wgsl.
    pub struct ReluBackwardParams {
        /// Elements.
        pub len: u32,
        /// Padding.
        pub _pad0: u32,
        /// Padding.
        pub _pad1: u32,
        /// Padding.
        pub _pad2: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 64;

/// The `relu_backward` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct ReluBackward;

impl GpuKernel for ReluBackward {
    const NAME: &'static str = "relu_backward";
    const SOURCE: &'static str = include_str!("../../../shaders/relu_backward.wgsl");
    const BINDS: &'static [BindKind] =
        &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = ReluBackwardParams;
    type CpuTwin = fn(&[f32], &[f32]) -> Vec<f32>;
    const CPU_TWIN: Self::CpuTwin = crate::cpu::relu_backward::relu_backward;
}

impl ReluBackwardParams {
    /// Parameters for `len` elements.
    pub fn new(len: usize) -> Result<ReluBackwardParams> {
        Ok(ReluBackwardParams { len: to_u32(len, "relu_backward elements")?, _pad0: 0, _pad1: 0, _pad2: 0 })
    }
}

/// Records `dz = out > 0 ? d_out : 0`, element by element.
pub fn record<'a>(
    rec: &mut Recorder<'a>,
    params: &ReluBackwardParams,
    out: &wgpu::Buffer,
    d_out: &wgpu::Buffer,
    dz: &wgpu::Buffer,
) -> Result<()> {
    rec.dispatch::<ReluBackward>(params, &[out, d_out, dz], workgroups(params.len as usize, WG_SIZE))
}

/// Runs the kernel on slices; `dz` (the length of `out`) holds the initial contents (a sentinel in tests) and
/// receives the result.
pub async fn run(gpu: &Gpu, out: &[f32], d_out: &[f32], dz: &mut [f32]) -> Result<()> {
    if d_out.len() != out.len() || dz.len() != out.len() || out.is_empty() {
        return Err(Error::invalid("relu_backward: slice lengths differ or are empty"));
    }
    let ctx = &gpu.context;
    let ob = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "out", out)?;
    let db = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "d_out", d_out)?;
    let zb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "dz", dz)?;
    let mut rec = Recorder::new(gpu, "relu_backward");
    record(&mut rec, &ReluBackwardParams::new(out.len())?, ob.raw(), db.raw(), zb.raw())?;
    let r = rec.read(zb.raw(), 0, (dz.len() * 4) as u64);
    let bytes = rec.finish().await?;
    dz.copy_from_slice(bytemuck::cast_slice(&bytes[r]));
    Ok(())
}
