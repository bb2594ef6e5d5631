//! The step-level seam: a scan's described rows stay where the backend computed them ([`ScanRows`]), and the
//! inputs of the steps that read them ([`PatchBatch`], [`RowMatch`], [`MatchedRows`]) are checked once, by
//! their constructors, before any backend sees them. The host versions here ([`HostScanRows`] and the
//! `host_*` steps) are what the CPU backend runs and what a backend without a device store falls back to;
//! they call the stage methods in the order the pipeline always did, so their results are those of before.

use super::{Backend, PoseRows, StepFuture, best_hypothesis, compare_hypotheses, hypotheses_of, ready};
use crate::cpu::hypotheses::Hypothesis;
use crate::cpu::mutual_knn::Match;
use crate::cpu::score_hypotheses::HypothesisScore;
use crate::error::{Error, Result};
use crate::model::Net;
use crate::preprocess::GatheredPatches;
use crate::settings::MatchMode;
use std::any::Any;
use std::sync::{Arc, Mutex, MutexGuard};

/// A scan's described rows (one per kept keypoint, in description order), held by the backend that described
/// them: its PPF-FoldNet codewords (`rows x codeword`), PC-FoldNet's inputs and the pose features computed from
/// them so far. Host vectors for the CPU backend, device buffers for the GPU backend; the `read_*` methods copy
/// them to the host (pickling, pooling, tests).
pub trait ScanRows: Send + Sync + std::fmt::Debug {
    /// Rows described so far.
    fn rows(&self) -> usize;
    /// Codeword width.
    fn codeword(&self) -> usize;
    /// The PPF-FoldNet codewords, `rows x codeword`, row-major (a readback for a device store).
    fn read_codewords(&self) -> StepFuture<'_, Vec<f32>>;
    /// PC-FoldNet's inputs and the pose features computed so far (a readback for a device store).
    fn read_pose_rows(&self) -> StepFuture<'_, PoseRows>;
    /// The store as `Any`, for the backend that made it to find its own type.
    fn as_any(&self) -> &dyn Any;
}

/// Rows held in host memory: the CPU backend's store.
#[derive(Debug)]
pub struct HostScanRows {
    codeword: usize,
    state: Mutex<HostRows>,
}

/// The content of a [`HostScanRows`].
#[derive(Clone, Debug, Default)]
pub struct HostRows {
    /// PPF-FoldNet codewords, `rows x codeword`.
    pub codewords: Vec<f32>,
    /// PC-FoldNet inputs and pose features.
    pub pose: PoseRows,
}

impl HostScanRows {
    /// An empty store for codewords of `codeword` values.
    pub fn new(codeword: usize) -> HostScanRows {
        HostScanRows { codeword, state: Mutex::new(HostRows::default()) }
    }

    /// A store holding `rows` (checked by [`check_restored`]).
    pub fn with_rows(codeword: usize, rows: HostRows) -> HostScanRows {
        HostScanRows { codeword, state: Mutex::new(rows) }
    }

    /// The content, also after a panic elsewhere poisoned the lock (every update leaves it consistent).
    pub fn lock(&self) -> MutexGuard<'_, HostRows> {
        self.state.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
    }
}

impl ScanRows for HostScanRows {
    fn rows(&self) -> usize {
        self.lock().pose.ready.len()
    }
    fn codeword(&self) -> usize {
        self.codeword
    }
    fn read_codewords(&self) -> StepFuture<'_, Vec<f32>> {
        ready(Ok(self.lock().codewords.clone()))
    }
    fn read_pose_rows(&self) -> StepFuture<'_, PoseRows> {
        ready(Ok(self.lock().pose.clone()))
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
}

/// Checks that saved rows (codewords and pose rows) fit `keypoints` rows of `codeword` values.
pub fn check_restored(codewords: &[f32], pose: &PoseRows, keypoints: usize, codeword: usize) -> Result<()> {
    let fits = codewords.len() == keypoints * codeword
        && pose.ready.len() == keypoints
        && pose.features.len() == keypoints * codeword
        && pose.input.len().is_multiple_of(keypoints.max(1));
    if !fits {
        return Err(Error::invalid(format!(
            "described rows: {} codeword values, {} pose inputs, {} pose features and {} flags do not fit \
             {keypoints} keypoints of {codeword} values",
            codewords.len(),
            pose.input.len(),
            pose.features.len(),
            pose.ready.len()
        )));
    }
    Ok(())
}

