//! Registration settings and results: the library's public vocabulary. The results live in
//! [`crate::result`] and are re-exported here.

pub use crate::result::{Correspondence, PoseEstimate, RegistrationResult, StageTime, serialize_matrix};
use serde::Serialize;
use std::path::PathBuf;

/// How keypoints are chosen on each scan.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum KeypointMode {
    /// Uniformly random points of the (downsampled) cloud, seeded: the 3DMatch convention.
    Random,
    /// Spatially uniform: farthest-point sampling from a seeded start point.
    Uniform,
}

/// How correspondences are formed from the invariant (PPF) codewords.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum MatchMode {
    /// a is among b's K nearest and b among a's K nearest (K = 1..4; K = 1 is mutual nearest neighbours).
    Mutual(usize),
    /// Every source keypoint with its nearest target keypoint (the paper's "Closest" ablation).
    Closest,
}

/// Which pose estimator turns correspondences into a transform.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Estimator {
    /// One hypothesis per correspondence from RelativeNet's rotation, exhaustive verification.
    RelativeNet,
    /// The baseline: 3-point RANSAC on the same correspondences.
    Ransac,
}

/// Which compute backend runs the learned stages.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum BackendKind {
    /// The plain-Rust reference path.
    Cpu,
    /// The WGSL kernels through wgpu; fails when no adapter exists.
    Gpu,
    /// A GPU when one exists, else the CPU with a warning.
    Auto,
}

/// RANSAC stopping criteria.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct RansacSettings {
    /// Upper bound on sampled 3-point hypotheses.
    pub max_iterations: usize,
    /// Stop once the probability of having drawn an all-inlier sample exceeds this.
    pub confidence: f64,
}

impl Default for RansacSettings {
    fn default() -> Self {
        RansacSettings { max_iterations: 100_000, confidence: 0.999 }
    }
}

/// Point-to-plane ICP settings (on by default; `RegistrationSettings.icp = None` turns it off).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct IcpSettings {
    /// Pairs further apart than this (in cloud units) are ignored. `None`: the patch radius / 12 (5 cm at
    /// r = 0.60 m), so it follows the cloud's units with the radius.
    pub max_correspondence_distance: Option<f32>,
    /// Iteration limit.
    pub max_iterations: usize,
}

impl Default for IcpSettings {
    fn default() -> Self {
        IcpSettings { max_correspondence_distance: None, max_iterations: DEFAULT_ICP_ITERATIONS }
    }
}

/// ICP's default iteration limit.
pub const DEFAULT_ICP_ITERATIONS: usize = 30;

