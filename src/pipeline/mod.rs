//! The registration pipeline: load weights, describe each scan (keypoints, patches, codewords), correspond,
//! estimate the pose. `register` runs it all; `Registrar` exposes the steps for evaluation tools and keeps the
//! model and backend loaded across pairs.

use crate::backend::{Backend, ContextRows, CpuBackend, MatchedRows, MatchedSide, RowMatch, ScanRows, ScanSettings};
use crate::cloud::PointCloud;
use crate::cpu::gemm::EncoderPrecision;
use crate::error::{Error, Result};
use crate::estimate::candidates;
use crate::estimate::icp::IcpProblem;
use crate::estimate::ransac_candidates;
use crate::estimate::visibility::PairViews;
use crate::model::{Model, Weights, WeightsView};
use crate::pose::matrix_from_hypothesis;
use crate::preprocess::select_keypoints;
use crate::rng::Rng;
use crate::scale::{ScaleChoice, ScaleReport};
use crate::settings::*;
use crate::verdict::Verdict;
use crate::verdict::handedness::mirror_image;
use std::path::PathBuf;
use std::sync::Arc;
// std's clock panics on wasm32-unknown-unknown; the browser's (performance.now) has the same interface.
#[cfg(not(target_arch = "wasm32"))]
use std::time::Instant;
#[cfg(target_arch = "wasm32")]
use web_time::Instant;

mod scan;
mod stages;

pub use crate::backend::{PoseRows, ScanFeatures};
use scan::DescribingScan;
pub use stages::{Round, keypoint_stages};

/// Fewest points a scan may have after preprocessing.
pub const MIN_POINTS: usize = 10;
/// Fewest correspondences an estimator accepts.
pub const MIN_CORRESPONDENCES: usize = 3;
/// Environment variable that overrides the default weights path.
pub const WEIGHTS_ENV: &str = "DPR_GPU_WEIGHTS";

/// The weights file that replaces the built-in default weights, if any: `settings.weights`, else the file
/// named by [`WEIGHTS_ENV`].
pub fn weights_file(settings: &RegistrationSettings) -> Option<PathBuf> {
    settings.weights.clone().or_else(|| std::env::var_os(WEIGHTS_ENV).map(PathBuf::from))
}

/// Loads the weights the settings name, or the built-in default weights ([`Weights::built_in`]), which are
/// compiled into the library: an installed binary or Python extension never looks for the source checkout.
pub fn load_weights(settings: &RegistrationSettings) -> Result<Weights> {
    match weights_file(settings) {
        Some(path) => Weights::load(&path),
        None => Weights::built_in(),
    }
}

/// Creates the backend `kind` for `model`; see [`choose_backend`].
pub fn create_backend(kind: BackendKind, model: Model) -> Result<Box<dyn Backend>> {
    Ok(choose_backend(kind, model)?.0)
}

/// Creates the backend `kind` for `model` and says why it is the one. `Auto` takes a hardware GPU adapter when
/// there is one and otherwise the CPU reference path; it never takes a software rasteriser (an adapter whose
/// device type is CPU, such as lavapipe) unless `DPR_GPU_ALLOW_SOFTWARE=1` or `WGPU_ADAPTER_NAME` asks for it.
pub fn choose_backend(kind: BackendKind, model: Model) -> Result<(Box<dyn Backend>, String)> {
    let cpu = |model: Model, why: String| -> Result<(Box<dyn Backend>, String)> {
        let (precision, how) = EncoderPrecision::from_env()?;
        Ok((Box::new(CpuBackend::with_precision(model, precision)?), format!("{why}; {how}")))
    };
    match kind {
        BackendKind::Cpu => cpu(model, "asked for (--backend cpu)".into()),
        #[cfg(feature = "gpu")]
        BackendKind::Gpu => Ok((Box::new(crate::gpu::GpuBackend::new(model)?), "asked for (--backend gpu)".into())),
        #[cfg(feature = "gpu")]
        BackendKind::Auto => match crate::gpu::GpuBackend::new_hardware(model.clone()) {
            Ok(gpu) => Ok((Box::new(gpu), "auto: a hardware GPU adapter was found".into())),
            Err(e) => cpu(model, format!("auto: {e}")),
        },
        #[cfg(not(feature = "gpu"))]
        BackendKind::Gpu => Err(Error::Gpu("dpr-gpu was built without its `gpu` feature".into())),
        #[cfg(not(feature = "gpu"))]
        BackendKind::Auto => cpu(model, "auto: built without the `gpu` feature".into()),
    }
}

/// Most patch points per scan (keypoints x points per patch): bounds the memory of the patch stages.
pub const MAX_PATCH_POINTS: usize = 1 << 25;

/// Checks the settings every constructor relies on, and the memory the keypoint count implies for `config`.
fn validate_settings(settings: &RegistrationSettings, config: &crate::model::ModelConfig) -> Result<()> {
    settings.validate()?;
    let patch_points = settings.keypoints.saturating_mul(config.points_per_patch);
    if patch_points > MAX_PATCH_POINTS {
        return Err(Error::invalid(format!(
            "keypoints x points per patch = {} x {} exceeds the limit of {MAX_PATCH_POINTS} patch points",
            settings.keypoints, config.points_per_patch
        )));
    }
    Ok(())
}

/// Called after every stage with its name (`source.normals`, `matching`...) and its wall time in seconds.
pub type ProgressFn = dyn Fn(&str, f64) + Send + Sync;

