//! A scan's described rows on the device ([`GpuScanRows`]) and the steps of [`GpuBackend`] that keep them
//! there: describing appends codewords and PC-FoldNet inputs by offset (nothing is read back), matching reads
//! the codewords in place (only the matches come back), pose features are computed where they are needed and
//! stay, and hypothesize-and-verify gathers its rows by device copies and returns only the scores and the best
//! hypotheses.

use super::device::buffer::{self, Workspace, storage_buffer};
use super::device::recorder::Recorder;
use super::kernels::{hypotheses, pose_feature, score_hypotheses};
use super::nets::{self, items_per_chunk};
use super::preprocess::{DeviceCloud, SampledPatches};
use super::{Gpu, GpuBackend, to_u32};
use crate::backend::{
    MatchedRows, PatchBatch, PoseRows, RankedHypothesis, RowMatch, ScanRows, Verified, check_restored, rank,
    repeat_per_candidate,
};
use crate::cpu::score_hypotheses::HypothesisScore;
use crate::error::{Error, Result};
use std::any::Any;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};

/// Source of backend identities: rows are only read by the backend (weights) that described them.
static NEXT_OWNER: AtomicU64 = AtomicU64::new(1);

/// A fresh backend identity.
pub(crate) fn new_owner() -> u64 {
    NEXT_OWNER.fetch_add(1, Ordering::Relaxed)
}

/// A scan's rows in device buffers; see the module docs.
pub struct GpuScanRows {
    gpu: Arc<Gpu>,
    owner: u64,
    codeword: usize,
    /// PC-FoldNet input values per row.
    pc_width: usize,
    state: Mutex<DeviceRows>,
}

impl std::fmt::Debug for GpuScanRows {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = self.lock();
        f.debug_struct("GpuScanRows").field("rows", &s.rows).field("capacity", &s.capacity).finish_non_exhaustive()
    }
}

/// PC-FoldNet inputs of consecutive rows, in one buffer (as patch features wrote them).
#[derive(Clone)]
struct Segment {
    first: usize,
    rows: usize,
    buffer: wgpu::Buffer,
}

#[derive(Clone)]
struct DeviceRows {
    rows: usize,
    capacity: usize,
    /// `capacity x codeword` PPF-FoldNet codewords (the first `rows` written).
    codewords: wgpu::Buffer,
    /// `capacity x codeword` pose features (rows where `ready`).
    pose: wgpu::Buffer,
    ready: Vec<bool>,
    segments: Vec<Segment>,
}

impl GpuScanRows {
    fn new(backend: &GpuBackend, capacity: usize) -> Result<GpuScanRows> {
        let c = &backend.model.config;
        let (codeword, pc_width) = (c.codeword(), c.points_per_patch * 3);
        let ctx = &backend.gpu.context;
        let capacity = capacity.max(1);
        let bytes = (capacity * codeword * 4) as u64;
        let state = DeviceRows {
            rows: 0,
            capacity,
            codewords: storage_buffer(ctx, "scan codewords", bytes)?,
            pose: storage_buffer(ctx, "scan pose features", bytes)?,
            ready: Vec::new(),
            segments: Vec::new(),
        };
        Ok(GpuScanRows {
            gpu: Arc::clone(&backend.gpu),
            owner: backend.owner,
            codeword,
            pc_width,
            state: Mutex::new(state),
        })
    }

    /// Whether the backend `owner` made these rows.
    pub(crate) fn owned_by(&self, owner: u64) -> bool {
        self.owner == owner
    }

    fn lock(&self) -> MutexGuard<'_, DeviceRows> {
        self.state.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    /// Grows the buffers to hold `rows` rows, copying what they hold on the device.
    fn reserve(&self, s: &mut DeviceRows, rows: usize) -> Result<()> {
        if rows <= s.capacity {
            return Ok(());
        }
        let capacity = rows.max(s.capacity * 2);
        let ctx = &self.gpu.context;
        let bytes = (capacity * self.codeword * 4) as u64;
        let (codewords, pose) =
            (storage_buffer(ctx, "scan codewords", bytes)?, storage_buffer(ctx, "scan pose features", bytes)?);
        let used = (s.rows * self.codeword * 4) as u64;
        let mut rec = Recorder::new(&self.gpu, "growing scan rows");
        rec.copy(&s.codewords, 0, &codewords, 0, used);
        rec.copy(&s.pose, 0, &pose, 0, used);
        rec.submit()?;
        (s.codewords, s.pose, s.capacity) = (codewords, pose, capacity);
        Ok(())
    }

