//! Host side of `shaders/chamfer_grad.wgsl`: the Chamfer distance of each patch pair and its gradient w.r.t. the
//! reconstruction (the second half of the reconstruction loss). CPU twin: [`crate::cpu::chamfer_grad`].

use crate::error::{Error, Result};
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};

gpu_params! {
    /// Mirrors `struct ChamferGradParams` in shaders/chamfer_grad.wgsl.
    pub struct ChamferGradParams {
        /// Patch pairs.
        pub patches: u32,
        /// Input points per patch.
        pub n: u32,
        /// Reconstructed points per patch.
        pub m: u32,
        /// Values per point.
        pub dim: u32,
        /// Factor of every gradient element (the loss weight and the batch mean).
        pub scale: f32,
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

/// The widest point the kernel takes (`MAX_DIM` in the shader).
pub const MAX_DIM: usize = 8;

/// The `chamfer_grad` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct ChamferGrad;

impl GpuKernel for ChamferGrad {
    const NAME: &'static str = "chamfer_grad";
    const SOURCE: &'static str = include_str!("../../../shaders/chamfer_grad.wgsl");
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
    type Params = ChamferGradParams;
    type CpuTwin = fn(&[f32], &[f32], usize, (usize, usize), (&[u32], &[f64]), f32) -> (Vec<f64>, Vec<f32>);
    const CPU_TWIN: Self::CpuTwin = crate::cpu::chamfer_grad::chamfer_grad;
}

impl ChamferGradParams {
    /// Parameters for `patches` pairs of `n` input and `m` reconstructed points of `dim` (at most [`MAX_DIM`])
    /// values, the gradient times `scale`.
    pub fn new(patches: usize, (n, m): (usize, usize), dim: usize, scale: f32) -> Result<ChamferGradParams> {
        if n == 0 || m == 0 || dim == 0 || dim > MAX_DIM {
            return Err(Error::invalid(format!(
                "chamfer_grad: needs non-empty point sets of 1..={MAX_DIM} values (n {n}, m {m}, dim {dim})"
            )));
        }
        to_u32(patches * (n + m).max(dim * n.max(m)), "chamfer_grad rows")?;
        Ok(ChamferGradParams {
            patches: to_u32(patches, "chamfer_grad patches")?,
            n: to_u32(n, "chamfer_grad n")?,
            m: to_u32(m, "chamfer_grad m")?,
            dim: to_u32(dim, "chamfer_grad dim")?,
            scale,
            ..Default::default()
        })
    }
}

/// Records the loss and gradient: `grad` (`patches * m x dim`) and `loss` (`patches`) are overwritten.
pub fn record<'a>(
    rec: &mut Recorder<'a>,
    params: &ChamferGradParams,
    [x, y, nearest, distance]: [&wgpu::Buffer; 4],
    [grad, loss]: [&wgpu::Buffer; 2],
) -> Result<()> {
    let rows = params.patches as usize * params.m as usize;
    rec.dispatch::<ChamferGrad>(params, &[x, y, nearest, distance, grad, loss], workgroups(rows, WG_SIZE))
}

/// Runs the kernel on slices (shapes as [`crate::cpu::chamfer_grad::chamfer_grad`], distances in f32); returns
/// the per-patch losses and the gradient.
pub async fn run(
    gpu: &Gpu,
    [x, y]: [&[f32]; 2],
    dim: usize,
    (n, m): (usize, usize),
    (nearest, distance): (&[u32], &[f32]),
    scale: f32,
) -> Result<(Vec<f32>, Vec<f32>)> {
    let patches = nearest.len() / (n + m).max(1);
    let fits = x.len() == patches * n * dim && y.len() == patches * m * dim && distance.len() == nearest.len();
    if n == 0 || m == 0 || nearest.len() != patches * (n + m) || !fits {
        return Err(Error::invalid("chamfer_grad: slice lengths do not match the shape"));
    }
    let params = ChamferGradParams::new(patches, (n, m), dim, scale)?;
    let ctx = &gpu.context;
    let up = |label: &str, v: &[f32]| crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, label, v);
    let (xb, yb, db) = (up("x", x)?, up("y", y)?, up("distance", distance)?);
    let nb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "nearest", nearest)?;
    let grad = crate::gpu::device::buffer::storage_buffer(ctx, "grad", (y.len() * 4) as u64)?;
    let loss = crate::gpu::device::buffer::storage_buffer(ctx, "loss", (patches * 4) as u64)?;
    let mut rec = Recorder::new(gpu, "chamfer_grad");
    record(&mut rec, &params, [xb.raw(), yb.raw(), nb.raw(), db.raw()], [&grad, &loss])?;
    let (rg, rl) = (rec.read(&grad, 0, (y.len() * 4) as u64), rec.read(&loss, 0, (patches * 4) as u64));
    let bytes = rec.finish().await?;
    Ok((bytemuck::pod_collect_to_vec(&bytes[rl]), bytemuck::pod_collect_to_vec(&bytes[rg])))
}
