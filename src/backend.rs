//! The backend seam: the learned and massively parallel stages of the pipeline, implemented by the CPU
//! reference (`CpuBackend`) and the WGSL kernels (`gpu::GpuBackend`). Geometry that is cheap or sequential
//! (normals, keypoints, patch gathering, the final rigid fit) stays on the CPU for every backend.

use crate::cpu::codeword_distance::codeword_distance;
use crate::cpu::hypotheses::{Hypothesis, hypotheses};
use crate::cpu::mutual_knn::{Match, mutual_knn};
use crate::cpu::score_hypotheses::{HypothesisScore, score_hypotheses};
use crate::error::Result;
use crate::model::{Model, Net};
use crate::preprocess::GatheredPatches;
use crate::settings::MatchMode;

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

/// The stages a backend implements. Every method is deterministic for given inputs.
pub trait Backend: Send + Sync {
    /// Human-readable backend name (and adapter, for a GPU).
    fn name(&self) -> String;

    /// The model the backend runs.
    fn model(&self) -> &Model;

    /// PPF (P x N x 4) and PC (P x N x 3) network inputs of gathered patches.
    fn patch_features(&self, patches: &GatheredPatches, radius: f32) -> Result<(Vec<f32>, Vec<f32>)>;

    /// Codewords (P x codeword) of `patches` patches of `points_per_patch` rows each.
    fn encode(&self, net: Net, input: &[f32], patches: usize) -> Result<Vec<f32>>;

    /// Correspondences between source and target codewords (rows of width `dim`).
    fn match_codewords(&self, source: &[f32], target: &[f32], dim: usize, mode: MatchMode) -> Result<Vec<Match>>;

    /// RelativeNet's rotations target_from_source (row-major, fragment frames) for rows of [source | target]
    /// pose features, given the keypoint normals of each row's source and target patch (the normal frames of
    /// `PoseFrame::Normal`): `rotation_output.candidates()` consecutive rotations per row.
    fn predict_rotations(&self, pose: RotationInputs<'_>) -> Result<Vec<[f32; 9]>>;

    /// One hypothesis per correspondence from its rotation.
    fn hypotheses(&self, rotations: &[[f32; 9]], source: &[[f32; 3]], target: &[[f32; 3]]) -> Result<Vec<Hypothesis>>;

    /// Inlier count and residual sum of every hypothesis over every correspondence.
    fn score_hypotheses(
        &self,
        hypotheses: &[Hypothesis],
        source: &[[f32; 3]],
        target: &[[f32; 3]],
        threshold: f32,
    ) -> Result<Vec<HypothesisScore>>;
}

/// The plain-Rust reference backend: the oracle for the GPU and the fallback without one.
pub struct CpuBackend {
    model: Model,
}

impl CpuBackend {
    /// Wraps a model.
    pub fn new(model: Model) -> CpuBackend {
        CpuBackend { model }
    }
}

impl Backend for CpuBackend {
    fn name(&self) -> String {
        format!("cpu ({} threads)", rayon::current_num_threads())
    }

    fn model(&self) -> &Model {
        &self.model
    }

    fn patch_features(&self, patches: &GatheredPatches, radius: f32) -> Result<(Vec<f32>, Vec<f32>)> {
        let c = &self.model.config;
        Ok(patches.features(c.points_per_patch, radius, c.pose_frame))
    }

    fn encode(&self, net: Net, input: &[f32], patches: usize) -> Result<Vec<f32>> {
        let n = self.model.config.points_per_patch;
        Ok(match net {
            Net::Ppf => self.model.ppf.encode(input, patches, n),
            Net::Pc => self.model.pc.encode(input, patches, n),
        })
    }

    fn match_codewords(&self, source: &[f32], target: &[f32], dim: usize, mode: MatchMode) -> Result<Vec<Match>> {
        let d = codeword_distance(source, target, dim);
        Ok(mutual_knn(&d, source.len() / dim, target.len() / dim, mode))
    }

    fn predict_rotations(&self, pose: RotationInputs<'_>) -> Result<Vec<[f32; 9]>> {
        let c = &self.model.config;
        pose.validate(c.codeword())?;
        let RotationInputs { source, target, source_normals, target_normals, rows } = pose;
        Ok(self.model.relative.predict(c, source, target, source_normals, target_normals, rows))
    }

    fn hypotheses(&self, rotations: &[[f32; 9]], source: &[[f32; 3]], target: &[[f32; 3]]) -> Result<Vec<Hypothesis>> {
        if source.len() != rotations.len() || target.len() != rotations.len() {
            return Err(crate::Error::invalid("hypotheses: rotations and points differ in length"));
        }
        Ok(hypotheses(rotations, source, target))
    }

    fn score_hypotheses(
        &self,
        hypotheses: &[Hypothesis],
        source: &[[f32; 3]],
        target: &[[f32; 3]],
        threshold: f32,
    ) -> Result<Vec<HypothesisScore>> {
        Ok(score_hypotheses(hypotheses, source, target, threshold))
    }
}