    /// Records copies of the PC-FoldNet inputs of `rows` into consecutive slots of `dst`.
    fn gather_pc_inputs(&self, s: &DeviceRows, rec: &mut Recorder<'_>, rows: &[u32], dst: &wgpu::Buffer) -> Result<()> {
        let row_bytes = (self.pc_width * 4) as u64;
        for (slot, &r) in rows.iter().enumerate() {
            let r = r as usize;
            let at = s.segments.partition_point(|g| g.first + g.rows <= r);
            let g = s.segments.get(at).filter(|g| g.first <= r).ok_or_else(|| {
                Error::invalid(format!("pose features: row {r} has no PC-FoldNet input (of {} rows)", s.rows))
            })?;
            rec.copy(&g.buffer, (r - g.first) as u64 * row_bytes, dst, slot as u64 * row_bytes, row_bytes);
        }
        Ok(())
    }

    /// Records copies of rows `rows` of `src` (`codeword` wide) into consecutive slots of `dst`.
    fn gather_rows(&self, rec: &mut Recorder<'_>, src: &wgpu::Buffer, rows: &[u32], dst: &wgpu::Buffer) {
        let row_bytes = (self.codeword * 4) as u64;
        for (slot, &r) in rows.iter().enumerate() {
            rec.copy(src, u64::from(r) * row_bytes, dst, slot as u64 * row_bytes, row_bytes);
        }
    }
}

impl ScanRows for GpuScanRows {
    fn rows(&self) -> usize {
        self.lock().rows
    }
    fn codeword(&self) -> usize {
        self.codeword
    }
    fn read_codewords<'a>(&'a self) -> crate::backend::StepFuture<'a, Vec<f32>> {
        Box::pin(async move {
            // A snapshot (buffer handles), so no lock is held while the readback is awaited.
            let s = self.lock().clone();
            let bytes =
                buffer::read_bytes(&self.gpu.context, &s.codewords, 0, (s.rows * self.codeword * 4) as u64).await?;
            Ok(bytemuck::pod_collect_to_vec(&bytes))
        })
    }
    fn read_pose_rows<'a>(&'a self) -> crate::backend::StepFuture<'a, PoseRows> {
        Box::pin(async move {
            let s = self.lock().clone();
            let ctx = &self.gpu.context;
            let mut input = Vec::with_capacity(s.rows * self.pc_width);
            for g in &s.segments {
                let bytes = buffer::read_bytes(ctx, &g.buffer, 0, (g.rows * self.pc_width * 4) as u64).await?;
                input.extend_from_slice(&bytemuck::pod_collect_to_vec::<u8, f32>(&bytes));
            }
            let features = buffer::read_bytes(ctx, &s.pose, 0, (s.rows * self.codeword * 4) as u64).await?;
            let mut features: Vec<f32> = bytemuck::pod_collect_to_vec(&features);
            for (r, &ready) in s.ready.iter().enumerate() {
                if !ready {
                    features[r * self.codeword..][..self.codeword].fill(f32::NAN);
                }
            }
            Ok(PoseRows { input, features, ready: s.ready.clone() })
        })
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
}

