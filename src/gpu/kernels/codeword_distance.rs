//! Host side of `shaders/codeword_distance.wgsl`: squared L2 distances between a chunk of source codewords
//! and all target codewords, as a tiled kernel. CPU twin: [`crate::cpu::codeword_distance`].

use crate::error::{Error, Result};
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32};

gpu_params! {
    /// Mirrors `struct CodewordDistanceParams` in shaders/codeword_distance.wgsl.
    pub struct CodewordDistanceParams {
        /// Source rows in this chunk.
        pub rows: u32,
        /// Target rows (columns of the output).
        pub cols: u32,
        /// Codeword length.
        pub dim: u32,
        /// First source row of the chunk.
        pub row_offset: u32,
        /// Column tiles (`ceil(cols / TILE)`).
        pub col_tiles: u32,
        /// Tiles in all.
        pub tiles: u32,
        /// Padding.
        pub _pad0: u32,
        /// Padding.
        pub _pad1: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 256;
/// Output tile edge.
pub const TILE: usize = 16;

/// The `codeword_distance` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct CodewordDistance;

impl GpuKernel for CodewordDistance {
    const NAME: &'static str = "codeword_distance";
    const SOURCE: &'static str = include_str!("../../../shaders/codeword_distance.wgsl");
    const BINDS: &'static [BindKind] =
        &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = CodewordDistanceParams;
    type CpuTwin = fn(&[f32], &[f32], usize) -> Vec<f32>;
    const CPU_TWIN: Self::CpuTwin = crate::cpu::codeword_distance::codeword_distance;
}

impl CodewordDistanceParams {
    /// Parameters for source rows `row_offset..row_offset + rows` against `cols` targets.
    pub fn new(rows: usize, cols: usize, dim: usize, row_offset: usize) -> Result<CodewordDistanceParams> {
        let col_tiles = cols.div_ceil(TILE);
        Ok(CodewordDistanceParams {
            rows: to_u32(rows, "distance rows")?,
            cols: to_u32(cols, "distance columns")?,
            dim: to_u32(dim, "codeword length")?,
            row_offset: to_u32(row_offset, "distance row offset")?,
            col_tiles: to_u32(col_tiles, "distance column tiles")?,
            tiles: to_u32(col_tiles * rows.div_ceil(TILE), "distance tiles")?,
            _pad0: 0,
            _pad1: 0,
        })
    }
}

/// Records the distances of one chunk into `out` (`rows x cols`).
pub fn record<'a>(
    rec: &mut Recorder<'a>,
    params: &CodewordDistanceParams,
    source: &wgpu::Buffer,
    target: &wgpu::Buffer,
    out: &wgpu::Buffer,
) -> Result<()> {
    rec.dispatch::<CodewordDistance>(params, &[source, target, out], u64::from(params.tiles))
}

/// Runs the kernel on slices in one dispatch; `out` (`ns x nt`) holds the initial contents (a sentinel in
/// tests) and receives the distances.
pub async fn run(gpu: &Gpu, source: &[f32], target: &[f32], dim: usize, out: &mut [f32]) -> Result<()> {
    if dim == 0 || !source.len().is_multiple_of(dim) || !target.len().is_multiple_of(dim) {
        return Err(Error::invalid("codeword_distance: codeword lengths must be multiples of dim"));
    }
    let (ns, nt) = (source.len() / dim, target.len() / dim);
    if out.len() != ns * nt {
        return Err(Error::invalid("codeword_distance: output must be ns x nt"));
    }
    let ctx = &gpu.context;
    let sb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "source", source)?;
    let tb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "target", target)?;
    let ob = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "distances", out)?;
    let mut rec = Recorder::new(gpu, "codeword_distance");
    record(&mut rec, &CodewordDistanceParams::new(ns, nt, dim, 0)?, sb.raw(), tb.raw(), ob.raw())?;
    let r = rec.read(ob.raw(), 0, (out.len() * 4) as u64);
    let bytes = rec.finish().await?;
    out.copy_from_slice(bytemuck::cast_slice(&bytes[r]));
    Ok(())
}
