//! What registration returns: the pose estimate and its support, the correspondences it came from, the stage
//! times, and the whole result of `register`. Re-exported by [`crate::settings`] (and the crate root), where
//! these types used to live.

use nalgebra::Matrix4;
use serde::Serialize;

/// One correspondence between a source keypoint and a target keypoint.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Correspondence {
    /// Index into the source scan's keypoints.
    pub source_index: u32,
    /// Index into the target scan's keypoints.
    pub target_index: u32,
    /// Source keypoint position (source frame).
    pub source_point: [f32; 3],
    /// Target keypoint position (target frame).
    pub target_point: [f32; 3],
    /// Euclidean distance between the two PPF codewords.
    pub feature_distance: f32,
}

/// Wall time of one pipeline stage.
#[derive(Clone, Debug, Serialize)]
pub struct StageTime {
    /// Stage name ("load", "normals", "ppf_encoder"...).
    pub stage: String,
    /// Seconds.
    pub seconds: f64,
}

/// A pose estimate and its support.
#[derive(Clone, Debug, Serialize)]
pub struct PoseEstimate {
    /// p_target = T p_source (row-major when serialised).
    #[serde(serialize_with = "serialize_matrix")]
    pub target_from_source: Matrix4<f64>,
    /// Correspondences within the inlier threshold under the final pose.
    pub inliers: usize,
    /// RMS residual of those inliers.
    pub inlier_rmse: f64,
    /// inliers / correspondences.
    pub fitness: f64,
    /// Pose hypotheses scored.
    pub hypotheses_scored: usize,
}

/// What `register` returns.
#[derive(Clone, Debug, Serialize)]
pub struct RegistrationResult {
    /// The final pose and its support.
    #[serde(flatten)]
    pub estimate: PoseEstimate,
    /// Number of correspondences fed to the estimator.
    pub correspondences: usize,
    /// Keypoints per scan of the round that gave the result (the progressive schedule stops at the first
    /// trusted round).
    pub keypoints: usize,
    /// Keypoints dropped (source + target) because no other point lay within the patch radius.
    pub empty_patches: usize,
    /// Wall time per stage, in pipeline order.
    pub timings: Vec<StageTime>,
    /// The backend (and adapter) that ran the learned stages.
    pub backend: String,
    /// Whether the pose can be trusted (see [`crate::verdict`]); the pose is returned either way.
    pub success: bool,
    /// Why it cannot be trusted (`None` on success).
    pub reason: Option<String>,
    /// The patch radius it ran at, how it was chosen, and the distances that follow it.
    pub scale: crate::scale::ScaleReport,
}

impl std::fmt::Display for PoseEstimate {
    /// `target_from_source` as four plain rows, then its support.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", crate::pose::matrix_text(&self.target_from_source))?;
        write!(
            f,
            "inliers {} (fitness {:.4}, inlier RMSE {:.5}), {} hypotheses scored",
            self.inliers, self.fitness, self.inlier_rmse, self.hypotheses_scored
        )
    }
}

impl std::fmt::Display for RegistrationResult {
    /// The pose (see [`PoseEstimate`]'s `Display`), the correspondences, the backend and the verdict.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "{}", self.estimate)?;
        writeln!(f, "{} correspondences, backend {}", self.correspondences, self.backend)?;
        match &self.reason {
            None => write!(f, "verdict: success"),
            Some(reason) => write!(f, "verdict: NOT TRUSTED: {reason}"),
        }
    }
}

/// Serialises a 4x4 matrix as four rows.
pub fn serialize_matrix<S: serde::Serializer>(m: &Matrix4<f64>, s: S) -> Result<S::Ok, S::Error> {
    let rows: Vec<[f64; 4]> = (0..4).map(|r| [m[(r, 0)], m[(r, 1)], m[(r, 2)], m[(r, 3)]]).collect();
    rows.serialize(s)
}
