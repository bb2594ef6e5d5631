//! The WGSL compute path: every learned and massively parallel stage as a hand-written kernel run through
//! wgpu on any GPU (Vulkan, Metal, DX12), checked against the CPU twins in [`crate::cpu`].
//!
//! Layout, bottom up, each room importing only the ones below it:
//! - [`device`]: [`context`] (instance, adapter, device, error scopes), [`features`] (the device features
//!   requested), [`buffer`] (typed buffers, reusable workspace, readback), [`kernel`] (the kernel trait),
//!   [`recorder`] (batched dispatches, one submission per chunk). It knows no kernel.
//! - [`kernels`]: one module per kernel (`shaders/k.wgsl` + `gpu/kernels/k.rs` declaring it as a
//!   [`kernel::GpuKernel`] + its CPU twin `cpu/k.rs`, listed once in [`registry::KERNELS`]).
//! - [`preprocess`] (a scan's cloud on the device: voxel grid, neighbours, normals, patches), [`nets`] (the
//!   networks composed from kernels), [`train`] (the trainer and its backward passes).
//! - Here: [`Gpu`] holds the device and its pipelines (compiled on first use, through the driver's pipeline
//!   cache kept across runs: [`device::pipeline_cache`]); [`GpuBackend`] adds the uploaded weights and
//!   implements [`Backend`], its steps in [`scan`], [`rows`] and [`icp`]; [`testing`] helps the tests.
//!
//! The dense layers' GEMM has variants ([`gemm::GemmVariant`]: the portable reference, a faster portable
//! kernel, and a cooperative-matrix f16 kernel where the adapter has one), chosen per device; every other
//! kernel is its portable f32 version.

pub mod device;
pub mod icp;
pub mod kernels;
pub mod nets;
pub mod parity;
pub mod preprocess;
pub mod rows;
pub mod scan;
pub mod testing;
pub mod train;

// The modules' paths from before the rooms (`gpu::dense`, `gpu::buffer`, `gpu::backward`...), kept for callers.
pub use device::{buffer, context, features, kernel, recorder};
pub use kernels::{
    adam_step, bitonic_sort, cell_bounds, cell_keys, chamfer_grad, chamfer_nearest, codeword_distance, dense,
    dense_coop_f16, dense_fast, dense_input_grad, dense_params, dense_weight_grad, farthest_point, gemm, gemm_choice,
    grid_knn, group_row_sums, hypotheses, icp_normal_equations, max_pool, max_pool_backward, mutual_knn,
    patch_features, patch_gather, patch_sample, pca_normals, pose_feature, prefix_scan, registry, relu_backward,
    rotation_head, score_hypotheses, segments, transpose, unit_rows, voxel_average,
};
pub use train::backward;

use crate::backend::{Backend, MatchedRows, PatchBatch, PoseRows, RotationInputs, RowMatch, ScanRows, Verified};
use crate::cpu::hypotheses::Hypothesis;
use crate::cpu::mutual_knn::Match;
use crate::cpu::score_hypotheses::HypothesisScore;
use crate::error::{Error, Result};
use crate::model::{Model, Net};
use crate::preprocess::GatheredPatches;
use crate::settings::MatchMode;
use buffer::Workspace;
pub use context::GpuContext;
use nets::{GpuModel, items_per_chunk};
use recorder::Recorder;
use registry::Kernels;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

/// `n` as a `u32` kernel parameter, or an error naming `what`.
pub(crate) fn to_u32(n: usize, what: &str) -> Result<u32> {
    u32::try_from(n).map_err(|_| Error::Gpu(format!("{what} = {n} does not fit a 32-bit kernel parameter")))
}

/// Workgroups covering `n` invocations of `wg_size`.
pub(crate) fn workgroups(n: usize, wg_size: u32) -> u64 {
    (n as u64).div_ceil(u64::from(wg_size))
}

