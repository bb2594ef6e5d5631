//! Host side of `shaders/icp_normal_equations.wgsl`: one point-to-plane ICP iteration's normal equations on
//! the device, reduced there in a fixed order (workgroup trees, then one workgroup over the partials) so that
//! only the 28-term total comes back. CPU twin: [`crate::cpu::icp_normal_equations`].

use super::grid_knn::{GridBuffers, upload_grid};
use crate::cpu::icp_normal_equations::{IcpSums, IcpTarget, PoseRows, TERMS, Terms, check, partial_count, used_points};
use crate::error::Result;
use crate::gpu::device::buffer::{GpuBuffer, storage_buffer};
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32};

gpu_params! {
    /// Mirrors `struct IcpNormalEquationsParams` in shaders/icp_normal_equations.wgsl.
    pub struct IcpNormalEquationsParams {
        /// First row of `[R | t]` (target_from_source).
        pub row0: [f32; 4],
        /// Second row.
        pub row1: [f32; 4],
        /// Third row.
        pub row2: [f32; 4],
        /// 0: pair terms and workgroup partials; 1: the total of the partials.
        pub stage: u32,
        /// Source points used (`ceil(points / stride)`).
        pub used: u32,
        /// Stride over the source points.
        pub stride: u32,
        /// Workgroups of stage 0 (`ceil(used / 64)`).
        pub partials: u32,
        /// 1 / cell size of the target's table.
        pub inv_cell: f32,
        /// Squared max pair distance.
        pub max_d2: f32,
        /// Always 0 (the shader's FMA fence).
        pub zero: u32,
        /// Padding.
        pub _pad0: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader): the twin's [`crate::cpu::icp_normal_equations::WG_SIZE`].
pub const WG_SIZE: u32 = 64;

/// The `icp_normal_equations` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct IcpNormalEquations;

impl GpuKernel for IcpNormalEquations {
    const NAME: &'static str = "icp_normal_equations";
    const SOURCE: &'static str = include_str!("../../../shaders/icp_normal_equations.wgsl");
    const BINDS: &'static [BindKind] = &[
        BindKind::Uniform,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadWrite,
    ];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = IcpNormalEquationsParams;
    type CpuTwin = fn(&[[f32; 3]], usize, &IcpTarget<'_>, &PoseRows, f32) -> Result<IcpSums>;
    const CPU_TWIN: Self::CpuTwin = crate::cpu::icp_normal_equations::icp_normal_equations;
}

/// Bytes of the sums buffer for `used` source points: the total, then one partial per workgroup.
pub fn sums_bytes(used: usize) -> u64 {
    ((1 + partial_count(used)) * TERMS * 4) as u64
}

/// The stage-0 parameters for `points` source points at `stride`, moved by `pose`, against a table of cells
/// `1 / inv_cell` wide, pairs within `max_distance` (stage 1 takes the same with `stage: 1`).
pub fn params(
    pose: &PoseRows,
    points: usize,
    stride: usize,
    inv_cell: f32,
    max_distance: f32,
) -> Result<IcpNormalEquationsParams> {
    let used = used_points(points, stride);
    Ok(IcpNormalEquationsParams {
        row0: pose[0],
        row1: pose[1],
        row2: pose[2],
        stage: 0,
        used: to_u32(used, "ICP source points")?,
        stride: to_u32(stride, "ICP stride")?,
        partials: to_u32(partial_count(used), "ICP partials")?,
        inv_cell,
        max_d2: max_distance * max_distance,
        zero: 0,
        _pad0: 0,
    })
}

/// Records both stages: the pair terms and partials of `source` against the target's table, `normals` and
/// all, then their total at the start of `sums` (at least [`sums_bytes`] long).
pub fn record(
    rec: &mut Recorder<'_>,
    params: &IcpNormalEquationsParams,
    source: &wgpu::Buffer,
    target: &GridBuffers<'_>,
    normals: &wgpu::Buffer,
    sums: &wgpu::Buffer,
) -> Result<()> {
    let buffers = [source, target.points, normals, target.grid, target.keys, target.starts, target.run_keys, sums];
    rec.dispatch::<IcpNormalEquations>(
        &IcpNormalEquationsParams { stage: 0, ..*params },
        &buffers,
        params.partials.into(),
    )?;
    rec.dispatch::<IcpNormalEquations>(&IcpNormalEquationsParams { stage: 1, ..*params }, &buffers, 1)
}

/// The total read back from `sums` (its first [`TERMS`] floats).
pub fn decode_total(bytes: &[u8]) -> Terms {
    let mut total = [0.0f32; TERMS];
    total.copy_from_slice(&bytemuck::pod_collect_to_vec::<u8, f32>(&bytes[..TERMS * 4]));
    total
}

/// Runs the kernel on the twin's inputs (parity tests): both stages, every partial read back.
pub async fn run(
    gpu: &Gpu,
    source: &[[f32; 3]],
    stride: usize,
    target: &IcpTarget<'_>,
    pose: &PoseRows,
    max_distance: f32,
) -> Result<IcpSums> {
    check(target, stride, max_distance)?;
    let ctx = &gpu.context;
    let used = used_points(source.len(), stride);
    let up = upload_grid(gpu, target.grid)?;
    let normals = GpuBuffer::from_slice(ctx, "icp_normals", target.normals)?;
    let source_buffer = (!source.is_empty()).then(|| GpuBuffer::from_slice(ctx, "icp_source", source)).transpose()?;
    let bytes = sums_bytes(used);
    let sums = storage_buffer(ctx, "icp_sums", bytes)?;
    crate::gpu::device::buffer::write(ctx, &sums, 0, &vec![f32::NAN; bytes as usize / 4]);
    let p = params(pose, source.len(), stride, target.grid.inv_cell, max_distance)?;
    let mut rec = Recorder::new(gpu, "icp_normal_equations");
    let source_raw = source_buffer.as_ref().map_or(&gpu.dummy, GpuBuffer::raw);
    record(&mut rec, &p, source_raw, &up.buffers(), normals.raw(), &sums)?;
    let r = rec.read(&sums, 0, bytes);
    let out = rec.finish().await?;
    let floats: Vec<f32> = bytemuck::pod_collect_to_vec(&out[r]);
    let mut chunks = floats.chunks_exact(TERMS).map(|c| {
        let mut t = [0.0f32; TERMS];
        t.copy_from_slice(c);
        t
    });
    let total = chunks.next().expect("the sums buffer holds the total");
    Ok(IcpSums { total, partials: chunks.collect() })
}
