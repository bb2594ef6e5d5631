//! Host side of `shaders/grid_knn.wgsl`: exact k nearest neighbours of query points on a uniform cell grid's
//! sorted cell table. CPU twin: [`crate::cpu::grid_knn`].

use crate::cpu::grid_knn::{CellGrid, K_MAX};
use crate::error::{Error, Result};
use crate::gpu::device::buffer::GpuBuffer;
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};

gpu_params! {
    /// Mirrors `struct GridKnnParams` in shaders/grid_knn.wgsl.
    pub struct GridKnnParams {
        /// Query points.
        pub queries: u32,
        /// Neighbours per query (1..=64).
        pub k: u32,
        /// 1 / cell size.
        pub inv_cell: f32,
        /// 1: query `i` is point `i` (the queries buffer is not read); 0: `queries[i]`.
        pub all_points: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 64;

/// The `grid_knn` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct GridKnn;

impl GpuKernel for GridKnn {
    const NAME: &'static str = "grid_knn";
    const SOURCE: &'static str = include_str!("../../../shaders/grid_knn.wgsl");
    const BINDS: &'static [BindKind] = &[
        BindKind::Uniform,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadOnly,
        BindKind::ReadWrite,
        BindKind::ReadWrite,
    ];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = GridKnnParams;
    type CpuTwin = fn(&CellGrid, &[u32], usize) -> Result<(Vec<u32>, Vec<f32>)>;
    const CPU_TWIN: Self::CpuTwin = crate::cpu::grid_knn::grid_knn;
}

/// An error unless `1 <= k <= 64`.
pub fn check_k(k: usize) -> Result<()> {
    if (1..=K_MAX).contains(&k) {
        Ok(())
    } else {
        Err(Error::invalid(format!("grid_knn: k = {k} neighbours, the GPU search keeps 1..={K_MAX}")))
    }
}

/// The cell table [`record`] reads (all on the GPU).
pub struct GridBuffers<'b> {
    /// Points (n x 3).
    pub points: &'b wgpu::Buffer,
    /// Grid words (box, invalid, cells).
    pub grid: &'b wgpu::Buffer,
    /// Sorted keys.
    pub keys: &'b wgpu::Buffer,
    /// Run starts.
    pub starts: &'b wgpu::Buffer,
    /// Run keys.
    pub run_keys: &'b wgpu::Buffer,
}

/// Records the search of `queries` (point indices) into `out_index` / `out_d2` (queries x k).
pub fn record(
    rec: &mut Recorder<'_>,
    params: &GridKnnParams,
    g: &GridBuffers<'_>,
    queries: &wgpu::Buffer,
    out: [&wgpu::Buffer; 2],
) -> Result<()> {
    check_k(params.k as usize)?;
    rec.dispatch::<GridKnn>(
        params,
        &[g.points, queries, g.grid, g.keys, g.starts, g.run_keys, out[0], out[1]],
        workgroups(params.queries as usize, WG_SIZE),
    )
}

/// Runs the kernel on the twin's cell table: `k` slots of indices and squared distances per query.
pub async fn run(gpu: &Gpu, grid: &CellGrid, queries: &[u32], k: usize) -> Result<(Vec<u32>, Vec<f32>)> {
    check_k(k)?;
    if queries.iter().any(|&q| q as usize >= grid.points.len()) {
        return Err(Error::invalid("grid_knn: a query is not a point"));
    }
    if queries.is_empty() {
        return Ok((Vec::new(), Vec::new()));
    }
    let ctx = &gpu.context;
    let up = upload_grid(gpu, grid)?;
    let qb = GpuBuffer::from_slice(ctx, "knn_queries", queries)?;
    let slots = queries.len() * k;
    let oi = GpuBuffer::from_slice(ctx, "knn_out_index", &vec![0xDEAD_BEEFu32; slots])?;
    let od = GpuBuffer::from_slice(ctx, "knn_out_d2", &vec![f32::NAN; slots])?;
    let params = GridKnnParams {
        queries: to_u32(queries.len(), "queries")?,
        k: k as u32,
        inv_cell: grid.inv_cell,
        all_points: 0,
    };
    let g = up.buffers();
    let mut rec = Recorder::new(gpu, "grid_knn");
    record(&mut rec, &params, &g, qb.raw(), [oi.raw(), od.raw()])?;
    let (ri, rd) = (rec.read(oi.raw(), 0, (slots * 4) as u64), rec.read(od.raw(), 0, (slots * 4) as u64));
    let out = rec.finish().await?;
    Ok((bytemuck::pod_collect_to_vec(&out[ri]), bytemuck::pod_collect_to_vec(&out[rd])))
}

/// A cell table uploaded from the twin's [`CellGrid`] (parity tests).
pub struct UploadedGrid {
    points: wgpu::Buffer,
    grid: wgpu::Buffer,
    keys: wgpu::Buffer,
    starts: wgpu::Buffer,
    run_keys: wgpu::Buffer,
}

impl UploadedGrid {
    /// The buffers as the kernels bind them.
    pub fn buffers(&self) -> GridBuffers<'_> {
        GridBuffers {
            points: &self.points,
            grid: &self.grid,
            keys: &self.keys,
            starts: &self.starts,
            run_keys: &self.run_keys,
        }
    }
}

/// Uploads `grid`'s points and cell table (grid words, sorted keys, runs).
pub fn upload_grid(gpu: &Gpu, grid: &CellGrid) -> Result<UploadedGrid> {
    let ctx = &gpu.context;
    let b = &grid.bounds;
    let words =
        [b.min[0], b.min[1], b.min[2], b.max[0], b.max[1], b.max[2], 0, to_u32(grid.cells.len(), "cells")? as i32];
    Ok(UploadedGrid {
        points: GpuBuffer::from_slice(ctx, "grid_points", &grid.points)?.raw().clone(),
        grid: GpuBuffer::from_slice(ctx, "grid_words", &words)?.raw().clone(),
        keys: GpuBuffer::from_slice(ctx, "grid_keys", &grid.sorted)?.raw().clone(),
        starts: GpuBuffer::from_slice(ctx, "grid_starts", &grid.cells.starts)?.raw().clone(),
        run_keys: GpuBuffer::from_slice(ctx, "grid_run_keys", &grid.cells.keys)?.raw().clone(),
    })
}
