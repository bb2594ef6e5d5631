//! Host side of `shaders/cell_bounds.wgsl`: the box of the cells of a point set on a uniform grid, by integer
//! atomics (deterministic). CPU twin: [`crate::cpu::cell_bounds`].

use crate::cpu::cell_bounds::{CellBox, check_inv_cell, out_of_range};
use crate::error::{Error, Result};
use crate::gpu::device::buffer::GpuBuffer;
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};

gpu_params! {
    /// Mirrors `struct CellBoundsParams` in shaders/cell_bounds.wgsl.
    pub struct CellBoundsParams {
        /// Points.
        pub n: u32,
        /// 1 / cell size.
        pub inv_cell: f32,
        /// Padding.
        pub _pad0: u32,
        /// Padding.
        pub _pad1: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 256;

/// The grid words' initial contents: `[min x3 = i32::MAX, max x3 = i32::MIN, invalid = 0, cells = 0]`.
pub const GRID_INIT: [i32; 8] = [i32::MAX, i32::MAX, i32::MAX, i32::MIN, i32::MIN, i32::MIN, 0, 0];

/// Index of the invalid-point flag in the grid words.
pub const GRID_INVALID: usize = 6;

/// Index of the number of occupied cells in the grid words (filled by the host after the segment scan).
pub const GRID_CELLS: usize = 7;

/// The `cell_bounds` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct CellBounds;

impl GpuKernel for CellBounds {
    const NAME: &'static str = "cell_bounds";
    const SOURCE: &'static str = include_str!("../../../shaders/cell_bounds.wgsl");
    const BINDS: &'static [BindKind] = &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = CellBoundsParams;
    type CpuTwin = fn(&[[f32; 3]], f32) -> Result<CellBox>;
    const CPU_TWIN: Self::CpuTwin = crate::cpu::cell_bounds::cell_bounds;
}

/// Records the bounds of `n` points (`points`, n x 3 f32) into `grid` (8 words starting as [`GRID_INIT`]).
pub fn record(
    rec: &mut Recorder<'_>,
    n: usize,
    inv_cell: f32,
    points: &wgpu::Buffer,
    grid: &wgpu::Buffer,
) -> Result<()> {
    let params = CellBoundsParams { n: to_u32(n, "points")?, inv_cell, _pad0: 0, _pad1: 0 };
    rec.dispatch::<CellBounds>(&params, &[points, grid], workgroups(n, WG_SIZE))
}

/// The box in grid words read back, or the error the twin gives for an invalid point or no points.
pub fn decode(grid: &[i32], inv_cell: f32) -> Result<CellBox> {
    if grid.len() < 8 {
        return Err(Error::Gpu("cell_bounds: short readback".into()));
    }
    if grid[GRID_INVALID] != 0 {
        return Err(out_of_range(None, inv_cell));
    }
    let b = CellBox { min: [grid[0], grid[1], grid[2]], max: [grid[3], grid[4], grid[5]] };
    if (0..3).any(|a| b.min[a] > b.max[a]) {
        return Err(Error::invalid("cell grid: no points"));
    }
    Ok(b)
}

/// Runs the kernel on a slice (the twin's input).
pub async fn run(gpu: &Gpu, points: &[[f32; 3]], inv_cell: f32) -> Result<CellBox> {
    check_inv_cell(inv_cell)?;
    if points.is_empty() {
        return Err(Error::invalid("cell grid: no points"));
    }
    let ctx = &gpu.context;
    let pb = GpuBuffer::from_slice(ctx, "cell_points", points)?;
    let gb = GpuBuffer::from_slice(ctx, "cell_grid", &GRID_INIT)?;
    let mut rec = Recorder::new(gpu, "cell_bounds");
    record(&mut rec, points.len(), inv_cell, pb.raw(), gb.raw())?;
    let r = rec.read(gb.raw(), 0, 32);
    let out = rec.finish().await?;
    decode(&bytemuck::pod_collect_to_vec::<u8, i32>(&out[r]), inv_cell)
}