impl GpuBackend {
    /// `rows` as this backend's device rows, or an error when another backend described them.
    fn own<'a>(&self, rows: &'a dyn ScanRows, step: &str) -> Result<&'a GpuScanRows> {
        rows.as_any()
            .downcast_ref::<GpuScanRows>()
            .filter(|r| r.owner == self.owner)
            .ok_or_else(|| Error::invalid(format!("{step}: the scan was described by another backend")))
    }

    pub(super) fn new_device_rows(&self, capacity: usize) -> Result<Arc<dyn ScanRows>> {
        Ok(Arc::new(self.gpu.context.scoped("scan rows", || GpuScanRows::new(self, capacity))??))
    }

    pub(super) fn restore_device_rows(
        &self,
        codewords: Vec<f32>,
        pose: PoseRows,
        keypoints: usize,
    ) -> Result<Arc<dyn ScanRows>> {
        let dim = self.model.config.codeword();
        check_restored(&codewords, &pose, keypoints, dim)?;
        let pc_width = self.model.config.points_per_patch * 3;
        if pose.input.len() != keypoints * pc_width {
            return Err(Error::invalid(format!(
                "described rows: {} PC-FoldNet inputs do not fit {keypoints} rows of {pc_width}",
                pose.input.len()
            )));
        }
        let rows = GpuScanRows::new(self, keypoints)?;
        let ctx = &self.gpu.context;
        {
            let mut s = rows.lock();
            buffer::write(ctx, &s.codewords, 0, &codewords);
            buffer::write(ctx, &s.pose, 0, &pose.features);
            let per_segment = items_per_chunk(ctx, (pc_width * 4) as u64, "PC-FoldNet input row")?;
            for first in (0..keypoints).step_by(per_segment.max(1)) {
                let n = per_segment.min(keypoints - first);
                let b = storage_buffer(ctx, "scan pc inputs", (n * pc_width * 4) as u64)?;
                buffer::write(ctx, &b, 0, &pose.input[first * pc_width..(first + n) * pc_width]);
                s.segments.push(Segment { first, rows: n, buffer: b });
            }
            s.rows = keypoints;
            s.ready = pose.ready;
        }
        Ok(Arc::new(rows))
    }

    /// Patch features and PPF-FoldNet on the device, appended to `rows` by offset; PC-FoldNet's inputs are kept
    /// as they were computed.
    pub(super) async fn describe_on_device(&self, batch: PatchBatch<'_>, rows: &dyn ScanRows) -> Result<()> {
        let store = self.own(rows, "describe")?;
        let patches = batch.patches();
        let n = self.model.config.points_per_patch;
        let ctx = &self.gpu.context;
        self.describe_chunks(store, batch.len(), batch.radius(), |_, ws, c0, cp| {
            Self::upload_patch_inputs(ws, ctx, patches, n, (c0, cp))
        })
        .await
    }

    /// Patches sampled on a device cloud, gathered, featurised and encoded on the device and appended to
    /// `rows` by offset (nothing is read back): [`GpuBackend::describe_on_device`] without the uploads.
    pub(super) async fn describe_sampled(
        &self,
        cloud: &DeviceCloud,
        sampled: &SampledPatches,
        rows: &dyn ScanRows,
    ) -> Result<()> {
        let store = self.own(rows, "describe")?;
        let p = sampled.table.len();
        let Some(candidates) = sampled.candidates().filter(|_| p > 0) else { return Ok(()) };
        let n = self.model.config.points_per_patch;
        let ctx = &self.gpu.context;
        self.describe_chunks(store, p, sampled.radius, |rec, ws, c0, cp| {
            let table = ws.upload(ctx, "pf_table", &sampled.table[c0..c0 + cp])?;
            let center_index = ws.buffer(ctx, "pf_center_index", (cp * 4) as u64)?;
            let centers = ws.buffer(ctx, "pf_centers", (cp * 12) as u64)?;
            let center_normals = ws.buffer(ctx, "pf_center_normals", (cp * 12) as u64)?;
            let index = ws.buffer(ctx, "pf_index", (cp * n * 4) as u64)?;
            let points = ws.buffer(ctx, "pf_points", (cp * n * 12) as u64)?;
            let normals = ws.buffer(ctx, "pf_normals", (cp * n * 12) as u64)?;
            cloud.record_gather(rec, candidates, &table, (cp, 1, true), [&center_index, &centers, &center_normals])?;
            cloud.record_gather(rec, candidates, &table, (cp, n, false), [&index, &points, &normals])?;
            Ok([centers, center_normals, points, normals])
        })
        .await
    }

    /// Appends `p` patches to `store`, in chunks that fit the device: `inputs` records (or uploads) the patch
    /// features' inputs `[centers, center normals, points, normals]` of patches `c0..c0 + cp`; patch features
    /// and PPF-FoldNet follow in the same submission, and the codewords land in the store by row offset.
    #[expect(
        clippy::await_holding_lock,
        reason = "the store stays locked until its rows are written; see `GpuBackend::run`"
    )]
    async fn describe_chunks(
        &self,
        store: &GpuScanRows,
        p: usize,
        radius: f32,
        mut inputs: impl FnMut(&mut Recorder<'_>, &mut Workspace, usize, usize) -> Result<[wgpu::Buffer; 4]>,
    ) -> Result<()> {
        if p == 0 {
            return Ok(());
        }
        let n = self.model.config.points_per_patch;
        let cw = store.codeword;
        let gpu = &self.gpu;
        let ctx = &gpu.context;
        self.run("describe", async |ws| {
            let mut s = store.lock();
            let start = s.rows;
            store.reserve(&mut s, start + p)?;
            let chunk = items_per_chunk(ctx, (n * 16) as u64, "patch's features")?.min(nets::encoder_chunk(
                ctx,
                &self.weights.ppf,
                n,
            )?);
            let mut pending = Vec::new();
            let mut segments = Vec::new();
            for c0 in (0..p).step_by(chunk) {
                let cp = chunk.min(p - c0);
                let mut rec = Recorder::new(gpu, "describe");
                let [centers, center_normals, points, normals] = inputs(&mut rec, ws, c0, cp)?;
                let ppf = ws.buffer(ctx, "pf_ppf", (cp * n * 16) as u64)?;
                let pc = storage_buffer(ctx, "scan pc inputs", (cp * n * 12) as u64)?;
                self.record_patch_features(
                    &mut rec,
                    radius,
                    cp,
                    [&centers, &center_normals, &points, &normals],
                    [&ppf, &pc],
                )?;
                let codewords = nets::record_encode(&mut rec, gpu, ws, &self.weights.ppf, &ppf, (cp, n))?;
                rec.copy(&codewords, 0, &s.codewords, ((start + c0) * cw * 4) as u64, (cp * cw * 4) as u64);
                pending.push(rec.submit()?);
                segments.push(Segment { first: start + c0, rows: cp, buffer: pc });
            }
            for pend in pending {
                pend.wait(gpu).await?;
            }
            s.segments.extend(segments);
            s.rows = start + p;
            s.ready.resize(start + p, false);
            Ok(())
        })
        .await
    }

    /// The pose features of rows `which` (computed), read back in that order: one copy per row into a
    /// workspace buffer, one readback.
    pub(super) async fn read_pose_features(&self, rows: &dyn ScanRows, which: &[u32]) -> Result<Vec<f32>> {
        let store = self.own(rows, "pose features")?;
        if which.is_empty() {
            return Ok(Vec::new());
        }
        let gpu = &self.gpu;
        let bytes = (which.len() * store.codeword * 4) as u64;
        let out = self
            .run("pose features", async |ws| {
                let dst = ws.buffer(&gpu.context, "pose_readback", bytes)?;
                let mut rec = Recorder::new(gpu, "pose features");
                store.gather_rows(&mut rec, &store.lock().pose, which, &dst);
                rec.read(&dst, 0, bytes);
                rec.finish().await
            })
            .await?;
        Ok(bytemuck::pod_collect_to_vec(&out[0]))
    }

    /// Mutual kNN on the codewords where they are; only the matches come back.
    /// With context rows, the matching rows are built where the codewords are ([`super::kernels::unit_rows`]).
    pub(super) async fn correspond_on_device(
        &self,
        request: RowMatch<'_>,
    ) -> Result<Vec<crate::cpu::mutual_knn::Match>> {
        let ((s, ns), (t, nt)) = (request.source(), request.target());
        let dim = s.codeword();
        let blocks = request.blocks();
        if blocks.is_empty() {
            let source = self.own(s, "correspond")?.lock().codewords.clone();
            let target = self.own(t, "correspond")?.lock().codewords.clone();
            return self.match_buffers(&source, &target, (ns, nt, dim), request.mode()).await;
        }
        let width = dim * blocks.len();
        let gpu = &self.gpu;
        let (source, target) = self
            .run("matching rows", async |ws| {
                let ctx = &gpu.context;
                let source = ws.buffer(ctx, "match_source_blocks", (ns.max(1) * width * 4) as u64)?;
                let target = ws.buffer(ctx, "match_target_blocks", (nt.max(1) * width * 4) as u64)?;
                let mut rec = Recorder::new(gpu, "matching rows");
                for (b, &(weight, bs, bt)) in blocks.iter().enumerate() {
                    let block =
                        super::kernels::unit_rows::Block { width: dim, out_width: width, column: b * dim, weight };
                    for (rows, n, out) in [(bs, ns, &source), (bt, nt, &target)] {
                        if n > 0 {
                            let codewords = self.own(rows, "correspond")?.lock().codewords.clone();
                            super::kernels::unit_rows::record(&mut rec, n, block, &codewords, out)?;
                        }
                    }
                }
                rec.finish().await?;
                Ok((source, target))
            })
            .await?;
        self.match_buffers(&source, &target, (ns, nt, width), request.mode()).await
    }

    /// PC-FoldNet on the rows of `which` whose pose features are missing; the features stay on the device.
    #[expect(
        clippy::await_holding_lock,
        reason = "the store stays locked until its rows are written; see `GpuBackend::run`"
    )]
    pub(super) async fn prepare_on_device(&self, rows: &dyn ScanRows, which: &[u32]) -> Result<()> {
        let store = self.own(rows, "pose features")?;
        let gpu = &self.gpu;
        let ctx = &gpu.context;
        let n = self.model.config.points_per_patch;
        let cw = store.codeword;
        self.run("pc_encoder", async |ws| {
            let mut s = store.lock();
            if let Some(&bad) = which.iter().find(|&&r| r as usize >= s.rows) {
                return Err(Error::invalid(format!(
                    "pose features: row {bad} asked of a scan with {} keypoints",
                    s.rows
                )));
            }
            let mut missing: Vec<u32> = which.iter().copied().filter(|&r| !s.ready[r as usize]).collect();
            missing.sort_unstable();
            missing.dedup();
            if missing.is_empty() {
                return Ok(());
            }
            let chunk = nets::encoder_chunk(ctx, &self.weights.pc, n)?;
            let mut pending = Vec::new();
            for part in missing.chunks(chunk) {
                let cp = part.len();
                let x_in = ws.buffer(ctx, "enc_input", (cp * store.pc_width * 4) as u64)?;
                let index = ws.upload(ctx, "pose_rows", part)?;
                let mut rec = Recorder::new(gpu, "pc_encoder");
                store.gather_pc_inputs(&s, &mut rec, part, &x_in)?;
                let pc = nets::record_encode(&mut rec, gpu, ws, &self.weights.pc, &x_in, (cp, n))?;
                pose_feature::record(&mut rec, (cp, cw), [&pc, &s.codewords, &index], &s.pose)?;
                pending.push(rec.submit()?);
            }
            for pend in pending {
                pend.wait(gpu).await?;
            }
            for &r in &missing {
                s.ready[r as usize] = true;
            }
            Ok(())
        })
        .await
    }

    /// RelativeNet, hypotheses and scores on the device from the matched rows' pose features; the scores come
    /// back (8 bytes per hypothesis), then only the kept hypotheses (48 bytes each), and the rotations when
    /// asked.
    pub(super) async fn verify_on_device(&self, request: MatchedRows<'_>) -> Result<Verified> {
        let (src, tgt) = (request.source(), request.target());
        self.prepare_on_device(src.scan, src.rows).await?;
        self.prepare_on_device(tgt.scan, tgt.rows).await?;
        let (ss, ts) = (self.own(src.scan, "verify")?, self.own(tgt.scan, "verify")?);
        let (source_pose, target_pose) = (ss.lock().pose.clone(), ts.lock().pose.clone());
        let config = &self.model.config;
        let layers = &self.weights.relative;
        let f = nets::relative_width(layers, config)?;
        if f != ss.codeword {
            return Err(Error::invalid(format!(
                "verify: RelativeNet takes {f} pose features, the scan has {}",
                ss.codeword
            )));
        }
        let m = config.rotation_output.candidates();
        let rows = request.len();
        let hf = hypotheses::HYPOTHESIS_FLOATS;
        let (rep_source, rep_target) = (repeat_per_candidate(src.points, m), repeat_per_candidate(tgt.points, m));
        let gpu = &self.gpu;
        let ctx = &gpu.context;
        let row_bytes = nets::relative_row_bytes(layers, config).max((m * hf * 4) as u64);
        let chunk = items_per_chunk(ctx, row_bytes, "RelativeNet row")?;
        let (pending, hyps) = self
            .run("verify", async |ws| {
                let points_s = ws.upload(ctx, "score_source", src.points)?;
                let points_t = ws.upload(ctx, "score_target", tgt.points)?;
                let mut pending = Vec::new();
                let mut hyps = Vec::new();
                for r0 in (0..rows).step_by(chunk) {
                    let n = chunk.min(rows - r0);
                    let s_in = ws.buffer(ctx, "rel_source", (n * f * 4) as u64)?;
                    let t_in = ws.buffer(ctx, "rel_target", (n * f * 4) as u64)?;
                    let ns = ws.upload(ctx, "rel_source_normals", &src.normals[r0..r0 + n])?;
                    let nt = ws.upload(ctx, "rel_target_normals", &tgt.normals[r0..r0 + n])?;
                    let hs = ws.upload(ctx, "hyp_source", &rep_source[r0 * m..(r0 + n) * m])?;
                    let ht = ws.upload(ctx, "hyp_target", &rep_target[r0 * m..(r0 + n) * m])?;
                    let h = storage_buffer(ctx, "verify hypotheses", (n * m * hf * 4) as u64)?;
                    let inliers = ws.buffer(ctx, "score_inliers", (n * m * 4) as u64)?;
                    let sums = ws.buffer(ctx, "score_sums", (n * m * 4) as u64)?;
                    let mut rec = Recorder::new(gpu, "verify");
                    ss.gather_rows(&mut rec, &source_pose, &src.rows[r0..r0 + n], &s_in);
                    ts.gather_rows(&mut rec, &target_pose, &tgt.rows[r0..r0 + n], &t_in);
                    let rotations =
                        nets::record_relative(&mut rec, gpu, ws, (layers, config), [&s_in, &t_in, &ns, &nt], n)?;
                    hypotheses::record(&mut rec, n * m, [&rotations, &hs, &ht], &h)?;
                    let params = score_hypotheses::ScoreHypothesesParams {
                        hypotheses: to_u32(n * m, "hypotheses")?,
                        correspondences: to_u32(rows, "correspondences")?,
                        threshold_sq: request.threshold() * request.threshold(),
                        write_mask: 0,
                    };
                    let out =
                        score_hypotheses::ScoreBuffers { inliers: &inliers, residual_sums: &sums, mask: &gpu.dummy_rw };
                    score_hypotheses::record(&mut rec, &params, [&h, &points_s, &points_t], &out)?;
                    rec.read(&inliers, 0, (n * m * 4) as u64);
                    rec.read(&sums, 0, (n * m * 4) as u64);
                    if request.wants_rotations() {
                        rec.read(&rotations, 0, (n * m * 36) as u64);
                    }
                    pending.push(rec.submit()?);
                    hyps.push((r0 * m, n * m, h));
                }
                Ok((pending, hyps))
            })
            .await?;
        let mut scores = Vec::with_capacity(rows * m);
        let mut rotations = request.wants_rotations().then(Vec::new);
        for p in pending {
            let data = p.wait(gpu).await?;
            let counts: Vec<u32> = bytemuck::pod_collect_to_vec(&data[0]);
            let sums: Vec<f32> = bytemuck::pod_collect_to_vec(&data[1]);
            scores.extend(
                counts.into_iter().zip(sums).map(|(inliers, residual_sum)| HypothesisScore { inliers, residual_sum }),
            );
            if let Some(r) = rotations.as_mut() {
                r.extend(bytemuck::pod_collect_to_vec::<u8, [f32; 9]>(&data[2]));
            }
        }
        let mut best = Vec::new();
        for index in rank(&scores, request.keep()) {
            let (first, _, h) =
                hyps.iter().rev().find(|(first, _, _)| *first <= index).expect("chunks cover every index");
            let bytes = buffer::read_bytes(ctx, h, ((index - first) * hf * 4) as u64, (hf * 4) as u64).await?;
            let hypothesis = hypotheses::from_row(&bytemuck::pod_collect_to_vec::<u8, f32>(&bytes));
            best.push(RankedHypothesis { index, hypothesis, score: scores[index] });
        }
        Ok(Verified { best, hypotheses: scores.len(), rotations })
    }
}
