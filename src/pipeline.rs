//! The registration pipeline: load weights, describe each scan (keypoints, patches, codewords), correspond,
//! estimate the pose. `register` runs it all; `Registrar` exposes the steps for evaluation tools.

use crate::cloud::PointCloud;
use crate::error::Result;
use crate::settings::*;

/// Per-scan output of the description stages.
#[derive(Clone, Debug)]
pub struct ScanFeatures {
    /// The scan after preprocessing (downsampled, with normals).
    pub cloud: PointCloud,
    /// Keypoint positions (scan frame).
    pub keypoints: Vec<[f32; 3]>,
    /// Rotation-invariant PPF-FoldNet codewords, `keypoints.len() x codeword_size`, row-major.
    pub ppf_codewords: Vec<f32>,
    /// Pose-variant features (PC codeword minus PPF codeword), same layout.
    pub pose_features: Vec<f32>,
    /// Stage times spent describing this scan.
    pub timings: Vec<StageTime>,
}

/// A configured pipeline: model and backend loaded once, reused across pairs.
pub struct Registrar {
    /// The settings it was built with.
    pub settings: RegistrationSettings,
}

impl Registrar {
    /// Loads the weights and prepares the backend.
    pub fn new(settings: &RegistrationSettings) -> Result<Registrar> {
        Ok(Registrar { settings: settings.clone() })
    }

    /// Preprocesses `cloud` and computes keypoints and codewords. `stream` separates the random choices of
    /// different scans under one seed (use 0 for the source, 1 for the target).
    pub fn describe(&self, cloud: &PointCloud, stream: u64) -> Result<ScanFeatures> {
        let _ = (cloud, stream);
        todo!("pipeline")
    }

    /// Correspondences between two described scans (matching rule from the settings).
    pub fn correspond(&self, source: &ScanFeatures, target: &ScanFeatures) -> Result<Vec<Correspondence>> {
        let _ = (source, target);
        todo!("pipeline")
    }

    /// Estimates target_from_source from the correspondences with the given estimator.
    pub fn estimate(
        &self,
        source: &ScanFeatures,
        target: &ScanFeatures,
        correspondences: &[Correspondence],
        estimator: Estimator,
    ) -> Result<PoseEstimate> {
        let _ = (source, target, correspondences, estimator);
        todo!("pipeline")
    }

    /// The whole pipeline on two clouds.
    pub fn register(&self, source: &PointCloud, target: &PointCloud) -> Result<RegistrationResult> {
        let _ = (source, target);
        todo!("pipeline")
    }
}

/// Registers `source` onto `target`: the returned `target_from_source` maps source points into the target frame.
pub fn register(source: &PointCloud, target: &PointCloud, settings: &RegistrationSettings) -> Result<RegistrationResult> {
    Registrar::new(settings)?.register(source, target)
}