/// Everything `register` needs to know besides the two clouds. Distances are in the clouds' units (metres by
/// default); scale `radius`, `voxel` and the thresholds together to work in other units.
#[derive(Clone, Debug, Serialize)]
pub struct RegistrationSettings {
    /// Weights file; `None` uses the shipped `weights/default.safetensors`.
    pub weights: Option<PathBuf>,
    /// Patch radius r, in cloud units. `None` (the default): chosen from the clouds themselves where the
    /// registration sees them all ([`crate::scale`]: [`crate::scale::RADIUS_PER_SIZE`] times the scans' median
    /// distance from their centre; `register`, `eval` per scene, `multiway` over all its scans), so clouds
    /// in any unit and at any scale register without it; where one scan is described alone, the radius the
    /// weights were trained with times [`RADIUS_PER_TRAINING_RADIUS`] (0.60 m for the shipped weights).
    pub radius: Option<f32>,
    /// Voxel size for downsampling before normals and keypoints; `Some(0.0)` keeps every point. `None` (the
    /// default): for a cloud without normals, the voxel the weights were trained with, scaled to the radius in
    /// use, `radius * VOXEL_PER_RADIUS` (2.5 cm at 0.60 m), so normals are estimated at the density the network
    /// saw; a cloud with normals keeps every point.
    pub voxel: Option<f32>,
    /// Keypoints per scan.
    pub keypoints: usize,
    /// The progressive schedule: describe this many keypoints per scan first, then twice as many, and so on up
    /// to `keypoints`, while the result is not trusted (`crate::pipeline::keypoint_stages`). `None` describes
    /// `keypoints` at once. A pair that needs every round ends with exactly the result of `None`.
    pub first_keypoints: Option<usize>,
    /// How keypoints are chosen.
    pub keypoint_mode: KeypointMode,
    /// Neighbours used for PCA normals (ignored when the file has normals).
    pub normal_neighbors: usize,
    /// Normals are flipped to face this point, in each scan's own frame.
    pub viewpoint: [f32; 3],
    /// Correspondence rule.
    pub matching: MatchMode,
    /// Pose estimator.
    pub estimator: Estimator,
    /// A correspondence is an inlier of a pose when |p_target - T p_source| is below this. `None`: radius / 6
    /// (0.10 m at r = 0.60 m: the 3DMatch feature-match distance tau1, and the distance the verdict's
    /// thresholds were validated at; at radius / 3 the verdict's spread rule rejects correct poses).
    pub inlier_threshold: Option<f32>,
    /// RANSAC criteria (for `Estimator::Ransac`).
    pub ransac: RansacSettings,
    /// Point-to-plane ICP after the estimator, against a voxel-downsampled copy of the target (on by default:
    /// it turns the keypoint-level pose into a surface-level one for about 0.2 s); `None` skips it.
    pub icp: Option<IcpSettings>,
    /// What loading does with points exactly at (0, 0, 0) (sensor no-returns): by default they are dropped when
    /// there are several (used where the library loads the clouds, e.g. the bindings' arrays).
    pub zero_points: crate::io::ZeroPoints,
    /// Seed for every random choice.
    pub seed: u64,
    /// Compute backend.
    pub backend: BackendKind,
    /// Thresholds of the success verdict on the result.
    pub verdict: crate::verdict::VerdictSettings,
    /// Context radii: each keypoint is also described with patches of these larger radii, and correspondences
    /// match on every radius's codeword, each scaled to unit length and weighted, side by side (the main
    /// radius's with weight 1). The pose features stay the main radius's. Default: [`DEFAULT_CONTEXT_RADII`]
    /// (twice the radius, weight 1); empty: matching on the main radius's codewords as they are.
    pub context_radii: Vec<ContextRadius>,
    /// Which rounds match on the context radii's codewords too (when there are context radii); default
    /// [`ContextWhen::Untrusted`].
    pub context_when: ContextWhen,
    /// How many of the estimator's best distinct poses compete for the result: each is refined on its inliers,
    /// and the estimator's choice (most inliers) stays when the verdict trusts it, or unless another with at
    /// least half its inliers puts clearly fewer points (5 % of those checked) in space the other scan saw
    /// empty, along lines of sight from each scan's `viewpoint`; then the most consistent of those wins
    /// ([`crate::estimate::candidates`]). 1: the estimator's choice alone, as for clouds in a shared world frame
    /// (where the frame origin is no sensor). In `1..=MAX_POSE_CANDIDATES`; default [`DEFAULT_POSE_CANDIDATES`].
    pub pose_candidates: usize,
}

/// Which registration rounds match on the codewords of the context radii
/// ([`RegistrationSettings::context_radii`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub enum ContextWhen {
    /// Every round: correspondences always come from the codewords of every radius.
    Always,
    /// The default. Only a last round, run when no round matching on the main radius's codewords alone gave a trusted
    /// result; it matches all keypoints on every radius. Pairs the main radius registers keep its result and
    /// its speed (the context patches are described only for such a round, but `describe` describes them
    /// always, so described scans can be registered either way).
    #[default]
    Untrusted,
}

/// A context radius of [`RegistrationSettings::context_radii`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ContextRadius {
    /// The patch radius as a multiple of the main radius, in `1..=MAX_CONTEXT_FACTOR` (larger patches keep
    /// every keypoint the main radius keeps).
    pub factor: f32,
    /// Weight of its unit-length codewords in matching, beside the main radius's 1; positive.
    pub weight: f32,
}

/// The default context radii: one patch twice the radius, its codewords weighted as the main radius's, used
/// only for pairs the main radius does not register with trust ([`ContextWhen::Untrusted`]). Chosen on the
/// synthetic validation sets (docs/experiments/context-radii.md, "Context radii only for untrusted pairs"): Kinect-like
/// registration recall 0.97 with either estimator at every rotation (RelativeNet 0.97-1.00, RANSAC 1.00 without
/// it), randomized feature-match recall 0.79 -> 0.88; pairs the main radius trusts pay nothing.
pub const DEFAULT_CONTEXT_RADII: [ContextRadius; 1] = [ContextRadius { factor: 2.0, weight: 1.0 }];

