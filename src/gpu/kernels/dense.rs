//! Host side of `shaders/dense.wgsl`: one shared-MLP layer as a tiled GEMM with bias / per-group term,
//! accumulation and ReLU. CPU twin: [`crate::cpu::dense`]. This is the portable reference GEMM; [`record`]
//! dispatches whichever [`GemmVariant`] the device runs (`dense`, `dense_fast` or `dense_coop_f16`, all with
//! these parameters and bindings).

use super::dense_coop_f16::DenseCoopF16;
use super::dense_fast::DenseFast;
pub use super::dense_params::{DenseParams, FLAG_ACCUMULATE, FLAG_HAS_GROUP, FLAG_RELU, TILE_M, TILE_N};
use crate::cpu::dense::DenseShape;
use crate::error::{Error, Result};
use crate::gpu::Gpu;
use crate::gpu::device::features::GemmVariant;
use crate::gpu::device::kernel::{BindKind, GpuKernel};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::kernels::gemm_choice::GemmChoice;

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 256;

/// The `dense` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct Dense;

impl GpuKernel for Dense {
    const NAME: &'static str = "dense";
    const SOURCE: &'static str = include_str!("../../../shaders/dense.wgsl");
    const BINDS: &'static [BindKind] =
        &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = DenseParams;
    type CpuTwin = fn(&DenseShape, &[f32], &[f32], &[f32], &mut [f32]);
    const CPU_TWIN: Self::CpuTwin = crate::cpu::dense::dense;
}

/// Records one layer call with the device's GEMM variant ([`Gpu::gemm_variant`]):
/// `out = act((acc ? out : 0) + group + x * w_t[w_row_offset..])`. `group` is `None` for no group term.
pub fn record<'a>(
    rec: &mut Recorder<'a>,
    gpu: &'a Gpu,
    params: &DenseParams,
    x: &wgpu::Buffer,
    w_t: &wgpu::Buffer,
    group: Option<&wgpu::Buffer>,
    out: &wgpu::Buffer,
) -> Result<()> {
    record_with(rec, gpu, gpu.gemm_variant(), params, [x, w_t], group, out)
}

/// [`record`] with an explicit variant (an error when the device cannot run it); `fast` and `coop_f16` run the
/// device's tile shapes ([`Gpu::gemm_choice`]).
pub fn record_with<'a>(
    rec: &mut Recorder<'a>,
    gpu: &'a Gpu,
    variant: GemmVariant,
    params: &DenseParams,
    [x, w_t]: [&wgpu::Buffer; 2],
    group: Option<&wgpu::Buffer>,
    out: &wgpu::Buffer,
) -> Result<()> {
    let choice = GemmChoice { variant, ..gpu.gemm_choice() };
    record_choice(rec, gpu, choice, params, [x, w_t], group, out)
}

/// [`record_with`] with explicit tile shapes too (`dpr-gpu bench --gemm-sweep`, parity tests); a cooperative
/// tile the device's workgroup memory cannot hold is an error naming the limit.
pub fn record_choice<'a>(
    rec: &mut Recorder<'a>,
    gpu: &'a Gpu,
    choice: GemmChoice,
    params: &DenseParams,
    [x, w_t]: [&wgpu::Buffer; 2],
    group: Option<&wgpu::Buffer>,
    out: &wgpu::Buffer,
) -> Result<()> {
    let group = group.unwrap_or(&gpu.dummy);
    let variant = choice.variant;
    let tile = match variant {
        GemmVariant::Fast => choice.tile.tile(),
        GemmVariant::CoopF16 => choice.coop.tile(),
        GemmVariant::Portable => variant.tile(),
    };
    let params = params.tiled(tile)?;
    let buffers = [x, w_t, group, out];
    let workgroups = u64::from(params.tiles);
    match variant {
        GemmVariant::Portable => rec.dispatch::<Dense>(&params, &buffers, workgroups),
        GemmVariant::Fast => {
            let kernel = gpu.kernels.fast_tile(&gpu.context, choice.tile)?;
            rec.dispatch_on::<DenseFast>(kernel, &params, &buffers, workgroups)
        }
        GemmVariant::CoopF16 => {
            let kernel = gpu.kernels.coop_tile(&gpu.context, choice.coop)?;
            rec.dispatch_on::<DenseCoopF16>(kernel, &params, &buffers, workgroups)
        }
    }
}

/// Runs one layer on slices with the device's GEMM variant, like the twin: `out` holds the initial contents
/// (read when accumulating, a sentinel in tests) and receives the result. `group_term` is empty or
/// `ceil(rows / rows_per_group) x out_dim`.
pub async fn run(
    gpu: &Gpu,
    shape: &DenseShape,
    x: &[f32],
    w_t: &[f32],
    group_term: &[f32],
    out: &mut [f32],
) -> Result<()> {
    run_with(gpu, gpu.gemm_variant(), shape, x, w_t, group_term, out).await
}

/// [`run`] with an explicit variant (an error when the device cannot run it).
pub async fn run_with(
    gpu: &Gpu,
    variant: GemmVariant,
    shape: &DenseShape,
    x: &[f32],
    w_t: &[f32],
    group_term: &[f32],
    out: &mut [f32],
) -> Result<()> {
    run_choice(gpu, GemmChoice { variant, ..gpu.gemm_choice() }, shape, x, w_t, group_term, out).await
}

/// [`run`] with an explicit variant and tile shapes (an error when the device cannot run them).
pub async fn run_choice(
    gpu: &Gpu,
    choice: GemmChoice,
    shape: &DenseShape,
    x: &[f32],
    w_t: &[f32],
    group_term: &[f32],
    out: &mut [f32],
) -> Result<()> {
    let groups = shape.rows.div_ceil(shape.rows_per_group.max(1));
    if x.len() != shape.rows * shape.in_dim
        || w_t.len() != shape.in_dim * shape.out_dim
        || out.len() != shape.rows * shape.out_dim
        || !(group_term.is_empty() || group_term.len() == groups * shape.out_dim)
    {
        return Err(Error::invalid(format!("dense: slice lengths do not match {shape:?}")));
    }
    let ctx = &gpu.context;
    let xb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "x", x)?;
    let wb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "w_t", w_t)?;
    let gb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "group_term", group_term)?;
    let ob = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "out", out)?;
    let params = DenseParams::new(shape, 0, !group_term.is_empty())?;
    let mut rec = Recorder::new(gpu, "dense");
    let group = (!group_term.is_empty()).then_some(gb.raw());
    record_choice(&mut rec, gpu, choice, &params, [xb.raw(), wb.raw()], group, ob.raw())?;
    let r = rec.read(ob.raw(), 0, (out.len() * 4) as u64);
    let bytes = rec.finish().await?;
    out.copy_from_slice(bytemuck::cast_slice(&bytes[r]));
    Ok(())
}
