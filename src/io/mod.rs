//! Point-cloud files: PLY (ascii, binary little/big endian), PCD (ascii, binary) and XYZ text in; binary PLY out.
//! Outputs are written atomically (temp file + rename).

use crate::cloud::PointCloud;
use crate::error::Result;
use std::path::Path;

/// Options applied while loading.
#[derive(Clone, Copy, Debug, Default)]
pub struct LoadOptions {
    /// Drop points that are exactly (0, 0, 0) (invalid returns in many LiDAR files).
    pub drop_zero_points: bool,
}

/// What loading did besides returning the cloud.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct LoadReport {
    /// Points dropped because a coordinate was NaN or infinite.
    pub dropped_non_finite: usize,
    /// Points dropped because they were exactly (0, 0, 0) and `drop_zero_points` was set.
    pub dropped_zero: usize,
}

/// Reads a cloud, choosing the format from the extension (.ply, .pcd, .xyz/.txt/.pts).
pub fn read_cloud(path: &Path, options: &LoadOptions) -> Result<(PointCloud, LoadReport)> {
    let _ = (path, options);
    todo!("io helper")
}

/// Writes `cloud` as binary little-endian PLY (normals included when present), atomically.
pub fn write_ply(path: &Path, cloud: &PointCloud) -> Result<()> {
    let _ = (path, cloud);
    todo!("io helper")
}

/// Writes `bytes` to `path` atomically: a temp file beside it, then a rename. Refuses to replace `protect`
/// paths (inputs).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let _ = (path, bytes);
    todo!("io helper")
}
