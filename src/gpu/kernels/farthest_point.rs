//! Host side of `shaders/farthest_point.wgsl`: farthest-point sampling on the device, two dispatches per
//! chosen point (update the running distances and reduce per workgroup; pick the farthest), only the chosen
//! indices read back. CPU twin: [`crate::cpu::farthest_point`] (the definition the CPU path uses).

use crate::error::{Error, Result};
use crate::gpu::device::buffer::{GpuBuffer, storage_buffer};
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};

gpu_params! {
    /// Mirrors `struct FarthestPointParams` in shaders/farthest_point.wgsl.
    pub struct FarthestPointParams {
        /// 0: update and reduce per workgroup; 1: pick.
        pub stage: u32,
        /// Points.
        pub n: u32,
        /// Workgroups of stage 0 (entries of `partials`).
        pub partials: u32,
        /// The step: stage 0 measures from `chosen[step]`, stage 1 writes `chosen[step + 1]`.
        pub step: u32,
        /// Always 0 (the shader's FMA fence).
        pub zero: u32,
        /// Padding.
        pub _pad0: u32,
        /// Padding.
        pub _pad1: u32,
        /// Padding.
        pub _pad2: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 256;
/// Steps recorded per submission.
const STEPS_PER_SUBMISSION: usize = 1024;

/// The `farthest_point` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct FarthestPoint;

impl GpuKernel for FarthestPoint {
    const NAME: &'static str = "farthest_point";
    const SOURCE: &'static str = include_str!("../../../shaders/farthest_point.wgsl");
    const BINDS: &'static [BindKind] =
        &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadWrite, BindKind::ReadWrite, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = FarthestPointParams;
    type CpuTwin = fn(&[[f32; 3]], usize, usize) -> Vec<usize>;
    const CPU_TWIN: Self::CpuTwin = crate::cpu::farthest_point::farthest_point;
}

/// `count` points of the `n` in `points` (on the device) by farthest-point sampling from `start`; only the
/// chosen indices come back.
pub async fn sample(gpu: &Gpu, points: &wgpu::Buffer, n: usize, count: usize, start: usize) -> Result<Vec<usize>> {
    if count > n || (count > 0 && start >= n) {
        return Err(Error::invalid(format!("farthest_point: {count} points from start {start} of {n}")));
    }
    if count == 0 {
        return Ok(Vec::new());
    }
    let ctx = &gpu.context;
    let groups = workgroups(n, WG_SIZE);
    let nearest = storage_buffer(ctx, "fps_nearest", (n * 4) as u64)?;
    let partials = storage_buffer(ctx, "fps_partials", groups * 8)?;
    let mut first = vec![0u32; count];
    first[0] = to_u32(start, "start")?;
    let chosen = GpuBuffer::from_slice(ctx, "fps_chosen", &first)?;
    let base = FarthestPointParams {
        n: to_u32(n, "points")?,
        partials: to_u32(groups as usize, "workgroups")?,
        ..FarthestPointParams::default()
    };
    let steps: Vec<usize> = (0..count - 1).collect();
    let mut pending = Vec::new();
    for part in steps.chunks(STEPS_PER_SUBMISSION) {
        let mut rec = Recorder::new(gpu, "farthest_point");
        for &step in part {
            let step = to_u32(step, "step")?;
            let buffers = [points, &nearest, &partials, chosen.raw()];
            rec.dispatch::<FarthestPoint>(&FarthestPointParams { stage: 0, step, ..base }, &buffers, groups)?;
            rec.dispatch::<FarthestPoint>(&FarthestPointParams { stage: 1, step, ..base }, &buffers, 1)?;
        }
        pending.push(rec.submit()?);
    }
    for p in pending {
        p.wait(gpu).await?;
    }
    let mut rec = Recorder::new(gpu, "farthest_point readback");
    let r = rec.read(chosen.raw(), 0, (count * 4) as u64);
    let out: Vec<u32> = bytemuck::pod_collect_to_vec(&rec.finish().await?[r]);
    Ok(out.into_iter().map(|i| i as usize).collect())
}

/// Runs the sampling on host points (the twin's inputs).
pub async fn run(gpu: &Gpu, points: &[[f32; 3]], count: usize, start: usize) -> Result<Vec<usize>> {
    if points.is_empty() {
        return sample(gpu, &gpu.dummy, 0, count, start).await;
    }
    let pb = GpuBuffer::from_slice(&gpu.context, "fps_points", points)?;
    sample(gpu, pb.raw(), points.len(), count, start).await
}