/// Stage times, reported to the progress callback as they finish.
struct Stopwatch<'a> {
    start: Instant,
    timings: Vec<StageTime>,
    /// The callback and the prefix its stage names get (beyond `scope`).
    progress: Option<(&'a ProgressFn, &'static str)>,
    /// The prefix of the recorded stage names (`source.`, `target.` or none).
    scope: &'static str,
}

impl<'a> Stopwatch<'a> {
    fn new(progress: Option<(&'a ProgressFn, &'static str)>) -> Self {
        Stopwatch { start: Instant::now(), timings: Vec::new(), progress, scope: "" }
    }
    fn lap(&mut self, stage: &str) {
        let now = Instant::now();
        let seconds = (now - self.start).as_secs_f64();
        let stage = format!("{}{stage}", self.scope);
        if let Some((report, prefix)) = self.progress {
            report(&format!("{prefix}{stage}"), seconds);
        }
        self.timings.push(StageTime { stage, seconds });
        self.start = now;
    }
}

/// Stages a pairwise registration's first round reports to the progress callback: six per scan (downsample,
/// index, keypoints, patches, normals, PPF-FoldNet with its patch features), then matching, PC-FoldNet on the
/// matched keypoints, and estimation.
pub const PAIR_STAGES: usize = 15;
/// Stages each further round of the progressive schedule reports: three per scan, then three for the pair.
pub const ROUND_STAGES: usize = 9;

/// A configured pipeline: model and backend loaded once, reused across pairs.
///
/// With no radius in its settings, [`Registrar::register`] chooses it from the two clouds
/// ([`crate::scale`]); the steps that see one scan at a time ([`Registrar::describe`],
/// [`Registrar::register_described`]) use the radius as it stands (the weights' training radius times
/// [`RADIUS_PER_TRAINING_RADIUS`]) unless the registrar comes from [`Registrar::at_scale_of`], which fixes it
/// from every scan of the job first.
pub struct Registrar {
    /// The settings it was built with.
    pub settings: RegistrationSettings,
    backend: Arc<dyn Backend>,
    /// Why this backend (see [`choose_backend`]).
    backend_reason: String,
    progress: Option<Arc<ProgressFn>>,
    /// How the radius was chosen, when [`Registrar::at_scale`] chose it from the data.
    auto_scale: Option<ScaleChoice>,
}

impl Registrar {
    /// Loads the weights and prepares the backend.
    pub fn new(settings: &RegistrationSettings) -> Result<Registrar> {
        match weights_file(settings) {
            Some(path) => Registrar::with_weights(settings, &Weights::load(&path)?),
            // Read in place: the built-in bytes are never copied.
            None => Registrar::with_view(settings, &Weights::built_in_view()?),
        }
    }

    /// Builds the pipeline from weights already in memory.
    pub fn with_weights(settings: &RegistrationSettings, weights: &Weights) -> Result<Registrar> {
        Registrar::with_view(settings, &weights.view())
    }

    /// [`Registrar::with_weights`] from a view of checked weights.
    fn with_view(settings: &RegistrationSettings, weights: &WeightsView<'_>) -> Result<Registrar> {
        validate_settings(settings, &weights.config)?;
        let model = Model::from_view(weights)?;
        let (backend, reason) = choose_backend(settings.backend, model)?;
        let mut registrar = Registrar::with_backend(settings, backend)?;
        registrar.backend_reason = reason;
        Ok(registrar)
    }

    /// Builds the pipeline around a backend made by the caller (e.g. one sharing a GPU device); the settings'
    /// `weights` and `backend` fields are ignored.
    pub fn with_backend(settings: &RegistrationSettings, backend: Box<dyn Backend>) -> Result<Registrar> {
        validate_settings(settings, &backend.model().config)?;
        Ok(Registrar {
            settings: settings.clone(),
            backend: Arc::from(backend),
            backend_reason: "given by the caller".into(),
            progress: None,
            auto_scale: None,
        })
    }

    /// This registrar at `scale`: the same backend and settings, with the radius `scale` chose when the settings
    /// give none (a given radius stays, whatever `scale` says).
    pub fn at_scale(&self, scale: ScaleChoice) -> Registrar {
        let mut settings = self.settings.clone();
        let auto_scale = match (self.settings.radius, &self.auto_scale) {
            (Some(_), auto) => auto.clone(),
            (None, _) => {
                settings.radius = Some(scale.radius);
                Some(scale)
            }
        };
        Registrar {
            settings,
            backend: self.backend.clone(),
            backend_reason: self.backend_reason.clone(),
            progress: self.progress.clone(),
            auto_scale,
        }
    }

    /// This registrar with the radius chosen from `clouds` (each named for errors) when its settings give none
    /// ([`crate::scale::choose_for`]); see [`Registrar::at_scale`].
    pub fn at_scale_of(&self, clouds: &[(&PointCloud, &str)]) -> Result<Registrar> {
        if self.settings.radius.is_some() {
            return Ok(self.at_scale(ScaleChoice::given(self.radius())));
        }
        for (cloud, what) in clouds {
            cloud.validate(what)?;
        }
        Ok(self.at_scale(crate::scale::choose_for(clouds)?))
    }

    /// How the radius in use was chosen: from the data ([`Registrar::at_scale_of`]) or given (the settings'
    /// radius, or the default [`Registrar::radius`] when neither is known yet).
    pub fn scale(&self) -> ScaleChoice {
        self.auto_scale.clone().unwrap_or_else(|| ScaleChoice::given(self.radius()))
    }

