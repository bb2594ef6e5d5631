//! Host side of `shaders/mutual_knn.wgsl`: K <= 4 nearest per source row and per target column of a
//! distance matrix (fed chunk by chunk of rows), the mutual check on the GPU, and a tiny host pass that
//! compacts the flagged slots into matches sorted by (source, target). CPU twin: [`crate::cpu::mutual_knn`].

use crate::cpu::mutual_knn::Match;
use crate::error::{Error, Result};
use crate::gpu::device::kernel::{BindKind, GpuKernel, gpu_params};
use crate::gpu::device::recorder::Recorder;
use crate::gpu::{Gpu, to_u32, workgroups};
use crate::settings::MatchMode;

gpu_params! {
    /// Mirrors `struct MutualKnnParams` in shaders/mutual_knn.wgsl.
    pub struct MutualKnnParams {
        /// [`MODE_ROWS`], [`MODE_COLS`] or [`MODE_FLAGS`].
        pub mode: u32,
        /// K (1..=4).
        pub k: u32,
        /// Rows of the distance chunk.
        pub rows: u32,
        /// Columns (targets).
        pub cols: u32,
        /// Global index of the chunk's first row.
        pub row_offset: u32,
        /// Source rows in all.
        pub sources: u32,
        /// 1 on the first chunk (column lists start empty).
        pub first_chunk: u32,
        /// Padding.
        pub _pad: u32,
    }
}

/// Invocations per workgroup (`WG_SIZE` in the shader).
pub const WG_SIZE: u32 = 64;
/// Largest K the kernel supports (list slots per row / column).
pub const K_MAX: usize = 4;
/// Index of an unused list slot.
pub const EMPTY: u32 = u32::MAX;
/// Per-row K nearest targets of a chunk.
pub const MODE_ROWS: u32 = 0;
/// Per-column K nearest sources, merged over chunks.
pub const MODE_COLS: u32 = 1;
/// Mutual flags per source row slot.
pub const MODE_FLAGS: u32 = 2;

/// The `mutual_knn` kernel, declared once (registered in [`super::registry::KERNELS`]).
#[derive(Clone, Copy, Debug)]
pub struct MutualKnn;

impl GpuKernel for MutualKnn {
    const NAME: &'static str = "mutual_knn";
    const SOURCE: &'static str = include_str!("../../../shaders/mutual_knn.wgsl");
    const BINDS: &'static [BindKind] = &[
        BindKind::Uniform,
        BindKind::ReadOnly,
        BindKind::ReadWrite,
        BindKind::ReadWrite,
        BindKind::ReadWrite,
        BindKind::ReadWrite,
        BindKind::ReadWrite,
    ];
    const WORKGROUP_SIZE: u32 = WG_SIZE;
    type Params = MutualKnnParams;
    type CpuTwin = fn(&[f32], usize, usize, MatchMode) -> Vec<Match>;
    const CPU_TWIN: Self::CpuTwin = crate::cpu::mutual_knn::mutual_knn;
}

/// K and whether the mutual check applies, for a match mode; `Error::InvalidInput` for K > 4.
pub fn mode_k(mode: MatchMode) -> Result<(usize, bool)> {
    match mode {
        MatchMode::Closest => Ok((1, false)),
        MatchMode::Mutual(k) if k <= K_MAX => Ok((k.max(1), true)),
        MatchMode::Mutual(k) => Err(Error::invalid(format!("mutual K = {k}: the GPU matcher supports K <= {K_MAX}"))),
    }
}

/// The list buffers: per source row and per target column, 4 (distance, index) slots, and per-row flags.
pub struct KnnBuffers {
    /// `sources x 4` distances.
    pub row_dist: wgpu::Buffer,
    /// `sources x 4` target indices.
    pub row_index: wgpu::Buffer,
    /// `targets x 4` distances.
    pub col_dist: wgpu::Buffer,
    /// `targets x 4` source indices.
    pub col_index: wgpu::Buffer,
    /// `sources x 4` mutual flags.
    pub flags: wgpu::Buffer,
}

