//! Preprocessing on the GPU, composed from the kernels: the sorted cell table of a point set on a uniform
//! grid (bounds, keys, bitonic sort, run table) and voxel downsampling on it. Every step is integer work or
//! a sequential per-cell sum, so results are deterministic, and each matches its CPU twin in [`crate::cpu`]
//! ([`crate::cpu::voxel_average::voxel_downsample`] is the definition the CPU path uses too).
//!
//! [`DeviceCloud`] keeps a scan on the device for description: its points, unit normals (given, or estimated
//! on the device) and the cell table of the patch radius, on which [`DeviceCloud::sample`] draws patches
//! (`patch_sample`, `bitonic_sort`, `patch_gather`; [`crate::cpu::patch_sample`]'s definition).

use super::Gpu;
use super::device::buffer::{GpuBuffer, storage_buffer};
use super::device::recorder::Recorder;
use super::kernels::cell_bounds::{self, GRID_CELLS, GRID_INIT};
use super::kernels::segments::SegmentBuffers;
use super::kernels::{bitonic_sort, cell_keys, patch_gather, patch_sample, voxel_average};
use crate::cloud::PointCloud;
use crate::cpu::cell_bounds::{CellBox, check_inv_cell};
use crate::cpu::patch_gather::PatchEntry;
use crate::error::{Error, Result};
use crate::preprocess::Patches;

/// A point set's cell table on the GPU: grid words (box, invalid flag, cell count), the sorted keys and the
/// runs of equal keys (one per occupied cell, in key order).
pub struct CellTable {
    /// Points (n x 3 f32).
    pub points: wgpu::Buffer,
    /// Points indexed.
    pub n: usize,
    /// 1 / cell size.
    pub inv_cell: f32,
    /// Grid words: `[min x3, max x3, invalid, cells]` (i32 / u32).
    pub grid: wgpu::Buffer,
    /// Sorted keys (`padded` vec4<u32>: hi, lo, point index, 0).
    pub keys: wgpu::Buffer,
    /// Worst status of the key pass.
    pub status: wgpu::Buffer,
    /// Runs.
    pub runs: SegmentBuffers,
}

impl CellTable {
    /// Records the construction of the table of `n` points (`points`, uploaded) with cells of `1 / inv_cell`.
    pub fn record(
        gpu: &Gpu,
        rec: &mut Recorder<'_>,
        points: wgpu::Buffer,
        n: usize,
        inv_cell: f32,
    ) -> Result<CellTable> {
        check_inv_cell(inv_cell)?;
        if n == 0 {
            return Err(Error::invalid("cell grid: no points"));
        }
        let ctx = &gpu.context;
        let padded = cell_keys::padded_len(n)?;
        let grid = GpuBuffer::from_slice(ctx, "cell_grid", &GRID_INIT)?.raw().clone();
        let status = GpuBuffer::from_slice(ctx, "cell_status", &[0u32])?.raw().clone();
        let keys = storage_buffer(ctx, "cell_keys", (padded * 16) as u64)?;
        let runs = SegmentBuffers::new(gpu, n)?;
        cell_bounds::record(rec, n, inv_cell, &points, &grid)?;
        cell_keys::record(rec, n, padded, inv_cell, &points, &grid, &keys, &status)?;
        bitonic_sort::record(rec, &keys, padded)?;
        super::kernels::segments::record(rec, &keys, &runs)?;
        rec.copy(&runs.block_sums, runs.count_offset(), &grid, (GRID_CELLS * 4) as u64, 4);
        Ok(CellTable { points, n, inv_cell, grid, keys, status, runs })
    }

    /// Requests the grid words and the status (read indices for [`CellTable::check`]).
    pub fn read_meta(&self, rec: &mut Recorder<'_>) -> (usize, usize) {
        (rec.read(&self.grid, 0, 32), rec.read(&self.status, 0, 4))
    }

    /// The box and number of occupied cells from the words read back, or the twin's error (invalid point, box
    /// too wide for a key).
    pub fn check(&self, grid: &[u8], status: &[u8]) -> Result<(CellBox, usize)> {
        let words: Vec<i32> = bytemuck::pod_collect_to_vec(grid);
        let b = cell_bounds::decode(&words, self.inv_cell)?;
        cell_keys::check_status(bytemuck::pod_read_unaligned(&status[..4]), &b)?;
        let cells = words[GRID_CELLS] as u32 as usize;
        if cells == 0 || cells > self.n {
            return Err(Error::Gpu(format!("cell grid: {cells} cells for {} points", self.n)));
        }
        Ok((b, cells))
    }
}

