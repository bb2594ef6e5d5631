//! A described scan as the backends hand it around ([`ScanFeatures`]) and the pose part of its rows on the host
//! ([`PoseRows`]): the vocabulary the pipeline and every backend share. Re-exported by [`crate::pipeline`].

use super::{ContextRows, HeldPoints, ScanRows};
use crate::cloud::PointCloud;
use crate::result::StageTime;
use std::sync::Arc;

/// Per-scan output of the description stages.
#[derive(Clone, Debug)]
pub struct ScanFeatures {
    /// The scan after preprocessing (downsampled, with unit normals). From `Registrar::register_detailed`, a
    /// cloud without normals in its file has `normals: None`: normals are estimated only where patches need
    /// them.
    pub cloud: PointCloud,
    /// Where the scan's sensor sat, in the scan's frame: estimated normals face it, and the choice among pose
    /// candidates reads lines of sight from it.
    pub viewpoint: [f32; 3],
    /// Keypoint positions (scan frame), only keypoints with a non-empty patch.
    pub keypoints: Vec<[f32; 3]>,
    /// Their unit normals (scan frame): the normal frames of normal-aligned patches.
    pub keypoint_normals: Vec<[f32; 3]>,
    /// Each kept keypoint's position in the scan's keypoint order (ascending; keypoints dropped for an empty
    /// patch leave gaps).
    pub keypoint_ranks: Vec<u32>,
    /// Keypoints of the order described so far, kept or dropped.
    pub candidates: usize,
    /// Keypoints dropped because their patch was empty.
    pub empty_patches: usize,
    /// The described rows (one per kept keypoint), held by the backend that described them: PPF-FoldNet
    /// codewords, PC-FoldNet's inputs and the pose features computed so far. Shared by clones; pairs that
    /// read one scan reuse them.
    pub rows: Arc<dyn ScanRows>,
    /// The rows described at each context radius of the settings (row for row with `rows`; empty without
    /// context radii): only their codewords are used, in matching. Shared by clones.
    pub context: Vec<ContextRows>,
    /// The preprocessed points as the backend that prepared the scan holds them (the GPU backend: a device
    /// buffer; `None` on the host, where `cloud.points` are they), for stages after description (ICP) to read
    /// them where they are. Shared by clones.
    pub held_points: Option<Arc<dyn HeldPoints>>,
    /// `Some(k)` where `cloud`'s normals are the host's PCA estimates over `k` neighbours facing `viewpoint`
    /// (NaN placeholders where none was needed yet, [`super::ScanCloud::host_estimated_normals`]); `None` where
    /// they came with the cloud or another backend holds them. ICP's copy of the target reuses such normals.
    pub estimated_normals: Option<usize>,
    /// Stage times spent describing this scan.
    pub timings: Vec<StageTime>,
}

impl ScanFeatures {
    /// The normals of `cloud` estimated on the host so far, and how ([`ScanFeatures::estimated_normals`]).
    pub fn known_normals(&self) -> Option<crate::estimate::icp::KnownNormals<'_>> {
        let (normals, neighbors) = (self.cloud.normals.as_deref()?, self.estimated_normals?);
        Some(crate::estimate::icp::KnownNormals { normals, neighbors, viewpoint: self.viewpoint })
    }

    /// Rows (kept keypoints) among the first `candidates` keypoints of the order.
    pub fn rows_within(&self, candidates: usize) -> usize {
        self.keypoint_ranks.partition_point(|&r| (r as usize) < candidates)
    }

    /// The rotation-invariant PPF-FoldNet codewords, `keypoints.len() x codeword`, row-major (read back from
    /// the backend that holds them; blocks: in a browser await `rows.read_codewords()`).
    pub fn read_codewords(&self) -> crate::Result<Vec<f32>> {
        crate::block_on(self.rows.read_codewords())
    }

    /// PC-FoldNet's inputs and the pose features computed so far (read back; blocks like
    /// [`ScanFeatures::read_codewords`]).
    pub fn read_pose_rows(&self) -> crate::Result<PoseRows> {
        crate::block_on(self.rows.read_pose_rows())
    }
}

/// PC-FoldNet's input rows (`points_per_patch x 3` per kept keypoint) and, once computed, each row's pose
/// feature (`codeword` wide): the pose part of a scan's rows on the host (e.g. to serialise a described scan).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PoseRows {
    /// PC-FoldNet input, `rows x input_width`.
    pub input: Vec<f32>,
    /// Pose features, `rows x codeword`; meaningful where `ready`.
    pub features: Vec<f32>,
    /// Whether each row's pose feature has been computed.
    pub ready: Vec<bool>,
}