/// A device and its pipelines, each compiled on first use: what the kernel functions (`gpu::k::run`) need.
pub struct Gpu {
    /// Device, queue and limits.
    pub context: GpuContext,
    /// The compiled kernels.
    pub kernels: Kernels,
    /// A small read-only placeholder for optional inputs.
    pub(crate) dummy: wgpu::Buffer,
    /// A small writable placeholder for unused outputs.
    pub(crate) dummy_rw: wgpu::Buffer,
    profiling: AtomicBool,
    gpu_time_ns: AtomicU64,
    gemm: gemm::GemmChoice,
}

impl std::fmt::Debug for Gpu {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Gpu").field("adapter", &self.adapter_info()).finish_non_exhaustive()
    }
}

impl Gpu {
    /// A device on the backends from the environment (its kernels compiled on first use).
    pub fn new() -> Result<Gpu> {
        Gpu::from_context(GpuContext::new()?)
    }

    /// [`Gpu::new`] on an adapter `policy` allows.
    pub fn with_policy(policy: context::AdapterPolicy) -> Result<Gpu> {
        Gpu::from_context(GpuContext::with_policy(context::backends_from_env()?, policy)?)
    }

    /// The kernels of `context` (compiled on first use: [`Kernels`]) and its GEMM choice.
    pub fn from_context(context: GpuContext) -> Result<Gpu> {
        let kernels = Kernels::new(&context);
        let dummy = buffer::storage_buffer(&context, "dummy", 16)?;
        let dummy_rw = buffer::storage_buffer(&context, "dummy_rw", 16)?;
        let gemm = gemm::select(&context)?;
        Ok(Gpu {
            context,
            kernels,
            dummy,
            dummy_rw,
            profiling: AtomicBool::new(false),
            gpu_time_ns: AtomicU64::new(0),
            gemm,
        })
    }

    /// The GEMM kernel the dense layers run on ([`gemm::select`] at creation).
    pub fn gemm_variant(&self) -> gemm::GemmVariant {
        self.gemm.variant
    }

    /// The fast GEMM's tile shape ([`gemm::select`] at creation: the recorded sweep's choice, else the default);
    /// it applies whenever the dense layers run [`gemm::GemmVariant::Fast`].
    pub fn gemm_tile(&self) -> dense_fast::FastTile {
        self.gemm.tile
    }

    /// The cooperative-matrix GEMM's tile shape ([`gemm::select`] at creation: the recorded sweep's choice, else
    /// the default); it applies whenever the dense layers run [`gemm::GemmVariant::CoopF16`].
    pub fn gemm_coop_tile(&self) -> dense_coop_f16::CoopTile {
        self.gemm.coop
    }

    /// The variant and tile shapes the dense layers run on ([`gemm::select`] at creation).
    pub fn gemm_choice(&self) -> gemm::GemmChoice {
        self.gemm
    }

    /// Runs the dense layers on `variant` from now on (tests and benchmarks); an error saying why when the
    /// device cannot run it.
    pub fn set_gemm_variant(&mut self, variant: gemm::GemmVariant) -> Result<()> {
        match variant.unavailable_reason(&self.context) {
            None => {
                self.gemm.variant = variant;
                Ok(())
            }
            Some(why) => Err(Error::Gpu(format!("GEMM variant {variant} cannot run on this device: {why}"))),
        }
    }

    /// One line describing the adapter.
    pub fn adapter_info(&self) -> String {
        self.context.adapter_info()
    }

    /// Turns GPU timestamps on or off (they need `TIMESTAMP_QUERY`; see [`Gpu::take_gpu_time`]).
    pub fn set_profiling(&self, on: bool) {
        self.profiling.store(on, Ordering::Relaxed);
    }

    /// Whether profiling is on.
    pub fn profiling(&self) -> bool {
        self.profiling.load(Ordering::Relaxed)
    }

    /// GPU time of the submissions since the last call (profiling on), or `None` without timestamp support.
    pub fn take_gpu_time(&self) -> Option<Duration> {
        let ns = self.gpu_time_ns.swap(0, Ordering::Relaxed);
        self.context.has_timestamps().then(|| Duration::from_nanos(ns))
    }

    pub(crate) fn add_gpu_time(&self, ns: u64) {
        self.gpu_time_ns.fetch_add(ns, Ordering::Relaxed);
    }
}

