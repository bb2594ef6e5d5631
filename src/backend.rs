//! The backend seam: the learned and massively parallel stages of the pipeline, implemented by the CPU
//! reference (`CpuBackend`) and the WGSL kernels (`gpu::GpuBackend`). Geometry that is cheap or sequential
//! (normals, keypoints, patch gathering, the final rigid fit) stays on the CPU for every backend.

use crate::cpu::hypotheses::{Hypothesis, hypotheses};
use crate::cpu::mutual_knn::{Match, codeword_distance, mutual_knn};
use crate::cpu::score_hypotheses::{HypothesisScore, score_hypotheses};
use crate::error::Result;
use crate::model::{Model, Net};
use crate::preprocess::GatheredPatches;
use crate::settings::MatchMode;

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

    /// RelativeNet's unit quaternions (target_from_source) for rows of [source | target] pose features.
    fn predict_rotations(&self, source: &[f32], target: &[f32], rows: usize) -> Result<Vec<[f32; 4]>>;

    /// One hypothesis per correspondence from its quaternion.
    fn hypotheses(&self, quaternions: &[[f32; 4]], source: &[[f32; 3]], target: &[[f32; 3]])
    -> Result<Vec<Hypothesis>>;

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
        Ok(patches.features(self.model.config.points_per_patch, radius))
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

    fn predict_rotations(&self, source: &[f32], target: &[f32], rows: usize) -> Result<Vec<[f32; 4]>> {
        Ok(self.model.relative.predict(source, target, rows))
    }

    fn hypotheses(
        &self,
        quaternions: &[[f32; 4]],
        source: &[[f32; 3]],
        target: &[[f32; 3]],
    ) -> Result<Vec<Hypothesis>> {
        Ok(hypotheses(quaternions, source, target))
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
