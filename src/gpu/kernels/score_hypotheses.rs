//! Host side of `shaders/score_hypotheses.wgsl`: inlier count and residual sum of every hypothesis over
//! every correspondence, one workgroup per hypothesis, plus the inlier mask of one hypothesis for
//! refinement. CPU twin: [`crate::cpu::score_hypotheses`].

use super::hypotheses::{HYPOTHESIS_FLOATS, to_row};
use crate::cpu::hypotheses::Hypothesis;
use crate::cpu::score_hypotheses::HypothesisScore;
use crate::error::{Error, Result};
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32};

gpu_params! {
    /// Mirrors `struct ScoreHypothesesParams` in shaders/score_hypotheses.wgsl.
    pub struct ScoreHypothesesParams {
        /// Hypotheses (one workgroup each).
        pub hypotheses: u32,
        /// Correspondences.
        pub correspondences: u32,
        /// Squared inlier threshold.
        pub threshold_sq: f32,
        /// 1: hypothesis 0 writes its per-correspondence inlier flags.
        pub write_mask: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 64;

/// The `score_hypotheses` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct ScoreHypotheses;

impl GpuKernel for ScoreHypotheses {
    const NAME: &'static str = "score_hypotheses";
    const SOURCE: &'static str = include_str!("../../../shaders/score_hypotheses.wgsl");
    const BINDS: &'static [BindKind] = &[
        BindKind::Uniform,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadWrite,
        BindKind::ReadWrite,
        BindKind::ReadWrite,
    ];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = ScoreHypothesesParams;
    type CpuTwin = fn(&[Hypothesis], &[[f32; 3]], &[[f32; 3]], f32) -> Vec<HypothesisScore>;
    const CPU_TWIN: Self::CpuTwin = crate::cpu::score_hypotheses::score_hypotheses;
}

/// Output buffers: inlier counts (u32 per hypothesis), residual sums (f32 per hypothesis), mask (u32 per
/// correspondence, written only with `write_mask`).
pub struct ScoreBuffers<'b> {
    /// Inlier counts.
    pub inliers: &'b wgpu::Buffer,
    /// Residual sums.
    pub residual_sums: &'b wgpu::Buffer,
    /// Inlier mask of hypothesis 0.
    pub mask: &'b wgpu::Buffer,
}

/// Records the scoring of `params.hypotheses` hypotheses (`hypotheses`: 12 floats each) over the
/// correspondences `source[i] -> target[i]`.
pub fn record<'a>(
    rec: &mut Recorder<'a>,
    params: &ScoreHypothesesParams,
    [hypotheses, source, target]: [&wgpu::Buffer; 3],
    out: &ScoreBuffers<'_>,
) -> Result<()> {
    rec.dispatch::<ScoreHypotheses>(
        params,
        &[hypotheses, source, target, out.inliers, out.residual_sums, out.mask],
        u64::from(params.hypotheses),
    )
}

/// Validates the correspondence arrays and returns their length.
fn correspondences(source: &[[f32; 3]], target: &[[f32; 3]]) -> Result<usize> {
    if source.len() != target.len() {
        return Err(Error::invalid("score_hypotheses: source and target points differ in length"));
    }
    Ok(source.len())
}

/// Runs the kernel on slices in one dispatch; `out` holds the initial contents (a sentinel in tests) and
/// receives the scores.
pub async fn run(
    gpu: &Gpu,
    hypotheses: &[Hypothesis],
    source: &[[f32; 3]],
    target: &[[f32; 3]],
    threshold: f32,
    out: &mut [HypothesisScore],
) -> Result<()> {
    let c = correspondences(source, target)?;
    if out.len() != hypotheses.len() {
        return Err(Error::invalid("score_hypotheses: one output per hypothesis"));
    }
    let ctx = &gpu.context;
    let rows: Vec<[f32; HYPOTHESIS_FLOATS]> = hypotheses.iter().map(to_row).collect();
    let up3 = |label, d: &[[f32; 3]]| crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, label, d);
    let hb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "hypotheses", &rows)?;
    let (sb, tb) = (up3("source", source)?, up3("target", target)?);
    let inl: Vec<u32> = out.iter().map(|s| s.inliers).collect();
    let res: Vec<f32> = out.iter().map(|s| s.residual_sum).collect();
    let ib = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "inliers", &inl)?;
    let rb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "residual_sums", &res)?;
    let params = ScoreHypothesesParams {
        hypotheses: to_u32(hypotheses.len(), "hypotheses")?,
        correspondences: to_u32(c, "correspondences")?,
        threshold_sq: threshold * threshold,
        write_mask: 0,
    };
    let mut rec = Recorder::new(gpu, "score_hypotheses");
    let bufs = ScoreBuffers { inliers: ib.raw(), residual_sums: rb.raw(), mask: &gpu.dummy_rw };
    record(&mut rec, &params, [hb.raw(), sb.raw(), tb.raw()], &bufs)?;
    let bytes = (out.len() * 4) as u64;
    let (a, b) = (rec.read(ib.raw(), 0, bytes), rec.read(rb.raw(), 0, bytes));
    let data = rec.finish().await?;
    let counts: Vec<u32> = bytemuck::pod_collect_to_vec(&data[a]);
    let sums: Vec<f32> = bytemuck::pod_collect_to_vec(&data[b]);
    for ((s, &inliers), &residual_sum) in out.iter_mut().zip(&counts).zip(&sums) {
        *s = HypothesisScore { inliers, residual_sum };
    }
    Ok(())
}

/// Per-correspondence inlier flags of one hypothesis (`|p_t - (R p_s + t)|^2 < threshold^2`), for the
/// refinement on the best hypothesis's inliers; `mask` holds the initial contents and receives 0 or 1.
pub async fn inlier_mask(
    gpu: &Gpu,
    hypothesis: &Hypothesis,
    source: &[[f32; 3]],
    target: &[[f32; 3]],
    threshold: f32,
    mask: &mut [u32],
) -> Result<()> {
    let c = correspondences(source, target)?;
    if mask.len() != c {
        return Err(Error::invalid("inlier_mask: one flag per correspondence"));
    }
    let ctx = &gpu.context;
    let hb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "hypothesis", &to_row(hypothesis))?;
    let sb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "source", source)?;
    let tb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "target", target)?;
    let mb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "mask", mask)?;
    let scratch = crate::gpu::device::buffer::GpuBuffer::<u32>::from_slice(ctx, "score", &[0, 0])?;
    let params = ScoreHypothesesParams {
        hypotheses: 1,
        correspondences: to_u32(c, "correspondences")?,
        threshold_sq: threshold * threshold,
        write_mask: 1,
    };
    let mut rec = Recorder::new(gpu, "inlier_mask");
    let bufs = ScoreBuffers { inliers: scratch.raw(), residual_sums: &gpu.dummy_rw, mask: mb.raw() };
    record(&mut rec, &params, [hb.raw(), sb.raw(), tb.raw()], &bufs)?;
    let r = rec.read(mb.raw(), 0, (c * 4) as u64);
    let data = rec.finish().await?;
    mask.copy_from_slice(bytemuck::cast_slice(&data[r]));
    Ok(())
}