    /// The radius in use with everything that follows it ([`ScaleReport`]).
    pub fn scale_report(&self) -> ScaleReport {
        ScaleReport {
            radius: self.radius(),
            rule: self.scale().rule(),
            voxel: self.voxel(false),
            inlier_threshold: self.inlier_threshold(),
            icp_distance: self.icp_max_distance(),
        }
    }

    /// Calls `progress` after every stage (for a progress display); see [`ProgressFn`].
    pub fn with_progress(mut self, progress: Box<ProgressFn>) -> Registrar {
        self.progress = Some(Arc::from(progress));
        self
    }

    /// The progress callback with the stage-name prefix of scan `stream` (0: source, 1: target).
    fn progress_for(&self, stream: u64) -> Option<(&ProgressFn, &'static str)> {
        let prefix = match stream {
            0 => "source.",
            1 => "target.",
            _ => "",
        };
        self.progress.as_deref().map(|p| (p, prefix))
    }

    /// The backend's name.
    pub fn backend_name(&self) -> String {
        self.backend.name()
    }

    /// Why the backend was chosen, e.g. "auto: no hardware GPU adapter (...)".
    pub fn backend_reason(&self) -> &str {
        &self.backend_reason
    }

    /// The backend.
    pub fn backend(&self) -> &dyn Backend {
        self.backend.as_ref()
    }

    /// Voxel size in use for a cloud with or without normals: the settings' (none for 0); by default, for a
    /// cloud whose normals must be estimated, the radius in use times [`crate::settings::VOXEL_PER_RADIUS`]
    /// (the density the normals were estimated at in training), and none for a cloud that has normals.
    pub fn voxel(&self, cloud_has_normals: bool) -> Option<f32> {
        match self.settings.voxel {
            Some(0.0) => None,
            Some(v) => Some(v),
            None if cloud_has_normals => None,
            None => Some(self.radius() * crate::settings::VOXEL_PER_RADIUS),
        }
    }

    /// Patch radius in use: the settings', by default the weights' training radius times
    /// [`crate::settings::RADIUS_PER_TRAINING_RADIUS`].
    pub fn radius(&self) -> f32 {
        self.settings.radius.unwrap_or(self.backend.model().config.radius * crate::settings::RADIUS_PER_TRAINING_RADIUS)
    }

    /// ICP's largest point-pair distance in use: the settings', by default the radius in use times
    /// [`crate::settings::ICP_DISTANCE_PER_RADIUS`]; `None` when ICP is off.
    pub fn icp_max_distance(&self) -> Option<f32> {
        self.settings.icp.map(|icp| icp.max_correspondence_distance.unwrap_or(self.default_icp_distance()))
    }

    fn default_icp_distance(&self) -> f32 {
        self.radius() * crate::settings::ICP_DISTANCE_PER_RADIUS
    }

    /// Inlier threshold in use: the settings', by default the radius in use times
    /// [`crate::settings::INLIER_THRESHOLD_PER_RADIUS`].
    pub fn inlier_threshold(&self) -> f32 {
        self.settings.inlier_threshold.unwrap_or(self.radius() * crate::settings::INLIER_THRESHOLD_PER_RADIUS)
    }

    /// The context radii in use (cloud units) with their weights: the settings' factors times the radius.
    pub fn context_radii(&self) -> Vec<(f32, f32)> {
        self.settings.context_radii.iter().map(|c| (c.factor * self.radius(), c.weight)).collect()
    }

    /// Preprocesses `cloud` and describes all its keypoints (`settings.keypoints`). `stream` separates the
    /// random choices of different scans under one seed (0 for the source, 1 for the target in `register`).
    /// Pose features are computed later, only for the keypoints an estimate needs.
    pub fn describe(&self, cloud: &PointCloud, stream: u64) -> Result<ScanFeatures> {
        self.describe_from(cloud, stream, self.settings.viewpoint)
    }

    /// [`Registrar::describe`] for a scan whose sensor sat at `viewpoint` (scan frame): estimated normals face
    /// it. A scan moved by a rigid motion M is described as the original when `viewpoint` moves with it (M
    /// times the original viewpoint).
    pub fn describe_from(&self, cloud: &PointCloud, stream: u64, viewpoint: [f32; 3]) -> Result<ScanFeatures> {
        crate::block_on(async {
            let mut clock = Stopwatch::new(self.progress_for(stream));
            let mut scan = self.start_description(cloud, stream, viewpoint, &mut clock).await?;
            self.extend_description(&mut scan, self.settings.keypoints, &mut clock).await?;
            self.describe_context(&mut scan, &mut clock).await?;
            scan.cloud.complete_normals(&mut scan.features.cloud).await?;
            clock.lap("remaining_normals");
            scan.features.timings = clock.timings;
            Ok(scan.features)
        })
    }

    /// What the backend's scan preparation and description need of the settings.
    fn scan_settings(&self, viewpoint: [f32; 3], cloud_has_normals: bool) -> ScanSettings {
        let s = &self.settings;
        ScanSettings {
            voxel: self.voxel(cloud_has_normals),
            radius: self.radius(),
            largest_radius: self.context_radii().into_iter().map(|(r, _)| r).fold(self.radius(), f32::max),
            points_per_patch: self.backend.model().config.points_per_patch,
            normal_neighbors: s.normal_neighbors,
            viewpoint,
            min_points: MIN_POINTS,
        }
    }

