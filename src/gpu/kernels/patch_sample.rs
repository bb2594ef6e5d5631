//! Host side of `shaders/patch_sample.wgsl`: the radius search of keypoints' patches on a uniform grid's cell
//! table, counted per (keypoint, block cell), then written as sort keys and sorted into each patch's ranking.
//! CPU twin: [`crate::cpu::patch_sample`] (the definition of a patch on every path).

use super::grid_knn::GridBuffers;
use crate::cpu::grid_knn::CellGrid;
use crate::cpu::patch_sample::{BLOCK_CELLS, PatchCandidates, check_radius, radius_squared, stream_key};
use crate::error::{Error, Result};
use crate::gpu::device::buffer::{GpuBuffer, storage_buffer};
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};

gpu_params! {
    /// Mirrors `struct PatchSampleParams` in shaders/patch_sample.wgsl.
    pub struct PatchSampleParams {
        /// 0: count, 1: write, 2: pad.
        pub stage: u32,
        /// Keypoint slots.
        pub keypoints: u32,
        /// 1 / cell size (cells at least the radius).
        pub inv_cell: f32,
        /// Patch radius.
        pub radius: f32,
        /// `radius * radius` in f32.
        pub r2: f32,
        /// Low word of the sampling seed.
        pub key0: u32,
        /// High word of the sampling seed.
        pub key1: u32,
        /// Always 0 (the shader's FMA fence).
        pub zero: u32,
        /// First key to pad (stage 2).
        pub pad_from: u32,
        /// End of the keys to pad (stage 2).
        pub pad_to: u32,
        /// Padding.
        pub _pad0: u32,
        /// Padding.
        pub _pad1: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 64;
/// Count of a keypoint whose search block is too wide (in its first block cell).
pub const BAD_BLOCK: u32 = u32::MAX;

/// The `patch_sample` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct PatchSample;

impl GpuKernel for PatchSample {
    const NAME: &'static str = "patch_sample";
    const SOURCE: &'static str = include_str!("../../../shaders/patch_sample.wgsl");
    const BINDS: &'static [BindKind] = &[
        BindKind::Uniform,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadWrite,
    ];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = PatchSampleParams;
    type CpuTwin = fn(&CellGrid, &[u32], f32, u64) -> Result<PatchCandidates>;
    const CPU_TWIN: Self::CpuTwin = crate::cpu::patch_sample::patch_sample;
}

/// The parameters of a search of `keypoints` slots with `radius` on cells of `1 / inv_cell`, seed `seed`.
pub fn params(keypoints: usize, inv_cell: f32, radius: f32, seed: u64) -> Result<PatchSampleParams> {
    check_radius(radius)?;
    let [key0, key1] = stream_key(seed);
    Ok(PatchSampleParams {
        stage: 0,
        keypoints: to_u32(keypoints, "keypoints")?,
        inv_cell,
        radius,
        r2: radius_squared(radius),
        key0,
        key1,
        ..PatchSampleParams::default()
    })
}

/// Records stage 0: `counts` (keypoints x [`BLOCK_CELLS`] u32) receives each block cell's candidates.
pub fn record_count(
    rec: &mut Recorder<'_>,
    params: &PatchSampleParams,
    g: &GridBuffers<'_>,
    keypoints: &wgpu::Buffer,
    dummy: &wgpu::Buffer,
    counts: &wgpu::Buffer,
) -> Result<()> {
    let p = PatchSampleParams { stage: 0, ..*params };
    let buffers = [g.points, keypoints, g.grid, g.keys, g.starts, g.run_keys, dummy, counts];
    rec.dispatch::<PatchSample>(&p, &buffers, workgroups(params.keypoints as usize * BLOCK_CELLS, WG_SIZE))
}

/// Per-slot candidate counts and the exclusive offsets of every (slot, block cell) from the counts stage 0
/// wrote, or the twin's error for a keypoint whose block is too wide.
pub fn offsets(counts: &[u32], keypoints: &[u32], params: &PatchSampleParams) -> Result<(Vec<u32>, Vec<u32>, usize)> {
    let mut per_slot = Vec::with_capacity(keypoints.len());
    let mut offsets = Vec::with_capacity(counts.len());
    let mut total = 0u64;
    for (slot, cells) in counts.chunks_exact(BLOCK_CELLS).enumerate() {
        if cells[0] == BAD_BLOCK {
            let k = keypoints.get(slot).copied().unwrap_or(slot as u32);
            return Err(crate::cpu::patch_sample::block_error(k, params.radius, params.inv_cell));
        }
        let mut sum = 0u32;
        for &c in cells {
            offsets.push(to_u32(total as usize, "patch candidates")?);
            total += u64::from(c);
            sum += c;
        }
        per_slot.push(sum);
    }
    Ok((per_slot, offsets, to_u32(total as usize, "patch candidates")? as usize))
}

/// Records stage 1 (write the `total` candidates at `offsets`), stage 2 (pad `candidates` to `padded`) and the
/// sort.
#[allow(clippy::too_many_arguments)]
pub fn record_write_and_sort(
    rec: &mut Recorder<'_>,
    params: &PatchSampleParams,
    g: &GridBuffers<'_>,
    keypoints: &wgpu::Buffer,
    offsets: &wgpu::Buffer,
    candidates: &wgpu::Buffer,
    total: usize,
    padded: usize,
) -> Result<()> {
    let p = PatchSampleParams { stage: 1, ..*params };
    let buffers = [g.points, keypoints, g.grid, g.keys, g.starts, g.run_keys, offsets, candidates];
    rec.dispatch::<PatchSample>(&p, &buffers, workgroups(params.keypoints as usize * BLOCK_CELLS, WG_SIZE))?;
    let pad = PatchSampleParams {
        stage: 2,
        pad_from: to_u32(total, "patch candidates")?,
        pad_to: to_u32(padded, "padded candidates")?,
        ..*params
    };
    rec.dispatch::<PatchSample>(&pad, &buffers, workgroups(padded - total, WG_SIZE))?;
    super::bitonic_sort::record(rec, candidates, padded)
}

/// Runs the search on the twin's inputs (the cell table uploaded from `grid`): every keypoint's candidates,
/// sorted, as [`crate::cpu::patch_sample::patch_sample`] returns them.
pub async fn run(gpu: &Gpu, grid: &CellGrid, keypoints: &[u32], radius: f32, seed: u64) -> Result<PatchCandidates> {
    let params = params(keypoints.len(), grid.inv_cell, radius, seed)?;
    if let Some(&bad) = keypoints.iter().find(|&&k| k as usize >= grid.points.len()) {
        return Err(Error::invalid(format!("patch_sample: keypoint {bad} is not a point")));
    }
    if keypoints.is_empty() {
        return Ok(PatchCandidates::default());
    }
    let ctx = &gpu.context;
    let up = super::grid_knn::upload_grid(gpu, grid)?;
    let g = up.buffers();
    let kb = GpuBuffer::from_slice(ctx, "ps_keypoints", keypoints)?;
    let counts = storage_buffer(ctx, "ps_counts", (keypoints.len() * BLOCK_CELLS * 4) as u64)?;
    let mut rec = Recorder::new(gpu, "patch_sample count");
    record_count(&mut rec, &params, &g, kb.raw(), &gpu.dummy, &counts)?;
    let r = rec.read(&counts, 0, (keypoints.len() * BLOCK_CELLS * 4) as u64);
    let counts: Vec<u32> = bytemuck::pod_collect_to_vec(&rec.finish().await?[r]);
    let (per_slot, offs, total) = offsets(&counts, keypoints, &params)?;
    let padded = super::cell_keys::padded_len(total)?;
    let ob = GpuBuffer::from_slice(ctx, "ps_offsets", &offs)?;
    let cands = storage_buffer(ctx, "ps_candidates", (padded * 16) as u64)?;
    let mut rec = Recorder::new(gpu, "patch_sample write");
    record_write_and_sort(&mut rec, &params, &g, kb.raw(), ob.raw(), &cands, total, padded)?;
    let r = rec.read(&cands, 0, (total.max(1) * 16) as u64);
    let mut sorted: Vec<[u32; 4]> = bytemuck::pod_collect_to_vec(&rec.finish().await?[r]);
    sorted.truncate(total);
    Ok(PatchCandidates { counts: per_slot, sorted })
}
