//! The backend seam: the learned and massively parallel stages of the pipeline, implemented by the CPU
//! reference (`CpuBackend`) and the WGSL kernels (`gpu::GpuBackend`). A scan's cloud is prepared where the
//! backend describes it ([`Backend::start_scan`]: the host for the CPU backend, the device for the GPU backend:
//! patches, normals and gathering there); ICP's per-point sums run there too ([`Backend::refine_icp`]); keypoint
//! selection, ICP's 6x6 solves and the final rigid fit stay on the host.

use crate::cpu::codeword_distance::codeword_distance;
use crate::cpu::gemm::{EncoderPrecision, Precision};
use crate::cpu::hypotheses::{Hypothesis, hypotheses};
use crate::cpu::mutual_knn::{Match, mutual_knn};
use crate::cpu::score_hypotheses::{HypothesisScore, score_hypotheses};
use crate::error::{Error, Result};
use crate::model::{Model, Net};
use crate::preprocess::GatheredPatches;
use crate::settings::MatchMode;
use std::sync::Arc;

mod features;
mod ranking;
mod scan;
mod steps;
pub use features::{PoseRows, ScanFeatures};
pub use ranking::{best_hypothesis, compare_hypotheses, hypotheses_of, repeat_per_candidate};
pub use scan::{
    DescribedKeypoints, HeldPoints, HostScanCloud, Lap, ScanCloud, ScanSettings, check_points, downsample,
    has_usable_normals, host_start_scan, kept_positions, normalise_usable_normals,
};
pub use steps::{
    ContextRows, HostRows, HostScanRows, MatchedRows, MatchedSide, PatchBatch, RankedHypothesis, RowMatch, ScanRows,
    Verified, check_restored, host_correspond, host_describe, host_pose_features, host_rows, host_verify, rank,
};

/// What RelativeNet needs per correspondence: `rows` rows of source and target pose features (`rows x
/// codeword` each) and the keypoint normals of both patches.
#[derive(Clone, Copy, Debug)]
pub struct RotationInputs<'a> {
    /// Source pose features.
    pub source: &'a [f32],
    /// Target pose features.
    pub target: &'a [f32],
    /// Source keypoint normals.
    pub source_normals: &'a [[f32; 3]],
    /// Target keypoint normals.
    pub target_normals: &'a [[f32; 3]],
    /// Correspondences.
    pub rows: usize,
}

impl RotationInputs<'_> {
    /// Checks every length against `rows` and the feature width `dim`.
    pub fn validate(&self, dim: usize) -> Result<()> {
        let r = self.rows;
        if self.source.len() != r * dim
            || self.target.len() != r * dim
            || self.source_normals.len() != r
            || self.target_normals.len() != r
        {
            return Err(crate::Error::invalid(format!(
                "predict_rotations: expected {r} rows of {dim} pose features and {r} normals per side, got {} and \
                 {} features, {} and {} normals",
                self.source.len(),
                self.target.len(),
                self.source_normals.len(),
                self.target_normals.len()
            )));
        }
        Ok(())
    }
}

/// What a backend's step or stage returns: a future of its result. The pipeline awaits it (in a browser a GPU
/// readback completes on the page's event loop); natively [`crate::block_on`] runs it. A CPU step is computed
/// when called and its future is ready ([`ready`]).
pub type StepFuture<'a, T> = std::pin::Pin<Box<dyn std::future::Future<Output = Result<T>> + 'a>>;

/// `result` as an already completed [`StepFuture`] (what the host computes synchronously).
pub fn ready<'a, T: 'a>(result: Result<T>) -> StepFuture<'a, T> {
    Box::pin(std::future::ready(result))
}

/// The steps and stages a backend implements. Every method is deterministic for given inputs.
///
/// The steps (`new_scan_rows`, `describe`, `correspond`, `pose_features`, `verify`) keep a scan's rows where
/// the backend computed them and take inputs checked by their constructors; their provided versions run on host
/// rows through the stages, which is what the CPU backend does. The stages (`patch_features` ...
/// `score_hypotheses`) take and return host vectors (benchmarks, parity tests).
pub trait Backend: Send + Sync {
    /// Human-readable backend name (and adapter, for a GPU).
    fn name(&self) -> String;

