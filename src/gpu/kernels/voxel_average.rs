//! Host side of `shaders/voxel_average.wgsl`: one averaged point (and normal) per run of equal voxel keys.
//! CPU twin: [`crate::cpu::voxel_average`].

use super::cell_bounds::GRID_CELLS;
use crate::cpu::cell_keys::SortKey;
use crate::cpu::segments::Segments;
use crate::cpu::voxel_average::Averages;
use crate::error::{Error, Result};
use crate::gpu::device::buffer::GpuBuffer;
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};

gpu_params! {
    /// Mirrors `struct VoxelAverageParams` in shaders/voxel_average.wgsl.
    pub struct VoxelAverageParams {
        /// Points (an upper bound on the runs; invocations past the run count return).
        pub n: u32,
        /// 1 when normals are averaged too.
        pub has_normals: u32,
        /// Padding.
        pub _pad0: u32,
        /// Padding.
        pub _pad1: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 64;

/// The `voxel_average` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct VoxelAverage;

/// The twin's signature: points, optional normals, sorted keys, runs -> averaged points and normals.
pub type VoxelAverageTwin = fn(&[[f32; 3]], Option<&[[f32; 3]]>, &[SortKey], &Segments) -> Averages;

impl GpuKernel for VoxelAverage {
    const NAME: &'static str = "voxel_average";
    const SOURCE: &'static str = include_str!("../../../shaders/voxel_average.wgsl");
    const BINDS: &'static [BindKind] = &[
        BindKind::Uniform,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadWrite,
        BindKind::ReadWrite,
    ];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = VoxelAverageParams;
    type CpuTwin = VoxelAverageTwin;
    const CPU_TWIN: Self::CpuTwin = crate::cpu::voxel_average::voxel_average;
}

/// The buffers [`record`] reads and writes.
pub struct VoxelAverageBuffers<'b> {
    /// Points (n x 3).
    pub points: &'b wgpu::Buffer,
    /// Normals (n x 3), or any buffer when absent.
    pub normals: Option<&'b wgpu::Buffer>,
    /// Sorted keys.
    pub keys: &'b wgpu::Buffer,
    /// Run starts (runs + 1).
    pub starts: &'b wgpu::Buffer,
    /// Grid words; word [`GRID_CELLS`] holds the number of runs.
    pub grid: &'b wgpu::Buffer,
    /// Averaged points (runs x 3).
    pub out_points: &'b wgpu::Buffer,
    /// Averaged normals (runs x 3), when normals are given.
    pub out_normals: Option<&'b wgpu::Buffer>,
}

/// Records the averages of at most `n` runs (the count is read on the GPU).
pub fn record(rec: &mut Recorder<'_>, gpu: &Gpu, n: usize, b: &VoxelAverageBuffers<'_>) -> Result<()> {
    let has_normals = b.normals.is_some() && b.out_normals.is_some();
    let params =
        VoxelAverageParams { n: to_u32(n, "points")?, has_normals: u32::from(has_normals), _pad0: 0, _pad1: 0 };
    let normals = b.normals.unwrap_or(&gpu.dummy);
    let out_normals = b.out_normals.unwrap_or(&gpu.dummy_rw);
    rec.dispatch::<VoxelAverage>(
        &params,
        &[b.points, normals, b.keys, b.starts, b.grid, b.out_points, out_normals],
        workgroups(n, WG_SIZE),
    )
}

/// Runs the kernel on slices (the twin's inputs).
pub async fn run(
    gpu: &Gpu,
    points: &[[f32; 3]],
    normals: Option<&[[f32; 3]]>,
    sorted: &[SortKey],
    seg: &Segments,
) -> Result<Averages> {
    let runs = seg.len();
    if sorted.len() != points.len() || normals.is_some_and(|n| n.len() != points.len()) || seg.starts.len() != runs + 1
    {
        return Err(Error::invalid("voxel_average: points, normals, keys and runs do not match"));
    }
    if runs == 0 {
        return Ok((Vec::new(), normals.map(|_| Vec::new())));
    }
    let ctx = &gpu.context;
    let n = points.len();
    let pb = GpuBuffer::from_slice(ctx, "va_points", points)?;
    let nb = normals.map(|ns| GpuBuffer::from_slice(ctx, "va_normals", ns)).transpose()?;
    let kb = GpuBuffer::from_slice(ctx, "va_keys", sorted)?;
    let sb = GpuBuffer::from_slice(ctx, "va_starts", &seg.starts)?;
    let mut grid = [0u32; 8];
    grid[GRID_CELLS] = to_u32(runs, "runs")?;
    let gb = GpuBuffer::from_slice(ctx, "va_grid", &grid)?;
    let sentinel = vec![[f32::NAN; 3]; runs];
    let op = GpuBuffer::from_slice(ctx, "va_out_points", &sentinel)?;
    let on = GpuBuffer::from_slice(ctx, "va_out_normals", &sentinel)?;
    let mut rec = Recorder::new(gpu, "voxel_average");
    let b = VoxelAverageBuffers {
        points: pb.raw(),
        normals: nb.as_ref().map(GpuBuffer::raw),
        keys: kb.raw(),
        starts: sb.raw(),
        grid: gb.raw(),
        out_points: op.raw(),
        out_normals: nb.as_ref().map(|_| on.raw()),
    };
    record(&mut rec, gpu, n, &b)?;
    let (rp, rn) = (rec.read(op.raw(), 0, (runs * 12) as u64), rec.read(on.raw(), 0, (runs * 12) as u64));
    let out = rec.finish().await?;
    let pts = bytemuck::pod_collect_to_vec(&out[rp]);
    Ok((pts, normals.map(|_| bytemuck::pod_collect_to_vec(&out[rn]))))
}