    /// Preprocesses `cloud` where the backend describes it (downsampling, normals) and fixes its keypoint
    /// order; no keypoint is described yet.
    async fn start_description(
        &self,
        cloud: &PointCloud,
        stream: u64,
        viewpoint: [f32; 3],
        clock: &mut Stopwatch<'_>,
    ) -> Result<DescribingScan> {
        let s = &self.settings;
        cloud.validate("cloud")?;
        let scan_settings = self.scan_settings(viewpoint, crate::backend::has_usable_normals(cloud));
        let (cloud, scan_cloud) =
            self.backend.start_scan(cloud, &scan_settings, &mut |stage| clock.lap(stage)).await.map_err(|e| {
                match (e, scan_settings.voxel) {
                    // A default voxel follows the radius: say so, since the user never set it.
                    (Error::InvalidInput(m), Some(v)) if s.voxel.is_none() => Error::invalid(format!(
                        "{m} (the default voxel size {v} is the radius {} / {}: set the radius or the voxel size \
                         for the cloud's units)",
                        self.radius(),
                        (1.0 / crate::settings::VOXEL_PER_RADIUS).round()
                    )),
                    (e, _) => e,
                }
            })?;
        let mut rng = Rng::derived(s.seed, 2 * stream);
        let order = match s.keypoint_mode {
            // Farthest-point sampling where the backend keeps the cloud (the same start draw as on the host).
            KeypointMode::Uniform if s.keypoints < cloud.len() => {
                let start = rng.below(cloud.len());
                scan_cloud.farthest_points(&cloud, s.keypoints, start).await?
            }
            _ => select_keypoints(&cloud.points, s.keypoints, s.keypoint_mode, &mut rng),
        };
        clock.lap("keypoints");
        let features = ScanFeatures {
            cloud,
            viewpoint,
            keypoints: Vec::new(),
            keypoint_normals: Vec::new(),
            keypoint_ranks: Vec::new(),
            candidates: 0,
            empty_patches: 0,
            rows: self.backend.new_scan_rows(order.len())?,
            context: self
                .context_radii()
                .into_iter()
                .map(|(radius, weight)| {
                    Ok(ContextRows { radius, weight, rows: self.backend.new_scan_rows(order.len())? })
                })
                .collect::<Result<_>>()?,
            held_points: scan_cloud.held_points(),
            estimated_normals: scan_cloud.host_estimated_normals(),
            timings: Vec::new(),
        };
        let patch_seed = Rng::derived(s.seed, 2 * stream + 1).next_u64();
        Ok(DescribingScan { features, cloud: scan_cloud, order, patch_seed })
    }

    /// Describes the keypoints of `scan`'s order up to the first `candidates` (patches, network inputs, PPF
    /// codewords); PC-FoldNet's inputs are kept for [`Registrar::estimate`]. Errors when, with the whole order
    /// described, no keypoint has a patch.
    async fn extend_description(
        &self,
        scan: &mut DescribingScan,
        candidates: usize,
        clock: &mut Stopwatch<'_>,
    ) -> Result<()> {
        let (from, to) = (scan.features.candidates, candidates.min(scan.order.len()));
        if from >= to {
            return Ok(());
        }
        let f = &mut scan.features;
        let described = scan
            .cloud
            .describe_keypoints(
                self.backend.as_ref(),
                &mut f.cloud,
                (&scan.order[from..to], self.radius()),
                scan.patch_seed,
                f.rows.as_ref(),
                &mut |stage| clock.lap(stage),
            )
            .await?;
        // Ranks of the kept keypoints: their positions in `scan.order[from..to]`.
        f.keypoint_ranks.extend(described.kept.iter().map(|&pos| (from + pos) as u32));
        f.keypoints.extend(described.centers);
        f.keypoint_normals.extend(described.center_normals);
        f.empty_patches += described.empty;
        f.candidates = to;
        if to == scan.order.len() && f.keypoints.is_empty() {
            return Err(Error::invalid(format!(
                "no keypoint has a neighbour within radius {}: is the radius right for the cloud's units?",
                self.radius()
            )));
        }
        if self.settings.context_when == ContextWhen::Always {
            self.describe_context(scan, clock).await?;
        }
        Ok(())
    }

    /// Describes the kept keypoints of `scan` that have no context rows yet again at every context radius.
    /// None is dropped (a larger patch holds every point of the main one), so the rows stay aligned.
    async fn describe_context(&self, scan: &mut DescribingScan, clock: &mut Stopwatch<'_>) -> Result<()> {
        let f = &mut scan.features;
        for c in &f.context {
            let kept: Vec<usize> =
                f.keypoint_ranks[c.rows.rows()..].iter().map(|&rank| scan.order[rank as usize]).collect();
            if kept.is_empty() {
                continue;
            }
            let again = scan
                .cloud
                .describe_keypoints(
                    self.backend.as_ref(),
                    &mut f.cloud,
                    (&kept, c.radius),
                    scan.patch_seed,
                    c.rows.as_ref(),
                    &mut |_| {},
                )
                .await?;
            if again.kept.len() != kept.len() {
                return Err(Error::invalid(format!(
                    "context radius {}: {} of {} keypoints kept",
                    c.radius,
                    again.kept.len(),
                    kept.len()
                )));
            }
            clock.lap("context_encoder");
        }
        Ok(())
    }

