//! Host side of `shaders/pose_feature.wgsl`: pose features written into a scan's device rows from PC-FoldNet
//! codewords encoded for some of them. CPU twin: [`crate::cpu::pose_feature`].

use crate::error::{Error, Result};
use crate::gpu::device::buffer::GpuBuffer;
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};

gpu_params! {
    /// Mirrors `struct PoseFeatureParams` in shaders/pose_feature.wgsl.
    pub struct PoseFeatureParams {
        /// Encoded rows (slots).
        pub slots: u32,
        /// Codeword width.
        pub width: u32,
        /// Padding.
        pub _pad0: u32,
        /// Padding.
        pub _pad1: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 64;

/// The `pose_feature` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct PoseFeature;

impl GpuKernel for PoseFeature {
    const NAME: &'static str = "pose_feature";
    const SOURCE: &'static str = include_str!("../../../shaders/pose_feature.wgsl");
    const BINDS: &'static [BindKind] =
        &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = PoseFeatureParams;
    type CpuTwin = fn(&[f32], &[f32], &[u32], usize, &mut [f32]);
    const CPU_TWIN: Self::CpuTwin = crate::cpu::pose_feature::pose_feature;
}

/// Records `slots` pose features of width `width`: `out[rows[s]] = pc[s] - ppf[rows[s]]`.
pub fn record<'a>(
    rec: &mut Recorder<'a>,
    (slots, width): (usize, usize),
    [pc, ppf, rows]: [&wgpu::Buffer; 3],
    out: &wgpu::Buffer,
) -> Result<()> {
    let params = PoseFeatureParams {
        slots: to_u32(slots, "pose feature rows")?,
        width: to_u32(width, "codeword")?,
        _pad0: 0,
        _pad1: 0,
    };
    to_u32(slots * width, "pose feature values")?;
    rec.dispatch::<PoseFeature>(&params, &[pc, ppf, rows, out], workgroups(slots * width, WG_SIZE))
}

/// Runs the kernel on slices; `out` holds the initial contents (a sentinel in tests) and receives the result.
pub async fn run(gpu: &Gpu, pc: &[f32], ppf: &[f32], rows: &[u32], width: usize, out: &mut [f32]) -> Result<()> {
    let scan_rows = ppf.len() / width.max(1);
    if width == 0
        || pc.len() != rows.len() * width
        || ppf.len() != out.len()
        || !ppf.len().is_multiple_of(width)
        || rows.iter().any(|&r| r as usize >= scan_rows)
    {
        return Err(Error::invalid("pose_feature: inputs do not fit the rows and width"));
    }
    let ctx = &gpu.context;
    let (p, f) = (GpuBuffer::from_slice(ctx, "pc", pc)?, GpuBuffer::from_slice(ctx, "ppf", ppf)?);
    let (r, o) = (GpuBuffer::from_slice(ctx, "rows", rows)?, GpuBuffer::from_slice(ctx, "out", out)?);
    let mut rec = Recorder::new(gpu, "pose_feature");
    record(&mut rec, (rows.len(), width), [p.raw(), f.raw(), r.raw()], o.raw())?;
    let read = rec.read(o.raw(), 0, (out.len() * 4) as u64);
    let bytes = rec.finish().await?;
    out.copy_from_slice(&bytemuck::pod_collect_to_vec::<u8, f32>(&bytes[read]));
    Ok(())
}
