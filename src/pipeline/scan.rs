//! A described scan: its preprocessed cloud, keypoints taken in a fixed seeded order and described prefix by
//! prefix, their PPF-FoldNet codewords, and pose features (PC-FoldNet codeword minus PPF codeword) computed only
//! for the keypoints a pose estimate asks for.
//!
//! Describing a scan's first k keypoints and later extending it to K gives exactly the features of describing
//! K at once: the keypoint order is a prefix-stable seeded sample, each patch draws from its own stream (derived
//! from its keypoint), and every network row depends only on its own patch.

use crate::backend::{ScanCloud, ScanFeatures};

/// A scan between description rounds: what extending its description needs besides the features so far.
pub(crate) struct DescribingScan {
    /// The features of the keypoints described so far (`features.cloud` is the preprocessed cloud).
    pub features: ScanFeatures,
    /// The cloud where the backend describes it.
    pub cloud: Box<dyn ScanCloud>,
    /// Cloud indices of the keypoints, in description order.
    pub order: Vec<usize>,
    /// Seed of the patch sampling streams.
    pub patch_seed: u64,
}