    /// The pose features (PC-FoldNet codeword minus PPF-FoldNet codeword) of `rows` of `scan`, in that order,
    /// `rows.len() x codeword` (read back from the backend). Rows not computed before run through PC-FoldNet
    /// now, once.
    pub fn pose_features(&self, scan: &ScanFeatures, rows: &[u32]) -> Result<Vec<f32>> {
        crate::block_on(self.backend.pose_features(scan.rows.as_ref(), rows))
    }

    /// `scan` with its rows held by this registrar's backend: the same rows when the backend described them,
    /// else a copy moved to it (e.g. a scan unpickled with host rows, registered on a GPU).
    pub fn adopt(&self, scan: &ScanFeatures) -> Result<ScanFeatures> {
        let adopt = |rows: &Arc<dyn ScanRows>| -> Result<Arc<dyn ScanRows>> {
            let rows = crate::block_on(self.backend.adopt_rows(rows))?;
            if rows.rows() != scan.keypoints.len() {
                return Err(Error::invalid(format!(
                    "described scan: {} rows for {} keypoints",
                    rows.rows(),
                    scan.keypoints.len()
                )));
            }
            Ok(rows)
        };
        let context = scan
            .context
            .iter()
            .map(|c| Ok(ContextRows { rows: adopt(&c.rows)?, ..c.clone() }))
            .collect::<Result<_>>()?;
        Ok(ScanFeatures { rows: adopt(&scan.rows)?, context, ..scan.clone() })
    }

    /// Correspondences between two described scans (matching rule from the settings).
    /// On the codewords of every radius, whatever [`ContextWhen`] says.
    pub fn correspond(&self, source: &ScanFeatures, target: &ScanFeatures) -> Result<Vec<Correspondence>> {
        crate::block_on(self.correspond_rows(source, source.keypoints.len(), target, target.keypoints.len(), true))
    }

    /// Correspondences between the first `source_rows` keypoints of `source` and the first `target_rows` of
    /// `target`, on the context radii's codewords too when `context`.
    async fn correspond_rows(
        &self,
        source: &ScanFeatures,
        source_rows: usize,
        target: &ScanFeatures,
        target_rows: usize,
        context: bool,
    ) -> Result<Vec<Correspondence>> {
        let request = RowMatch::new(
            (source.rows.as_ref(), source_rows),
            (target.rows.as_ref(), target_rows),
            self.settings.matching,
        )?;
        let request = if context { request.with_context(&source.context, &target.context)? } else { request };
        let matches = self.backend.correspond(request).await?;
        Ok(matches
            .into_iter()
            .map(|m| Correspondence {
                source_index: m.source,
                target_index: m.target,
                source_point: source.keypoints[m.source as usize],
                target_point: target.keypoints[m.target as usize],
                feature_distance: m.distance,
            })
            .collect())
    }

    /// Estimates target_from_source from the correspondences with `estimator`, then ICP when enabled.
    pub fn estimate(
        &self,
        source: &ScanFeatures,
        target: &ScanFeatures,
        correspondences: &[Correspondence],
        estimator: Estimator,
    ) -> Result<PoseEstimate> {
        Ok(crate::block_on(self.estimate_judged(source, target, correspondences, estimator))?.0)
    }

    /// [`Registrar::estimate`], with the verdict on the estimate when choosing it took one (so it is not judged
    /// twice).
    async fn estimate_judged(
        &self,
        source: &ScanFeatures,
        target: &ScanFeatures,
        correspondences: &[Correspondence],
        estimator: Estimator,
    ) -> Result<(PoseEstimate, Option<Verdict>)> {
        if correspondences.len() < MIN_CORRESPONDENCES {
            let weights = weights_file(&self.settings)
                .map_or_else(|| "the built-in weights".to_string(), |p| format!("the weights {}", p.display()));
            return Err(Error::invalid(format!(
                "only {} correspondences; at least {MIN_CORRESPONDENCES} are needed to estimate a pose (the scans' \
                 features matched too few keypoints: {weights} may not describe these scans, being untrained or \
                 trained for other data, or the scans may not overlap)",
                correspondences.len()
            )));
        }
        let src: Vec<[f32; 3]> = correspondences.iter().map(|c| c.source_point).collect();
        let tgt: Vec<[f32; 3]> = correspondences.iter().map(|c| c.target_point).collect();
        let threshold = self.inlier_threshold();
        let keep = self.settings.pose_candidates;
        let (poses, scored) = match estimator {
            Estimator::RelativeNet => {
                let source_rows: Vec<u32> = correspondences.iter().map(|c| c.source_index).collect();
                let target_rows: Vec<u32> = correspondences.iter().map(|c| c.target_index).collect();
                let normals = |scan: &ScanFeatures, rows: &[u32]| -> Result<Vec<[f32; 3]>> {
                    rows.iter()
                        .map(|&r| {
                            scan.keypoint_normals.get(r as usize).copied().ok_or_else(|| {
                                Error::invalid(format!(
                                    "estimate: row {r} of a scan with {} keypoints",
                                    scan.keypoints.len()
                                ))
                            })
                        })
                        .collect()
                };
                let (ns, nt) = (normals(source, &source_rows)?, normals(target, &target_rows)?);
                let request = MatchedRows::new(
                    MatchedSide { scan: source.rows.as_ref(), rows: &source_rows, points: &src, normals: &ns },
                    MatchedSide { scan: target.rows.as_ref(), rows: &target_rows, points: &tgt, normals: &nt },
                    threshold,
                    keep,
                )?;
                let verified = self.backend.verify(request).await?;
                (verified.best.iter().map(|b| matrix_from_hypothesis(&b.hypothesis)).collect(), verified.hypotheses)
            }
            Estimator::Ransac => {
                let (best, iterations) =
                    ransac_candidates(&src, &tgt, threshold, &self.settings.ransac, self.settings.seed, keep)?;
                (best.iter().map(|b| b.target_from_source).collect::<Vec<_>>(), iterations)
            }
        };
        let candidates = candidates::distinct_refined(&poses, &src, &tgt, threshold, scored);
        // ICP when enabled, then the estimate over the correspondences.
        let finish = async |estimate: &PoseEstimate| -> Result<PoseEstimate> {
            let Some(icp) = &self.settings.icp else { return Ok(estimate.clone()) };
            let refined = self.refine_by_icp(source, target, estimate.target_from_source, icp).await?;
            Ok(crate::estimate::evaluate(refined, &src, &tgt, threshold, estimate.hypotheses_scored))
        };
        // The estimator's choice as today; the others compete only when the verdict does not trust it.
        let first = finish(candidates.first().ok_or_else(|| Error::invalid("no hypotheses to verify"))?).await?;
        if candidates.len() == 1 {
            return Ok((first, None));
        }
        let verdict = self.judge((source, target), &first, correspondences);
        if verdict.success {
            return Ok((first, Some(verdict)));
        }
        let views = PairViews::new(
            (&source.cloud.points, source.viewpoint),
            (&target.cloud.points, target.viewpoint),
            threshold,
        );
        // The others compete with the finished choice, the pose that would be returned.
        let mut candidates = candidates;
        candidates[0] = first.clone();
        match candidates::choose(&candidates, &views) {
            0 => Ok((first, Some(verdict))),
            k => Ok((finish(&candidates[k]).await?, None)),
        }
    }

