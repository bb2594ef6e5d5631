//! The registration pipeline: load weights, describe each scan (keypoints, patches, codewords), correspond,
//! estimate the pose. `register` runs it all; `Registrar` exposes the steps for evaluation tools and keeps the
//! model and backend loaded across pairs.

use crate::backend::{Backend, CpuBackend, RotationInputs};
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::estimate::{icp_point_to_plane, ransac, verify};
use crate::model::{Model, Net, Weights};
use crate::preprocess::{estimate_normals, extract_patches, gather, select_keypoints, voxel_downsample};
use crate::rng::Rng;
use crate::settings::*;
use crate::spatial::PointIndex;
use std::path::PathBuf;
use std::time::Instant;

/// Fewest points a scan may have after preprocessing.
pub const MIN_POINTS: usize = 10;
/// Fewest correspondences an estimator accepts.
pub const MIN_CORRESPONDENCES: usize = 3;
/// Environment variable that overrides the default weights path.
pub const WEIGHTS_ENV: &str = "DPR_GPU_WEIGHTS";

/// Per-scan output of the description stages.
#[derive(Clone, Debug)]
pub struct ScanFeatures {
    /// The scan after preprocessing (downsampled, with unit normals).
    pub cloud: PointCloud,
    /// Keypoint positions (scan frame), only keypoints with a non-empty patch.
    pub keypoints: Vec<[f32; 3]>,
    /// Their unit normals (scan frame): the normal frames of normal-aligned patches.
    pub keypoint_normals: Vec<[f32; 3]>,
    /// Keypoints dropped because their patch was empty.
    pub empty_patches: usize,
    /// Rotation-invariant PPF-FoldNet codewords, `keypoints.len() x codeword`, row-major.
    pub ppf_codewords: Vec<f32>,
    /// Pose-variant features (PC codeword minus PPF codeword), same layout.
    pub pose_features: Vec<f32>,
    /// Stage times spent describing this scan.
    pub timings: Vec<StageTime>,
}

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
    match kind {
        BackendKind::Cpu => Ok((Box::new(CpuBackend::new(model)), "asked for (--backend cpu)".into())),
        #[cfg(feature = "gpu")]
        BackendKind::Gpu => Ok((Box::new(crate::gpu::GpuBackend::new(model)?), "asked for (--backend gpu)".into())),
        #[cfg(feature = "gpu")]
        BackendKind::Auto => match crate::gpu::GpuBackend::new_hardware(model.clone()) {
            Ok(gpu) => Ok((Box::new(gpu), "auto: a hardware GPU adapter was found".into())),
            Err(e) => Ok((Box::new(CpuBackend::new(model)), format!("auto: {e}"))),
        },
        #[cfg(not(feature = "gpu"))]
        BackendKind::Gpu => Err(Error::Gpu("dpr-gpu was built without its `gpu` feature".into())),
        #[cfg(not(feature = "gpu"))]
        BackendKind::Auto => Ok((Box::new(CpuBackend::new(model)), "auto: built without the `gpu` feature".into())),
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
    /// The callback and the prefix of this scan's stage names.
    progress: Option<(&'a ProgressFn, &'static str)>,
}

impl<'a> Stopwatch<'a> {
    fn new(progress: Option<(&'a ProgressFn, &'static str)>) -> Self {
        Stopwatch { start: Instant::now(), timings: Vec::new(), progress }
    }
    fn lap(&mut self, stage: &str) {
        let now = Instant::now();
        let seconds = (now - self.start).as_secs_f64();
        if let Some((report, prefix)) = self.progress {
            report(&format!("{prefix}{stage}"), seconds);
        }
        self.timings.push(StageTime { stage: stage.to_string(), seconds });
        self.start = now;
    }
}

/// Stages a pairwise registration reports to the progress callback: seven per scan, then matching and
/// estimation.
pub const PAIR_STAGES: usize = 16;

/// A configured pipeline: model and backend loaded once, reused across pairs.
pub struct Registrar {
    /// The settings it was built with.
    pub settings: RegistrationSettings,
    backend: Box<dyn Backend>,
    /// Why this backend (see [`choose_backend`]).
    backend_reason: String,
    progress: Option<Box<ProgressFn>>,
}

impl Registrar {
    /// Loads the weights and prepares the backend.
    pub fn new(settings: &RegistrationSettings) -> Result<Registrar> {
        let weights = load_weights(settings)?;
        Registrar::with_weights(settings, &weights)
    }

