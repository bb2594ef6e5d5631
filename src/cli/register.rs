//! `dpr-gpu register` and the registration options shared with `eval`.

use crate::settings::*;
use std::path::PathBuf;

/// Registration options (shared by `register` and `eval`).
#[derive(clap::Args, Debug, Clone)]
pub struct RegisterOptions {
    /// Weights file (safetensors); default: the shipped weights/default.safetensors.
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// Keypoints per scan.
    #[arg(long, default_value_t = 1000)]
    pub keypoints: usize,
    /// Patch radius in cloud units (default: the radius the weights were trained with, 0.30 m).
    #[arg(long)]
    pub radius: Option<f32>,
    /// Voxel size for downsampling (cloud units); default: none.
    #[arg(long)]
    pub voxel: Option<f32>,
    /// Pose estimator: relativenet or ransac.
    #[arg(long, default_value = "relativenet")]
    pub estimator: String,
    /// Mutual K nearest neighbours (1..4), or 0 for the "closest" rule.
    #[arg(long, default_value_t = 1)]
    pub mutual: usize,
    /// Inlier threshold in cloud units (default: radius / 3).
    #[arg(long)]
    pub inlier_threshold: Option<f32>,
    /// Seed for every random choice.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Refine the final pose with point-to-plane ICP.
    #[arg(long)]
    pub icp: bool,
    /// Drop exact (0,0,0) points when loading.
    #[arg(long)]
    pub drop_zero: bool,
}

impl RegisterOptions {
    /// The settings these options describe (the estimator string is parsed by the caller when it allows more
    /// than `relativenet|ransac`, as `eval --estimator both` does).
    pub fn to_settings(&self) -> anyhow::Result<RegistrationSettings> {
        todo!("pipeline")
    }
}