    /// Point-to-plane ICP from `initial` on a voxel-downsampled copy of the target (voxel: half the largest
    /// point-pair distance, by default radius / 12; normals estimated on the copy), so it needs no normal of the
    /// full clouds and costs little next to description. It runs where the backend keeps the clouds
    /// ([`Backend::refine_icp`]).
    async fn refine_by_icp(
        &self,
        source: &ScanFeatures,
        target: &ScanFeatures,
        initial: nalgebra::Matrix4<f64>,
        icp: &IcpSettings,
    ) -> Result<nalgebra::Matrix4<f64>> {
        let problem = IcpProblem {
            max_distance: icp.max_correspondence_distance.unwrap_or(self.default_icp_distance()),
            max_iterations: icp.max_iterations,
            normal_neighbors: self.settings.normal_neighbors,
        };
        self.backend.refine_icp(source, target, initial, &problem).await
    }

    /// Whether `estimate` (computed from `correspondences` between `source` and `target`) can be trusted: the
    /// settings' verdict thresholds, then the handedness check on the clouds.
    pub fn judge(
        &self,
        (source, target): (&ScanFeatures, &ScanFeatures),
        estimate: &PoseEstimate,
        correspondences: &[Correspondence],
    ) -> Verdict {
        let (threshold, settings) = (self.inlier_threshold(), &self.settings.verdict);
        let verdict = crate::verdict::judge(estimate, correspondences, threshold, settings);
        if !verdict.success {
            return verdict;
        }
        let clouds = (source.cloud.points.as_slice(), target.cloud.points.as_slice());
        let draws = settings.max_reflection_draws;
        if let Some(reason) = mirror_image(estimate, correspondences, clouds, threshold, draws, self.settings.seed) {
            return Verdict::fail(reason);
        }
        if settings.free_space_check {
            let views = PairViews::new((clouds.0, source.viewpoint), (clouds.1, target.viewpoint), threshold);
            let (violate, allowed) =
                (views.consistency(&estimate.target_from_source).violate, views.allowed_violation());
            if violate > allowed {
                return Verdict::fail(format!(
                    "the pose puts {:.1} % of the points in space the other scan saw empty, more than the {:.1} % \
                     allowed (what the views leave unexplained, at least {:.0} %): repeated structure, or the \
                     sensors are not at the scans' viewpoints",
                    100.0 * violate,
                    100.0 * allowed,
                    100.0 * crate::estimate::visibility::MIN_ALLOWED_VIOLATION
                ));
            }
        }
        verdict
    }

    /// The keypoint counts of the progressive schedule (see [`keypoint_stages`]).
    pub fn keypoint_stages(&self) -> Vec<usize> {
        keypoint_stages(self.settings.first_keypoints, self.settings.keypoints)
    }

    /// Whether every round matches on the context radii too (else only the last round of [`ContextWhen::Untrusted`]).
    fn context_in_every_round(&self) -> bool {
        self.settings.context_when == ContextWhen::Always
    }

    /// Whether the rounds of `outcome` call for the last round of [`ContextWhen::Untrusted`].
    fn needs_context_round(&self, outcome: &stages::Outcome) -> bool {
        !self.settings.context_radii.is_empty() && !self.context_in_every_round() && !outcome.trusted()
    }