/// Voxel-grid downsampling on the GPU: [`crate::cpu::voxel_average::voxel_downsample`]'s definition (the CPU
/// path's), with the same voxel membership bit for bit and averages within f32 rounding of the twin's.
pub async fn voxel_downsample(gpu: &Gpu, cloud: &PointCloud, voxel: f32) -> Result<PointCloud> {
    Ok(voxel_downsample_held(gpu, cloud, voxel).await?.0)
}

/// [`voxel_downsample`], also returning the device buffer whose first `points.len()` entries hold the
/// downsampled points (`None` for an empty cloud), so that a scan can be described from it without uploading
/// the points again.
pub async fn voxel_downsample_held(
    gpu: &Gpu,
    cloud: &PointCloud,
    voxel: f32,
) -> Result<(PointCloud, Option<wgpu::Buffer>)> {
    if let Some(empty) = crate::cpu::voxel_average::check_downsample(cloud, voxel)? {
        return Ok((empty, None));
    }
    let ctx = &gpu.context;
    let n = cloud.len();
    let points = GpuBuffer::from_slice(ctx, "voxel_points", &cloud.points)?.raw().clone();
    let normals = cloud.normals.as_ref().map(|ns| GpuBuffer::from_slice(ctx, "voxel_normals", ns)).transpose()?;
    let out_points = storage_buffer(ctx, "voxel_out_points", (n * 12) as u64)?;
    let out_normals =
        normals.as_ref().map(|_| storage_buffer(ctx, "voxel_out_normals", (n * 12) as u64)).transpose()?;
    let mut rec = Recorder::new(gpu, "voxel_downsample");
    let table = CellTable::record(gpu, &mut rec, points, n, 1.0 / voxel)?;
    let b = voxel_average::VoxelAverageBuffers {
        points: &table.points,
        normals: normals.as_ref().map(GpuBuffer::raw),
        keys: &table.keys,
        starts: &table.runs.starts,
        grid: &table.grid,
        out_points: &out_points,
        out_normals: out_normals.as_ref(),
    };
    voxel_average::record(&mut rec, gpu, n, &b)?;
    let (rg, rs) = table.read_meta(&mut rec);
    let out = rec.finish().await?;
    let (_, cells) = table.check(&out[rg], &out[rs])?;
    let mut rec = Recorder::new(gpu, "voxel_downsample readback");
    let rp = rec.read(&out_points, 0, (cells * 12) as u64);
    let rn = out_normals.as_ref().map(|o| rec.read(o, 0, (cells * 12) as u64));
    let out = rec.finish().await?;
    let host = PointCloud {
        points: bytemuck::pod_collect_to_vec(&out[rp]),
        normals: rn.map(|r| bytemuck::pod_collect_to_vec(&out[r])),
    };
    Ok((host, Some(out_points)))
}

/// The grid cell size for k-nearest-neighbour searches on a cloud downsampled at `voxel`: about the radius
/// holding `k` points of a surface sampled one point per voxel (it only affects speed, never the result).
pub fn knn_cell(voxel: f32, k: usize) -> f32 {
    voxel * ((k as f32).sqrt() * 0.5).max(1.0)
}

/// Neighbour lists and normals of every point of a [`CellTable`], recorded.
pub(crate) struct NormalBuffers {
    knn_index: wgpu::Buffer,
    knn_d2: wgpu::Buffer,
    /// Unit normals (n x 3), when a viewpoint was given.
    pub(crate) normals: wgpu::Buffer,
}

