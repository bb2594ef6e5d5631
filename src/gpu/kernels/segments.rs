//! Host side of `shaders/segments.wgsl`: the runs of equal keys in sorted keys (heads flagged, numbered by
//! [`super::prefix_scan`], scattered), i.e. the cell table of a grid. CPU twin: [`crate::cpu::segments`].

use super::prefix_scan;
use crate::cpu::cell_keys::SortKey;
use crate::cpu::segments::Segments;
use crate::error::Result;
use crate::gpu::device::buffer::{GpuBuffer, storage_buffer};
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};

gpu_params! {
    /// Mirrors `struct SegmentsParams` in shaders/segments.wgsl.
    pub struct SegmentsParams {
        /// Sorted keys (excluding padding).
        pub n: u32,
        /// [`MODE_HEADS`] or [`MODE_SCATTER`].
        pub mode: u32,
        /// Padding.
        pub _pad0: u32,
        /// Padding.
        pub _pad1: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 256;
/// Flag the heads of runs.
pub const MODE_HEADS: u32 = 0;
/// Scatter run starts and keys.
pub const MODE_SCATTER: u32 = 1;

/// The `segments` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct SegmentsKernel;

impl GpuKernel for SegmentsKernel {
    const NAME: &'static str = "segments";
    const SOURCE: &'static str = include_str!("../../../shaders/segments.wgsl");
    const BINDS: &'static [BindKind] = &[
        BindKind::Uniform,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadWrite,
        BindKind::ReadWrite,
        BindKind::ReadWrite,
    ];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = SegmentsParams;
    type CpuTwin = fn(&[SortKey]) -> Segments;
    const CPU_TWIN: Self::CpuTwin = crate::cpu::segments::segments;
}

/// The buffers of a cell table over `n` sorted keys (sized for the worst case of `n` runs).
pub struct SegmentBuffers {
    /// Head flags (n).
    pub heads: wgpu::Buffer,
    /// Run number of each element (n).
    pub offsets: wgpu::Buffer,
    /// The scan's block offsets, then at [`SegmentBuffers::count_offset`] the number of runs.
    pub block_sums: wgpu::Buffer,
    /// Run starts (runs + 1).
    pub starts: wgpu::Buffer,
    /// Run keys (runs x 2).
    pub run_keys: wgpu::Buffer,
    /// Sorted keys.
    pub n: usize,
}

impl SegmentBuffers {
    /// Allocates the buffers for `n` sorted keys.
    pub fn new(gpu: &Gpu, n: usize) -> Result<SegmentBuffers> {
        let ctx = &gpu.context;
        Ok(SegmentBuffers {
            heads: storage_buffer(ctx, "seg_heads", (n * 4) as u64)?,
            offsets: storage_buffer(ctx, "seg_offsets", (n * 4) as u64)?,
            block_sums: storage_buffer(ctx, "seg_block_sums", ((prefix_scan::blocks(n) + 1) * 4) as u64)?,
            starts: storage_buffer(ctx, "seg_starts", ((n + 1) * 4) as u64)?,
            run_keys: storage_buffer(ctx, "seg_run_keys", (n * 8) as u64)?,
            n,
        })
    }

    /// Byte offset of the number of runs in `block_sums`.
    pub fn count_offset(&self) -> u64 {
        (prefix_scan::blocks(self.n) * 4) as u64
    }
}

/// Records the cell table of the first `b.n` keys of `keys` (sorted).
pub fn record(rec: &mut Recorder<'_>, keys: &wgpu::Buffer, b: &SegmentBuffers) -> Result<()> {
    let mut params = SegmentsParams { n: to_u32(b.n, "sorted keys")?, mode: MODE_HEADS, _pad0: 0, _pad1: 0 };
    let wg = workgroups(b.n, WG_SIZE);
    rec.dispatch::<SegmentsKernel>(&params, &[keys, &b.offsets, &b.heads, &b.starts, &b.run_keys], wg)?;
    prefix_scan::record(rec, b.n, &b.heads, &b.offsets, &b.block_sums)?;
    params.mode = MODE_SCATTER;
    rec.dispatch::<SegmentsKernel>(&params, &[keys, &b.offsets, &b.heads, &b.starts, &b.run_keys], wg)
}

/// Runs the kernel on sorted keys: their runs.
pub async fn run(gpu: &Gpu, sorted: &[SortKey]) -> Result<Segments> {
    let n = sorted.len();
    if n == 0 {
        return Ok(Segments { starts: vec![0], keys: Vec::new() });
    }
    let kb = GpuBuffer::from_slice(&gpu.context, "seg_keys", sorted)?;
    let b = SegmentBuffers::new(gpu, n)?;
    crate::gpu::device::buffer::write(&gpu.context, &b.starts, 0, &vec![0xDEAD_BEEFu32; n + 1]);
    let mut rec = Recorder::new(gpu, "segments");
    record(&mut rec, kb.raw(), &b)?;
    let rc = rec.read(&b.block_sums, b.count_offset(), 4);
    let out = rec.finish().await?;
    let runs: u32 = bytemuck::pod_read_unaligned(&out[rc][..4]);
    let runs = (runs as usize).min(n);
    let mut rec = Recorder::new(gpu, "segments readback");
    let (rs, rk) = (rec.read(&b.starts, 0, ((runs + 1) * 4) as u64), rec.read(&b.run_keys, 0, (runs * 8) as u64));
    let out = rec.finish().await?;
    Ok(Segments { starts: bytemuck::pod_collect_to_vec(&out[rs]), keys: bytemuck::pod_collect_to_vec(&out[rk]) })
}