    /// One round: correspondences among the first `keypoints` keypoints of each scan (on the context radii's
    /// codewords too when `context`), the pose, its verdict.
    async fn round(
        &self,
        (source, target): (&ScanFeatures, &ScanFeatures),
        keypoints: usize,
        (estimator, context): (Estimator, bool),
        clock: &mut Stopwatch<'_>,
    ) -> Result<Round> {
        clock.scope = "";
        let (sr, tr) = (source.rows_within(keypoints), target.rows_within(keypoints));
        let correspondences = self.correspond_rows(source, sr, target, tr, context).await?;
        clock.lap("matching");
        if estimator == Estimator::RelativeNet {
            // Computed here (and kept in the scans) to time PC-FoldNet on its own.
            let (s, t) = (source.rows.as_ref(), target.rows.as_ref());
            let source_rows: Vec<u32> = correspondences.iter().map(|c| c.source_index).collect();
            let target_rows: Vec<u32> = correspondences.iter().map(|c| c.target_index).collect();
            self.backend.prepare_pose_features(s, &source_rows).await?;
            self.backend.prepare_pose_features(t, &target_rows).await?;
        }
        clock.lap("pc_encoder");
        let (estimate, verdict) = self.estimate_judged(source, target, &correspondences, estimator).await?;
        clock.lap("estimation");
        let verdict = verdict.unwrap_or_else(|| self.judge((source, target), &estimate, &correspondences));
        Ok(Round { keypoints, correspondences, estimate, verdict })
    }

    /// Registers two described scans with the progressive schedule, over the keypoints they have: the rounds
    /// and the result [`Registrar::register`] gives for the same clouds and settings (descriptions extend prefix
    /// by prefix, so describing everything first changes nothing but the time).
    pub fn register_described(
        &self,
        source: &ScanFeatures,
        target: &ScanFeatures,
        estimator: Estimator,
    ) -> Result<Round> {
        crate::block_on(async {
            let mut clock = Stopwatch::new(None);
            let plan = (estimator, self.context_in_every_round());
            let (outcome, last) = self.progressive_rounds(&mut (source, target), plan, &mut clock).await?;
            self.conclude(outcome, (source, target), last, estimator, &mut clock).await
        })
    }

    /// The progressive schedule: for each keypoint stage k, `scans` are readied for k keypoints a scan
    /// ([`RoundScans::prepare`]); a round runs when that changed the rows it would match, and the first trusted
    /// round ends the schedule. Returns the rounds' outcome and the last stage.
    async fn progressive_rounds(
        &self,
        scans: &mut impl RoundScans,
        plan: (Estimator, bool),
        clock: &mut Stopwatch<'_>,
    ) -> Result<(stages::Outcome, usize)> {
        let mut outcome = stages::Outcome::default();
        let mut rows = None;
        let stages = self.keypoint_stages();
        for &k in &stages {
            let now = scans.prepare(self, k, clock).await?;
            if rows == Some(now) {
                continue;
            }
            rows = Some(now);
            if outcome.offer(self.round(scans.pair(), k, plan, clock).await) {
                break;
            }
        }
        Ok((outcome, stages[stages.len() - 1]))
    }

    /// One round on all keypoints of two described scans (and the round on the context radii too when
    /// [`ContextWhen::Untrusted`] calls for it): the result of [`Registrar::register_described`] without the
    /// progressive schedule.
    pub fn register_described_at_once(
        &self,
        source: &ScanFeatures,
        target: &ScanFeatures,
        estimator: Estimator,
    ) -> Result<Round> {
        crate::block_on(async {
            let mut clock = Stopwatch::new(None);
            let mut outcome = stages::Outcome::default();
            let all = source.candidates.max(target.candidates);
            let plan = (estimator, self.context_in_every_round());
            outcome.offer(self.round((source, target), all, plan, &mut clock).await);
            self.conclude(outcome, (source, target), all, estimator, &mut clock).await
        })
    }

    /// The result of the rounds in `outcome`, after the round on every radius over `keypoints` keypoints when
    /// [`ContextWhen::Untrusted`] calls for it (the scans' context rows are described already).
    async fn conclude(
        &self,
        mut outcome: stages::Outcome,
        scans: (&ScanFeatures, &ScanFeatures),
        keypoints: usize,
        estimator: Estimator,
        clock: &mut Stopwatch<'_>,
    ) -> Result<Round> {
        if self.needs_context_round(&outcome) {
            outcome.offer(self.round(scans, keypoints, (estimator, true), clock).await);
        }
        outcome.finish()
    }

    /// The whole pipeline on two clouds (blocks until done: [`Registrar::register_async`] awaits).
    pub fn register(&self, source: &PointCloud, target: &PointCloud) -> Result<RegistrationResult> {
        Ok(self.register_detailed(source, target)?.result)
    }

    /// [`Registrar::register`] as a future: what a browser awaits (its GPU readbacks complete on the page's
    /// event loop).
    pub async fn register_async(&self, source: &PointCloud, target: &PointCloud) -> Result<RegistrationResult> {
        Ok(self.register_detailed_async(source, target).await?.result)
    }

    /// [`Registrar::register`], also returning the described scans and the correspondences the result came from
    /// (for bindings and pictures that show keypoints and matches). Runs the progressive schedule: each round
    /// describes more keypoints of both scans, and the first trusted round ends it.
    pub fn register_detailed(&self, source: &PointCloud, target: &PointCloud) -> Result<Registration> {
        crate::block_on(self.register_detailed_async(source, target))
    }

