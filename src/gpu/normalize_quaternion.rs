//! Host side of `shaders/normalize_quaternion.wgsl`: RelativeNet's raw outputs to unit quaternions.
//! CPU twin: [`crate::model::relativenet::normalize_quaternion`].

use super::kernel::{BindKind, KernelSpec, ParamsLayout, gpu_params};
use super::recorder::Recorder;
use super::{Gpu, to_u32, workgroups};
use crate::error::{Error, Result};
use crate::model::relativenet::MIN_QUATERNION_NORM;

gpu_params! {
    /// Mirrors `struct NormalizeQuaternionParams` in shaders/normalize_quaternion.wgsl.
    pub struct NormalizeQuaternionParams {
        /// Quaternions.
        pub rows: u32,
        /// Norms not above this give the identity ([`MIN_QUATERNION_NORM`]).
        pub min_norm: f32,
        /// Padding.
        pub _pad0: u32,
        /// Padding.
        pub _pad1: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 64;

/// The kernel's registry entry.
pub const SPEC: KernelSpec = KernelSpec {
    name: "normalize_quaternion",
    source: include_str!("../../shaders/normalize_quaternion.wgsl"),
    binds: &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadWrite],
    workgroup_size: WG_SIZE,
    params: ParamsLayout::of::<NormalizeQuaternionParams>(),
};

/// Records the normalisation of `rows` quaternions from `raw` into `out`.
pub fn record<'a>(
    rec: &mut Recorder<'a>,
    gpu: &'a Gpu,
    rows: usize,
    raw: &wgpu::Buffer,
    out: &wgpu::Buffer,
) -> Result<()> {
    let params = NormalizeQuaternionParams {
        rows: to_u32(rows, "quaternions")?,
        min_norm: MIN_QUATERNION_NORM,
        _pad0: 0,
        _pad1: 0,
    };
    rec.dispatch(&gpu.kernels.normalize_quaternion, &params, &[raw, out], workgroups(rows, WG_SIZE))
}

/// Runs the kernel on slices; `out` holds the initial contents (a sentinel in tests) and receives the result.
pub fn run(gpu: &Gpu, raw: &[[f32; 4]], out: &mut [[f32; 4]]) -> Result<()> {
    if raw.len() != out.len() {
        return Err(Error::invalid("normalize_quaternion: input and output lengths differ"));
    }
    let ctx = &gpu.context;
    let rb = super::buffer::GpuBuffer::from_slice(ctx, "raw", raw)?;
    let ob = super::buffer::GpuBuffer::from_slice(ctx, "quaternions", out)?;
    let mut rec = Recorder::new(gpu, "normalize_quaternion");
    record(&mut rec, gpu, raw.len(), rb.raw(), ob.raw())?;
    let r = rec.read(ob.raw(), 0, (out.len() * 16) as u64);
    let bytes = rec.finish()?;
    out.copy_from_slice(bytemuck::cast_slice(&bytes[r]));
    Ok(())
}