/// The GPU backend: the model's weights uploaded once, pipelines compiled once, scratch buffers reused
/// across calls.
pub struct GpuBackend {
    gpu: Arc<Gpu>,
    model: Arc<Model>,
    weights: Arc<GpuModel>,
    workspace: Arc<Mutex<Workspace>>,
    /// Identity of this backend: the scan rows it makes are only read by it.
    owner: u64,
}

impl GpuBackend {
    /// Creates a device (backends from the environment, any adapter) and uploads `model`'s weights.
    pub fn new(model: Model) -> Result<GpuBackend> {
        GpuBackend::with_gpu(Arc::new(Gpu::new()?), model)
    }

    /// [`GpuBackend::new`] on a hardware adapter only (what `--backend auto` takes).
    pub fn new_hardware(model: Model) -> Result<GpuBackend> {
        GpuBackend::with_gpu(Arc::new(Gpu::with_policy(context::AdapterPolicy::HardwareOnly)?), model)
    }

    /// Uploads `model`'s weights to an existing (possibly shared) device.
    pub fn with_gpu(gpu: Arc<Gpu>, model: Model) -> Result<GpuBackend> {
        let weights = gpu.context.scoped("uploading weights", || GpuModel::upload(&gpu.context, &model))??;
        Ok(GpuBackend {
            gpu,
            model: Arc::new(model),
            weights: Arc::new(weights),
            workspace: Arc::new(Mutex::new(Workspace::default())),
            owner: rows::new_owner(),
        })
    }

    /// Another handle on this backend: the same device, weights, workspace and identity (rows it describes
    /// are this backend's).
    pub(crate) fn handle(&self) -> GpuBackend {
        GpuBackend {
            gpu: Arc::clone(&self.gpu),
            model: Arc::clone(&self.model),
            weights: Arc::clone(&self.weights),
            workspace: Arc::clone(&self.workspace),
            owner: self.owner,
        }
    }

    /// One line describing the adapter.
    pub fn adapter_info(&self) -> String {
        self.gpu.adapter_info()
    }

    /// The device and kernels.
    pub fn gpu(&self) -> &Gpu {
        &self.gpu
    }

    /// The shared handle of the device (another backend can use the same device).
    pub fn gpu_arc(&self) -> &Arc<Gpu> {
        &self.gpu
    }

    /// Fills every scratch buffer with `value` before use (tests: unwritten elements then show up).
    pub fn set_poison(&self, value: Option<f32>) -> Result<()> {
        self.workspace()?.poison = value.map(f32::to_bits);
        Ok(())
    }

    /// Bytes of scratch buffers currently held.
    pub fn workspace_bytes(&self) -> Result<u64> {
        Ok(self.workspace()?.bytes())
    }

