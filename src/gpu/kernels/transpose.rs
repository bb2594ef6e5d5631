//! Host side of `shaders/transpose.wgsl`: a row-major matrix transposed (the trainer's refresh of each forward
//! weight after an optimiser step). CPU twin: [`crate::cpu::transpose`].

use crate::error::{Error, Result};
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};

gpu_params! {
    /// Mirrors `struct TransposeParams` in shaders/transpose.wgsl.
    pub struct TransposeParams {
        /// Rows of the input.
        pub rows: u32,
        /// Columns of the input.
        pub cols: u32,
        /// Padding.
        pub _pad0: u32,
        /// Padding.
        pub _pad1: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 64;

/// The `transpose` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct Transpose;

impl GpuKernel for Transpose {
    const NAME: &'static str = "transpose";
    const SOURCE: &'static str = include_str!("../../../shaders/transpose.wgsl");
    const BINDS: &'static [BindKind] = &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = TransposeParams;
    type CpuTwin = fn(&[f32], usize, usize) -> Vec<f32>;
    const CPU_TWIN: Self::CpuTwin = crate::cpu::transpose::transpose;
}

impl TransposeParams {
    /// Parameters for a `rows x cols` input.
    pub fn new(rows: usize, cols: usize) -> Result<TransposeParams> {
        to_u32(rows * cols, "transpose values")?;
        Ok(TransposeParams {
            rows: to_u32(rows, "transpose rows")?,
            cols: to_u32(cols, "transpose cols")?,
            _pad0: 0,
            _pad1: 0,
        })
    }
}

/// Records `out` (`cols x rows`) = `x` (`rows x cols`) transposed.
pub fn record<'a>(
    rec: &mut Recorder<'a>,
    params: &TransposeParams,
    x: &wgpu::Buffer,
    out: &wgpu::Buffer,
) -> Result<()> {
    let n = params.rows as usize * params.cols as usize;
    rec.dispatch::<Transpose>(params, &[x, out], workgroups(n, WG_SIZE))
}

/// Runs the kernel on slices: `out` (`cols x rows`) holds the initial contents (a sentinel in tests) and
/// receives the result.
pub async fn run(gpu: &Gpu, x: &[f32], rows: usize, cols: usize, out: &mut [f32]) -> Result<()> {
    if rows == 0 || cols == 0 || x.len() != rows * cols || out.len() != x.len() {
        return Err(Error::invalid("transpose: slice lengths do not match the shape"));
    }
    let ctx = &gpu.context;
    let xb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "x", x)?;
    let ob = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "out", out)?;
    let mut rec = Recorder::new(gpu, "transpose");
    record(&mut rec, &TransposeParams::new(rows, cols)?, xb.raw(), ob.raw())?;
    let r = rec.read(ob.raw(), 0, (out.len() * 4) as u64);
    let bytes = rec.finish().await?;
    out.copy_from_slice(bytemuck::cast_slice(&bytes[r]));
    Ok(())
}