    /// The model the backend runs.
    fn model(&self) -> &Model;

    /// Prepares a validated `cloud` for description on this backend: the preprocessed cloud on the host (what
    /// the pipeline keeps of the scan) and the backend's [`ScanCloud`], which describes keypoints of it. The
    /// provided version is the host's ([`host_start_scan`]); `lap` marks the `downsample` and `index` stages.
    fn start_scan<'a>(
        &'a self,
        cloud: &'a crate::cloud::PointCloud,
        settings: &'a ScanSettings,
        lap: Lap<'a>,
    ) -> StepFuture<'a, (crate::cloud::PointCloud, Box<dyn ScanCloud>)> {
        ready(host_start_scan(cloud, settings, lap))
    }

    /// An empty store for a scan's rows; `capacity` rows (the scan's whole keypoint order) are expected.
    fn new_scan_rows(&self, capacity: usize) -> Result<Arc<dyn ScanRows>> {
        let _ = capacity;
        Ok(Arc::new(HostScanRows::new(self.model().config.codeword())))
    }

    /// A store holding saved rows (e.g. an unpickled scan), checked with [`check_restored`] for `keypoints`.
    fn restore_scan_rows(&self, codewords: Vec<f32>, pose: PoseRows, keypoints: usize) -> Result<Arc<dyn ScanRows>> {
        let dim = self.model().config.codeword();
        check_restored(&codewords, &pose, keypoints, dim)?;
        Ok(Arc::new(HostScanRows::with_rows(dim, HostRows { codewords, pose })))
    }

    /// `rows` as a store of this backend: the same store when this backend made it (or it is on the host and
    /// this backend keeps host rows), else a copy restored from a readback (e.g. unpickled host rows moved to
    /// a GPU).
    fn adopt_rows<'a>(&'a self, rows: &'a Arc<dyn ScanRows>) -> StepFuture<'a, Arc<dyn ScanRows>> {
        Box::pin(async move {
            if rows.as_any().is::<HostScanRows>() {
                return Ok(Arc::clone(rows));
            }
            self.restore_scan_rows(rows.read_codewords().await?, rows.read_pose_rows().await?, rows.rows())
        })
    }

    /// Appends the rows of `batch` to `rows`: patch features, PPF-FoldNet codewords, PC-FoldNet's inputs kept.
    fn describe<'a>(&'a self, batch: PatchBatch<'a>, rows: &'a dyn ScanRows) -> StepFuture<'a, ()> {
        Box::pin(host_describe(self, batch, rows))
    }

    /// Correspondences between the first rows of two scans.
    fn correspond<'a>(&'a self, request: RowMatch<'a>) -> StepFuture<'a, Vec<Match>> {
        Box::pin(host_correspond(self, request))
    }

    /// The pose features of rows `which` of a scan, in that order (`which.len() x codeword`, a readback);
    /// rows not computed before run through PC-FoldNet now, once.
    fn pose_features<'a>(&'a self, rows: &'a dyn ScanRows, which: &'a [u32]) -> StepFuture<'a, Vec<f32>> {
        Box::pin(host_pose_features(self, rows, which))
    }

    /// Computes the pose features of rows `which` that are missing, keeping them in the store (nothing is
    /// read back from a device store).
    fn prepare_pose_features<'a>(&'a self, rows: &'a dyn ScanRows, which: &'a [u32]) -> StepFuture<'a, ()> {
        Box::pin(async move { self.pose_features(rows, which).await.map(drop) })
    }

    /// RelativeNet's hypothesize-and-verify on matched rows: the missing pose features, a rotation per
    /// correspondence, a hypothesis per rotation, every hypothesis scored over the correspondences; only the
    /// best hypotheses and their scores come back (the rotations too when asked).
    fn verify<'a>(&'a self, request: MatchedRows<'a>) -> StepFuture<'a, Verified> {
        Box::pin(host_verify(self, request))
    }

    /// Point-to-plane ICP of `source` onto `target` from `initial` (target_from_source): the target's
    /// downsampled copy, its normals and the per-iteration normal equations where this backend keeps the
    /// scans; the solves and stopping rules of [`crate::estimate::icp::iterate`]. The provided version runs
    /// on the host clouds ([`crate::estimate::icp::refine_on_host`]).
    fn refine_icp<'a>(
        &'a self,
        source: &'a ScanFeatures,
        target: &'a ScanFeatures,
        initial: nalgebra::Matrix4<f64>,
        problem: &'a crate::estimate::icp::IcpProblem,
    ) -> StepFuture<'a, nalgebra::Matrix4<f64>> {
        let target_cloud = (&target.cloud, target.known_normals());
        ready(crate::estimate::icp::refine_on_host(&source.cloud, target_cloud, initial, problem))
    }

    /// PPF (P x N x 4) and PC (P x N x 3) network inputs of gathered patches.
    fn patch_features<'a>(&'a self, patches: &'a GatheredPatches, radius: f32) -> StepFuture<'a, (Vec<f32>, Vec<f32>)>;

    /// Codewords (P x codeword) of `patches` patches of `points_per_patch` rows each.
    fn encode<'a>(&'a self, net: Net, input: &'a [f32], patches: usize) -> StepFuture<'a, Vec<f32>>;

    /// Correspondences between source and target codewords (rows of width `dim`).
    fn match_codewords<'a>(
        &'a self,
        source: &'a [f32],
        target: &'a [f32],
        dim: usize,
        mode: MatchMode,
    ) -> StepFuture<'a, Vec<Match>>;

    /// RelativeNet's rotations target_from_source (row-major, fragment frames) for rows of [source | target]
    /// pose features, given the keypoint normals of each row's source and target patch (the normal frames of
    /// `PoseFrame::Normal`): `rotation_output.candidates()` consecutive rotations per row.
    fn predict_rotations<'a>(&'a self, pose: RotationInputs<'a>) -> StepFuture<'a, Vec<[f32; 9]>>;

    /// One hypothesis per correspondence from its rotation.
    fn hypotheses<'a>(
        &'a self,
        rotations: &'a [[f32; 9]],
        source: &'a [[f32; 3]],
        target: &'a [[f32; 3]],
    ) -> StepFuture<'a, Vec<Hypothesis>>;

    /// Inlier count and residual sum of every hypothesis over every correspondence.
    fn score_hypotheses<'a>(
        &'a self,
        hypotheses: &'a [Hypothesis],
        source: &'a [[f32; 3]],
        target: &'a [[f32; 3]],
        threshold: f32,
    ) -> StepFuture<'a, Vec<HypothesisScore>>;
}