    /// [`Registrar::register_detailed`] as a future.
    pub async fn register_detailed_async(&self, source: &PointCloud, target: &PointCloud) -> Result<Registration> {
        if self.settings.radius.is_none() {
            let scaled = self.at_scale_of(&[(source, "source"), (target, "target")])?;
            return Box::pin(scaled.register_detailed_async(source, target)).await;
        }
        let mut clock = Stopwatch::new(self.progress.as_deref().map(|p| (p, "")));
        let viewpoint = self.settings.viewpoint;
        clock.scope = "source.";
        let src = self.start_description(source, 0, viewpoint, &mut clock).await.map_err(|e| prefix("source", e))?;
        clock.scope = "target.";
        let tgt = self.start_description(target, 1, viewpoint, &mut clock).await.map_err(|e| prefix("target", e))?;
        let plan = (self.settings.estimator, self.context_in_every_round());
        let mut scans = (src, tgt);
        let (outcome, last) = self.progressive_rounds(&mut scans, plan, &mut clock).await?;
        let (mut src, mut tgt) = scans;
        if self.needs_context_round(&outcome) {
            clock.scope = "source.";
            self.describe_context(&mut src, &mut clock).await.map_err(|e| prefix("source", e))?;
            clock.scope = "target.";
            self.describe_context(&mut tgt, &mut clock).await.map_err(|e| prefix("target", e))?;
        }
        let scans = (&src.features, &tgt.features);
        let round = self.conclude(outcome, scans, last, self.settings.estimator, &mut clock).await?;
        for scan in [&mut src, &mut tgt] {
            if !scan.cloud.normals_complete() {
                // Normals were estimated only where patches needed them.
                scan.features.cloud.normals = None;
            }
        }
        let (mut described_source, mut described_target) = (src.features, tgt.features);
        for (scope, f) in [("source.", &mut described_source), ("target.", &mut described_target)] {
            f.timings = clock
                .timings
                .iter()
                .filter_map(|t| {
                    let stage = t.stage.strip_prefix(scope)?.to_string();
                    Some(StageTime { stage, seconds: t.seconds })
                })
                .collect();
        }
        let Round { keypoints, correspondences, estimate, verdict } = round;
        let result = RegistrationResult {
            success: verdict.success,
            reason: verdict.reason,
            estimate,
            correspondences: correspondences.len(),
            keypoints,
            empty_patches: described_source.empty_patches + described_target.empty_patches,
            timings: clock.timings,
            backend: self.backend.name(),
            scale: self.scale_report(),
        };
        Ok(Registration { result, source: described_source, target: described_target, correspondences })
    }
}

/// The two scans a progressive schedule registers ([`Registrar::progressive_rounds`]).
trait RoundScans {
    /// Readies the scans for a round over their first `keypoints` keypoints (describing more where needed) and
    /// says how many rows of each such a round would match.
    async fn prepare(
        &mut self,
        registrar: &Registrar,
        keypoints: usize,
        clock: &mut Stopwatch<'_>,
    ) -> Result<(usize, usize)>;

    /// The (source, target) features a round matches.
    fn pair(&self) -> (&ScanFeatures, &ScanFeatures);
}

/// Scans described already ([`Registrar::register_described`]): nothing to do but count rows.
impl RoundScans for (&ScanFeatures, &ScanFeatures) {
    async fn prepare(&mut self, _: &Registrar, keypoints: usize, _: &mut Stopwatch<'_>) -> Result<(usize, usize)> {
        Ok((self.0.rows_within(keypoints), self.1.rows_within(keypoints)))
    }

    fn pair(&self) -> (&ScanFeatures, &ScanFeatures) {
        *self
    }
}

/// Scans being described ([`Registrar::register_detailed`]): each stage describes more keypoints of both.
impl RoundScans for (DescribingScan, DescribingScan) {
    async fn prepare(
        &mut self,
        registrar: &Registrar,
        keypoints: usize,
        clock: &mut Stopwatch<'_>,
    ) -> Result<(usize, usize)> {
        clock.scope = "source.";
        registrar.extend_description(&mut self.0, keypoints, clock).await.map_err(|e| prefix("source", e))?;
        clock.scope = "target.";
        registrar.extend_description(&mut self.1, keypoints, clock).await.map_err(|e| prefix("target", e))?;
        Ok((self.0.features.keypoints.len(), self.1.features.keypoints.len()))
    }

    fn pair(&self) -> (&ScanFeatures, &ScanFeatures) {
        (&self.0.features, &self.1.features)
    }
}

/// Everything [`Registrar::register_detailed`] computed: the result, and what it was computed from.
#[derive(Clone, Debug)]
pub struct Registration {
    /// What [`Registrar::register`] returns.
    pub result: RegistrationResult,
    /// The described source scan (stream 0).
    pub source: ScanFeatures,
    /// The described target scan (stream 1).
    pub target: ScanFeatures,
    /// The correspondences fed to the estimator (indices into the scans' keypoints).
    pub correspondences: Vec<Correspondence>,
}

fn prefix(what: &str, e: Error) -> Error {
    match e {
        Error::InvalidInput(m) => Error::InvalidInput(format!("{what}: {m}")),
        other => other,
    }
}

/// Registers `source` onto `target`: the returned `target_from_source` maps source points into the target frame.
pub fn register(
    source: &PointCloud,
    target: &PointCloud,
    settings: &RegistrationSettings,
) -> Result<RegistrationResult> {
    Registrar::new(settings)?.register(source, target)
}