/// The host store behind `rows`, or an error when another backend made it.
pub fn host_rows<'a>(rows: &'a dyn ScanRows, step: &str) -> Result<&'a HostScanRows> {
    rows.as_any()
        .downcast_ref::<HostScanRows>()
        .ok_or_else(|| Error::invalid(format!("{step}: the scan was described by another backend")))
}

/// Gathered patches checked against the model: `patches` patches of `points_per_patch` points with normals.
#[derive(Clone, Copy)]
pub struct PatchBatch<'a> {
    patches: &'a GatheredPatches,
    radius: f32,
}

impl std::fmt::Debug for PatchBatch<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PatchBatch").field("patches", &self.len()).field("radius", &self.radius).finish()
    }
}

impl<'a> PatchBatch<'a> {
    /// Checks every length of `patches` against `points_per_patch`, and the radius.
    pub fn new(patches: &'a GatheredPatches, points_per_patch: usize, radius: f32) -> Result<PatchBatch<'a>> {
        let (p, n) = (patches.centers.len(), points_per_patch);
        if patches.center_normals.len() != p || patches.points.len() != p * n || patches.normals.len() != p * n {
            return Err(Error::invalid(format!(
                "patches: expected {p} centre normals and {p} x {n} points and normals, got {}, {} and {}",
                patches.center_normals.len(),
                patches.points.len(),
                patches.normals.len()
            )));
        }
        if !(radius.is_finite() && radius > 0.0) {
            return Err(Error::invalid(format!("patches: radius must be positive, got {radius}")));
        }
        Ok(PatchBatch { patches, radius })
    }
    /// The patches.
    pub fn patches(&self) -> &'a GatheredPatches {
        self.patches
    }
    /// Patches in the batch.
    pub fn len(&self) -> usize {
        self.patches.centers.len()
    }
    /// Whether the batch holds no patch.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Patch radius.
    pub fn radius(&self) -> f32 {
        self.radius
    }
}

/// A scan's rows described at a context radius ([`crate::settings::ContextRadius`]), row for row with its main
/// rows, and the weight of their unit-length codewords in matching.
#[derive(Clone, Debug)]
pub struct ContextRows {
    /// The patch radius (cloud units).
    pub radius: f32,
    /// Weight in matching (the main radius's is 1).
    pub weight: f32,
    /// The rows (their PPF-FoldNet codewords are what matching reads).
    pub rows: Arc<dyn ScanRows>,
}

/// Matching the first rows of two described scans, checked: both prefixes within the rows described and the
/// codeword widths equal and non-zero; with context rows (both scans described at the same context radii and
/// weights), each row matches on its codewords of every radius side by side ([`RowMatch::blocks`]).
#[derive(Clone, Copy, Debug)]
pub struct RowMatch<'a> {
    source: &'a dyn ScanRows,
    source_rows: usize,
    target: &'a dyn ScanRows,
    target_rows: usize,
    mode: MatchMode,
    source_context: &'a [ContextRows],
    target_context: &'a [ContextRows],
}

impl<'a> RowMatch<'a> {
    /// Checks the prefixes and widths.
    pub fn new(
        (source, source_rows): (&'a dyn ScanRows, usize),
        (target, target_rows): (&'a dyn ScanRows, usize),
        mode: MatchMode,
    ) -> Result<RowMatch<'a>> {
        if source.codeword() == 0 || source.codeword() != target.codeword() {
            return Err(Error::invalid(format!(
                "correspond: codeword widths {} and {} differ or are zero",
                source.codeword(),
                target.codeword()
            )));
        }
        if source_rows > source.rows() || target_rows > target.rows() {
            return Err(Error::invalid(format!(
                "correspond: {source_rows} and {target_rows} rows asked of scans with {} and {} rows",
                source.rows(),
                target.rows()
            )));
        }
        Ok(RowMatch { source, source_rows, target, target_rows, mode, source_context: &[], target_context: &[] })
    }

    /// Matches on the codewords of the context rows too: both scans' context radii and weights must be equal
    /// and their context rows hold at least the prefixes matched, in the main rows' width.
    pub fn with_context(mut self, source: &'a [ContextRows], target: &'a [ContextRows]) -> Result<RowMatch<'a>> {
        let described = |c: &[ContextRows]| c.iter().map(|c| (c.radius, c.weight)).collect::<Vec<_>>();
        if described(source) != described(target) {
            return Err(Error::invalid(format!(
                "correspond: the scans were described at different context radii and weights ({:?} and {:?})",
                described(source),
                described(target)
            )));
        }
        for (c, prefix) in
            source.iter().map(|c| (c, self.source_rows)).chain(target.iter().map(|c| (c, self.target_rows)))
        {
            if c.rows.codeword() != self.source.codeword() || c.rows.rows() < prefix {
                return Err(Error::invalid(format!(
                    "correspond: context rows at radius {} hold {} rows of {} values, {prefix} rows of {} needed",
                    c.radius,
                    c.rows.rows(),
                    c.rows.codeword(),
                    self.source.codeword()
                )));
            }
        }
        (self.source_context, self.target_context) = (source, target);
        Ok(self)
    }