/// Checks of the stage inputs, shared by every backend so that none divides by zero or truncates on lengths
/// that do not fit.
pub mod check {
    use crate::error::{Error, Result};

    /// `input` holds `patches x points x width` values.
    pub fn encode_input(input: &[f32], patches: usize, points: usize, width: usize) -> Result<()> {
        if input.len() != patches * points * width {
            return Err(Error::invalid(format!(
                "encode: input has {} values, expected {patches} patches x {points} points x {width}",
                input.len()
            )));
        }
        Ok(())
    }

    /// Both codeword arrays are whole rows of `dim > 0` values.
    pub fn codeword_rows(source: &[f32], target: &[f32], dim: usize) -> Result<()> {
        if dim == 0 || !source.len().is_multiple_of(dim) || !target.len().is_multiple_of(dim) {
            return Err(Error::invalid(format!("match_codewords: codeword arrays are not rows of {dim}")));
        }
        Ok(())
    }

    /// One source and one target point per rotation.
    pub fn hypothesis_inputs(rotations: usize, source: usize, target: usize) -> Result<()> {
        if source != rotations || target != rotations {
            return Err(Error::invalid("hypotheses: rotations and points differ in length"));
        }
        Ok(())
    }

    /// As many source as target points.
    pub fn correspondences(source: usize, target: usize) -> Result<()> {
        if source != target {
            return Err(Error::invalid("score_hypotheses: source and target points differ in length"));
        }
        Ok(())
    }
}