    /// Builds the pipeline from weights already in memory.
    pub fn with_weights(settings: &RegistrationSettings, weights: &Weights) -> Result<Registrar> {
        validate_settings(settings, &weights.config)?;
        let model = Model::from_weights(weights)?;
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
            backend,
            backend_reason: "given by the caller".into(),
            progress: None,
        })
    }

    /// Calls `progress` after every stage (for a progress display); see [`ProgressFn`].
    pub fn with_progress(mut self, progress: Box<ProgressFn>) -> Registrar {
        self.progress = Some(progress);
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

    /// Patch radius in use.
    pub fn radius(&self) -> f32 {
        self.settings.radius.unwrap_or(self.backend.model().config.radius)
    }

    /// Inlier threshold in use.
    pub fn inlier_threshold(&self) -> f32 {
        self.settings.inlier_threshold.unwrap_or(self.radius() / 3.0)
    }

    /// Preprocesses `cloud` and computes keypoints and codewords. `stream` separates the random choices of
    /// different scans under one seed (0 for the source, 1 for the target in `register`).
    pub fn describe(&self, cloud: &PointCloud, stream: u64) -> Result<ScanFeatures> {
        self.describe_from(cloud, stream, self.settings.viewpoint)
    }

    /// [`Registrar::describe`] for a scan whose sensor sat at `viewpoint` (scan frame): estimated normals face
    /// it. A scan moved by a rigid motion M is described as the original when `viewpoint` moves with it (M
    /// times the original viewpoint).
    pub fn describe_from(&self, cloud: &PointCloud, stream: u64, viewpoint: [f32; 3]) -> Result<ScanFeatures> {
        let s = &self.settings;
        let mut clock = Stopwatch::new(self.progress_for(stream));
        cloud.validate("cloud")?;
        let mut cloud = match s.voxel {
            Some(v) => voxel_downsample(cloud, v)?,
            None => cloud.clone(),
        };
        if cloud.len() < MIN_POINTS {
            return Err(Error::invalid(format!(
                "cloud has {} points after preprocessing; at least {MIN_POINTS} are needed",
                cloud.len()
            )));
        }
        clock.lap("downsample");
        let index = PointIndex::new(&cloud.points)?;
        let usable_normals =
            cloud.normals.as_ref().is_some_and(|ns| ns.iter().all(|n| n[0] * n[0] + n[1] * n[1] + n[2] * n[2] > 1e-12));
        if usable_normals {
            for n in cloud.normals.as_mut().expect("checked") {
                let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                *n = n.map(|c| c / len);
            }
        } else {
            cloud.normals = Some(estimate_normals(&cloud.points, &index, s.normal_neighbors, viewpoint));
        }
        clock.lap("normals");
        let mut rng = Rng::derived(s.seed, 2 * stream);
        let keypoint_ids = select_keypoints(&cloud.points, s.keypoints, s.keypoint_mode, &mut rng);
        clock.lap("keypoints");
        let config = &self.backend.model().config;
        let radius = self.radius();
        let patches = extract_patches(&cloud.points, &index, &keypoint_ids, radius, config.points_per_patch, {
            Rng::derived(s.seed, 2 * stream + 1).next_u64()
        });
        if patches.keypoints.is_empty() {
            return Err(Error::invalid(format!(
                "no keypoint has a neighbour within radius {radius}: is the radius right for the cloud's units?"
            )));
        }
        let normals = cloud.normals.as_ref().expect("normals set above");
        let gathered = gather(&cloud.points, normals, &patches);
        clock.lap("patches");
        let (ppf_input, pc_input) = self.backend.patch_features(&gathered, radius)?;
        clock.lap("patch_features");
        let count = patches.keypoints.len();
        let ppf_codewords = self.backend.encode(Net::Ppf, &ppf_input, count)?;
        clock.lap("ppf_encoder");
        let pc_codewords = self.backend.encode(Net::Pc, &pc_input, count)?;
        let pose_features = crate::model::pose_feature(&pc_codewords, &ppf_codewords);
        clock.lap("pc_encoder");
        Ok(ScanFeatures {
            keypoints: gathered.centers,
            keypoint_normals: gathered.center_normals,
            empty_patches: patches.empty.len(),
            cloud,
            ppf_codewords,
            pose_features,
            timings: clock.timings,
        })
    }

    /// Correspondences between two described scans (matching rule from the settings).
    pub fn correspond(&self, source: &ScanFeatures, target: &ScanFeatures) -> Result<Vec<Correspondence>> {
        let dim = self.backend.model().config.codeword();
        let matches =
            self.backend.match_codewords(&source.ppf_codewords, &target.ppf_codewords, dim, self.settings.matching)?;
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
        if correspondences.len() < MIN_CORRESPONDENCES {
            return Err(Error::invalid(format!(
                "only {} correspondences; at least {MIN_CORRESPONDENCES} are needed to estimate a pose",
                correspondences.len()
            )));
        }
        let src: Vec<[f32; 3]> = correspondences.iter().map(|c| c.source_point).collect();
        let tgt: Vec<[f32; 3]> = correspondences.iter().map(|c| c.target_point).collect();
        let threshold = self.inlier_threshold();
        let mut estimate = match estimator {
            Estimator::RelativeNet => {
                let dim = self.backend.model().config.codeword();
                let rows = |f: &ScanFeatures, idx: &mut dyn Iterator<Item = usize>| -> Vec<f32> {
                    idx.flat_map(|i| f.pose_features[i * dim..(i + 1) * dim].iter().copied()).collect()
                };
                let fs = rows(source, &mut correspondences.iter().map(|c| c.source_index as usize));
                let ft = rows(target, &mut correspondences.iter().map(|c| c.target_index as usize));
                let ns: Vec<[f32; 3]> =
                    correspondences.iter().map(|c| source.keypoint_normals[c.source_index as usize]).collect();
                let nt: Vec<[f32; 3]> =
                    correspondences.iter().map(|c| target.keypoint_normals[c.target_index as usize]).collect();
                let pose = RotationInputs {
                    source: &fs,
                    target: &ft,
                    source_normals: &ns,
                    target_normals: &nt,
                    rows: correspondences.len(),
                };
                let rotations = self.backend.predict_rotations(pose)?;
                verify(self.backend.as_ref(), &rotations, &src, &tgt, threshold)?
            }
            Estimator::Ransac => ransac(&src, &tgt, threshold, &self.settings.ransac, self.settings.seed)?,
        };
        if let Some(icp) = &self.settings.icp {
            let index = PointIndex::new(&target.cloud.points)?;
            let refined = icp_point_to_plane(&source.cloud, &target.cloud, &index, estimate.target_from_source, icp)?;
            let scored = estimate.hypotheses_scored;
            estimate = crate::estimate::evaluate(refined, &src, &tgt, threshold, scored);
        }
        Ok(estimate)
    }

    /// Whether `estimate` (computed from `correspondences`) can be trusted, by the settings' verdict thresholds.
    pub fn judge(&self, estimate: &PoseEstimate, correspondences: &[Correspondence]) -> crate::verdict::Verdict {
        crate::verdict::judge(estimate, correspondences, self.inlier_threshold(), &self.settings.verdict)
    }

    /// The whole pipeline on two clouds.
    pub fn register(&self, source: &PointCloud, target: &PointCloud) -> Result<RegistrationResult> {
        Ok(self.register_detailed(source, target)?.result)
    }

    /// [`Registrar::register`], also returning the described scans and the correspondences the result came from
    /// (for bindings and pictures that show keypoints and matches).
    pub fn register_detailed(&self, source: &PointCloud, target: &PointCloud) -> Result<Registration> {
        let described_source = self.describe(source, 0).map_err(|e| prefix("source", e))?;
        let described_target = self.describe(target, 1).map_err(|e| prefix("target", e))?;
        let mut clock = Stopwatch::new(self.progress_for(2));
        let correspondences = self.correspond(&described_source, &described_target)?;
        clock.lap("matching");
        let estimate =
            self.estimate(&described_source, &described_target, &correspondences, self.settings.estimator)?;
        clock.lap("estimation");
        let mut timings = Vec::new();
        for (scan, f) in [("source", &described_source), ("target", &described_target)] {
            timings.extend(
                f.timings.iter().map(|t| StageTime { stage: format!("{scan}.{}", t.stage), seconds: t.seconds }),
            );
        }
        timings.extend(clock.timings);
        let verdict = self.judge(&estimate, &correspondences);
        let result = RegistrationResult {
            success: verdict.success,
            reason: verdict.reason,
            estimate,
            correspondences: correspondences.len(),
            empty_patches: described_source.empty_patches + described_target.empty_patches,
            timings,
            backend: self.backend.name(),
        };
        Ok(Registration { result, source: described_source, target: described_target, correspondences })
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