    /// The blocks of the matching rows: (weight, source rows, target rows) of the main radius (weight 1) and
    /// each context radius; empty without context rows (matching then reads the main codewords as they are).
    pub fn blocks(&self) -> Vec<(f32, &'a dyn ScanRows, &'a dyn ScanRows)> {
        if self.source_context.is_empty() {
            return Vec::new();
        }
        let main = std::iter::once((1.0, self.source, self.target));
        main.chain(
            self.source_context
                .iter()
                .zip(self.target_context)
                .map(|(s, t)| (s.weight, s.rows.as_ref(), t.rows.as_ref())),
        )
        .collect()
    }
    /// Source rows and how many of the first to match.
    pub fn source(&self) -> (&'a dyn ScanRows, usize) {
        (self.source, self.source_rows)
    }
    /// Target rows and how many of the first to match.
    pub fn target(&self) -> (&'a dyn ScanRows, usize) {
        (self.target, self.target_rows)
    }
    /// Matching rule.
    pub fn mode(&self) -> MatchMode {
        self.mode
    }
}

/// One side of the matched rows: the scan, the row of each correspondence, and those rows' keypoint positions
/// and normals (scan frame).
#[derive(Clone, Copy, Debug)]
pub struct MatchedSide<'a> {
    /// The scan's rows.
    pub scan: &'a dyn ScanRows,
    /// Row of each correspondence.
    pub rows: &'a [u32],
    /// Keypoint position of each correspondence.
    pub points: &'a [[f32; 3]],
    /// Keypoint normal of each correspondence.
    pub normals: &'a [[f32; 3]],
}

/// What RelativeNet's hypothesize-and-verify takes, checked: equally many rows, points and normals per side
/// (at least one), rows within their scans, equal codeword widths, a positive threshold.
#[derive(Clone, Copy, Debug)]
pub struct MatchedRows<'a> {
    source: MatchedSide<'a>,
    target: MatchedSide<'a>,
    threshold: f32,
    keep: usize,
    with_rotations: bool,
}

impl<'a> MatchedRows<'a> {
    /// Checks the lengths, rows, widths and threshold; `keep` best hypotheses come back (at least one).
    pub fn new(source: MatchedSide<'a>, target: MatchedSide<'a>, threshold: f32, keep: usize) -> Result<Self> {
        let n = source.rows.len();
        for (name, side) in [("source", &source), ("target", &target)] {
            if n == 0 || side.rows.len() != n || side.points.len() != n || side.normals.len() != n {
                return Err(Error::invalid(format!(
                    "verify: {name} has {} rows, {} points and {} normals for {n} correspondences (at least one)",
                    side.rows.len(),
                    side.points.len(),
                    side.normals.len()
                )));
            }
            if let Some(&bad) = side.rows.iter().find(|&&r| r as usize >= side.scan.rows()) {
                return Err(Error::invalid(format!(
                    "verify: {name} row {bad} asked of a scan with {} rows",
                    side.scan.rows()
                )));
            }
        }
        if source.scan.codeword() == 0 || source.scan.codeword() != target.scan.codeword() {
            return Err(Error::invalid("verify: the scans' codeword widths differ or are zero"));
        }
        if !(threshold.is_finite() && threshold > 0.0) {
            return Err(Error::invalid(format!("verify: inlier threshold must be positive, got {threshold}")));
        }
        Ok(MatchedRows { source, target, threshold, keep: keep.max(1), with_rotations: false })
    }
    /// Also returns every predicted rotation (tests, diagnostics); off by default, as they are the largest
    /// result.
    pub fn with_rotations(mut self) -> Self {
        self.with_rotations = true;
        self
    }
    /// Source side.
    pub fn source(&self) -> &MatchedSide<'a> {
        &self.source
    }
    /// Target side.
    pub fn target(&self) -> &MatchedSide<'a> {
        &self.target
    }
    /// Correspondences.
    pub fn len(&self) -> usize {
        self.source.rows.len()
    }
    /// Never true (checked), for symmetry with `len`.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Inlier threshold.
    pub fn threshold(&self) -> f32 {
        self.threshold
    }
    /// Best hypotheses asked for.
    pub fn keep(&self) -> usize {
        self.keep
    }
    /// Whether the rotations are asked for.
    pub fn wants_rotations(&self) -> bool {
        self.with_rotations
    }
}

