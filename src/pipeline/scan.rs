//! A described scan: its preprocessed cloud, keypoints taken in a fixed seeded order and described prefix by
//! prefix, their PPF-FoldNet codewords, and pose features (PC-FoldNet codeword minus PPF codeword) computed only
//! for the keypoints a pose estimate asks for.
//!
//! Describing a scan's first k keypoints and later extending it to K gives exactly the features of describing
//! K at once: the keypoint order is a prefix-stable seeded sample, each patch draws from its own stream (derived
//! from its keypoint), and every network row depends only on its own patch.

use crate::cloud::PointCloud;
use crate::settings::StageTime;
use crate::spatial::PointIndex;
use std::sync::Mutex;

/// Per-scan output of the description stages.
#[derive(Clone, Debug)]
pub struct ScanFeatures {
    /// The scan after preprocessing (downsampled, with unit normals). From `Registrar::register_detailed`, a
    /// cloud without normals in its file has `normals: None`: normals are estimated only where patches need
    /// them.
    pub cloud: PointCloud,
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
    /// Rotation-invariant PPF-FoldNet codewords, `keypoints.len() x codeword`, row-major.
    pub ppf_codewords: Vec<f32>,
    /// Stage times spent describing this scan.
    pub timings: Vec<StageTime>,
    /// PC-FoldNet's inputs and the pose features computed from them so far.
    pub pose: PoseFeatures,
}

impl ScanFeatures {
    /// Rows (kept keypoints) among the first `candidates` keypoints of the order.
    pub fn rows_within(&self, candidates: usize) -> usize {
        self.keypoint_ranks.partition_point(|&r| (r as usize) < candidates)
    }
}

/// PC-FoldNet's input rows (`points_per_patch x 3` per kept keypoint) and, once computed, each row's pose
/// feature (`codeword` wide). Behind a lock so that estimates reading one scan from several pairs compute each
/// row once.
#[derive(Debug, Default)]
pub struct PoseFeatures {
    rows: Mutex<PoseRows>,
}

/// The content of [`PoseFeatures`] (e.g. to serialise a described scan).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PoseRows {
    /// PC-FoldNet input, `rows x input_width`.
    pub input: Vec<f32>,
    /// Pose features, `rows x codeword`; meaningful where `ready`.
    pub features: Vec<f32>,
    /// Whether each row's pose feature has been computed.
    pub ready: Vec<bool>,
}

impl Clone for PoseFeatures {
    fn clone(&self) -> Self {
        PoseFeatures { rows: Mutex::new(self.lock().clone()) }
    }
}

impl PoseFeatures {
    /// Pose features from their content; errors when the lengths do not fit `keypoints` rows of `codeword`.
    pub fn from_rows(rows: PoseRows, keypoints: usize, codeword: usize) -> crate::Result<PoseFeatures> {
        let fits = rows.ready.len() == keypoints
            && rows.features.len() == keypoints * codeword
            && rows.input.len().is_multiple_of(keypoints.max(1));
        if !fits {
            return Err(crate::Error::invalid(format!(
                "pose features: {} input values, {} features and {} flags do not fit {keypoints} keypoints of \
                 {codeword} values",
                rows.input.len(),
                rows.features.len(),
                rows.ready.len()
            )));
        }
        Ok(PoseFeatures { rows: Mutex::new(rows) })
    }

    /// A copy of the content.
    pub fn rows(&self) -> PoseRows {
        self.lock().clone()
    }

    /// The rows, also after a panic elsewhere poisoned the lock (every update leaves them consistent).
    pub(crate) fn lock(&self) -> std::sync::MutexGuard<'_, PoseRows> {
        self.rows.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
    }
}

/// A scan between description rounds: what extending its description needs besides the features so far.
pub(crate) struct DescribingScan {
    /// The features of the keypoints described so far (`features.cloud` is the preprocessed cloud).
    pub features: ScanFeatures,
    /// Spatial index over `features.cloud.points`.
    pub index: PointIndex,
    /// Cloud indices of the keypoints, in description order.
    pub order: Vec<usize>,
    /// Seed of the patch sampling streams.
    pub patch_seed: u64,
    /// Normals still to estimate (`None` when the cloud came with normals or all are computed).
    pub missing_normals: Option<MissingNormals>,
}

/// Which estimated normals a cloud still lacks (placeholders until then), and where they face.
pub(crate) struct MissingNormals {
    /// Whether each point's normal is computed.
    pub ready: Vec<bool>,
    /// The viewpoint estimated normals face (scan frame).
    pub viewpoint: [f32; 3],
}
