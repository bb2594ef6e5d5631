//! Host side of `shaders/pca_normals.wgsl`: PCA normals from neighbour lists (from [`super::grid_knn`]),
//! oriented towards a viewpoint. CPU twin: [`crate::cpu::pca_normals`].

use crate::error::Result;
use crate::gpu::device::buffer::GpuBuffer;
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};

gpu_params! {
    /// Mirrors `struct PcaNormalsParams` in shaders/pca_normals.wgsl.
    pub struct PcaNormalsParams {
        /// Query points.
        pub queries: u32,
        /// Neighbour slots per query.
        pub k: u32,
        /// 1: query `i` is point `i` (the queries buffer is not read); 0: `queries[i]`.
        pub all_points: u32,
        /// Padding.
        pub _pad0: u32,
        /// Where the sensor was: normals face it.
        pub viewpoint: [f32; 3],
        /// Padding.
        pub _pad1: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 64;

/// The `pca_normals` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct PcaNormals;

impl GpuKernel for PcaNormals {
    const NAME: &'static str = "pca_normals";
    const SOURCE: &'static str = include_str!("../../../shaders/pca_normals.wgsl");
    const BINDS: &'static [BindKind] =
        &[BindKind::Uniform, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadOnly, BindKind::ReadWrite];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = PcaNormalsParams;
    type CpuTwin = fn(&[[f32; 3]], &[u32], &[u32], usize, [f32; 3]) -> Result<Vec<[f32; 3]>>;
    const CPU_TWIN: Self::CpuTwin = crate::cpu::pca_normals::pca_normals;
}

/// Records the normals of `params.queries` queries into `normals` (queries x 3).
pub fn record(
    rec: &mut Recorder<'_>,
    params: &PcaNormalsParams,
    points: &wgpu::Buffer,
    queries: &wgpu::Buffer,
    knn_index: &wgpu::Buffer,
    normals: &wgpu::Buffer,
) -> Result<()> {
    rec.dispatch::<PcaNormals>(
        params,
        &[points, queries, knn_index, normals],
        workgroups(params.queries as usize, WG_SIZE),
    )
}

/// Runs the kernel on slices (the twin's inputs).
pub async fn run(
    gpu: &Gpu,
    points: &[[f32; 3]],
    queries: &[u32],
    knn_index: &[u32],
    k: usize,
    viewpoint: [f32; 3],
) -> Result<Vec<[f32; 3]>> {
    crate::cpu::pca_normals::check_inputs(points, queries, knn_index, k)?;
    if queries.is_empty() {
        return Ok(Vec::new());
    }
    let ctx = &gpu.context;
    let pb = GpuBuffer::from_slice(ctx, "pca_points", points)?;
    let qb = GpuBuffer::from_slice(ctx, "pca_queries", queries)?;
    let kb = GpuBuffer::from_slice(ctx, "pca_knn", knn_index)?;
    let ob = GpuBuffer::from_slice(ctx, "pca_normals", &vec![[f32::NAN; 3]; queries.len()])?;
    let params = PcaNormalsParams {
        queries: to_u32(queries.len(), "queries")?,
        k: to_u32(k, "k")?,
        all_points: 0,
        _pad0: 0,
        viewpoint,
        _pad1: 0,
    };
    let mut rec = Recorder::new(gpu, "pca_normals");
    record(&mut rec, &params, pb.raw(), qb.raw(), kb.raw(), ob.raw())?;
    let r = rec.read(ob.raw(), 0, (queries.len() * 12) as u64);
    let out = rec.finish().await?;
    Ok(bytemuck::pod_collect_to_vec(&out[r]))
}