    fn workspace(&self) -> Result<MutexGuard<'_, Workspace>> {
        self.workspace.lock().map_err(|_| Error::Gpu("a previous GPU call panicked (workspace lock poisoned)".into()))
    }

    /// Runs `f` on the workspace; a device error it caused outside the recorders' own scopes (creating or writing
    /// a buffer) is reported as `Error::Gpu("{what}: ...")`.
    ///
    /// The workspace (and a scan's rows, in the steps that write them) stays locked while `f` awaits its readbacks,
    /// as it stayed locked while a blocking call waited before: the buffers are in use until the GPU is done.
    /// Natively the future runs on the thread that locked ([`crate::block_on`]); in a browser the page has one
    /// thread, so one call at a time may use a backend (the web bindings queue calls).
    #[expect(clippy::await_holding_lock, reason = "the workspace's buffers are in use until the readback; see above")]
    async fn run<T>(&self, what: &str, f: impl AsyncFnOnce(&mut Workspace) -> Result<T>) -> Result<T> {
        let mut ws = self.workspace()?;
        let out = f(&mut ws).await;
        self.gpu.context.deferred_errors(what)?;
        out
    }

    /// Reconstructions (`patches x grid_points x io_width`) of codewords, as `model.{ppf,pc}.decode`.
    pub async fn decode(&self, net: Net, codewords: &[f32], patches: usize) -> Result<Vec<f32>> {
        let f = self.foldnet(net);
        self.run("decode", async |ws| nets::decode(&self.gpu, ws, f, codewords, patches).await).await
    }

    /// Inlier flags of one hypothesis over the correspondences (for refinement on the best hypothesis).
    pub async fn inlier_mask(
        &self,
        hypothesis: &Hypothesis,
        source: &[[f32; 3]],
        target: &[[f32; 3]],
        threshold: f32,
    ) -> Result<Vec<bool>> {
        let mut mask = vec![0u32; source.len()];
        score_hypotheses::inlier_mask(&self.gpu, hypothesis, source, target, threshold, &mut mask).await?;
        Ok(mask.into_iter().map(|m| m == 1).collect())
    }

    /// Records the patch features of `patches` patches (`[centers, center normals, points, normals]` on the
    /// device) into `[ppf, pc]`.
    fn record_patch_features<'a>(
        &self,
        rec: &mut Recorder<'a>,
        radius: f32,
        patches: usize,
        [centers, center_normals, points, normals]: [&wgpu::Buffer; 4],
        [ppf, pc]: [&wgpu::Buffer; 2],
    ) -> Result<()> {
        let n = self.model.config.points_per_patch;
        let params = patch_features::PatchFeaturesParams {
            rows: to_u32(patches * n, "patch points")?,
            points_per_patch: to_u32(n, "points per patch")?,
            radius,
            normal_frame: u32::from(self.model.config.pose_frame == crate::model::config::PoseFrame::Normal),
        };
        let b = patch_features::PatchFeaturesBuffers { centers, center_normals, points, normals, ppf, pc };
        patch_features::record(rec, &params, &b)
    }

    /// Uploads the patch features' inputs `[centers, center normals, points, normals]` of patches `c0..c0 + cp`
    /// of `patches` (`n` points each) for [`GpuBackend::record_patch_features`].
    fn upload_patch_inputs(
        ws: &mut Workspace,
        ctx: &GpuContext,
        patches: &GatheredPatches,
        n: usize,
        (c0, cp): (usize, usize),
    ) -> Result<[wgpu::Buffer; 4]> {
        let pts = c0 * n..(c0 + cp) * n;
        Ok([
            ws.upload(ctx, "pf_centers", &patches.centers[c0..c0 + cp])?,
            ws.upload(ctx, "pf_center_normals", &patches.center_normals[c0..c0 + cp])?,
            ws.upload(ctx, "pf_points", &patches.points[pts.clone()])?,
            ws.upload(ctx, "pf_normals", &patches.normals[pts])?,
        ])
    }

    /// Mutual kNN between the first `ns` rows of `source` and the first `nt` of `target` (codewords of `dim`
    /// on the device); only the per-row lists come back.
    async fn match_buffers(
        &self,
        s: &wgpu::Buffer,
        t: &wgpu::Buffer,
        (ns, nt, dim): (usize, usize, usize),
        mode: MatchMode,
    ) -> Result<Vec<Match>> {
        let (k, mutual) = mutual_knn::mode_k(mode)?;
        if ns == 0 || nt == 0 {
            return Ok(Vec::new());
        }
        let gpu = &self.gpu;
        let ctx = &gpu.context;
        self.run("match_codewords", async |ws| {
            let chunk = items_per_chunk(ctx, (nt * 4) as u64, "row of the distance matrix")?;
            let lists = mutual_knn::KnnBuffers::new(|name, bytes| ws.buffer(ctx, name, bytes), ns, nt)?;
            let dist = ws.buffer(ctx, "match_distances", (chunk.min(ns) * nt * 4) as u64)?;
            let mut rec = Recorder::new(gpu, "match_codewords");
            for r0 in (0..ns).step_by(chunk) {
                let rows = chunk.min(ns - r0);
                let params = codeword_distance::CodewordDistanceParams::new(rows, nt, dim, r0)?;
                codeword_distance::record(&mut rec, &params, s, t, &dist)?;
                mutual_knn::record_chunk(&mut rec, &lists, &dist, (rows, nt, r0, ns), k, mutual)?;
            }
            if mutual {
                mutual_knn::record_flags(&mut rec, &lists, &dist, ns, nt, k)?;
            }
            let bytes = (ns * mutual_knn::K_MAX * 4) as u64;
            rec.read(&lists.row_dist, 0, bytes);
            rec.read(&lists.row_index, 0, bytes);
            rec.read(&lists.flags, 0, bytes);
            let out = rec.finish().await?;
            let flags: Vec<u32> = bytemuck::pod_collect_to_vec(&out[2]);
            Ok(mutual_knn::compact(
                &bytemuck::pod_collect_to_vec::<u8, f32>(&out[0]),
                &bytemuck::pod_collect_to_vec::<u8, u32>(&out[1]),
                mutual.then_some(flags.as_slice()),
                k,
            ))
        })
        .await
    }

    fn foldnet(&self, net: Net) -> &nets::GpuFoldNet {
        match net {
            Net::Ppf => &self.weights.ppf,
            Net::Pc => &self.weights.pc,
        }
    }
}

