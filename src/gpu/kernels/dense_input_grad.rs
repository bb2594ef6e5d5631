//! Host side of `shaders/dense_input_grad.wgsl`: the gradient w.r.t. one per-row input slice of a dense layer, added to
//! the slice's gradient buffer. CPU twin: [`crate::cpu::dense_input_grad`].

use super::dense_weight_grad::slice_sizes;
use crate::cpu::dense_weight_grad::SliceShape;
use crate::error::{Error, Result};
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, workgroups};

gpu_params! {
    /// Mirrors `struct DenseInputGradParams` in shaders/dense_input_grad.wgsl.
    pub struct DenseInputGradParams {
        /// Rows of `dz` and of the slice.
        pub rows: u32,
        /// Output width.
        pub out_dim: u32,
        /// Full input width (the weight's row length).
        pub in_dim: u32,
        /// The slice's width.
        pub width: u32,
        /// First weight column of the slice.
        pub offset: u32,
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

/// The `dense_input_grad` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct DenseInputGrad;

impl GpuKernel for DenseInputGrad {
    const NAME: &'static str = "dense_input_grad";
    const SOURCE: &'static str = include_str!("../../../shaders/dense_input_grad.wgsl");
    const BINDS: &'static [BindKind] =
        &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = DenseInputGradParams;
    type CpuTwin = fn(&SliceShape, &[f32], &[f32], &mut [f32]);
    const CPU_TWIN: Self::CpuTwin = crate::cpu::dense_input_grad::dense_input_grad;
}

impl DenseInputGradParams {
    /// Parameters for `shape`.
    pub fn new(shape: &SliceShape) -> Result<DenseInputGradParams> {
        let [rows, out_dim, in_dim, width, offset] = slice_sizes(shape, "dense_input_grad")?;
        Ok(DenseInputGradParams { rows, out_dim, in_dim, width, offset, _pad0: 0, _pad1: 0, _pad2: 0 })
    }
}

/// Records the gradient of one slice: `dz` (`rows x out_dim`) and the layer's `weight` (`out_dim x in_dim`),
/// added to `dx` (`rows x width`).
pub fn record<'a>(
    rec: &mut Recorder<'a>,
    params: &DenseInputGradParams,
    dz: &wgpu::Buffer,
    weight: &wgpu::Buffer,
    dx: &wgpu::Buffer,
) -> Result<()> {
    let n = params.rows as usize * params.width as usize;
    rec.dispatch::<DenseInputGrad>(params, &[dz, weight, dx], workgroups(n, WG_SIZE))
}

/// Runs the kernel on slices; `dx` holds what is added to and receives the sum.
pub async fn run(gpu: &Gpu, shape: &SliceShape, dz: &[f32], weight: &[f32], dx: &mut [f32]) -> Result<()> {
    let params = DenseInputGradParams::new(shape)?;
    if dz.len() != shape.rows * shape.out_dim
        || weight.len() != shape.out_dim * shape.in_dim
        || dx.len() != shape.rows * shape.width
    {
        return Err(Error::invalid("dense_input_grad: slice lengths do not match the shape"));
    }
    let ctx = &gpu.context;
    let dzb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "dz", dz)?;
    let wb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "weight", weight)?;
    let dxb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "dx", dx)?;
    let mut rec = Recorder::new(gpu, "dense_input_grad");
    record(&mut rec, &params, dzb.raw(), wb.raw(), dxb.raw())?;
    let r = rec.read(dxb.raw(), 0, (dx.len() * 4) as u64);
    let bytes = rec.finish().await?;
    dx.copy_from_slice(bytemuck::cast_slice(&bytes[r]));
    Ok(())
}
