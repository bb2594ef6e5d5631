//! Host side of `shaders/dense_weight_grad.wgsl`: the weight (and optionally bias) gradient of one per-row input
//! slice of a dense layer, added to the gradient buffers. CPU twin: [`crate::cpu::dense_weight_grad`].

use crate::cpu::dense_weight_grad::SliceShape;
use crate::error::{Error, Result};
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};

gpu_params! {
    /// Mirrors `struct DenseWeightGradParams` in shaders/dense_weight_grad.wgsl.
    pub struct DenseWeightGradParams {
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
        /// 1: also add the bias gradient.
        pub bias: u32,
        /// Padding.
        pub _pad0: u32,
        /// Padding.
        pub _pad1: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 64;

/// The `dense_weight_grad` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct DenseWeightGrad;

impl GpuKernel for DenseWeightGrad {
    const NAME: &'static str = "dense_weight_grad";
    const SOURCE: &'static str = include_str!("../../../shaders/dense_weight_grad.wgsl");
    const BINDS: &'static [BindKind] =
        &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadWrite, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = DenseWeightGradParams;
    type CpuTwin = fn(&SliceShape, &[f32], &[f32], &mut [f32], Option<&mut [f32]>);
    const CPU_TWIN: Self::CpuTwin = crate::cpu::dense_weight_grad::dense_weight_grad;
}

/// Checks `shape` and converts it to 32-bit kernel sizes: `[rows, out_dim, in_dim, width, offset]`. Shared
/// with [`super::dense_input_grad`].
pub(crate) fn slice_sizes(shape: &SliceShape, kernel: &str) -> Result<[u32; 5]> {
    if !shape.is_valid() {
        return Err(Error::invalid(format!("{kernel}: the slice does not fit the layer: {shape:?}")));
    }
    to_u32(shape.rows * shape.out_dim.max(shape.width), &format!("{kernel} elements"))?;
    to_u32(shape.out_dim * shape.in_dim, &format!("{kernel} weights"))?;
    let s = shape;
    Ok([s.rows, s.out_dim, s.in_dim, s.width, s.offset].map(|v| v as u32))
}

impl DenseWeightGradParams {
    /// Parameters for `shape`, with or without the bias gradient.
    pub fn new(shape: &SliceShape, bias: bool) -> Result<DenseWeightGradParams> {
        let [rows, out_dim, in_dim, width, offset] = slice_sizes(shape, "dense_weight_grad")?;
        to_u32(shape.out_dim * (shape.width + 1), "dense_weight_grad invocations")?;
        let bias = bias as u32;
        Ok(DenseWeightGradParams { rows, out_dim, in_dim, width, offset, bias, _pad0: 0, _pad1: 0 })
    }

    fn invocations(&self) -> usize {
        self.out_dim as usize * (self.width as usize + self.bias as usize)
    }
}

/// Records the gradient of one slice: `dz` (`rows x out_dim`), `x` (`rows x width`), added to `weight_grad`
/// (`out_dim x in_dim`) and, with `params.bias`, to `bias_grad` (`out_dim`; any buffer without it).
pub fn record<'a>(
    rec: &mut Recorder<'a>,
    params: &DenseWeightGradParams,
    dz: &wgpu::Buffer,
    x: &wgpu::Buffer,
    weight_grad: &wgpu::Buffer,
    bias_grad: &wgpu::Buffer,
) -> Result<()> {
    rec.dispatch::<DenseWeightGrad>(params, &[dz, x, weight_grad, bias_grad], workgroups(params.invocations(), WG_SIZE))
}

/// Runs the kernel on slices; the gradient buffers hold what is added to and receive the sums.
pub async fn run(
    gpu: &Gpu,
    shape: &SliceShape,
    dz: &[f32],
    x: &[f32],
    weight_grad: &mut [f32],
    bias_grad: Option<&mut [f32]>,
) -> Result<()> {
    let params = DenseWeightGradParams::new(shape, bias_grad.is_some())?;
    let bias_ok = bias_grad.as_ref().is_none_or(|b| b.len() == shape.out_dim);
    if dz.len() != shape.rows * shape.out_dim
        || x.len() != shape.rows * shape.width
        || weight_grad.len() != shape.out_dim * shape.in_dim
        || !bias_ok
    {
        return Err(Error::invalid("dense_weight_grad: slice lengths do not match the shape"));
    }
    let ctx = &gpu.context;
    let dzb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "dz", dz)?;
    let xb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "x", x)?;
    let wb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "weight_grad", weight_grad)?;
    let bias_init = bias_grad.as_deref().unwrap_or(&[0.0]);
    let bb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "bias_grad", bias_init)?;
    let mut rec = Recorder::new(gpu, "dense_weight_grad");
    record(&mut rec, &params, dzb.raw(), xb.raw(), wb.raw(), bb.raw())?;
    let rw = rec.read(wb.raw(), 0, (weight_grad.len() * 4) as u64);
    let rb = rec.read(bb.raw(), 0, (bias_init.len() * 4) as u64);
    let bytes = rec.finish().await?;
    weight_grad.copy_from_slice(bytemuck::cast_slice(&bytes[rw]));
    if let Some(b) = bias_grad {
        b.copy_from_slice(bytemuck::cast_slice(&bytes[rb]));
    }
    Ok(())
}