/// Largest context radius, as a multiple of the main radius.
pub const MAX_CONTEXT_FACTOR: f32 = 8.0;
/// Most context radii.
pub const MAX_CONTEXT_RADII: usize = 4;

/// The default of `RegistrationSettings::pose_candidates`: the 16 best distinct poses compete. Chosen on the
/// synthetic tuning sets (docs/experiments/pose-candidates.md, "Choosing among the best poses by what both scans saw"): on the
/// repetition tuning set RelativeNet registration recall 65 -> 72 of 75 and RANSAC's 63 -> 65, on the
/// randomized one RelativeNet 80 -> 81 of 85 (RANSAC unchanged), no false alarm added.
pub const DEFAULT_POSE_CANDIDATES: usize = 16;
/// Most pose candidates.
pub const MAX_POSE_CANDIDATES: usize = 64;

/// The default patch radius as a multiple of the radius the weights were trained with: describing each keypoint
/// with twice the context it was trained on (a patch keeps its number of points, so it samples a larger
/// neighbourhood more sparsely). Chosen on synthetic validation scenes that no training saw (docs/experiments/inference-radius.md,
/// "Inference radius"): with the randomized generator, feature-match recall 0.47 at 1x, 0.70 at 1.5x, 0.79 at 2x,
/// 0.80 at 3x, registration recall 71, 76, 81 and 80 of 85; with the Kinect-like one FMR 0.96 -> 0.99.
pub const RADIUS_PER_TRAINING_RADIUS: f32 = 2.0;

/// The default voxel size for clouds without normals, as a fraction of the patch radius: `train`'s voxel
/// (0.025 m at its 0.30 m radius) at the default radius, so normals are estimated at the density training
/// estimated them at. On the synthetic validation scenes with their normals removed, feature-match recall at
/// the training radius is 0.69 at full density and 0.85 at this voxel; with the files' own normals it is 0.96 at
/// full density and 0.87 at this voxel, so clouds with normals keep every point. At the default radius, on the
/// randomized validation scenes without normals, this voxel gives FMR 0.62 where radius / 12 (the training
/// voxel per training radius) gives 0.54 (docs/experiments/inference-radius.md).
pub const VOXEL_PER_RADIUS: f32 = 1.0 / 24.0;

/// The default inlier threshold as a fraction of the patch radius: 0.10 m at the default 0.60 m, the 3DMatch
/// feature-match distance tau1 and the distance the verdict's thresholds were validated at (at radius / 3 its
/// spread rule rejects correct poses; docs/experiments/inference-radius.md, "Inference radius").
pub const INLIER_THRESHOLD_PER_RADIUS: f32 = 1.0 / 6.0;

/// ICP's default largest point-pair distance as a fraction of the patch radius: 5 cm at the default 0.60 m
/// (chosen on synthetic validation scenes: rotation errors half those of radius / 6 at the same recall).
pub const ICP_DISTANCE_PER_RADIUS: f32 = 1.0 / 12.0;

/// Keypoints per scan of the progressive schedule's first round (see `RegistrationSettings::first_keypoints`).
pub const DEFAULT_FIRST_KEYPOINTS: usize = 250;
/// Most keypoints per scan.
pub const MAX_KEYPOINTS: usize = 1_000_000;
/// Most neighbours for PCA normals.
pub const MAX_NORMAL_NEIGHBORS: usize = 1_000;
/// Most RANSAC iterations.
pub const MAX_RANSAC_ITERATIONS: usize = 100_000_000;
/// Most ICP iterations.
pub const MAX_ICP_ITERATIONS: usize = 10_000;