/// A hypothesis kept by [`Backend::verify`]: its index among all, the pose and its score.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RankedHypothesis {
    /// Index among all hypotheses (`candidates` consecutive per correspondence).
    pub index: usize,
    /// The pose.
    pub hypothesis: Hypothesis,
    /// Its score over every correspondence.
    pub score: HypothesisScore,
}

/// What [`Backend::verify`] returns: the best hypotheses, best first (most inliers, then smallest residual
/// sum, then lowest index), how many were scored, and the rotations when asked.
#[derive(Clone, Debug)]
pub struct Verified {
    /// The best `keep` hypotheses, best first.
    pub best: Vec<RankedHypothesis>,
    /// Hypotheses scored.
    pub hypotheses: usize,
    /// Every rotation (`candidates` per correspondence), when asked.
    pub rotations: Option<Vec<[f32; 9]>>,
}

/// The `keep` best of `scores` in the order of [`best_hypothesis`].
pub fn rank(scores: &[HypothesisScore], keep: usize) -> Vec<usize> {
    if keep == 1 {
        return best_hypothesis(scores).into_iter().collect();
    }
    let mut order: Vec<usize> = (0..scores.len()).collect();
    order.sort_by(|&a, &b| compare_hypotheses(scores, a, b));
    order.truncate(keep);
    order
}

/// Describes a batch into host rows: patch features, PPF-FoldNet, and PC-FoldNet's inputs kept.
pub async fn host_describe<B: Backend + ?Sized>(backend: &B, batch: PatchBatch<'_>, rows: &dyn ScanRows) -> Result<()> {
    let store = host_rows(rows, "describe")?;
    let count = batch.len();
    if count == 0 {
        return Ok(());
    }
    let (ppf_input, pc_input) = backend.patch_features(batch.patches(), batch.radius()).await?;
    let codewords = backend.encode(Net::Ppf, &ppf_input, count).await?;
    let dim = store.codeword;
    if codewords.len() != count * dim {
        return Err(Error::invalid(format!("describe: {} codeword values for {count} rows of {dim}", codewords.len())));
    }
    let mut s = store.lock();
    s.codewords.extend(codewords);
    if s.pose.input.is_empty() {
        // The first keypoints' input kept as computed (a scan's largest buffer is not copied).
        s.pose.input = pc_input;
    } else {
        s.pose.input.extend(pc_input);
    }
    let rows = s.pose.ready.len() + count;
    s.pose.features.resize(rows * dim, f32::NAN);
    s.pose.ready.resize(rows, false);
    Ok(())
}