impl KnnBuffers {
    /// Allocates the lists for `ns` sources and `nt` targets with `alloc(name, bytes)`.
    pub fn new(
        mut alloc: impl FnMut(&'static str, u64) -> Result<wgpu::Buffer>,
        ns: usize,
        nt: usize,
    ) -> Result<KnnBuffers> {
        let (rows, cols) = ((ns * K_MAX * 4) as u64, (nt * K_MAX * 4) as u64);
        Ok(KnnBuffers {
            row_dist: alloc("knn_row_dist", rows)?,
            row_index: alloc("knn_row_index", rows)?,
            col_dist: alloc("knn_col_dist", cols)?,
            col_index: alloc("knn_col_index", cols)?,
            flags: alloc("knn_flags", rows)?,
        })
    }
}

/// Records the row (and, when `mutual`, column) passes over one chunk of `rows` distance rows starting at
/// global row `row_offset` of `sources`.
pub fn record_chunk<'a>(
    rec: &mut Recorder<'a>,
    b: &KnnBuffers,
    distances: &wgpu::Buffer,
    (rows, cols, row_offset, sources): (usize, usize, usize, usize),
    k: usize,
    mutual: bool,
) -> Result<()> {
    let mut params = MutualKnnParams {
        mode: MODE_ROWS,
        k: to_u32(k, "K")?,
        rows: to_u32(rows, "distance rows")?,
        cols: to_u32(cols, "targets")?,
        row_offset: to_u32(row_offset, "row offset")?,
        sources: to_u32(sources, "sources")?,
        first_chunk: u32::from(row_offset == 0),
        _pad: 0,
    };
    let bufs = [distances, &b.row_dist, &b.row_index, &b.col_dist, &b.col_index, &b.flags];
    rec.dispatch::<MutualKnn>(&params, &bufs, workgroups(rows, WG_SIZE))?;
    if mutual {
        params.mode = MODE_COLS;
        rec.dispatch::<MutualKnn>(&params, &bufs, workgroups(cols, WG_SIZE))?;
    }
    Ok(())
}

/// Records the mutual check of all `sources` rows (after every chunk).
pub fn record_flags<'a>(
    rec: &mut Recorder<'a>,
    b: &KnnBuffers,
    distances: &wgpu::Buffer,
    sources: usize,
    cols: usize,
    k: usize,
) -> Result<()> {
    let params = MutualKnnParams {
        mode: MODE_FLAGS,
        k: to_u32(k, "K")?,
        rows: 0,
        cols: to_u32(cols, "targets")?,
        row_offset: 0,
        sources: to_u32(sources, "sources")?,
        first_chunk: 0,
        _pad: 0,
    };
    let bufs = [distances, &b.row_dist, &b.row_index, &b.col_dist, &b.col_index, &b.flags];
    rec.dispatch::<MutualKnn>(&params, &bufs, workgroups(sources, WG_SIZE))
}

/// The host compaction: flagged (or, without flags, all) filled slots of each row as matches, distances
/// `sqrt(max(d, 0))` as in the twin, sorted by (source, target).
pub fn compact(row_dist: &[f32], row_index: &[u32], flags: Option<&[u32]>, k: usize) -> Vec<Match> {
    let mut out = Vec::new();
    for (i, (d, j)) in row_dist.chunks_exact(K_MAX).zip(row_index.chunks_exact(K_MAX)).enumerate() {
        for q in 0..k.min(K_MAX) {
            let keep = j[q] != EMPTY && flags.is_none_or(|f| f[i * K_MAX + q] == 1);
            if keep {
                out.push(Match { source: i as u32, target: j[q], distance: d[q].max(0.0).sqrt() });
            }
        }
    }
    out.sort_by_key(|m| (m.source, m.target));
    out
}

/// Runs the matcher on a whole `ns x nt` distance matrix in one chunk (the twin's input); the GPU lists
/// start filled with a sentinel so unwritten slots show up.
pub async fn run(gpu: &Gpu, distances: &[f32], ns: usize, nt: usize, mode: MatchMode) -> Result<Vec<Match>> {
    if distances.len() != ns * nt {
        return Err(Error::invalid("mutual_knn: distances must be ns x nt"));
    }
    let (k, mutual) = mode_k(mode)?;
    if ns == 0 || nt == 0 {
        return Ok(Vec::new());
    }
    let ctx = &gpu.context;
    let db = crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, "distances", distances)?;
    let b = KnnBuffers::new(
        |name, bytes| {
            let sentinel = vec![0x7fc0_0badu32; (bytes / 4) as usize];
            Ok(crate::gpu::device::buffer::GpuBuffer::from_slice(ctx, name, &sentinel)?.raw().clone())
        },
        ns,
        nt,
    )?;
    let mut rec = Recorder::new(gpu, "mutual_knn");
    record_chunk(&mut rec, &b, db.raw(), (ns, nt, 0, ns), k, mutual)?;
    if mutual {
        record_flags(&mut rec, &b, db.raw(), ns, nt, k)?;
    }
    let bytes = (ns * K_MAX * 4) as u64;
    let (rd, ri, fl) =
        (rec.read(&b.row_dist, 0, bytes), rec.read(&b.row_index, 0, bytes), rec.read(&b.flags, 0, bytes));
    let out = rec.finish().await?;
    let flags: Vec<u32> = bytemuck::pod_collect_to_vec(&out[fl]);
    Ok(compact(
        &bytemuck::pod_collect_to_vec::<u8, f32>(&out[rd]),
        &bytemuck::pod_collect_to_vec::<u8, u32>(&out[ri]),
        mutual.then_some(flags.as_slice()),
        k,
    ))
}
