//! Pose estimation from correspondences: RelativeNet hypothesize-and-verify, the RANSAC baseline, the shared
//! inlier refinement, and optional point-to-plane ICP.

pub mod candidates;
pub mod icp;
pub mod ransac;
pub mod refine;
pub mod visibility;

pub use icp::icp_point_to_plane;
pub use ransac::{ransac, ransac_candidates, required_iterations};
pub use refine::{evaluate, inlier_set, refine};