/// Matches the first rows of two host stores (side by side with their context rows, if any).
pub async fn host_correspond<B: Backend + ?Sized>(backend: &B, request: RowMatch<'_>) -> Result<Vec<Match>> {
    let ((s, sn), (t, tn)) = (request.source(), request.target());
    let dim = s.codeword();
    let prefix = |rows: &dyn ScanRows, n: usize| -> Result<Vec<f32>> {
        Ok(host_rows(rows, "correspond")?.lock().codewords[..n * dim].to_vec())
    };
    let blocks = request.blocks();
    if blocks.is_empty() {
        return backend.match_codewords(&prefix(s, sn)?, &prefix(t, tn)?, dim, request.mode()).await;
    }
    let width = dim * blocks.len();
    let (mut source, mut target) = (vec![0.0; sn * width], vec![0.0; tn * width]);
    for (b, &(weight, bs, bt)) in blocks.iter().enumerate() {
        crate::cpu::unit_rows::unit_rows(&prefix(bs, sn)?, dim, weight, b * dim, width, &mut source);
        crate::cpu::unit_rows::unit_rows(&prefix(bt, tn)?, dim, weight, b * dim, width, &mut target);
    }
    backend.match_codewords(&source, &target, width, request.mode()).await
}

/// The pose features (PC-FoldNet codeword minus PPF-FoldNet codeword) of `which` rows of a host store, in
/// that order; rows not computed before run through PC-FoldNet now, once.
#[expect(clippy::await_holding_lock, reason = "host rows: the stage's future is computed when called, nothing waits")]
pub async fn host_pose_features<B: Backend + ?Sized>(
    backend: &B,
    rows: &dyn ScanRows,
    which: &[u32],
) -> Result<Vec<f32>> {
    let store = host_rows(rows, "pose features")?;
    let dim = store.codeword;
    let mut s = store.lock();
    let count = s.pose.ready.len();
    if let Some(&bad) = which.iter().find(|&&r| r as usize >= count) {
        return Err(Error::invalid(format!("pose features: row {bad} asked of a scan with {count} keypoints")));
    }
    let mut missing: Vec<u32> = which.iter().copied().filter(|&r| !s.pose.ready[r as usize]).collect();
    missing.sort_unstable();
    missing.dedup();
    if !missing.is_empty() {
        let width = s.pose.input.len() / count.max(1);
        let input: Vec<f32> =
            missing.iter().flat_map(|&r| s.pose.input[r as usize * width..][..width].iter().copied()).collect();
        let pc = backend.encode(Net::Pc, &input, missing.len()).await?;
        let HostRows { codewords, pose } = &mut *s;
        for (slot, &r) in missing.iter().enumerate() {
            let r = r as usize;
            let feature = crate::model::pose_feature(&pc[slot * dim..][..dim], &codewords[r * dim..][..dim]);
            pose.features[r * dim..][..dim].copy_from_slice(&feature);
            pose.ready[r] = true;
        }
    }
    Ok(which.iter().flat_map(|&r| s.pose.features[r as usize * dim..][..dim].iter().copied()).collect())
}