/// Records the k nearest neighbours (itself included) of every point of `table` and, with a viewpoint, their
/// normals.
pub(crate) fn record_knn_normals(
    gpu: &Gpu,
    rec: &mut Recorder<'_>,
    table: &CellTable,
    k: usize,
    viewpoint: Option<[f32; 3]>,
) -> Result<NormalBuffers> {
    super::kernels::grid_knn::check_k(k)?;
    let ctx = &gpu.context;
    let n = table.n;
    let slots = (n * k * 4) as u64;
    let out = NormalBuffers {
        knn_index: storage_buffer(ctx, "knn_index", slots)?,
        knn_d2: storage_buffer(ctx, "knn_d2", slots)?,
        normals: storage_buffer(ctx, "normals", (n * 12) as u64)?,
    };
    let params = super::kernels::grid_knn::GridKnnParams {
        queries: super::to_u32(n, "points")?,
        k: k as u32,
        inv_cell: table.inv_cell,
        all_points: 1,
    };
    let g = super::kernels::grid_knn::GridBuffers {
        points: &table.points,
        grid: &table.grid,
        keys: &table.keys,
        starts: &table.runs.starts,
        run_keys: &table.runs.run_keys,
    };
    super::kernels::grid_knn::record(rec, &params, &g, &gpu.dummy, [&out.knn_index, &out.knn_d2])?;
    if let Some(viewpoint) = viewpoint {
        let params = super::kernels::pca_normals::PcaNormalsParams {
            queries: params.queries,
            k: params.k,
            all_points: 1,
            _pad0: 0,
            viewpoint,
            _pad1: 0,
        };
        super::kernels::pca_normals::record(rec, &params, &table.points, &gpu.dummy, &out.knn_index, &out.normals)?;
    }
    Ok(out)
}

fn check_cell(cell: f32) -> Result<f32> {
    if cell.is_finite() && cell > 0.0 {
        Ok(1.0 / cell)
    } else {
        Err(Error::invalid(format!("neighbour grid: the cell size must be positive and finite, got {cell}")))
    }
}

/// The `k` nearest neighbours (itself included) of every point, found on a GPU grid of cells of side `cell`:
/// `k` slots per point of indices and squared distances, ascending by (distance, index), unused slots
/// `u32::MAX` and infinity. The same lists as [`crate::cpu::grid_knn::grid_knn`] (and a brute-force search).
pub async fn knn(gpu: &Gpu, points: &[[f32; 3]], k: usize, cell: f32) -> Result<(Vec<u32>, Vec<f32>)> {
    let inv_cell = check_cell(cell)?;
    super::kernels::grid_knn::check_k(k)?;
    if points.is_empty() {
        return Ok((Vec::new(), Vec::new()));
    }
    let pb = GpuBuffer::from_slice(&gpu.context, "knn_points", points)?.raw().clone();
    let mut rec = Recorder::new(gpu, "knn");
    let table = CellTable::record(gpu, &mut rec, pb, points.len(), inv_cell)?;
    let out = record_knn_normals(gpu, &mut rec, &table, k, None)?;
    let (rg, rs) = table.read_meta(&mut rec);
    let slots = (points.len() * k * 4) as u64;
    let (ri, rd) = (rec.read(&out.knn_index, 0, slots), rec.read(&out.knn_d2, 0, slots));
    let bytes = rec.finish().await?;
    table.check(&bytes[rg], &bytes[rs])?;
    Ok((bytemuck::pod_collect_to_vec(&bytes[ri]), bytemuck::pod_collect_to_vec(&bytes[rd])))
}

/// PCA normals of every point from its `max(k, 3)` nearest neighbours, facing `viewpoint`, on the GPU
/// (grid search on cells of side `cell`, then [`super::kernels::pca_normals`]): the definition of
/// [`crate::cpu::pca_normals`].
pub async fn normals(
    gpu: &Gpu,
    points: &[[f32; 3]],
    k: usize,
    viewpoint: [f32; 3],
    cell: f32,
) -> Result<Vec<[f32; 3]>> {
    let inv_cell = check_cell(cell)?;
    let k = k.max(3);
    super::kernels::grid_knn::check_k(k)?;
    if points.is_empty() {
        return Ok(Vec::new());
    }
    let pb = GpuBuffer::from_slice(&gpu.context, "normal_points", points)?.raw().clone();
    let mut rec = Recorder::new(gpu, "normals");
    let table = CellTable::record(gpu, &mut rec, pb, points.len(), inv_cell)?;
    let out = record_knn_normals(gpu, &mut rec, &table, k, Some(viewpoint))?;
    let (rg, rs) = table.read_meta(&mut rec);
    let rn = rec.read(&out.normals, 0, (points.len() * 12) as u64);
    let bytes = rec.finish().await?;
    table.check(&bytes[rg], &bytes[rs])?;
    Ok(bytemuck::pod_collect_to_vec(&bytes[rn]))
}

