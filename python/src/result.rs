//! `RegistrationResult` and `PoseEstimate`: what registration returns, as numpy arrays and plain Python values.

use crate::arrays::{index_pairs, matrix, positions, values};
use dpr_gpu::snapshot::{SnapshotOptions, inlier_lines, write_snapshot};
use dpr_gpu::{Correspondence, PointCloud, PoseEstimate as RustPoseEstimate, StageTime};
use nalgebra::Matrix4;
use numpy::{PyArray1, PyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// Stage name -> seconds, in pipeline order (first occurrence); a stage that ran several times (the rounds of
/// the progressive keypoint schedule) gets the sum of its times.
pub(crate) fn timings_dict<'py>(py: Python<'py>, timings: &[StageTime]) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    for t in timings {
        let before = match d.get_item(&t.stage)? {
            Some(v) => v.extract::<f64>()?,
            None => 0.0,
        };
        d.set_item(&t.stage, before + t.seconds)?;
    }
    Ok(d)
}

/// What `RegistrationResult.snapshot(path)` draws: both scans as registered (after the loader's filtering, in
/// the shifted frame the computation used) and the pose between them in that frame. The correspondences are on
/// the result itself.
pub(crate) struct SnapshotInputs {
    /// The source scan.
    pub source: PointCloud,
    /// The target scan.
    pub target: PointCloud,
    /// target_from_source between the shifted scans.
    pub shifted_target_from_source: Matrix4<f64>,
    /// The registrar's inlier threshold (cloud units), for the inlier lines.
    pub inlier_threshold: f32,
}

/// The outcome of registering a source scan onto a target scan.
///
/// ``target_from_source`` maps source points into the target frame: ``p_target = T @ p_source`` (homogeneous
/// coordinates), so ``source @ T[:3, :3].T + T[:3, 3]`` moves an (N, 3) source array onto the target. The pose
/// is returned whether or not it can be trusted: check ``success`` (and ``reason``).
#[pyclass(frozen, module = "dpr_gpu")]
pub struct RegistrationResult {
    /// The library's result (pose in the caller's frame, i.e. with any origin shift undone).
    pub(crate) result: dpr_gpu::RegistrationResult,
    /// The correspondences fed to the estimator (points in the shifted frame).
    pub(crate) correspondences: Vec<Correspondence>,
    /// Source keypoints (shifted frame).
    pub(crate) source_keypoints: Vec<[f32; 3]>,
    /// Target keypoints (shifted frame).
    pub(crate) target_keypoints: Vec<[f32; 3]>,
    /// The origin subtracted from both scans before the computation (zero unless coordinates were large).
    pub(crate) origin: [i64; 3],
    /// Input rows dropped (non-finite values, or points exactly at (0, 0, 0) as `drop_zero_points` says), both
    /// scans together.
    pub(crate) dropped_points: usize,
    /// Kept for `snapshot(path)`.
    pub(crate) snapshot: SnapshotInputs,
}

