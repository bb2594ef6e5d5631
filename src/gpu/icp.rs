//! Point-to-plane ICP on the device (the GPU backend's [`crate::backend::Backend::refine_icp`]): the target's
//! downsampled copy (`voxel_average` at half the distance), its cell table and PCA normals (`grid_knn`,
//! `pca_normals`, facing the origin) are built from the target's points where the scan left them, and each
//! iteration's normal equations come from `icp_normal_equations` on the source's points there. Per iteration
//! only the 28-term total (112 bytes) comes back; the 6x6 solve, the update and the stopping rules are the
//! host's ([`crate::estimate::icp::iterate`], shared with the CPU path). Besides, building the target reads
//! back the grid words of two tables (72 bytes).
//!
//! The same stride rule as the host ([`crate::estimate::icp::source_stride`]); the sums are f32 in a fixed
//! order (deterministic), where the host sums f64.

use super::device::buffer::{GpuBuffer, storage_buffer};
use super::device::recorder::Recorder;
use super::kernels::grid_knn::GridBuffers;
use super::kernels::icp_normal_equations::{decode_total, params, record, sums_bytes};
use super::preprocess::{CellTable, downsample_buffer, knn_cell, record_knn_normals};
use super::{Gpu, GpuBackend};
use crate::backend::HeldPoints;
use crate::backend::ScanFeatures;
use crate::cpu::icp_normal_equations::{TERMS, normal_equations, pose_rows, used_points};
use crate::error::{Error, Result};
use crate::estimate::icp::{IcpProblem, iterate, source_stride};
use nalgebra::Matrix4;
use std::sync::Arc;

/// Relative margin of the ICP grid's cells over the max distance: a pair within the distance then lies less
/// than `1 - 2^-8` cells apart per axis, so the f32 rounding of `floor(p / cell)` (relative 2^-24 of the cell
/// coordinate) cannot put it two cells apart for coordinates below 2^15 cells.
pub const CELL_MARGIN: f32 = 1.0 / 256.0;

/// A scan's points on a device ([`HeldPoints`] of the GPU backend): the buffer its description used.
#[derive(Debug)]
pub struct DevicePoints {
    /// The device holding them.
    pub gpu: Arc<Gpu>,
    /// Points (n x 3 f32).
    pub buffer: wgpu::Buffer,
    /// Points held.
    pub n: usize,
}

impl HeldPoints for DevicePoints {
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

/// The target of a device ICP: its downsampled points' cell table (cells at least the distance wide, also
/// those of the normals' neighbour search) and their normals.
pub struct DeviceIcpTarget {
    table: CellTable,
    normals: wgpu::Buffer,
}

/// The cell size of the ICP target's table: wide enough for the 3 x 3 x 3 pair search (the distance plus
/// [`CELL_MARGIN`]) and at least the neighbour search's cell ([`knn_cell`]).
pub fn icp_cell(max_distance: f32, voxel: f32, k: usize) -> f32 {
    knn_cell(voxel, k).max(max_distance * (1.0 + CELL_MARGIN))
}

impl DeviceIcpTarget {
    /// Builds the target from the `n` points in `points`: voxel averages at `problem.max_distance / 2`, their
    /// cell table and PCA normals of `max(k, 3)` neighbours facing the origin (as the host path). Two
    /// submissions; only grid words come back.
    pub async fn build(gpu: &Gpu, points: &wgpu::Buffer, n: usize, problem: &IcpProblem) -> Result<DeviceIcpTarget> {
        let distance = problem.max_distance;
        if !(distance.is_finite() && distance > 0.0) {
            return Err(Error::invalid(format!("ICP max correspondence distance {distance} must be positive")));
        }
        let k = problem.normal_neighbors.max(3);
        super::kernels::grid_knn::check_k(k)?;
        if n == 0 {
            return Err(Error::invalid("ICP: the target has no points"));
        }
        let voxel = distance / 2.0;
        let (small, cells) = downsample_buffer(gpu, points.clone(), n, voxel).await?;
        let mut rec = Recorder::new(gpu, "icp target");
        let table = CellTable::record(gpu, &mut rec, small, cells, 1.0 / icp_cell(distance, voxel, k))?;
        let nb = record_knn_normals(gpu, &mut rec, &table, k, Some([0.0; 3]))?;
        let (rg, rs) = table.read_meta(&mut rec);
        let out = rec.finish().await?;
        table.check(&out[rg], &out[rs])?;
        Ok(DeviceIcpTarget { table, normals: nb.normals })
    }