/// Voxel downsampling then, unless the cloud brings normals (averaged like the points, as the CPU path
/// keeps file normals), PCA normals from the `max(k, 3)` nearest neighbours facing `viewpoint`: both on the
/// GPU, the downsampled points never leaving it in between. The host only uploads the points and reads the
/// result (and one count).
pub async fn downsample_and_normals(
    gpu: &Gpu,
    cloud: &PointCloud,
    voxel: f32,
    k: usize,
    viewpoint: [f32; 3],
) -> Result<PointCloud> {
    let k = k.max(3);
    super::kernels::grid_knn::check_k(k)?;
    if cloud.normals.is_some() || cloud.is_empty() {
        return voxel_downsample(gpu, cloud, voxel).await;
    }
    if !(voxel.is_finite() && voxel > 0.0) {
        return Err(Error::invalid(format!("voxel size must be positive, got {voxel}")));
    }
    let points = GpuBuffer::from_slice(&gpu.context, "voxel_points", &cloud.points)?.raw().clone();
    let (out_points, cells) = downsample_buffer(gpu, points, cloud.len(), voxel).await?;
    let mut rec = Recorder::new(gpu, "normals");
    let grid = CellTable::record(gpu, &mut rec, out_points.clone(), cells, 1.0 / knn_cell(voxel, k))?;
    let nb = record_knn_normals(gpu, &mut rec, &grid, k, Some(viewpoint))?;
    let (rg, rs) = grid.read_meta(&mut rec);
    let (rp, rn) = (rec.read(&out_points, 0, (cells * 12) as u64), rec.read(&nb.normals, 0, (cells * 12) as u64));
    let out = rec.finish().await?;
    grid.check(&out[rg], &out[rs])?;
    Ok(PointCloud {
        points: bytemuck::pod_collect_to_vec(&out[rp]),
        normals: Some(bytemuck::pod_collect_to_vec(&out[rn])),
    })
}

/// Voxel downsampling of the `n` points in `points` on the device ([`voxel_downsample`]'s definition), the
/// result left there: a buffer of the voxel averages (sized for `n`) and how many there are. Reads back only
/// the grid words.
pub async fn downsample_buffer(gpu: &Gpu, points: wgpu::Buffer, n: usize, voxel: f32) -> Result<(wgpu::Buffer, usize)> {
    if !(voxel.is_finite() && voxel > 0.0) {
        return Err(Error::invalid(format!("voxel size must be positive, got {voxel}")));
    }
    let out_points = storage_buffer(&gpu.context, "voxel_out_points", (n * 12) as u64)?;
    let mut rec = Recorder::new(gpu, "voxel_downsample");
    let table = CellTable::record(gpu, &mut rec, points, n, 1.0 / voxel)?;
    let b = voxel_average::VoxelAverageBuffers {
        points: &table.points,
        normals: None,
        keys: &table.keys,
        starts: &table.runs.starts,
        grid: &table.grid,
        out_points: &out_points,
        out_normals: None,
    };
    voxel_average::record(&mut rec, gpu, n, &b)?;
    let (rg, rs) = table.read_meta(&mut rec);
    let out = rec.finish().await?;
    let (_, cells) = table.check(&out[rg], &out[rs])?;
    Ok((out_points, cells))
}

/// Where a [`DeviceCloud`]'s normals come from.
#[derive(Clone, Copy, Debug)]
pub enum NormalSource<'a> {
    /// One unit normal per point.
    Given(&'a [[f32; 3]]),
    /// PCA normals of the `max(k, 3)` nearest neighbours facing `viewpoint`, estimated on the device for every
    /// point ([`crate::cpu::pca_normals`]'s definition).
    Estimate {
        /// Neighbours.
        k: usize,
        /// Where the sensor was.
        viewpoint: [f32; 3],
    },
}

/// A scan on the device: points, unit normals and the cell table of cells one patch radius wide. Nothing
/// per point comes back from it.
pub struct DeviceCloud {
    n: usize,
    radius: f32,
    normals: wgpu::Buffer,
    table: CellTable,
}

