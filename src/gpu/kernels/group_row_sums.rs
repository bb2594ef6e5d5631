//! Host side of `shaders/group_row_sums.wgsl`: rows summed over each group of consecutive rows. CPU twin:
//! [`crate::cpu::group_row_sums`].

use crate::error::{Error, Result};
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};

gpu_params! {
    /// Mirrors `struct GroupRowSumsParams` in shaders/group_row_sums.wgsl.
    pub struct GroupRowSumsParams {
        /// Groups (output rows).
        pub groups: u32,
        /// Input rows per group.
        pub rows_per_group: u32,
        /// Row width.
        pub width: u32,
        /// Padding.
        pub _pad: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 64;

/// The `group_row_sums` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct GroupRowSums;

impl GpuKernel for GroupRowSums {
    const NAME: &'static str = "group_row_sums";
    const SOURCE: &'static str = include_str!("../../../shaders/group_row_sums.wgsl");
    const BINDS: &'static [BindKind] = &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = GroupRowSumsParams;
    type CpuTwin = fn(&[f32], usize, usize) -> Vec<f32>;
    const CPU_TWIN: Self::CpuTwin = crate::cpu::group_row_sums::group_row_sums;
}

impl GroupRowSumsParams {
    /// Parameters for `groups x rows_per_group` rows of `width`.
    pub fn new(groups: usize, rows_per_group: usize, width: usize) -> Result<GroupRowSumsParams> {
        to_u32(groups * rows_per_group * width, "group_row_sums inputs")?;
        Ok(GroupRowSumsParams {
            groups: to_u32(groups, "group_row_sums groups")?,
            rows_per_group: to_u32(rows_per_group, "group_row_sums rows per group")?,
            width: to_u32(width, "group_row_sums width")?,
            _pad: 0,
        })
    }
}

/// Records the sums of `x` into `sums` (`groups x width`, overwritten).
pub fn record<'a>(
    rec: &mut Recorder<'a>,
    params: &GroupRowSumsParams,
    x: &wgpu::Buffer,
    sums: &wgpu::Buffer,
) -> Result<()> {
    let n = params.groups as usize * params.width as usize;
    rec.dispatch::<GroupRowSums>(params, &[x, sums], workgroups(n, WG_SIZE))
}

/// Runs the kernel on slices: `x` is `groups * rows_per_group x width`; `sums` (`groups x width`) holds the
/// initial contents (a sentinel in tests) and receives the result.
pub async fn run(gpu: &Gpu, x: &[f32], rows_per_group: usize, width: usize, sums: &mut [f32]) -> Result<()> {
    let groups = sums.len() / width.max(1);
    if rows_per_group == 0 || width == 0 || sums.is_empty() || x.len() != groups * rows_per_group * width {
        return Err(Error::invalid("group_row_sums: slice lengths do not match the shape"));
    }
    let ctx = &gpu.context;
    let xb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "x", x)?;
    let sb = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "sums", sums)?;
    let mut rec = Recorder::new(gpu, "group_row_sums");
    record(&mut rec, &GroupRowSumsParams::new(groups, rows_per_group, width)?, xb.raw(), sb.raw())?;
    let r = rec.read(sb.raw(), 0, (sums.len() * 4) as u64);
    let bytes = rec.finish().await?;
    sums.copy_from_slice(bytemuck::cast_slice(&bytes[r]));
    Ok(())
}