/// Hypothesize and verify through the stage methods: pose features, RelativeNet, one hypothesis per rotation,
/// every hypothesis scored over the correspondences.
pub async fn host_verify<B: Backend + ?Sized>(backend: &B, request: MatchedRows<'_>) -> Result<Verified> {
    let (s, t) = (request.source(), request.target());
    let fs = backend.pose_features(s.scan, s.rows).await?;
    let ft = backend.pose_features(t.scan, t.rows).await?;
    let inputs = super::RotationInputs {
        source: &fs,
        target: &ft,
        source_normals: s.normals,
        target_normals: t.normals,
        rows: request.len(),
    };
    let rotations = backend.predict_rotations(inputs).await?;
    let m = backend.model().config.rotation_output.candidates();
    if rotations.len() != m * request.len() {
        return Err(Error::invalid(format!("verify: {} rotations for {} rows", rotations.len(), request.len())));
    }
    let hypotheses = hypotheses_of(backend, &rotations, s.points, t.points, m).await?;
    let scores = backend.score_hypotheses(&hypotheses, s.points, t.points, request.threshold()).await?;
    if scores.len() != hypotheses.len() {
        return Err(Error::invalid("verify: a score per hypothesis expected"));
    }
    let best = rank(&scores, request.keep())
        .into_iter()
        .map(|index| RankedHypothesis { index, hypothesis: hypotheses[index], score: scores[index] })
        .collect();
    Ok(Verified { best, hypotheses: hypotheses.len(), rotations: request.wants_rotations().then_some(rotations) })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::CpuBackend;
    use crate::model::{Model, ModelConfig, Weights};

    fn host(rows: usize, codeword: usize) -> HostScanRows {
        let pose =
            PoseRows { input: vec![0.0; rows * 3], features: vec![0.0; rows * codeword], ready: vec![false; rows] };
        HostScanRows::with_rows(codeword, HostRows { codewords: vec![0.5; rows * codeword], pose })
    }

    #[test]
    fn row_match_refuses_prefixes_past_the_rows_and_unequal_widths() {
        let (a, b, c) = (host(4, 3), host(6, 3), host(6, 2));
        assert!(RowMatch::new((&a, 4), (&b, 6), MatchMode::Mutual(1)).is_ok());
        assert!(RowMatch::new((&a, 5), (&b, 6), MatchMode::Mutual(1)).is_err());
        assert!(RowMatch::new((&a, 4), (&b, 7), MatchMode::Mutual(1)).is_err());
        assert!(RowMatch::new((&a, 4), (&c, 6), MatchMode::Mutual(1)).is_err());
        assert!(RowMatch::new((&host(1, 0), 1), (&host(1, 0), 1), MatchMode::Mutual(1)).is_err());
    }

    #[test]
    fn matched_rows_refuse_inconsistent_lengths_rows_and_thresholds() {
        let (a, b) = (host(4, 3), host(6, 3));
        let p = [[0.0f32; 3]; 2];
        let ok = |rows_s: &[u32], ps: &[[f32; 3]], thr: f32| {
            MatchedRows::new(
                MatchedSide { scan: &a, rows: rows_s, points: ps, normals: &p },
                MatchedSide { scan: &b, rows: &[5, 0], points: &p, normals: &p },
                thr,
                1,
            )
            .is_ok()
        };
        assert!(ok(&[3, 0], &p, 0.1));
        assert!(!ok(&[4, 0], &p, 0.1), "row past the scan");
        assert!(!ok(&[3], &p, 0.1), "one row for two correspondences");
        assert!(!ok(&[3, 0], &p[..1], 0.1), "one point for two correspondences");
        assert!(!ok(&[3, 0], &p, 0.0) && !ok(&[3, 0], &p, f32::NAN), "threshold");
        let empty = MatchedRows::new(
            MatchedSide { scan: &a, rows: &[], points: &[], normals: &[] },
            MatchedSide { scan: &b, rows: &[], points: &[], normals: &[] },
            0.1,
            1,
        );
        assert!(empty.is_err(), "no correspondence");
    }

    #[test]
    fn cpu_stages_refuse_inconsistent_lengths_instead_of_dividing_or_truncating() {
        let config = ModelConfig { points_per_patch: 16, ..ModelConfig::default() };
        let cpu = CpuBackend::new(Model::from_weights(&Weights::init(&config, 1).unwrap()).unwrap());
        assert!(
            crate::block_on(cpu.match_codewords(&[0.0; 8], &[0.0; 8], 0, MatchMode::Mutual(1))).is_err(),
            "zero width"
        );
        assert!(
            crate::block_on(cpu.match_codewords(&[0.0; 8], &[0.0; 6], 4, MatchMode::Mutual(1))).is_err(),
            "ragged rows"
        );
        assert!(crate::block_on(cpu.encode(Net::Ppf, &[0.0; 7], 1)).is_err());
        assert!(crate::block_on(cpu.hypotheses(&[[0.0; 9]; 2], &[[0.0; 3]; 2], &[[0.0; 3]; 1])).is_err());
        let h = Hypothesis { rotation: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], translation: [0.0; 3] };
        assert!(crate::block_on(cpu.score_hypotheses(&[h], &[[0.0; 3]; 2], &[[0.0; 3]; 3], 0.1)).is_err());
    }

    #[test]
    fn rank_orders_by_inliers_then_residual_then_index() {
        let s = |inliers, residual_sum| HypothesisScore { inliers, residual_sum };
        let scores = [s(3, 0.5), s(5, 0.9), s(5, 0.2), s(1, 0.0), s(5, 0.2)];
        assert_eq!(rank(&scores, 1), vec![2]);
        assert_eq!(rank(&scores, 3), vec![2, 4, 1]);
        assert_eq!(rank(&scores, 9), vec![2, 4, 1, 0, 3]);
        assert_eq!(rank(&scores, 1), vec![best_hypothesis(&scores).unwrap()]);
        assert!(rank(&[], 2).is_empty());
    }
}