/// Patches drawn on a [`DeviceCloud`]: the ranked candidates stay on the device; the host holds the
/// per-keypoint table and the kept keypoints' positions and normals (small readbacks).
pub struct SampledPatches {
    /// Slot (in the keypoints asked) of each kept patch, ascending.
    pub kept: Vec<usize>,
    /// Slots whose patch is empty.
    pub empty: Vec<usize>,
    /// `[keypoint, start, count, 0]` per kept patch.
    pub table: Vec<PatchEntry>,
    /// Kept keypoints' positions.
    pub centers: Vec<[f32; 3]>,
    /// Kept keypoints' unit normals.
    pub center_normals: Vec<[f32; 3]>,
    /// The patch radius they were drawn at.
    pub radius: f32,
    /// Sorted candidate keys (device).
    candidates: Option<wgpu::Buffer>,
}

impl DeviceCloud {
    /// Uploads `points` and builds the cloud (see [`DeviceCloud::from_buffer`]).
    pub async fn new(gpu: &Gpu, points: &[[f32; 3]], normals: NormalSource<'_>, radius: f32) -> Result<DeviceCloud> {
        if points.is_empty() {
            return Err(Error::invalid("device cloud: no points"));
        }
        let pb = GpuBuffer::from_slice(&gpu.context, "cloud_points", points)?.raw().clone();
        DeviceCloud::from_buffer(gpu, pb, points.len(), normals, radius).await
    }

    /// The cloud of the `n` points already in `points` (e.g. downsampled on the device): the cell table of
    /// cells `radius` wide and the normals (uploaded, or estimated on the device on a second grid whose cells
    /// suit the neighbour count). Reads back only the grid words.
    pub async fn from_buffer(
        gpu: &Gpu,
        points: wgpu::Buffer,
        n: usize,
        normals: NormalSource<'_>,
        radius: f32,
    ) -> Result<DeviceCloud> {
        crate::cpu::patch_sample::check_radius(radius)?;
        let mut rec = Recorder::new(gpu, "device cloud");
        let table = CellTable::record(gpu, &mut rec, points, n, 1.0 / radius)?;
        let (rg, rs) = table.read_meta(&mut rec);
        let out = rec.finish().await?;
        let (_, cells) = table.check(&out[rg], &out[rs])?;
        let normals = match normals {
            NormalSource::Given(ns) => {
                if ns.len() != n {
                    return Err(Error::invalid(format!("device cloud: {} normals for {n} points", ns.len())));
                }
                GpuBuffer::from_slice(&gpu.context, "cloud_normals", ns)?.raw().clone()
            }
            NormalSource::Estimate { k, viewpoint } => {
                let k = k.max(3);
                super::kernels::grid_knn::check_k(k)?;
                // Point spacing of a surface with this many points per radius-wide cell: only speed depends on it.
                let spacing = radius / (n as f32 / cells as f32).max(1.0).sqrt();
                let mut rec = Recorder::new(gpu, "device normals");
                let grid = CellTable::record(gpu, &mut rec, table.points.clone(), n, 1.0 / knn_cell(spacing, k))?;
                let nb = record_knn_normals(gpu, &mut rec, &grid, k, Some(viewpoint))?;
                let (rg, rs) = grid.read_meta(&mut rec);
                let out = rec.finish().await?;
                grid.check(&out[rg], &out[rs])?;
                nb.normals
            }
        };
        Ok(DeviceCloud { n, radius, normals, table })
    }

    /// Points.
    pub fn len(&self) -> usize {
        self.n
    }

    /// The points (n x 3 f32) on the device.
    pub fn points(&self) -> &wgpu::Buffer {
        &self.table.points
    }

    /// The largest patch radius it samples (the cell size of its table); the default of [`DeviceCloud::sample`].
    pub fn radius(&self) -> f32 {
        self.radius
    }

    /// Always false (a device cloud has points).
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// `count` points by farthest-point sampling from `start` ([`super::kernels::farthest_point`]); only the chosen
    /// indices come back.
    pub async fn farthest_points(&self, gpu: &Gpu, count: usize, start: usize) -> Result<Vec<usize>> {
        super::kernels::farthest_point::sample(gpu, &self.table.points, self.n, count, start).await
    }

    /// The normals, read back (every point's: a per-point readback, for callers that ask for the whole cloud).
    pub async fn read_normals(&self, gpu: &Gpu) -> Result<Vec<[f32; 3]>> {
        let bytes = super::device::buffer::read_bytes(&gpu.context, &self.normals, 0, (self.n * 12) as u64).await?;
        Ok(bytemuck::pod_collect_to_vec(&bytes))
    }

