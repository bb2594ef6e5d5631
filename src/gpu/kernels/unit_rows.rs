//! Host side of `shaders/unit_rows.wgsl`: rows scaled to unit length and weighted into a column block of wider
//! rows, where the codewords are (the matching rows of codewords at several patch radii). CPU twin:
//! [`crate::cpu::unit_rows`].

use crate::error::{Error, Result};
use crate::gpu::device::buffer::GpuBuffer;
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};

gpu_params! {
    /// Mirrors `struct UnitRowsParams` in shaders/unit_rows.wgsl.
    pub struct UnitRowsParams {
        /// Rows.
        pub rows: u32,
        /// Values per input row.
        pub width: u32,
        /// Values per output row.
        pub out_width: u32,
        /// First output column of the block.
        pub column: u32,
        /// Weight of the block.
        pub weight: f32,
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

/// The `unit_rows` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct UnitRows;

impl GpuKernel for UnitRows {
    const NAME: &'static str = "unit_rows";
    const SOURCE: &'static str = include_str!("../../../shaders/unit_rows.wgsl");
    const BINDS: &'static [BindKind] = &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = UnitRowsParams;
    type CpuTwin = fn(&[f32], usize, f32, usize, usize, &mut [f32]);
    const CPU_TWIN: Self::CpuTwin = crate::cpu::unit_rows::unit_rows;
}

/// Where a block goes: `width` input values per row, written at `column` of rows `out_width` wide, times
/// `weight`.
#[derive(Clone, Copy, Debug)]
pub struct Block {
    /// Values per input row.
    pub width: usize,
    /// Values per output row.
    pub out_width: usize,
    /// First output column.
    pub column: usize,
    /// Weight.
    pub weight: f32,
}

impl Block {
    fn params(&self, rows: usize) -> Result<UnitRowsParams> {
        if self.width == 0 || self.column + self.width > self.out_width || !self.weight.is_finite() {
            return Err(Error::invalid(format!(
                "unit_rows: a block of {} values at column {} of rows of {} (weight {})",
                self.width, self.column, self.out_width, self.weight
            )));
        }
        to_u32(rows * self.out_width, "unit_rows output values")?;
        Ok(UnitRowsParams {
            rows: to_u32(rows, "unit_rows rows")?,
            width: to_u32(self.width, "unit_rows width")?,
            out_width: to_u32(self.out_width, "unit_rows output width")?,
            column: to_u32(self.column, "unit_rows column")?,
            weight: self.weight,
            _pad0: 0,
            _pad1: 0,
            _pad2: 0,
        })
    }
}

/// Records the block of the first `rows` rows of `input` into `out`.
pub fn record<'a>(
    rec: &mut Recorder<'a>,
    rows: usize,
    block: Block,
    input: &wgpu::Buffer,
    out: &wgpu::Buffer,
) -> Result<()> {
    let params = block.params(rows)?;
    rec.dispatch::<UnitRows>(&params, &[input, out], workgroups(rows, WG_SIZE))
}

/// Runs the kernel on slices; `out` holds the initial contents (a sentinel in tests) and receives the block.
pub async fn run(gpu: &Gpu, input: &[f32], block: Block, out: &mut [f32]) -> Result<()> {
    if block.width == 0 || !input.len().is_multiple_of(block.width) {
        return Err(Error::invalid("unit_rows: the input is not whole rows"));
    }
    let rows = input.len() / block.width;
    if out.len() != rows * block.out_width {
        return Err(Error::invalid("unit_rows: the output must hold as many rows as the input"));
    }
    let ctx = &gpu.context;
    let (i, o) = (GpuBuffer::from_slice(ctx, "input", input)?, GpuBuffer::from_slice(ctx, "out", out)?);
    let mut rec = Recorder::new(gpu, "unit_rows");
    record(&mut rec, rows, block, i.raw(), o.raw())?;
    let read = rec.read(o.raw(), 0, (out.len() * 4) as u64);
    let bytes = rec.finish().await?;
    out.copy_from_slice(&bytemuck::pod_collect_to_vec::<u8, f32>(&bytes[read]));
    Ok(())
}
