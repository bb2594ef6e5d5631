//! Host side of `shaders/dense.wgsl`: one shared-MLP layer as a tiled GEMM with bias / per-group term,
//! accumulation and ReLU. CPU twin: [`crate::cpu::dense`]. This is the portable reference GEMM; [`record`]
//! dispatches whichever [`GemmVariant`] the device runs (`dense`, `dense_fast` or `dense_coop_f16`, all with
//! these parameters and bindings).

use super::dense_coop_f16::DenseCoopF16;
use super::dense_fast::DenseFast;
use super::gemm::GemmVariant;
use super::kernel::{BindKind, GpuKernel, gpu_params};
use super::recorder::Recorder;
use super::{Gpu, to_u32};
use crate::cpu::dense::DenseShape;
use crate::error::{Error, Result};

gpu_params! {
    /// Mirrors `struct DenseParams` in shaders/dense.wgsl.
    pub struct DenseParams {
        /// Rows of `x` and `out`.
        pub rows: u32,
        /// Input width (row stride of `x`).
        pub in_dim: u32,
        /// Output width (row stride of `out` and of the weight).
        pub out_dim: u32,
        /// Rows sharing one row of the group term.
        pub rows_per_group: u32,
        /// First row of the transposed weight used (the slice of a concatenated input).
        pub w_row_offset: u32,
        /// [`FLAG_ACCUMULATE`] | [`FLAG_RELU`] | [`FLAG_HAS_GROUP`].
        pub flags: u32,
        /// Output column tiles (`ceil(out_dim / tile columns)`, for the variant that runs: [`record_with`]
        /// sets it).
        pub col_tiles: u32,
        /// Output tiles in all (for the variant that runs).
        pub tiles: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 256;
/// Output rows per workgroup tile.
pub const TILE_M: usize = 64;
/// Output columns per workgroup tile.
pub const TILE_N: usize = 64;
/// Add to the existing output.
pub const FLAG_ACCUMULATE: u32 = 1;
/// Apply ReLU.
pub const FLAG_RELU: u32 = 2;
/// Add the group term.
pub const FLAG_HAS_GROUP: u32 = 4;

/// The `dense` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct Dense;

impl GpuKernel for Dense {
    const NAME: &'static str = "dense";
    const SOURCE: &'static str = include_str!("../../shaders/dense.wgsl");
    const BINDS: &'static [BindKind] =
        &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = DenseParams;
    type CpuTwin = fn(&DenseShape, &[f32], &[f32], &[f32], &mut [f32]);
    const CPU_TWIN: Self::CpuTwin = crate::cpu::dense::dense;
}

impl DenseParams {
    /// Parameters for `shape`, reading weight rows from `w_row_offset`, with or without a group term (tiled for
    /// the reference kernel; [`record_with`] retiles them for the variant it dispatches).
    pub fn new(shape: &DenseShape, w_row_offset: usize, has_group: bool) -> Result<DenseParams> {
        let col_tiles = shape.out_dim.div_ceil(TILE_N);
        let tiles = col_tiles * shape.rows.div_ceil(TILE_M);
        let flag = |on: bool, bit: u32| if on { bit } else { 0 };
        let flags =
            flag(shape.accumulate, FLAG_ACCUMULATE) | flag(shape.relu, FLAG_RELU) | flag(has_group, FLAG_HAS_GROUP);
        Ok(DenseParams {
            rows: to_u32(shape.rows, "dense rows")?,
            in_dim: to_u32(shape.in_dim, "dense input width")?,
            out_dim: to_u32(shape.out_dim, "dense output width")?,
            rows_per_group: to_u32(shape.rows_per_group.max(1), "dense rows per group")?,
            w_row_offset: to_u32(w_row_offset, "dense weight offset")?,
            flags,
            col_tiles: to_u32(col_tiles, "dense column tiles")?,
            tiles: to_u32(tiles, "dense tiles")?,
        })
    }

    /// These parameters with the tile counts of `(tile rows, tile columns)` output tiles.
    pub fn tiled(&self, (tile_m, tile_n): (usize, usize)) -> Result<DenseParams> {
        let col_tiles = (self.out_dim as usize).div_ceil(tile_n);
        let tiles = col_tiles * (self.rows as usize).div_ceil(tile_m);
        Ok(DenseParams {
            col_tiles: to_u32(col_tiles, "dense column tiles")?,
            tiles: to_u32(tiles, "dense tiles")?,
            ..*self
        })
    }
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

/// [`record`] with an explicit variant (an error when the device cannot run it).
pub fn record_with<'a>(
    rec: &mut Recorder<'a>,
    gpu: &'a Gpu,
    variant: GemmVariant,
    params: &DenseParams,
    [x, w_t]: [&wgpu::Buffer; 2],
    group: Option<&wgpu::Buffer>,
    out: &wgpu::Buffer,
) -> Result<()> {
    let group = group.unwrap_or(&gpu.dummy);
    let params = params.tiled(variant.tile())?;
    let buffers = [x, w_t, group, out];
    let workgroups = u64::from(params.tiles);
    match variant {
        GemmVariant::Portable => rec.dispatch::<Dense>(&params, &buffers, workgroups),
        GemmVariant::Fast => rec.dispatch::<DenseFast>(&params, &buffers, workgroups),
        GemmVariant::CoopF16 => rec.dispatch::<DenseCoopF16>(&params, &buffers, workgroups),
    }
}

/// Runs one layer on slices with the device's GEMM variant, like the twin: `out` holds the initial contents
/// (read when accumulating, a sentinel in tests) and receives the result. `group_term` is empty or
/// `ceil(rows / rows_per_group) x out_dim`.
pub fn run(gpu: &Gpu, shape: &DenseShape, x: &[f32], w_t: &[f32], group_term: &[f32], out: &mut [f32]) -> Result<()> {
    run_with(gpu, gpu.gemm_variant(), shape, x, w_t, group_term, out)
}

/// [`run`] with an explicit variant (an error when the device cannot run it).
pub fn run_with(
    gpu: &Gpu,
    variant: GemmVariant,
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
    let xb = super::buffer::GpuBuffer::from_slice(ctx, "x", x)?;
    let wb = super::buffer::GpuBuffer::from_slice(ctx, "w_t", w_t)?;
    let gb = super::buffer::GpuBuffer::from_slice(ctx, "group_term", group_term)?;
    let ob = super::buffer::GpuBuffer::from_slice(ctx, "out", out)?;
    let params = DenseParams::new(shape, 0, !group_term.is_empty())?;
    let mut rec = Recorder::new(gpu, "dense");
    let group = (!group_term.is_empty()).then_some(gb.raw());
    record_with(&mut rec, gpu, variant, &params, [xb.raw(), wb.raw()], group, ob.raw())?;
    let r = rec.read(ob.raw(), 0, (out.len() * 4) as u64);
    let bytes = rec.finish()?;
    out.copy_from_slice(bytemuck::cast_slice(&bytes[r]));
    Ok(())
}
