//! Host side of `shaders/rotation_head.wgsl`: RelativeNet's raw outputs (quaternion or 6-D) to rotations
//! target_from_source in the fragments' frames. CPU twin: [`crate::cpu::rotation_head`].

use crate::cpu::rotation_head::{MIN_NORM, MIN_ORTHOGONAL_SHARE};
use crate::error::{Error, Result};
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};
use crate::model::config::{PoseFrame, RotationOutput};

gpu_params! {
    /// Mirrors `struct RotationHeadParams` in shaders/rotation_head.wgsl.
    pub struct RotationHeadParams {
        /// Rows (correspondences).
        pub rows: u32,
        /// Raw values per row: 4 (quaternion), 6 (two columns) or the angle bins.
        pub width: u32,
        /// 1 for normal-aligned patches, 0 for fragment-frame patches.
        pub frame: u32,
        /// 0 quaternion, 1 6-D, 2 angle bins.
        pub mode: u32,
        /// Rotations per row (1, or the angle candidates).
        pub candidates: u32,
        /// Norms not above this give the identity ([`MIN_NORM`]).
        pub min_norm: f32,
        /// `cpu::rotation_head::MIN_ORTHOGONAL_SHARE`.
        pub min_orthogonal_share: f32,
        /// Padding.
        pub _pad1: u32,
    }
}

impl RotationHeadParams {
    /// Parameters for `rows` rows of `output` in `frame`.
    pub fn new(rows: usize, output: RotationOutput, frame: PoseFrame) -> Result<RotationHeadParams> {
        let mode = match output {
            RotationOutput::Quaternion => 0,
            RotationOutput::SixD => 1,
            RotationOutput::AngleBins { .. } => 2,
        };
        Ok(RotationHeadParams {
            rows: to_u32(rows, "rotations")?,
            width: to_u32(output.width(), "rotation output width")?,
            frame: u32::from(frame == PoseFrame::Normal),
            mode,
            candidates: to_u32(output.candidates(), "rotation candidates")?,
            min_norm: MIN_NORM,
            min_orthogonal_share: MIN_ORTHOGONAL_SHARE,
            _pad1: 0,
        })
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 64;

/// The `rotation_head` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct RotationHead;

impl GpuKernel for RotationHead {
    const NAME: &'static str = "rotation_head";
    const SOURCE: &'static str = include_str!("../../../shaders/rotation_head.wgsl");
    const BINDS: &'static [BindKind] =
        &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = RotationHeadParams;
    type CpuTwin = fn(&[f32], RotationOutput, PoseFrame, &[[f32; 3]], &[[f32; 3]]) -> Vec<[f32; 9]>;
    const CPU_TWIN: Self::CpuTwin = crate::cpu::rotation_head::rotation_head;
}

/// Records the rotations of `params.rows` rows: `raw` outputs and the rows' keypoint normals into `out`
/// (`candidates x 9` floats per row).
pub fn record<'a>(
    rec: &mut Recorder<'a>,
    params: &RotationHeadParams,
    [raw, source_normals, target_normals]: [&wgpu::Buffer; 3],
    out: &wgpu::Buffer,
) -> Result<()> {
    let groups = workgroups(params.rows as usize, WG_SIZE);
    rec.dispatch::<RotationHead>(params, &[raw, source_normals, target_normals, out], groups)
}

/// Runs the kernel on slices; `out` holds the initial contents (a sentinel in tests) and receives the result.
pub async fn run(
    gpu: &Gpu,
    raw: &[f32],
    output: RotationOutput,
    frame: PoseFrame,
    [source_normals, target_normals]: [&[[f32; 3]]; 2],
    out: &mut [[f32; 9]],
) -> Result<()> {
    let rows = source_normals.len();
    let m = output.candidates();
    if raw.len() != rows * output.width() || target_normals.len() != rows || out.len() != rows * m {
        return Err(Error::invalid("rotation_head: raw outputs, normals and outputs differ in length"));
    }
    let ctx = &gpu.context;
    let params = RotationHeadParams::new(rows, output, frame)?;
    let rb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "raw", raw)?;
    let sb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "source_normals", source_normals)?;
    let tb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "target_normals", target_normals)?;
    let ob = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "rotations", out)?;
    let mut rec = Recorder::new(gpu, "rotation_head");
    record(&mut rec, &params, [rb.raw(), sb.raw(), tb.raw()], ob.raw())?;
    let r = rec.read(ob.raw(), 0, (out.len() * 36) as u64);
    let bytes = rec.finish().await?;
    out.copy_from_slice(bytemuck::cast_slice(&bytes[r]));
    Ok(())
}