#[pymethods]
impl RegistrationResult {
    /// The 4x4 rigid transform (float64) that maps source points into the target frame.
    #[getter]
    fn target_from_source<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        matrix(py, &self.result.estimate.target_from_source)
    }

    /// Inliers / correspondences under the final pose.
    #[getter]
    fn fitness(&self) -> f64 {
        self.result.estimate.fitness
    }

    /// RMS residual of the inlier correspondences (cloud units).
    #[getter]
    fn inlier_rmse(&self) -> f64 {
        self.result.estimate.inlier_rmse
    }

    /// Correspondences within the inlier threshold under the final pose.
    #[getter]
    fn inliers(&self) -> usize {
        self.result.estimate.inliers
    }

    /// Pose hypotheses scored by the estimator.
    #[getter]
    fn hypotheses_scored(&self) -> usize {
        self.result.estimate.hypotheses_scored
    }

    /// The correspondences as a (K, 2) int64 array: column 0 indexes ``source_keypoints``, column 1
    /// ``target_keypoints``.
    #[getter]
    fn correspondences<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<i64>> {
        index_pairs(py, self.correspondences.iter().map(|c| [c.source_index, c.target_index]))
    }

    /// Codeword (feature) distance of each correspondence, a (K,) float32 array.
    #[getter]
    fn feature_distances<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f32>> {
        values(py, self.correspondences.iter().map(|c| c.feature_distance).collect())
    }

    /// Source keypoints (source frame) as an (Ns, 3) float64 array; ``source_keypoints[correspondences[:, 0]]``
    /// are the source ends of the correspondences.
    #[getter]
    fn source_keypoints<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        positions(py, &self.source_keypoints, self.origin)
    }

    /// Target keypoints (target frame) as an (Nt, 3) float64 array; ``target_keypoints[correspondences[:, 1]]``
    /// are the target ends of the correspondences.
    #[getter]
    fn target_keypoints<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        positions(py, &self.target_keypoints, self.origin)
    }

    /// Keypoints dropped (source and target together) because no other point lay within the patch radius.
    #[getter]
    fn empty_patches(&self) -> usize {
        self.result.empty_patches
    }

    /// Input rows dropped (source and target together): rows with a NaN or infinite value, and points exactly at
    /// (0, 0, 0) as ``drop_zero_points`` says (by default when there are two or more in a scan).
    #[getter]
    fn dropped_points(&self) -> usize {
        self.dropped_points
    }

    /// Wall time per pipeline stage in seconds, a dict in pipeline order (``"source.patches"``,
    /// ``"target.ppf_encoder"``, ``"matching"``, ``"pc_encoder"``, ``"estimation"``...); a stage that ran in
    /// several rounds of the progressive keypoint schedule has the sum of its times.
    #[getter]
    fn timings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        timings_dict(py, &self.result.timings)
    }

    /// The scale the pair was registered at, a dict: ``radius`` (the patch radius), ``rule`` (``"given"`` or how
    /// it was chosen from the two clouds), ``voxel`` (for a cloud without normals; None: every point kept),
    /// ``inlier_threshold`` and ``icp_distance`` (None: ICP off), all in cloud units.
    #[getter]
    fn scale<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = &self.result.scale;
        let d = PyDict::new(py);
        d.set_item("radius", s.radius)?;
        d.set_item("rule", &s.rule)?;
        d.set_item("voxel", s.voxel)?;
        d.set_item("inlier_threshold", s.inlier_threshold)?;
        d.set_item("icp_distance", s.icp_distance)?;
        Ok(d)
    }

    /// The backend (and adapter) that ran the learned stages, e.g. ``"cpu"``.
    #[getter]
    fn backend(&self) -> &str {
        &self.result.backend
    }

    /// Whether the pose can be trusted, judged from its own support (inlier count, inlier ratio, spread) and
    /// its handedness (untrusted when a mirror image fits better).
    #[getter]
    fn success(&self) -> bool {
        self.result.success
    }

    /// Why the pose cannot be trusted; None on success.
    #[getter]
    fn reason(&self) -> Option<&str> {
        self.result.reason.as_deref()
    }

    fn __repr__(&self) -> String {
        let e = &self.result.estimate;
        format!(
            "RegistrationResult(success={}, fitness={:.4}, inliers={}, correspondences={}, inlier_rmse={:.5}, \
             backend='{}')",
            if self.result.success { "True" } else { "False" },
            e.fitness,
            e.inliers,
            self.correspondences.len(),
            e.inlier_rmse,
            self.result.backend
        )
    }

    /// Writes a PNG picture of the registration to ``path``: the top row shows both scans as given, the bottom
    /// row after moving the source by ``target_from_source``; the columns are orthographic views along the
    /// target's principal axes. Source orange, target blue, overlap olive; with ``inliers`` the inlier
    /// correspondences are drawn in the bottom row. Written atomically, never onto an existing input.
    #[pyo3(signature = (path, *, inliers = true))]
    fn snapshot(&self, py: Python<'_>, path: std::path::PathBuf, inliers: bool) -> PyResult<()> {
        let s = &self.snapshot;
        let mut options = SnapshotOptions::default();
        if inliers {
            options.lines = inlier_lines(&self.correspondences, &s.shifted_target_from_source, s.inlier_threshold);
        }
        py.detach(|| write_snapshot(&path, &s.source, &s.target, &s.shifted_target_from_source, &options))
            .map_err(crate::errors::to_py_err)
    }
}

/// A pose estimated from correspondences (``Registrar.estimate``).
#[pyclass(frozen, module = "dpr_gpu")]
pub struct PoseEstimate {
    /// The library's estimate.
    pub(crate) estimate: RustPoseEstimate,
}

#[pymethods]
impl PoseEstimate {
    /// The 4x4 rigid transform (float64) that maps source points into the target frame.
    #[getter]
    fn target_from_source<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        matrix(py, &self.estimate.target_from_source)
    }

    /// Inliers / correspondences under the pose.
    #[getter]
    fn fitness(&self) -> f64 {
        self.estimate.fitness
    }

    /// RMS residual of the inlier correspondences (cloud units).
    #[getter]
    fn inlier_rmse(&self) -> f64 {
        self.estimate.inlier_rmse
    }

    /// Correspondences within the inlier threshold under the pose.
    #[getter]
    fn inliers(&self) -> usize {
        self.estimate.inliers
    }

    /// Pose hypotheses scored by the estimator.
    #[getter]
    fn hypotheses_scored(&self) -> usize {
        self.estimate.hypotheses_scored
    }

    fn __repr__(&self) -> String {
        let e = &self.estimate;
        format!("PoseEstimate(fitness={:.4}, inliers={}, inlier_rmse={:.5})", e.fitness, e.inliers, e.inlier_rmse)
    }
}