/// The plain-Rust reference backend: the oracle for the GPU and the fallback without one.
pub struct CpuBackend {
    model: Model,
    precision: EncoderPrecision,
}

impl CpuBackend {
    /// Wraps a model; the encoders run in f32 (bit-identical to the twins).
    pub fn new(model: Model) -> CpuBackend {
        CpuBackend { model, precision: Precision::F32.into() }
    }

    /// Wraps a model whose encoders' wide layers run at `precision` (one for both, or one per encoder); errors
    /// when this CPU lacks it.
    pub fn with_precision(model: Model, precision: impl Into<EncoderPrecision>) -> Result<CpuBackend> {
        let precision = precision.into();
        if !precision.is_available() {
            return Err(Error::invalid(format!(
                "CPU precision {} needs AVX-512 BF16 (bf16) or VNNI (int8), which this CPU does not have",
                precision.name()
            )));
        }
        Ok(CpuBackend { model, precision })
    }

    /// The encoders' arithmetic.
    pub fn precision(&self) -> EncoderPrecision {
        self.precision
    }
}

impl Backend for CpuBackend {
    fn name(&self) -> String {
        match self.precision.name().as_str() {
            "f32" => format!("cpu ({} threads)", rayon::current_num_threads()),
            p => format!("cpu ({} threads, {p})", rayon::current_num_threads()),
        }
    }

    fn model(&self) -> &Model {
        &self.model
    }

    fn patch_features<'a>(&'a self, patches: &'a GatheredPatches, radius: f32) -> StepFuture<'a, (Vec<f32>, Vec<f32>)> {
        let c = &self.model.config;
        ready(
            PatchBatch::new(patches, c.points_per_patch, radius)
                .map(|_| patches.features(c.points_per_patch, radius, c.pose_frame)),
        )
    }

    fn encode<'a>(&'a self, net: Net, input: &'a [f32], patches: usize) -> StepFuture<'a, Vec<f32>> {
        let n = self.model.config.points_per_patch;
        let (foldnet, precision) = match net {
            Net::Ppf => (&self.model.ppf, self.precision.ppf),
            Net::Pc => (&self.model.pc, self.precision.pc),
        };
        ready(
            check::encode_input(input, patches, n, net.io_width())
                .map(|_| foldnet.encode_at(precision, input, patches, n)),
        )
    }

    fn match_codewords<'a>(
        &'a self,
        source: &'a [f32],
        target: &'a [f32],
        dim: usize,
        mode: MatchMode,
    ) -> StepFuture<'a, Vec<Match>> {
        ready(check::codeword_rows(source, target, dim).map(|_| {
            let d = codeword_distance(source, target, dim);
            mutual_knn(&d, source.len() / dim, target.len() / dim, mode)
        }))
    }

    fn predict_rotations<'a>(&'a self, pose: RotationInputs<'a>) -> StepFuture<'a, Vec<[f32; 9]>> {
        let c = &self.model.config;
        let RotationInputs { source, target, source_normals, target_normals, rows } = pose;
        ready(
            pose.validate(c.codeword())
                .map(|_| self.model.relative.predict(c, source, target, source_normals, target_normals, rows)),
        )
    }

    fn hypotheses<'a>(
        &'a self,
        rotations: &'a [[f32; 9]],
        source: &'a [[f32; 3]],
        target: &'a [[f32; 3]],
    ) -> StepFuture<'a, Vec<Hypothesis>> {
        ready(
            check::hypothesis_inputs(rotations.len(), source.len(), target.len())
                .map(|_| hypotheses(rotations, source, target)),
        )
    }

    fn score_hypotheses<'a>(
        &'a self,
        hypotheses: &'a [Hypothesis],
        source: &'a [[f32; 3]],
        target: &'a [[f32; 3]],
        threshold: f32,
    ) -> StepFuture<'a, Vec<HypothesisScore>> {
        ready(
            check::correspondences(source.len(), target.len())
                .map(|_| score_hypotheses(hypotheses, source, target, threshold)),
        )
    }
}
