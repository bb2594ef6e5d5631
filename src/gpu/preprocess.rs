//! Preprocessing on the GPU, composed from the kernels: the sorted cell table of a point set on a uniform
//! grid (bounds, keys, bitonic sort, run table) and voxel downsampling on it. Every step is integer work or
//! a sequential per-cell sum, so results are deterministic, and each matches its CPU twin in [`crate::cpu`]
//! ([`crate::cpu::voxel_average::voxel_downsample`] is the definition the CPU path uses too).
//!
//! Not wired into the pipeline yet: these are host-level entry points for the backend to call.

use super::buffer::{GpuBuffer, storage_buffer};
use super::cell_bounds::{self, GRID_CELLS, GRID_INIT};
use super::recorder::Recorder;
use super::segments::SegmentBuffers;
use super::{Gpu, bitonic_sort, cell_keys, voxel_average};
use crate::cloud::PointCloud;
use crate::cpu::cell_bounds::{CellBox, check_inv_cell};
use crate::error::{Error, Result};

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
        super::segments::record(rec, &keys, &runs)?;
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
pub fn voxel_downsample(gpu: &Gpu, cloud: &PointCloud, voxel: f32) -> Result<PointCloud> {
    if let Some(empty) = crate::cpu::voxel_average::check_downsample(cloud, voxel)? {
        return Ok(empty);
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
    let out = rec.finish()?;
    let (_, cells) = table.check(&out[rg], &out[rs])?;
    let mut rec = Recorder::new(gpu, "voxel_downsample readback");
    let rp = rec.read(&out_points, 0, (cells * 12) as u64);
    let rn = out_normals.as_ref().map(|o| rec.read(o, 0, (cells * 12) as u64));
    let out = rec.finish()?;
    Ok(PointCloud {
        points: bytemuck::pod_collect_to_vec(&out[rp]),
        normals: rn.map(|r| bytemuck::pod_collect_to_vec(&out[r])),
    })
}

/// The grid cell size for k-nearest-neighbour searches on a cloud downsampled at `voxel`: about the radius
/// holding `k` points of a surface sampled one point per voxel (it only affects speed, never the result).
pub fn knn_cell(voxel: f32, k: usize) -> f32 {
    voxel * ((k as f32).sqrt() * 0.5).max(1.0)
}

/// Neighbour lists and normals of every point of a [`CellTable`], recorded.
struct NormalBuffers {
    knn_index: wgpu::Buffer,
    knn_d2: wgpu::Buffer,
    normals: wgpu::Buffer,
}

/// Records the k nearest neighbours (itself included) of every point of `table` and, with a viewpoint, their
/// normals.
fn record_knn_normals(
    gpu: &Gpu,
    rec: &mut Recorder<'_>,
    table: &CellTable,
    k: usize,
    viewpoint: Option<[f32; 3]>,
) -> Result<NormalBuffers> {
    super::grid_knn::check_k(k)?;
    let ctx = &gpu.context;
    let n = table.n;
    let slots = (n * k * 4) as u64;
    let out = NormalBuffers {
        knn_index: storage_buffer(ctx, "knn_index", slots)?,
        knn_d2: storage_buffer(ctx, "knn_d2", slots)?,
        normals: storage_buffer(ctx, "normals", (n * 12) as u64)?,
    };
    let params = super::grid_knn::GridKnnParams {
        queries: super::to_u32(n, "points")?,
        k: k as u32,
        inv_cell: table.inv_cell,
        all_points: 1,
    };
    let g = super::grid_knn::GridBuffers {
        points: &table.points,
        grid: &table.grid,
        keys: &table.keys,
        starts: &table.runs.starts,
        run_keys: &table.runs.run_keys,
    };
    super::grid_knn::record(rec, &params, &g, &gpu.dummy, [&out.knn_index, &out.knn_d2])?;
    if let Some(viewpoint) = viewpoint {
        let params = super::pca_normals::PcaNormalsParams {
            queries: params.queries,
            k: params.k,
            all_points: 1,
            _pad0: 0,
            viewpoint,
            _pad1: 0,
        };
        super::pca_normals::record(rec, &params, &table.points, &gpu.dummy, &out.knn_index, &out.normals)?;
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
pub fn knn(gpu: &Gpu, points: &[[f32; 3]], k: usize, cell: f32) -> Result<(Vec<u32>, Vec<f32>)> {
    let inv_cell = check_cell(cell)?;
    super::grid_knn::check_k(k)?;
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
    let bytes = rec.finish()?;
    table.check(&bytes[rg], &bytes[rs])?;
    Ok((bytemuck::pod_collect_to_vec(&bytes[ri]), bytemuck::pod_collect_to_vec(&bytes[rd])))
}

/// PCA normals of every point from its `max(k, 3)` nearest neighbours, facing `viewpoint`, on the GPU
/// (grid search on cells of side `cell`, then [`super::pca_normals`]): the definition of
/// [`crate::cpu::pca_normals`].
pub fn normals(gpu: &Gpu, points: &[[f32; 3]], k: usize, viewpoint: [f32; 3], cell: f32) -> Result<Vec<[f32; 3]>> {
    let inv_cell = check_cell(cell)?;
    let k = k.max(3);
    super::grid_knn::check_k(k)?;
    if points.is_empty() {
        return Ok(Vec::new());
    }
    let pb = GpuBuffer::from_slice(&gpu.context, "normal_points", points)?.raw().clone();
    let mut rec = Recorder::new(gpu, "normals");
    let table = CellTable::record(gpu, &mut rec, pb, points.len(), inv_cell)?;
    let out = record_knn_normals(gpu, &mut rec, &table, k, Some(viewpoint))?;
    let (rg, rs) = table.read_meta(&mut rec);
    let rn = rec.read(&out.normals, 0, (points.len() * 12) as u64);
    let bytes = rec.finish()?;
    table.check(&bytes[rg], &bytes[rs])?;
    Ok(bytemuck::pod_collect_to_vec(&bytes[rn]))
}

/// Voxel downsampling then, unless the cloud brings normals (averaged like the points, as the CPU path
/// keeps file normals), PCA normals from the `max(k, 3)` nearest neighbours facing `viewpoint`: both on the
/// GPU, the downsampled points never leaving it in between. The host only uploads the points and reads the
/// result (and one count).
pub fn downsample_and_normals(
    gpu: &Gpu,
    cloud: &PointCloud,
    voxel: f32,
    k: usize,
    viewpoint: [f32; 3],
) -> Result<PointCloud> {
    let k = k.max(3);
    super::grid_knn::check_k(k)?;
    if cloud.normals.is_some() || cloud.is_empty() {
        return voxel_downsample(gpu, cloud, voxel);
    }
    if !(voxel.is_finite() && voxel > 0.0) {
        return Err(Error::invalid(format!("voxel size must be positive, got {voxel}")));
    }
    let ctx = &gpu.context;
    let n = cloud.len();
    let points = GpuBuffer::from_slice(ctx, "voxel_points", &cloud.points)?.raw().clone();
    let out_points = storage_buffer(ctx, "voxel_out_points", (n * 12) as u64)?;
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
    let out = rec.finish()?;
    let (_, cells) = table.check(&out[rg], &out[rs])?;
    drop(table);
    let mut rec = Recorder::new(gpu, "normals");
    let grid = CellTable::record(gpu, &mut rec, out_points.clone(), cells, 1.0 / knn_cell(voxel, k))?;
    let nb = record_knn_normals(gpu, &mut rec, &grid, k, Some(viewpoint))?;
    let (rg, rs) = grid.read_meta(&mut rec);
    let (rp, rn) = (rec.read(&out_points, 0, (cells * 12) as u64), rec.read(&nb.normals, 0, (cells * 12) as u64));
    let out = rec.finish()?;
    grid.check(&out[rg], &out[rs])?;
    Ok(PointCloud {
        points: bytemuck::pod_collect_to_vec(&out[rp]),
        normals: Some(bytemuck::pod_collect_to_vec(&out[rn])),
    })
}
