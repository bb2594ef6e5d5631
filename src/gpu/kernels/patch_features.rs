//! Host side of `shaders/patch_features.wgsl`: PPF and PC network inputs of gathered patches, one invocation
//! per patch point. CPU twin: [`crate::cpu::patch_features`].

use crate::error::{Error, Result};
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};
use crate::model::config::PoseFrame;
use crate::preprocess::GatheredPatches;

gpu_params! {
    /// Mirrors `struct PatchFeaturesParams` in shaders/patch_features.wgsl.
    pub struct PatchFeaturesParams {
        /// Points in the dispatch (patches x points_per_patch).
        pub rows: u32,
        /// Points per patch (N).
        pub points_per_patch: u32,
        /// Patch radius r.
        pub radius: f32,
        /// 1: PC coordinates in the keypoint's normal frame (`PoseFrame::Normal`); 0: in the fragment's frame.
        pub normal_frame: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 64;

/// The `patch_features` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct PatchFeatures;

impl GpuKernel for PatchFeatures {
    const NAME: &'static str = "patch_features";
    const SOURCE: &'static str = include_str!("../../../shaders/patch_features.wgsl");
    const BINDS: &'static [BindKind] = &[
        BindKind::Uniform,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadWrite,
        BindKind::ReadWrite,
    ];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = PatchFeaturesParams;
    type CpuTwin =
        fn(&[[f32; 3]], &[[f32; 3]], &[[f32; 3]], &[[f32; 3]], usize, f32, PoseFrame) -> (Vec<f32>, Vec<f32>);
    const CPU_TWIN: Self::CpuTwin = crate::cpu::patch_features::patch_features;
}

/// Input and output buffers: centres and centre normals (xyz per patch), points and normals (xyz per point),
/// ppf (4 per point) and pc (3 per point).
pub struct PatchFeaturesBuffers<'b> {
    /// Patch centres.
    pub centers: &'b wgpu::Buffer,
    /// Patch centre normals.
    pub center_normals: &'b wgpu::Buffer,
    /// Neighbour points.
    pub points: &'b wgpu::Buffer,
    /// Neighbour normals.
    pub normals: &'b wgpu::Buffer,
    /// PPF output.
    pub ppf: &'b wgpu::Buffer,
    /// PC output.
    pub pc: &'b wgpu::Buffer,
}

/// Records one dispatch over `params.rows` points.
pub fn record<'a>(rec: &mut Recorder<'a>, params: &PatchFeaturesParams, b: &PatchFeaturesBuffers<'_>) -> Result<()> {
    rec.dispatch::<PatchFeatures>(
        params,
        &[b.centers, b.center_normals, b.points, b.normals, b.ppf, b.pc],
        workgroups(params.rows as usize, WG_SIZE),
    )
}

/// Runs the kernel on gathered patches in one dispatch (the inputs must fit the buffer cap). `ppf` and `pc` hold
/// the initial buffer contents (a sentinel in tests) and receive the result, as the twin's outputs.
pub async fn run(
    gpu: &Gpu,
    patches: &GatheredPatches,
    points_per_patch: usize,
    radius: f32,
    frame: PoseFrame,
    ppf: &mut [f32],
    pc: &mut [f32],
) -> Result<()> {
    let GatheredPatches { centers, center_normals, points, normals } = patches;
    let rows = points.len();
    let count = centers.len();
    if points_per_patch == 0
        || normals.len() != rows
        || center_normals.len() != count
        || rows != count * points_per_patch
        || ppf.len() != rows * 4
        || pc.len() != rows * 3
    {
        return Err(Error::invalid("patch_features: inconsistent input or output lengths"));
    }
    let ctx = &gpu.context;
    let up = |label, data: &[[f32; 3]]| crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, label, data);
    let (c, cn, p, n) = (
        up("centers", centers)?,
        up("center_normals", center_normals)?,
        up("points", points)?,
        up("normals", normals)?,
    );
    let ppf_buf = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "ppf", ppf)?;
    let pc_buf = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "pc", pc)?;
    let params = PatchFeaturesParams {
        rows: to_u32(rows, "patch points")?,
        points_per_patch: to_u32(points_per_patch, "points per patch")?,
        radius,
        normal_frame: u32::from(frame == PoseFrame::Normal),
    };
    let mut rec = Recorder::new(gpu, "patch_features");
    let buffers = PatchFeaturesBuffers {
        centers: c.raw(),
        center_normals: cn.raw(),
        points: p.raw(),
        normals: n.raw(),
        ppf: ppf_buf.raw(),
        pc: pc_buf.raw(),
    };
    record(&mut rec, &params, &buffers)?;
    let a = rec.read(ppf_buf.raw(), 0, (ppf.len() * 4) as u64);
    let b = rec.read(pc_buf.raw(), 0, (pc.len() * 4) as u64);
    let out = rec.finish().await?;
    ppf.copy_from_slice(bytemuck::cast_slice(&out[a]));
    pc.copy_from_slice(bytemuck::cast_slice(&out[b]));
    Ok(())
}
