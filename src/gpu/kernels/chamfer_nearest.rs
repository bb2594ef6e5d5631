//! Host side of `shaders/chamfer_nearest.wgsl`: each point's nearest point of the other set, per patch pair (the
//! first half of the reconstruction loss). CPU twin: [`crate::cpu::chamfer_nearest`].

use crate::error::{Error, Result};
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};

gpu_params! {
    /// Mirrors `struct ChamferNearestParams` in shaders/chamfer_nearest.wgsl.
    pub struct ChamferNearestParams {
        /// Patch pairs.
        pub patches: u32,
        /// Input points per patch.
        pub n: u32,
        /// Reconstructed points per patch.
        pub m: u32,
        /// Values per point.
        pub dim: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 64;

/// The `chamfer_nearest` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct ChamferNearest;

impl GpuKernel for ChamferNearest {
    const NAME: &'static str = "chamfer_nearest";
    const SOURCE: &'static str = include_str!("../../../shaders/chamfer_nearest.wgsl");
    const BINDS: &'static [BindKind] =
        &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadWrite, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = ChamferNearestParams;
    type CpuTwin = fn(&[f32], &[f32], usize, (usize, usize)) -> (Vec<u32>, Vec<f64>);
    const CPU_TWIN: Self::CpuTwin = crate::cpu::chamfer_nearest::chamfer_nearest;
}

impl ChamferNearestParams {
    /// Parameters for `patches` pairs of `n` input and `m` reconstructed points of `dim` values (none empty).
    pub fn new(patches: usize, (n, m): (usize, usize), dim: usize) -> Result<ChamferNearestParams> {
        if n == 0 || m == 0 || dim == 0 {
            return Err(Error::invalid("chamfer_nearest: empty point sets"));
        }
        to_u32(patches * (n + m).max(dim * n.max(m)), "chamfer_nearest rows")?;
        Ok(ChamferNearestParams {
            patches: to_u32(patches, "chamfer_nearest patches")?,
            n: to_u32(n, "chamfer_nearest n")?,
            m: to_u32(m, "chamfer_nearest m")?,
            dim: to_u32(dim, "chamfer_nearest dim")?,
        })
    }
}

/// Records the search: `nearest` (u32) and `distance` (f32), `patches * (n + m)` each, overwritten.
pub fn record<'a>(
    rec: &mut Recorder<'a>,
    params: &ChamferNearestParams,
    [x, y]: [&wgpu::Buffer; 2],
    [nearest, distance]: [&wgpu::Buffer; 2],
) -> Result<()> {
    let rows = params.patches as usize * (params.n + params.m) as usize;
    rec.dispatch::<ChamferNearest>(params, &[x, y, nearest, distance], workgroups(rows, WG_SIZE))
}

/// Runs the kernel on slices: `x` is `patches * n x dim`, `y` `patches * m x dim`; returns the nearest indices
/// and distances as the twin orders them.
pub async fn run(gpu: &Gpu, x: &[f32], y: &[f32], dim: usize, (n, m): (usize, usize)) -> Result<(Vec<u32>, Vec<f32>)> {
    let patches = x.len() / (n * dim).max(1);
    if n == 0 || m == 0 || dim == 0 || x.len() != patches * n * dim || y.len() != patches * m * dim {
        return Err(Error::invalid("chamfer_nearest: slice lengths do not match the shape"));
    }
    let ctx = &gpu.context;
    let rows = patches * (n + m);
    let xb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "x", x)?;
    let yb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "y", y)?;
    let nearest = crate::gpu::device::buffer::storage_buffer(ctx, "nearest", (rows * 4) as u64)?;
    let distance = crate::gpu::device::buffer::storage_buffer(ctx, "distance", (rows * 4) as u64)?;
    let mut rec = Recorder::new(gpu, "chamfer_nearest");
    record(&mut rec, &ChamferNearestParams::new(patches, (n, m), dim)?, [xb.raw(), yb.raw()], [&nearest, &distance])?;
    let (rn, rd) = (rec.read(&nearest, 0, (rows * 4) as u64), rec.read(&distance, 0, (rows * 4) as u64));
    let bytes = rec.finish().await?;
    Ok((bytemuck::pod_collect_to_vec(&bytes[rn]), bytemuck::pod_collect_to_vec(&bytes[rd])))
}
