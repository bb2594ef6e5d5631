//! Host side of `shaders/patch_gather.wgsl`: the sampled rows of kept patches (cloud index, point, normal),
//! or their keypoints, in the layout `patch_features` reads. CPU twin: [`crate::cpu::patch_gather`].

use crate::cpu::cell_keys::SortKey;
use crate::cpu::patch_gather::{Gathered, PatchEntry};
use crate::error::{Error, Result};
use crate::gpu::device::buffer::{GpuBuffer, storage_buffer};
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};

gpu_params! {
    /// Mirrors `struct PatchGatherParams` in shaders/patch_gather.wgsl.
    pub struct PatchGatherParams {
        /// Rows written (patches x points per patch, or patches in centre mode).
        pub rows: u32,
        /// Rows per patch.
        pub points_per_patch: u32,
        /// 1: one row per patch, its keypoint.
        pub centers: u32,
        /// Padding.
        pub _pad: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 64;

/// The `patch_gather` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct PatchGather;

impl GpuKernel for PatchGather {
    const NAME: &'static str = "patch_gather";
    const SOURCE: &'static str = include_str!("../../../shaders/patch_gather.wgsl");
    const BINDS: &'static [BindKind] = &[
        BindKind::Uniform,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadWrite,
        BindKind::ReadWrite,
        BindKind::ReadWrite,
    ];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = PatchGatherParams;
    type CpuTwin = fn(&[[f32; 3]], &[[f32; 3]], &[SortKey], &[PatchEntry], usize, bool) -> Result<Gathered>;
    const CPU_TWIN: Self::CpuTwin = crate::cpu::patch_gather::patch_gather;
}

/// Records the gather of `patches` patches of `n` rows (or their keypoints with `centers`): `[points, normals,
/// sorted candidates, table]` in, `[index, points, normals]` out.
pub fn record(
    rec: &mut Recorder<'_>,
    (patches, n, centers): (usize, usize, bool),
    inputs: [&wgpu::Buffer; 4],
    out: [&wgpu::Buffer; 3],
) -> Result<()> {
    let rows = if centers { patches } else { patches * n };
    let params = PatchGatherParams {
        rows: to_u32(rows, "patch rows")?,
        points_per_patch: to_u32(n.max(1), "points per patch")?,
        centers: u32::from(centers),
        _pad: 0,
    };
    let [p, nn, s, t] = inputs;
    rec.dispatch::<PatchGather>(&params, &[p, nn, s, t, out[0], out[1], out[2]], workgroups(rows, WG_SIZE))
}

/// Runs the kernel on the twin's inputs.
pub async fn run(
    gpu: &Gpu,
    points: &[[f32; 3]],
    normals: &[[f32; 3]],
    sorted: &[SortKey],
    table: &[PatchEntry],
    n: usize,
    centers: bool,
) -> Result<Gathered> {
    if normals.len() != points.len() {
        return Err(Error::invalid("patch_gather: one normal per point is needed"));
    }
    // The twin checks every index; the kernel trusts them.
    crate::cpu::patch_gather::patch_gather(points, normals, sorted, table, n, centers)?;
    let rows = if centers { table.len() } else { table.len() * n };
    if rows == 0 {
        return Ok((Vec::new(), Vec::new(), Vec::new()));
    }
    let ctx = &gpu.context;
    let up = |label, data: &[[f32; 3]]| -> Result<wgpu::Buffer> {
        Ok(GpuBuffer::from_slice(ctx, label, data)?.raw().clone())
    };
    let (pb, nb) = (up("pg_points", points)?, up("pg_normals", normals)?);
    let sb = GpuBuffer::from_slice(ctx, "pg_sorted", if sorted.is_empty() { &[[0u32; 4]][..] } else { sorted })?;
    let tb = GpuBuffer::from_slice(ctx, "pg_table", table)?;
    let oi = storage_buffer(ctx, "pg_index", (rows * 4) as u64)?;
    let op = storage_buffer(ctx, "pg_out_points", (rows * 12) as u64)?;
    let on = storage_buffer(ctx, "pg_out_normals", (rows * 12) as u64)?;
    let mut rec = Recorder::new(gpu, "patch_gather");
    record(&mut rec, (table.len(), n, centers), [&pb, &nb, sb.raw(), tb.raw()], [&oi, &op, &on])?;
    let r = [
        rec.read(&oi, 0, (rows * 4) as u64),
        rec.read(&op, 0, (rows * 12) as u64),
        rec.read(&on, 0, (rows * 12) as u64),
    ];
    let out = rec.finish().await?;
    Ok((
        bytemuck::pod_collect_to_vec(&out[r[0]]),
        bytemuck::pod_collect_to_vec(&out[r[1]]),
        bytemuck::pod_collect_to_vec(&out[r[2]]),
    ))
}
