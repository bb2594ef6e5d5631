//! Host side of `shaders/adam_step.wgsl`: one AdamW update of one tensor on the device, in f32. CPU twin:
//! [`crate::cpu::adam_step`] (f64 per element).

use crate::cpu::adam_step::AdamStep as Step;
use crate::error::{Error, Result};
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};

gpu_params! {
    /// Mirrors `struct AdamStepParams` in shaders/adam_step.wgsl.
    pub struct AdamStepParams {
        /// Learning rate of this step.
        pub lr: f32,
        /// First-moment decay.
        pub beta1: f32,
        /// `1 - beta1`, computed in f64.
        pub one_minus_beta1: f32,
        /// Second-moment decay.
        pub beta2: f32,
        /// `1 - beta2`, computed in f64.
        pub one_minus_beta2: f32,
        /// Denominator guard.
        pub eps: f32,
        /// Decoupled weight decay (0 for a tensor that takes none).
        pub weight_decay: f32,
        /// First-moment bias correction.
        pub c1: f32,
        /// Second-moment bias correction.
        pub c2: f32,
        /// Elements.
        pub len: u32,
        /// Padding.
        pub _pad0: u32,
        /// Padding.
        pub _pad1: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 64;

/// The `adam_step` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct AdamStep;

impl GpuKernel for AdamStep {
    const NAME: &'static str = "adam_step";
    const SOURCE: &'static str = include_str!("../../../shaders/adam_step.wgsl");
    const BINDS: &'static [BindKind] =
        &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadWrite, BindKind::ReadWrite, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = AdamStepParams;
    type CpuTwin = fn(&Step, bool, &mut [f32], &[f32], &mut [f32], &mut [f32]);
    const CPU_TWIN: Self::CpuTwin = crate::cpu::adam_step::adam_step;
}

impl AdamStepParams {
    /// Parameters for one tensor of `len` elements, with weight decay when `decay`.
    pub fn new(step: &Step, decay: bool, len: usize) -> Result<AdamStepParams> {
        Ok(AdamStepParams {
            lr: step.lr as f32,
            beta1: step.beta1 as f32,
            one_minus_beta1: (1.0 - step.beta1) as f32,
            beta2: step.beta2 as f32,
            one_minus_beta2: (1.0 - step.beta2) as f32,
            eps: step.eps as f32,
            weight_decay: if decay { step.weight_decay as f32 } else { 0.0 },
            c1: step.c1 as f32,
            c2: step.c2 as f32,
            len: to_u32(len, "adam_step elements")?,
            _pad0: 0,
            _pad1: 0,
        })
    }
}

/// Records the update of one tensor: `value`, `m` and `v` are updated in place from `grad`.
pub fn record<'a>(
    rec: &mut Recorder<'a>,
    params: &AdamStepParams,
    grad: &wgpu::Buffer,
    value: &wgpu::Buffer,
    m: &wgpu::Buffer,
    v: &wgpu::Buffer,
) -> Result<()> {
    rec.dispatch::<AdamStep>(params, &[grad, value, m, v], workgroups(params.len as usize, WG_SIZE))
}

/// Runs the kernel on slices (all of one length), updating `value`, `m` and `v` in place.
pub async fn run(
    gpu: &Gpu,
    step: &Step,
    decay: bool,
    value: &mut [f32],
    grad: &[f32],
    m: &mut [f32],
    v: &mut [f32],
) -> Result<()> {
    let n = value.len();
    if grad.len() != n || m.len() != n || v.len() != n || n == 0 {
        return Err(Error::invalid("adam_step: slice lengths differ or are empty"));
    }
    let ctx = &gpu.context;
    let upload = |label: &str, data: &[f32]| crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, label, data);
    let (gb, xb, mb, vb) = (upload("grad", grad)?, upload("value", value)?, upload("m", m)?, upload("v", v)?);
    let mut rec = Recorder::new(gpu, "adam_step");
    record(&mut rec, &AdamStepParams::new(step, decay, n)?, gb.raw(), xb.raw(), mb.raw(), vb.raw())?;
    let bytes = (n * 4) as u64;
    let reads = [rec.read(xb.raw(), 0, bytes), rec.read(mb.raw(), 0, bytes), rec.read(vb.raw(), 0, bytes)];
    let out = rec.finish().await?;
    for (dst, r) in [value, m, v].into_iter().zip(reads) {
        dst.copy_from_slice(bytemuck::cast_slice(&out[r]));
    }
    Ok(())
}