    fn grid_buffers(&self) -> super::kernels::grid_knn::GridBuffers<'_> {
        super::kernels::grid_knn::GridBuffers {
            points: &self.table.points,
            grid: &self.table.grid,
            keys: &self.table.keys,
            starts: &self.table.runs.starts,
            run_keys: &self.table.runs.run_keys,
        }
    }

    /// The patches of `keypoints` (cloud indices) ranked with `seed`: two submissions (count; write, sort and
    /// gather the centres); the per-(keypoint, cell) counts and the kept centres come back. `None` when their
    /// candidates (16 bytes each, padded to a power of two) would not fit one buffer: the caller splits the
    /// keypoints.
    pub async fn sample(&self, gpu: &Gpu, keypoints: &[u32], seed: u64) -> Result<Option<SampledPatches>> {
        self.sample_at(gpu, keypoints, seed, self.radius).await
    }

    /// [`DeviceCloud::sample`] with patches of `radius`, at most the cell size (the cloud's radius).
    pub async fn sample_at(
        &self,
        gpu: &Gpu,
        keypoints: &[u32],
        seed: u64,
        radius: f32,
    ) -> Result<Option<SampledPatches>> {
        if radius > self.radius {
            return Err(Error::invalid(format!(
                "patch_sample: radius {radius} is larger than the cells ({}) of the cloud's table",
                self.radius
            )));
        }
        let params = patch_sample::params(keypoints.len(), self.table.inv_cell, radius, seed)?;
        let mut out = SampledPatches {
            kept: Vec::new(),
            empty: Vec::new(),
            table: Vec::new(),
            centers: Vec::new(),
            center_normals: Vec::new(),
            radius,
            candidates: None,
        };
        if keypoints.is_empty() {
            return Ok(Some(out));
        }
        if let Some(&bad) = keypoints.iter().find(|&&k| k as usize >= self.n) {
            return Err(Error::invalid(format!("patch_sample: keypoint {bad} of a cloud of {} points", self.n)));
        }
        let ctx = &gpu.context;
        let kb = GpuBuffer::from_slice(ctx, "ps_keypoints", keypoints)?;
        let count_bytes = (keypoints.len() * crate::cpu::patch_sample::BLOCK_CELLS * 4) as u64;
        let counts = storage_buffer(ctx, "ps_counts", count_bytes)?;
        let g = self.grid_buffers();
        let mut rec = Recorder::new(gpu, "patch_sample count");
        patch_sample::record_count(&mut rec, &params, &g, kb.raw(), &gpu.dummy, &counts)?;
        let r = rec.read(&counts, 0, count_bytes);
        let counts: Vec<u32> = bytemuck::pod_collect_to_vec(&rec.finish().await?[r]);
        let (per_slot, offsets, total) = patch_sample::offsets(&counts, keypoints, &params)?;
        let mut start = 0u32;
        for (slot, &count) in per_slot.iter().enumerate() {
            if count == 0 {
                out.empty.push(slot);
            } else {
                out.kept.push(slot);
                out.table.push([keypoints[slot], start, count, 0]);
            }
            start += count;
        }
        if out.table.is_empty() {
            return Ok(Some(out));
        }
        let padded = cell_keys::padded_len(total)?;
        if (padded * 16) as u64 > ctx.max_buffer_bytes() {
            if keypoints.len() == 1 {
                return Err(Error::Gpu(format!(
                    "patch_sample: keypoint {} has {total} points within radius {radius}, more than one buffer holds",
                    keypoints[0]
                )));
            }
            return Ok(None);
        }
        let ob = GpuBuffer::from_slice(ctx, "ps_offsets", &offsets)?;
        let cands = storage_buffer(ctx, "ps_candidates", (padded * 16) as u64)?;
        let p = out.table.len();
        let tb = GpuBuffer::from_slice(ctx, "ps_table", &out.table)?;
        let (ci, cp, cn) = (
            storage_buffer(ctx, "ps_center_index", (p * 4) as u64)?,
            storage_buffer(ctx, "ps_centers", (p * 12) as u64)?,
            storage_buffer(ctx, "ps_center_normals", (p * 12) as u64)?,
        );
        let mut rec = Recorder::new(gpu, "patch_sample write");
        patch_sample::record_write_and_sort(&mut rec, &params, &g, kb.raw(), ob.raw(), &cands, total, padded)?;
        self.record_gather(&mut rec, &cands, tb.raw(), (p, 1, true), [&ci, &cp, &cn])?;
        let (rp, rn) = (rec.read(&cp, 0, (p * 12) as u64), rec.read(&cn, 0, (p * 12) as u64));
        let bytes = rec.finish().await?;
        out.centers = bytemuck::pod_collect_to_vec(&bytes[rp]);
        out.center_normals = bytemuck::pod_collect_to_vec(&bytes[rn]);
        out.candidates = Some(cands);
        Ok(Some(out))
    }

    /// [`DeviceCloud::sample`], splitting `keypoints` in halves until each part's candidates fit a buffer;
    /// `each` receives every part's patches in order with the position of its first keypoint.
    pub async fn sample_in_parts(
        &self,
        gpu: &Gpu,
        (keypoints, radius): (&[u32], f32),
        seed: u64,
        first: usize,
        mut each: impl AsyncFnMut(usize, SampledPatches) -> Result<()>,
    ) -> Result<()> {
        // Parts still to sample, the next one last: a part whose candidates do not fit is split in halves.
        let mut parts = vec![(first, keypoints)];
        while let Some((first, part)) = parts.pop() {
            match self.sample_at(gpu, part, seed, radius).await? {
                Some(sampled) => each(first, sampled).await?,
                None => {
                    let half = part.len() / 2;
                    parts.push((first + half, &part[half..]));
                    parts.push((first, &part[..half]));
                }
            }
        }
        Ok(())
    }

    /// Records the gather of the patches of `table` (a device copy of entries of `sampled.table`): `n` rows
    /// each, or their centres, into `[index, points, normals]`.
    pub fn record_gather(
        &self,
        rec: &mut Recorder<'_>,
        candidates: &wgpu::Buffer,
        table: &wgpu::Buffer,
        shape: (usize, usize, bool),
        out: [&wgpu::Buffer; 3],
    ) -> Result<()> {
        patch_gather::record(rec, shape, [&self.table.points, &self.normals, candidates, table], out)
    }
}

