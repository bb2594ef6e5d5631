//! Host side of `shaders/hypotheses.wgsl`: one rigid pose per correspondence from its rotation.
//! CPU twin: [`crate::cpu::hypotheses`].

use crate::cpu::hypotheses::Hypothesis;
use crate::error::{Error, Result};
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};

gpu_params! {
    /// Mirrors `struct HypothesesParams` in shaders/hypotheses.wgsl.
    pub struct HypothesesParams {
        /// Correspondences.
        pub rows: u32,
        /// Padding.
        pub _pad0: u32,
        /// Padding.
        pub _pad1: u32,
        /// Padding.
        pub _pad2: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 64;
/// Floats per hypothesis on the GPU: rotation (row-major 3 x 3), then translation.
pub const HYPOTHESIS_FLOATS: usize = 12;

/// The `hypotheses` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct Hypotheses;

impl GpuKernel for Hypotheses {
    const NAME: &'static str = "hypotheses";
    const SOURCE: &'static str = include_str!("../../../shaders/hypotheses.wgsl");
    const BINDS: &'static [BindKind] =
        &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = HypothesesParams;
    type CpuTwin = fn(&[[f32; 9]], &[[f32; 3]], &[[f32; 3]]) -> Vec<Hypothesis>;
    const CPU_TWIN: Self::CpuTwin = crate::cpu::hypotheses::hypotheses;
}

/// A hypothesis as its 12 GPU floats.
pub fn to_row(h: &Hypothesis) -> [f32; HYPOTHESIS_FLOATS] {
    let mut row = [0.0; HYPOTHESIS_FLOATS];
    row[..9].copy_from_slice(&h.rotation);
    row[9..].copy_from_slice(&h.translation);
    row
}

/// A hypothesis from its 12 GPU floats.
pub fn from_row(row: &[f32]) -> Hypothesis {
    let mut h = Hypothesis { rotation: [0.0; 9], translation: [0.0; 3] };
    h.rotation.copy_from_slice(&row[..9]);
    h.translation.copy_from_slice(&row[9..HYPOTHESIS_FLOATS]);
    h
}

/// Records `rows` hypotheses from `rotations` (9 floats per row), `source` and `target` into `out`.
pub fn record<'a>(
    rec: &mut Recorder<'a>,
    rows: usize,
    [rotations, source, target]: [&wgpu::Buffer; 3],
    out: &wgpu::Buffer,
) -> Result<()> {
    let params = HypothesesParams { rows: to_u32(rows, "hypotheses")?, _pad0: 0, _pad1: 0, _pad2: 0 };
    rec.dispatch::<Hypotheses>(&params, &[rotations, source, target, out], workgroups(rows, WG_SIZE))
}

/// Runs the kernel on slices; `out` holds the initial contents (a sentinel in tests) and receives the result.
pub async fn run(
    gpu: &Gpu,
    rotations: &[[f32; 9]],
    source: &[[f32; 3]],
    target: &[[f32; 3]],
    out: &mut [Hypothesis],
) -> Result<()> {
    let rows = rotations.len();
    if source.len() != rows || target.len() != rows || out.len() != rows {
        return Err(Error::invalid("hypotheses: rotations, points and outputs must have the same length"));
    }
    let ctx = &gpu.context;
    let init: Vec<[f32; HYPOTHESIS_FLOATS]> = out.iter().map(to_row).collect();
    let q = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "rotations", rotations)?;
    let s = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "source", source)?;
    let t = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "target", target)?;
    let o = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "hypotheses", &init)?;
    let mut rec = Recorder::new(gpu, "hypotheses");
    record(&mut rec, rows, [q.raw(), s.raw(), t.raw()], o.raw())?;
    let r = rec.read(o.raw(), 0, (rows * HYPOTHESIS_FLOATS * 4) as u64);
    let bytes = rec.finish().await?;
    let floats: Vec<f32> = bytemuck::pod_collect_to_vec(&bytes[r]);
    for (h, row) in out.iter_mut().zip(floats.chunks_exact(HYPOTHESIS_FLOATS)) {
        *h = from_row(row);
    }
    Ok(())
}