    /// Downsampled target points.
    pub fn len(&self) -> usize {
        self.table.n
    }

    /// Always false (a target has points).
    pub fn is_empty(&self) -> bool {
        self.table.n == 0
    }

    fn grid_buffers(&self) -> GridBuffers<'_> {
        GridBuffers {
            points: &self.table.points,
            grid: &self.table.grid,
            keys: &self.table.keys,
            starts: &self.table.runs.starts,
            run_keys: &self.table.runs.run_keys,
        }
    }
}

/// Point-to-plane ICP of the `n` source points in `source` onto `target` from `initial`: every
/// [`source_stride`]-th point, pairs within `problem.max_distance`, the host's loop and stopping rules. One
/// submission and 112 bytes read back per iteration.
pub async fn refine(
    gpu: &Gpu,
    source: &wgpu::Buffer,
    n: usize,
    target: &DeviceIcpTarget,
    initial: Matrix4<f64>,
    problem: &IcpProblem,
) -> Result<Matrix4<f64>> {
    let stride = source_stride(n);
    let sums = storage_buffer(&gpu.context, "icp_sums", sums_bytes(used_points(n, stride)))?;
    let grid = target.grid_buffers();
    iterate(initial, problem.max_iterations, async |pose| {
        let p = params(&pose_rows(pose), n, stride, target.table.inv_cell, problem.max_distance)?;
        let mut rec = Recorder::new(gpu, "icp_normal_equations");
        record(&mut rec, &p, source, &grid, &target.normals, &sums)?;
        let r = rec.read(&sums, 0, (TERMS * 4) as u64);
        let out = rec.finish().await?;
        Ok(normal_equations(&decode_total(&out[r])))
    })
    .await
}

impl GpuBackend {
    /// A scan's points on this backend's device: the buffer its description left there, else an upload of
    /// its host points (a scan described elsewhere, or restored).
    fn device_points(&self, scan: &ScanFeatures) -> Result<(wgpu::Buffer, usize)> {
        let held = scan.held_points.as_ref().and_then(|h| h.as_any().downcast_ref::<DevicePoints>());
        if let Some(h) = held.filter(|h| Arc::ptr_eq(&h.gpu, &self.gpu) && h.n == scan.cloud.len()) {
            return Ok((h.buffer.clone(), h.n));
        }
        if scan.cloud.is_empty() {
            return Err(Error::invalid("ICP: a scan has no points"));
        }
        Ok((
            GpuBuffer::from_slice(&self.gpu.context, "icp_points", &scan.cloud.points)?.raw().clone(),
            scan.cloud.len(),
        ))
    }

    /// [`crate::backend::Backend::refine_icp`] on the device; see the module docs.
    pub(super) async fn refine_icp_on_device(
        &self,
        source: &ScanFeatures,
        target: &ScanFeatures,
        initial: Matrix4<f64>,
        problem: &IcpProblem,
    ) -> Result<Matrix4<f64>> {
        let (s, ns) = self.device_points(source)?;
        let (t, nt) = self.device_points(target)?;
        self.run("icp", async |_| {
            let small = DeviceIcpTarget::build(&self.gpu, &t, nt, problem).await?;
            refine(&self.gpu, &s, ns, &small, initial, problem).await
        })
        .await
    }
}
