//! Per-scan preprocessing: voxel downsampling, normals, keypoints and patches.

pub mod keypoints;
pub mod normals;
pub mod patches;
pub mod voxel;

pub use keypoints::select_keypoints;
pub use normals::{estimate_normals, estimate_normals_at};
pub use patches::{Patches, extract_patch_where, extract_patches};
pub use voxel::voxel_downsample;

use crate::cpu::patch_features::patch_features;
use crate::model::config::PoseFrame;

/// Gathers patch centres, neighbours and normals in the layout of the `patch_features` kernel.
pub struct GatheredPatches {
    /// One keypoint position per patch.
    pub centers: Vec<[f32; 3]>,
    /// One keypoint normal per patch.
    pub center_normals: Vec<[f32; 3]>,
    /// `patches x N` neighbour positions.
    pub points: Vec<[f32; 3]>,
    /// `patches x N` neighbour normals.
    pub normals: Vec<[f32; 3]>,
}

/// Gathers the data the feature kernel reads.
pub fn gather(points: &[[f32; 3]], normals: &[[f32; 3]], patches: &Patches) -> GatheredPatches {
    GatheredPatches {
        centers: patches.keypoints.iter().map(|&k| points[k]).collect(),
        center_normals: patches.keypoints.iter().map(|&k| normals[k]).collect(),
        points: patches.neighbors.iter().map(|&j| points[j as usize]).collect(),
        normals: patches.neighbors.iter().map(|&j| normals[j as usize]).collect(),
    }
}

impl GatheredPatches {
    /// PPF (P x N x 4) and PC (P x N x 3, in `frame`) inputs on the CPU.
    pub fn features(&self, points_per_patch: usize, radius: f32, frame: PoseFrame) -> (Vec<f32>, Vec<f32>) {
        let (c, cn) = (&self.centers, &self.center_normals);
        patch_features(c, cn, &self.points, &self.normals, points_per_patch, radius, frame)
    }
}
