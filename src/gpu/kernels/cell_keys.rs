//! Host side of `shaders/cell_keys.wgsl`: each point's cell key (a u32 pair) and index, padded to a power of
//! two for the sort. CPU twin: [`crate::cpu::cell_keys`].

use crate::cpu::cell_bounds::CellBox;
use crate::cpu::cell_keys::{SortKey, grid_dims};
use crate::error::{Error, Result};
use crate::gpu::device::buffer::GpuBuffer;
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};

gpu_params! {
    /// Mirrors `struct CellKeysParams` in shaders/cell_keys.wgsl.
    pub struct CellKeysParams {
        /// Points.
        pub n: u32,
        /// Keys written (a power of two >= n; the rest are padding).
        pub padded: u32,
        /// 1 / cell size.
        pub inv_cell: f32,
        /// Padding.
        pub _pad: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 256;
/// Status: a point's cell is invalid or outside the box.
pub const STATUS_OUTSIDE: u32 = 1;
/// Status: the box spans more than 2^21 cells on an axis.
pub const STATUS_TOO_WIDE: u32 = 2;

/// The `cell_keys` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct CellKeys;

impl GpuKernel for CellKeys {
    const NAME: &'static str = "cell_keys";
    const SOURCE: &'static str = include_str!("../../../shaders/cell_keys.wgsl");
    const BINDS: &'static [BindKind] =
        &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadWrite, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = CellKeysParams;
    type CpuTwin = fn(&[[f32; 3]], f32, &CellBox) -> Result<Vec<SortKey>>;
    const CPU_TWIN: Self::CpuTwin = crate::cpu::cell_keys::cell_keys;
}

/// The sort length for `n` keys: the next power of two.
pub fn padded_len(n: usize) -> Result<usize> {
    let p = n.max(1).checked_next_power_of_two().ok_or_else(|| Error::invalid("cell grid: too many points"))?;
    to_u32(p, "padded keys")?;
    Ok(p)
}

/// Records the keys of `n` points into `keys` (`padded` vec4<u32>); `status` (one u32, starting at 0)
/// receives the worst status.
#[allow(clippy::too_many_arguments)]
pub fn record(
    rec: &mut Recorder<'_>,
    n: usize,
    padded: usize,
    inv_cell: f32,
    points: &wgpu::Buffer,
    grid: &wgpu::Buffer,
    keys: &wgpu::Buffer,
    status: &wgpu::Buffer,
) -> Result<()> {
    let params = CellKeysParams { n: to_u32(n, "points")?, padded: to_u32(padded, "padded keys")?, inv_cell, _pad: 0 };
    rec.dispatch::<CellKeys>(&params, &[points, grid, keys, status], workgroups(padded, WG_SIZE))
}

/// The error for a non-zero `status` with box `b` (the twin's error where it gives one).
pub fn check_status(status: u32, b: &CellBox) -> Result<()> {
    grid_dims(b)?;
    match status {
        0 => Ok(()),
        _ => Err(Error::invalid("cell grid: a point lies outside the grid's box")),
    }
}

/// Runs the kernel on a slice with the box `b`: the padded keys (`padded_len(points.len())` of them).
pub async fn run(gpu: &Gpu, points: &[[f32; 3]], inv_cell: f32, b: &CellBox) -> Result<Vec<SortKey>> {
    let n = points.len();
    let padded = padded_len(n)?;
    let ctx = &gpu.context;
    let pb = GpuBuffer::from_slice(ctx, "cell_points", if n == 0 { &[[0.0f32; 3]][..] } else { points })?;
    let grid = [b.min[0], b.min[1], b.min[2], b.max[0], b.max[1], b.max[2], 0, 0];
    let gb = GpuBuffer::from_slice(ctx, "cell_grid", &grid)?;
    let kb = GpuBuffer::from_slice(ctx, "cell_keys", &vec![[0xDEAD_BEEFu32; 4]; padded])?;
    let sb = GpuBuffer::from_slice(ctx, "cell_status", &[0u32])?;
    let mut rec = Recorder::new(gpu, "cell_keys");
    record(&mut rec, n, padded, inv_cell, pb.raw(), gb.raw(), kb.raw(), sb.raw())?;
    let (rk, rs) = (rec.read(kb.raw(), 0, (padded * 16) as u64), rec.read(sb.raw(), 0, 4));
    let out = rec.finish().await?;
    check_status(bytemuck::pod_read_unaligned(&out[rs][..4]), b)?;
    Ok(bytemuck::pod_collect_to_vec(&out[rk]))
}
