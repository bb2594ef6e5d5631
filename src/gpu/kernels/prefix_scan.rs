//! Host side of `shaders/prefix_scan.wgsl`: exclusive prefix sums of u32 values (per-block scans, a scan of
//! the block totals, then the block offsets added). CPU twin: [`crate::cpu::prefix_scan`].

use crate::error::Result;
use crate::gpu::device::buffer::GpuBuffer;
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};

gpu_params! {
    /// Mirrors `struct PrefixScanParams` in shaders/prefix_scan.wgsl.
    pub struct PrefixScanParams {
        /// Values.
        pub n: u32,
        /// [`MODE_BLOCKS`], [`MODE_SUMS`] or [`MODE_ADD`].
        pub mode: u32,
        /// Blocks of [`WG_SIZE`] values.
        pub blocks: u32,
        /// Padding.
        pub _pad: u32,
    }
}

/// Invocations per workgroup and values per block (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 256;
/// Per-block scans.
pub const MODE_BLOCKS: u32 = 0;
/// The scan of the block totals.
pub const MODE_SUMS: u32 = 1;
/// Block offsets added.
pub const MODE_ADD: u32 = 2;

/// The `prefix_scan` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct PrefixScan;

impl GpuKernel for PrefixScan {
    const NAME: &'static str = "prefix_scan";
    const SOURCE: &'static str = include_str!("../../../shaders/prefix_scan.wgsl");
    const BINDS: &'static [BindKind] =
        &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadWrite, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = PrefixScanParams;
    type CpuTwin = fn(&[u32]) -> (Vec<u32>, u32);
    const CPU_TWIN: Self::CpuTwin = crate::cpu::prefix_scan::prefix_scan;
}

/// Blocks of `n` values.
pub fn blocks(n: usize) -> usize {
    workgroups(n, WG_SIZE) as usize
}

/// Records the scan of `n` values into `sums`; `block_sums` (`blocks(n) + 1` words) ends with the scanned
/// block offsets and, at index `blocks(n)`, the total.
pub fn record(
    rec: &mut Recorder<'_>,
    n: usize,
    values: &wgpu::Buffer,
    sums: &wgpu::Buffer,
    block_sums: &wgpu::Buffer,
) -> Result<()> {
    let b = blocks(n);
    let mut params = PrefixScanParams {
        n: to_u32(n, "scan values")?,
        mode: MODE_BLOCKS,
        blocks: to_u32(b, "scan blocks")?,
        _pad: 0,
    };
    let bufs = [values, sums, block_sums];
    rec.dispatch::<PrefixScan>(&params, &bufs, b as u64)?;
    params.mode = MODE_SUMS;
    rec.dispatch::<PrefixScan>(&params, &bufs, 1)?;
    params.mode = MODE_ADD;
    rec.dispatch::<PrefixScan>(&params, &bufs, b as u64)
}

/// Runs the scan on a slice: the exclusive sums and the total.
pub async fn run(gpu: &Gpu, values: &[u32]) -> Result<(Vec<u32>, u32)> {
    let n = values.len();
    let ctx = &gpu.context;
    let vb = GpuBuffer::from_slice(ctx, "scan_values", if n == 0 { &[0u32][..] } else { values })?;
    let sb = GpuBuffer::from_slice(ctx, "scan_sums", &vec![0xDEAD_BEEFu32; n.max(1)])?;
    let bb = GpuBuffer::from_slice(ctx, "scan_blocks", &vec![0xDEAD_BEEFu32; blocks(n) + 1])?;
    let mut rec = Recorder::new(gpu, "prefix_scan");
    record(&mut rec, n, vb.raw(), sb.raw(), bb.raw())?;
    let (rs, rt) = (rec.read(sb.raw(), 0, (n * 4) as u64), rec.read(bb.raw(), (blocks(n) * 4) as u64, 4));
    let out = rec.finish().await?;
    Ok((bytemuck::pod_collect_to_vec(&out[rs]), bytemuck::pod_read_unaligned(&out[rt][..4])))
}
