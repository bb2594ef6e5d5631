//! Host side of `shaders/dense.wgsl`: one shared-MLP layer as a tiled GEMM with bias / per-group term,
//! accumulation and ReLU. CPU twin: [`crate::cpu::dense`].

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
        /// Output column tiles (`ceil(out_dim / TILE_N)`).
        pub col_tiles: u32,
        /// Output tiles in all.
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
    /// Parameters for `shape`, reading weight rows from `w_row_offset`, with or without a group term.
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
}

/// Records one layer call: `out = act((acc ? out : 0) + group + x * w_t[w_row_offset..])`. `group` is `None`
/// for no group term.
pub fn record<'a>(
    rec: &mut Recorder<'a>,
    gpu: &'a Gpu,
    params: &DenseParams,
    x: &wgpu::Buffer,
    w_t: &wgpu::Buffer,
    group: Option<&wgpu::Buffer>,
    out: &wgpu::Buffer,
) -> Result<()> {
    let group = group.unwrap_or(&gpu.dummy);
    rec.dispatch::<Dense>(params, &[x, w_t, group, out], u64::from(params.tiles))
}

/// Runs one layer on slices, like the twin: `out` holds the initial contents (read when accumulating, a
/// sentinel in tests) and receives the result. `group_term` is empty or `ceil(rows / rows_per_group) x out_dim`.
pub fn run(gpu: &Gpu, shape: &DenseShape, x: &[f32], w_t: &[f32], group_term: &[f32], out: &mut [f32]) -> Result<()> {
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
    record(&mut rec, gpu, &params, xb.raw(), wb.raw(), (!group_term.is_empty()).then_some(gb.raw()), ob.raw())?;
    let r = rec.read(ob.raw(), 0, (out.len() * 4) as u64);
    let bytes = rec.finish()?;
    out.copy_from_slice(bytemuck::cast_slice(&bytes[r]));
    Ok(())
}