impl RegistrationSettings {
    /// Checks every setting against its documented bound; the error names the setting and the limit.
    pub fn validate(&self) -> crate::Result<()> {
        use crate::Error;
        let positive = |name: &str, v: Option<f32>| match v {
            Some(x) if !(x.is_finite() && x > 0.0) => Err(Error::invalid(format!("{name} must be positive, got {x}"))),
            _ => Ok(()),
        };
        positive("radius", self.radius)?;
        if let Some(v) = self.voxel
            && !(v.is_finite() && v >= 0.0)
        {
            return Err(Error::invalid(format!("voxel size must be positive (or 0 for none), got {v}")));
        }
        positive("inlier threshold", self.inlier_threshold)?;
        if !(1..=MAX_KEYPOINTS).contains(&self.keypoints) {
            return Err(Error::invalid(format!("keypoints must be 1..={MAX_KEYPOINTS}, got {}", self.keypoints)));
        }
        if let Some(first) = self.first_keypoints
            && !(1..=MAX_KEYPOINTS).contains(&first)
        {
            return Err(Error::invalid(format!("first keypoints must be 1..={MAX_KEYPOINTS}, got {first}")));
        }
        if !(3..=MAX_NORMAL_NEIGHBORS).contains(&self.normal_neighbors) {
            return Err(Error::invalid(format!(
                "normal neighbours must be 3..={MAX_NORMAL_NEIGHBORS}, got {}",
                self.normal_neighbors
            )));
        }
        if let MatchMode::Mutual(k) = self.matching
            && !(1..=4).contains(&k)
        {
            return Err(Error::invalid(format!("mutual K must be 1..4, got {k}")));
        }
        if !(1..=MAX_RANSAC_ITERATIONS).contains(&self.ransac.max_iterations) {
            return Err(Error::invalid(format!(
                "RANSAC iterations must be 1..={MAX_RANSAC_ITERATIONS}, got {}",
                self.ransac.max_iterations
            )));
        }
        if !(self.ransac.confidence > 0.0 && self.ransac.confidence < 1.0) {
            return Err(Error::invalid(format!("RANSAC confidence must be in (0, 1), got {}", self.ransac.confidence)));
        }
        if let Some(icp) = &self.icp {
            positive("ICP max correspondence distance", icp.max_correspondence_distance)?;
            if !(1..=MAX_ICP_ITERATIONS).contains(&icp.max_iterations) {
                return Err(Error::invalid(format!(
                    "ICP iterations must be 1..={MAX_ICP_ITERATIONS}, got {}",
                    icp.max_iterations
                )));
            }
        }
        if !self.viewpoint.iter().all(|c| c.is_finite()) {
            return Err(Error::invalid(format!("viewpoint must be finite, got {:?}", self.viewpoint)));
        }
        if !(1..=MAX_POSE_CANDIDATES).contains(&self.pose_candidates) {
            return Err(Error::invalid(format!(
                "pose candidates must be 1..={MAX_POSE_CANDIDATES}, got {}",
                self.pose_candidates
            )));
        }
        if self.context_radii.len() > MAX_CONTEXT_RADII {
            return Err(Error::invalid(format!(
                "at most {MAX_CONTEXT_RADII} context radii, got {}",
                self.context_radii.len()
            )));
        }
        for c in &self.context_radii {
            if !(c.factor >= 1.0 && c.factor <= MAX_CONTEXT_FACTOR) {
                return Err(Error::invalid(format!(
                    "context radius factor must be in 1..={MAX_CONTEXT_FACTOR} (a multiple of the radius), got {}",
                    c.factor
                )));
            }
            if !(c.weight.is_finite() && c.weight > 0.0) {
                return Err(Error::invalid(format!("context radius weight must be positive, got {}", c.weight)));
            }
        }
        self.verdict.validate()
    }
}

impl Default for RegistrationSettings {
    fn default() -> Self {
        RegistrationSettings {
            weights: None,
            radius: None,
            voxel: None,
            keypoints: 2500,
            first_keypoints: Some(DEFAULT_FIRST_KEYPOINTS),
            keypoint_mode: KeypointMode::Random,
            normal_neighbors: 30,
            viewpoint: [0.0; 3],
            matching: MatchMode::Mutual(1),
            estimator: Estimator::RelativeNet,
            inlier_threshold: None,
            ransac: RansacSettings::default(),
            icp: Some(IcpSettings::default()),
            zero_points: crate::io::ZeroPoints::Auto,
            seed: 0,
            backend: BackendKind::Auto,
            verdict: crate::verdict::VerdictSettings::default(),
            context_radii: DEFAULT_CONTEXT_RADII.to_vec(),
            context_when: ContextWhen::default(),
            pose_candidates: DEFAULT_POSE_CANDIDATES,
        }
    }
}