impl SampledPatches {
    /// The sorted candidates on the device (none when every patch is empty).
    pub fn candidates(&self) -> Option<&wgpu::Buffer> {
        self.candidates.as_ref()
    }
}

/// Patches of `keypoints` sampled entirely on the GPU (cell table, search, sort, gather), read back as the CPU
/// path's [`Patches`]: the same patches as [`crate::preprocess::extract_patches`].
pub async fn sample_patches(
    gpu: &Gpu,
    points: &[[f32; 3]],
    keypoints: &[u32],
    radius: f32,
    points_per_patch: usize,
    seed: u64,
) -> Result<Patches> {
    // The points stand in for normals: only indices are read back.
    let cloud = DeviceCloud::new(gpu, points, NormalSource::Given(points), radius).await?;
    let n = points_per_patch;
    let mut out = Patches { points_per_patch: n, ..Patches::default() };
    cloud
        .sample_in_parts(gpu, (keypoints, radius), seed, 0, async |first, sampled| {
            out.keypoints.extend(sampled.kept.iter().map(|&s| keypoints[first + s] as usize));
            out.empty.extend(sampled.empty.iter().map(|&s| keypoints[first + s] as usize));
            let rows = sampled.table.len() * n;
            let Some(cands) = sampled.candidates().filter(|_| rows > 0) else { return Ok(()) };
            let ctx = &gpu.context;
            let tb = GpuBuffer::from_slice(ctx, "sp_table", &sampled.table)?;
            let (oi, op, on) = (
                storage_buffer(ctx, "sp_index", (rows * 4) as u64)?,
                storage_buffer(ctx, "sp_points", (rows * 12) as u64)?,
                storage_buffer(ctx, "sp_normals", (rows * 12) as u64)?,
            );
            let mut rec = Recorder::new(gpu, "sample_patches");
            cloud.record_gather(&mut rec, cands, tb.raw(), (sampled.table.len(), n, false), [&oi, &op, &on])?;
            let r = rec.read(&oi, 0, (rows * 4) as u64);
            out.neighbors.extend(bytemuck::pod_collect_to_vec::<u8, u32>(&rec.finish().await?[r]));
            Ok(())
        })
        .await?;
    Ok(out)
}