impl Backend for GpuBackend {
    fn name(&self) -> String {
        format!("gpu ({}; gemm {})", self.adapter_info(), self.gpu.gemm_choice().name())
    }

    fn model(&self) -> &Model {
        &self.model
    }

    fn start_scan<'a>(
        &'a self,
        cloud: &'a crate::cloud::PointCloud,
        settings: &'a crate::backend::ScanSettings,
        lap: crate::backend::Lap<'a>,
    ) -> crate::backend::StepFuture<'a, (crate::cloud::PointCloud, Box<dyn crate::backend::ScanCloud>)> {
        Box::pin(async move { self.start_device_scan(cloud, settings, lap).await })
    }

    fn new_scan_rows(&self, capacity: usize) -> Result<Arc<dyn ScanRows>> {
        self.new_device_rows(capacity)
    }

    fn restore_scan_rows(&self, codewords: Vec<f32>, pose: PoseRows, keypoints: usize) -> Result<Arc<dyn ScanRows>> {
        self.restore_device_rows(codewords, pose, keypoints)
    }

    fn adopt_rows<'a>(&'a self, rows: &'a Arc<dyn ScanRows>) -> crate::backend::StepFuture<'a, Arc<dyn ScanRows>> {
        Box::pin(async move {
            if rows.as_any().downcast_ref::<rows::GpuScanRows>().is_some_and(|r| r.owned_by(self.owner)) {
                return Ok(Arc::clone(rows));
            }
            self.restore_device_rows(rows.read_codewords().await?, rows.read_pose_rows().await?, rows.rows())
        })
    }

    fn describe<'a>(&'a self, batch: PatchBatch<'a>, rows: &'a dyn ScanRows) -> crate::backend::StepFuture<'a, ()> {
        Box::pin(async move { self.describe_on_device(batch, rows).await })
    }

    fn correspond<'a>(&'a self, request: RowMatch<'a>) -> crate::backend::StepFuture<'a, Vec<Match>> {
        Box::pin(async move { self.correspond_on_device(request).await })
    }

    fn pose_features<'a>(
        &'a self,
        rows: &'a dyn ScanRows,
        which: &'a [u32],
    ) -> crate::backend::StepFuture<'a, Vec<f32>> {
        Box::pin(async move {
            self.prepare_on_device(rows, which).await?;
            self.read_pose_features(rows, which).await
        })
    }

    fn prepare_pose_features<'a>(
        &'a self,
        rows: &'a dyn ScanRows,
        which: &'a [u32],
    ) -> crate::backend::StepFuture<'a, ()> {
        Box::pin(async move { self.prepare_on_device(rows, which).await })
    }

    fn verify<'a>(&'a self, request: MatchedRows<'a>) -> crate::backend::StepFuture<'a, Verified> {
        Box::pin(async move { self.verify_on_device(request).await })
    }

    fn refine_icp<'a>(
        &'a self,
        source: &'a crate::backend::ScanFeatures,
        target: &'a crate::backend::ScanFeatures,
        initial: nalgebra::Matrix4<f64>,
        problem: &'a crate::estimate::icp::IcpProblem,
    ) -> crate::backend::StepFuture<'a, nalgebra::Matrix4<f64>> {
        Box::pin(async move { self.refine_icp_on_device(source, target, initial, problem).await })
    }

    fn patch_features<'a>(
        &'a self,
        patches: &'a GatheredPatches,
        radius: f32,
    ) -> crate::backend::StepFuture<'a, (Vec<f32>, Vec<f32>)> {
        Box::pin(async move {
            let n = self.model.config.points_per_patch;
            let p = patches.centers.len();
            PatchBatch::new(patches, n, radius)?;
            let gpu = &self.gpu;
            let ctx = &gpu.context;
            self.run("patch_features", async |ws| {
                let chunk = items_per_chunk(ctx, (n * 16) as u64, "patch's features")?;
                let mut pending = Vec::new();
                for c0 in (0..p).step_by(chunk) {
                    let cp = chunk.min(p - c0);
                    let rows = cp * n;
                    let [centers, center_normals, points, normals] =
                        Self::upload_patch_inputs(ws, ctx, patches, n, (c0, cp))?;
                    let ppf = ws.buffer(ctx, "pf_ppf", (rows * 16) as u64)?;
                    let pc = ws.buffer(ctx, "pf_pc", (rows * 12) as u64)?;
                    let mut rec = Recorder::new(gpu, "patch_features");
                    self.record_patch_features(
                        &mut rec,
                        radius,
                        cp,
                        [&centers, &center_normals, &points, &normals],
                        [&ppf, &pc],
                    )?;
                    rec.read(&ppf, 0, (rows * 16) as u64);
                    rec.read(&pc, 0, (rows * 12) as u64);
                    pending.push(rec.submit()?);
                }
                let (mut ppf, mut pc) = (Vec::with_capacity(p * n * 4), Vec::with_capacity(p * n * 3));
                for pend in pending {
                    let out = pend.wait(gpu).await?;
                    ppf.extend_from_slice(bytemuck::cast_slice::<u8, f32>(&out[0]));
                    pc.extend_from_slice(bytemuck::cast_slice::<u8, f32>(&out[1]));
                }
                Ok((ppf, pc))
            })
            .await
        })
    }

    fn encode<'a>(&'a self, net: Net, input: &'a [f32], patches: usize) -> crate::backend::StepFuture<'a, Vec<f32>> {
        Box::pin(async move {
            let n = self.model.config.points_per_patch;
            let f = self.foldnet(net);
            self.run("encode", async |ws| nets::encode(&self.gpu, ws, f, input, patches, n).await).await
        })
    }

    fn match_codewords<'a>(
        &'a self,
        source: &'a [f32],
        target: &'a [f32],
        dim: usize,
        mode: MatchMode,
    ) -> crate::backend::StepFuture<'a, Vec<Match>> {
        Box::pin(async move {
            crate::backend::check::codeword_rows(source, target, dim)?;
            let (ns, nt) = (source.len() / dim, target.len() / dim);
            if ns == 0 || nt == 0 {
                return Ok(Vec::new());
            }
            mutual_knn::mode_k(mode)?;
            let (s, t) = self
                .run("match_codewords", async |ws| {
                    let ctx = &self.gpu.context;
                    Ok((ws.upload(ctx, "match_source", source)?, ws.upload(ctx, "match_target", target)?))
                })
                .await?;
            self.match_buffers(&s, &t, (ns, nt, dim), mode).await
        })
    }

    fn predict_rotations<'a>(&'a self, pose: RotationInputs<'a>) -> crate::backend::StepFuture<'a, Vec<[f32; 9]>> {
        Box::pin(async move {
            let c = &self.model.config;
            pose.validate(c.codeword())?;
            self.run("predict_rotations", async |ws| {
                nets::relative(&self.gpu, ws, &self.weights.relative, c, pose).await
            })
            .await
        })
    }

    fn hypotheses<'a>(
        &'a self,
        rotations: &'a [[f32; 9]],
        source: &'a [[f32; 3]],
        target: &'a [[f32; 3]],
    ) -> crate::backend::StepFuture<'a, Vec<Hypothesis>> {
        Box::pin(async move {
            let rows = rotations.len();
            crate::backend::check::hypothesis_inputs(rows, source.len(), target.len())?;
            let gpu = &self.gpu;
            let ctx = &gpu.context;
            self.run("hypotheses", async |ws| {
                let chunk = items_per_chunk(ctx, (hypotheses::HYPOTHESIS_FLOATS * 4) as u64, "hypothesis")?;
                let mut pending = Vec::new();
                for r0 in (0..rows).step_by(chunk) {
                    let n = chunk.min(rows - r0);
                    let q = ws.upload(ctx, "hyp_rotations", &rotations[r0..r0 + n])?;
                    let s = ws.upload(ctx, "hyp_source", &source[r0..r0 + n])?;
                    let t = ws.upload(ctx, "hyp_target", &target[r0..r0 + n])?;
                    let bytes = (n * hypotheses::HYPOTHESIS_FLOATS * 4) as u64;
                    let out = ws.buffer(ctx, "hyp_out", bytes)?;
                    let mut rec = Recorder::new(gpu, "hypotheses");
                    hypotheses::record(&mut rec, n, [&q, &s, &t], &out)?;
                    rec.read(&out, 0, bytes);
                    pending.push(rec.submit()?);
                }
                let mut out = Vec::with_capacity(rows);
                for p in pending {
                    let floats: Vec<f32> = bytemuck::pod_collect_to_vec(&p.wait(gpu).await?[0]);
                    out.extend(floats.chunks_exact(hypotheses::HYPOTHESIS_FLOATS).map(hypotheses::from_row));
                }
                Ok(out)
            })
            .await
        })
    }

    fn score_hypotheses<'a>(
        &'a self,
        hypotheses: &'a [Hypothesis],
        source: &'a [[f32; 3]],
        target: &'a [[f32; 3]],
        threshold: f32,
    ) -> crate::backend::StepFuture<'a, Vec<HypothesisScore>> {
        Box::pin(async move {
            crate::backend::check::correspondences(source.len(), target.len())?;
            let gpu = &self.gpu;
            let ctx = &gpu.context;
            self.run("score_hypotheses", async |ws| {
                let s = ws.upload(ctx, "score_source", source)?;
                let t = ws.upload(ctx, "score_target", target)?;
                let chunk = items_per_chunk(ctx, (hypotheses::HYPOTHESIS_FLOATS * 4) as u64, "hypothesis")?;
                let mut pending = Vec::new();
                for h0 in (0..hypotheses.len()).step_by(chunk) {
                    let n = chunk.min(hypotheses.len() - h0);
                    let rows: Vec<[f32; hypotheses::HYPOTHESIS_FLOATS]> =
                        hypotheses[h0..h0 + n].iter().map(hypotheses::to_row).collect();
                    let h = ws.upload(ctx, "score_hypotheses", &rows)?;
                    let inliers = ws.buffer(ctx, "score_inliers", (n * 4) as u64)?;
                    let sums = ws.buffer(ctx, "score_sums", (n * 4) as u64)?;
                    let params = score_hypotheses::ScoreHypothesesParams {
                        hypotheses: to_u32(n, "hypotheses")?,
                        correspondences: to_u32(source.len(), "correspondences")?,
                        threshold_sq: threshold * threshold,
                        write_mask: 0,
                    };
                    let mut rec = Recorder::new(gpu, "score_hypotheses");
                    let out =
                        score_hypotheses::ScoreBuffers { inliers: &inliers, residual_sums: &sums, mask: &gpu.dummy_rw };
                    score_hypotheses::record(&mut rec, &params, [&h, &s, &t], &out)?;
                    rec.read(&inliers, 0, (n * 4) as u64);
                    rec.read(&sums, 0, (n * 4) as u64);
                    pending.push(rec.submit()?);
                }
                let mut out = Vec::with_capacity(hypotheses.len());
                for p in pending {
                    let data = p.wait(gpu).await?;
                    let counts: Vec<u32> = bytemuck::pod_collect_to_vec(&data[0]);
                    let sums: Vec<f32> = bytemuck::pod_collect_to_vec(&data[1]);
                    out.extend(
                        counts
                            .into_iter()
                            .zip(sums)
                            .map(|(inliers, residual_sum)| HypothesisScore { inliers, residual_sum }),
                    );
                }
                Ok(out)
            })
            .await
        })
    }
}
