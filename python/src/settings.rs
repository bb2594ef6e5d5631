//! Registration settings from Python keyword arguments, and back to a dict. The keyword names are the Rust
//! field names of [`RegistrationSettings`], flattened (`ransac.max_iterations` is `ransac_iterations`, the
//! verdict thresholds are top-level, ICP is `icp=True` plus its two parameters).

use crate::errors::value_error;
use dpr_gpu::io::ZeroPoints;
use dpr_gpu::settings::{ContextRadius, ContextWhen};
use dpr_gpu::verdict::VerdictSettings;
use dpr_gpu::{BackendKind, Estimator, IcpSettings, KeypointMode, MatchMode, RansacSettings, RegistrationSettings};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;

/// The library's default context radii as `(factor, weight)` pairs: the default of `context_radii`.
pub(crate) fn default_context_radii() -> Vec<(f32, f32)> {
    dpr_gpu::settings::DEFAULT_CONTEXT_RADII.iter().map(|c| (c.factor, c.weight)).collect()
}

/// The keyword arguments of `Registrar(...)` and `register(...)`, as Python gave them.
pub(crate) struct SettingsArgs {
    pub weights: Option<PathBuf>,
    pub radius: Option<f32>,
    pub voxel: Option<f32>,
    pub keypoints: i64,
    pub first_keypoints: Option<i64>,
    pub keypoint_mode: String,
    pub normal_neighbors: i64,
    pub viewpoint: [f32; 3],
    pub matching: String,
    pub mutual_k: i64,
    pub estimator: String,
    pub inlier_threshold: Option<f32>,
    pub ransac_iterations: i64,
    pub ransac_confidence: f64,
    pub icp: bool,
    pub icp_max_correspondence_distance: Option<f32>,
    pub icp_max_iterations: i64,
    pub drop_zero_points: Option<bool>,
    pub seed: i128,
    pub backend: String,
    pub min_inliers: i64,
    pub min_inlier_ratio: f64,
    pub min_spread_over_threshold: f64,
    pub free_space_check: bool,
    pub context_radii: Vec<(f32, f32)>,
    pub context_when: String,
    pub pose_candidates: i64,
}

/// `value` as a count; negative values are refused naming `name`.
fn count(name: &str, value: i64) -> PyResult<usize> {
    usize::try_from(value).map_err(|_| value_error(format!("{name} must not be negative, got {value}")))
}

/// Parses `value` among the `(name, choice)` pairs; the error lists the names.
pub(crate) fn choose<T: Copy>(setting: &str, value: &str, choices: &[(&str, T)]) -> PyResult<T> {
    choices.iter().find(|(name, _)| *name == value).map(|&(_, choice)| choice).ok_or_else(|| {
        let names = choices.iter().map(|(n, _)| format!("'{n}'")).collect::<Vec<_>>().join(", ");
        value_error(format!("unknown {setting} '{value}' (expected one of {names})"))
    })
}

/// Backend names and kinds.
const BACKENDS: &[(&str, BackendKind)] =
    &[("auto", BackendKind::Auto), ("cpu", BackendKind::Cpu), ("gpu", BackendKind::Gpu)];
/// Estimator names.
pub(crate) const ESTIMATORS: &[(&str, Estimator)] =
    &[("relativenet", Estimator::RelativeNet), ("ransac", Estimator::Ransac)];
/// `context_when` names.
const CONTEXT_WHEN: &[(&str, ContextWhen)] = &[("untrusted", ContextWhen::Untrusted), ("always", ContextWhen::Always)];
/// Keypoint mode names.
const KEYPOINT_MODES: &[(&str, KeypointMode)] = &[("random", KeypointMode::Random), ("uniform", KeypointMode::Uniform)];

/// The Python name of a library value (the inverse of [`choose`]).
pub(crate) fn name_of<T: Copy + PartialEq>(value: T, choices: &[(&'static str, T)]) -> &'static str {
    choices.iter().find(|(_, c)| *c == value).map_or("?", |(n, _)| n)
}

impl SettingsArgs {
    /// The library settings; defaults that follow the radius (ICP distance, voxel, inlier threshold) stay unset
    /// for the library to derive. Bounds are checked later, by the library (`RegistrationSettings::validate`),
    /// so the messages are the library's.
    pub fn to_settings(&self) -> PyResult<RegistrationSettings> {
        let matching = match self.matching.as_str() {
            "mutual" => MatchMode::Mutual(count("mutual_k", self.mutual_k)?),
            "closest" => MatchMode::Closest,
            other => return Err(value_error(format!("unknown matching '{other}' (expected 'mutual' or 'closest')"))),
        };
        let icp = self.icp.then(|| -> PyResult<IcpSettings> {
            Ok(IcpSettings {
                max_correspondence_distance: self.icp_max_correspondence_distance,
                max_iterations: count("icp_max_iterations", self.icp_max_iterations)?,
            })
        });
        Ok(RegistrationSettings {
            weights: self.weights.clone(),
            radius: self.radius,
            voxel: self.voxel,
            keypoints: count("keypoints", self.keypoints)?,
            first_keypoints: self.first_keypoints.map(|k| count("first_keypoints", k)).transpose()?,
            keypoint_mode: choose("keypoint_mode", &self.keypoint_mode, KEYPOINT_MODES)?,
            normal_neighbors: count("normal_neighbors", self.normal_neighbors)?,
            viewpoint: self.viewpoint,
            matching,
            estimator: choose("estimator", &self.estimator, ESTIMATORS)?,
            inlier_threshold: self.inlier_threshold,
            ransac: RansacSettings {
                max_iterations: count("ransac_iterations", self.ransac_iterations)?,
                confidence: self.ransac_confidence,
            },
            icp: icp.transpose()?,
            zero_points: ZeroPoints::from_flag(self.drop_zero_points),
            seed: u64::try_from(self.seed)
                .map_err(|_| value_error(format!("seed must be in 0..=2**64-1, got {}", self.seed)))?,
            backend: choose("backend", &self.backend, BACKENDS)?,
            verdict: VerdictSettings {
                min_inliers: count("min_inliers", self.min_inliers)?,
                min_inlier_ratio: self.min_inlier_ratio,
                min_spread_over_threshold: self.min_spread_over_threshold,
                free_space_check: self.free_space_check,
                ..VerdictSettings::default()
            },
            context_radii: self
                .context_radii
                .iter()
                .map(|&(factor, weight)| ContextRadius { factor, weight })
                .collect(),
            context_when: choose("context_when", &self.context_when, CONTEXT_WHEN)?,
            pose_candidates: count("pose_candidates", self.pose_candidates)?,
        })
    }
}

/// `settings` as a dict keyed by the Python keyword names (ICP off: `icp=False` and the ICP parameters None).
pub(crate) fn settings_dict<'py>(py: Python<'py>, s: &RegistrationSettings) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("weights", s.weights.as_ref().map(|p| p.display().to_string()))?;
    d.set_item("radius", s.radius)?;
    d.set_item("voxel", s.voxel)?;
    d.set_item("keypoints", s.keypoints)?;
    d.set_item("first_keypoints", s.first_keypoints)?;
    d.set_item("keypoint_mode", name_of(s.keypoint_mode, KEYPOINT_MODES))?;
    d.set_item("normal_neighbors", s.normal_neighbors)?;
    d.set_item("viewpoint", (s.viewpoint[0], s.viewpoint[1], s.viewpoint[2]))?;
    let (matching, k) = match s.matching {
        MatchMode::Mutual(k) => ("mutual", k),
        MatchMode::Closest => ("closest", 1),
    };
    d.set_item("matching", matching)?;
    d.set_item("mutual_k", k)?;
    d.set_item("estimator", name_of(s.estimator, ESTIMATORS))?;
    d.set_item("inlier_threshold", s.inlier_threshold)?;
    d.set_item("ransac_iterations", s.ransac.max_iterations)?;
    d.set_item("ransac_confidence", s.ransac.confidence)?;
    d.set_item("icp", s.icp.is_some())?;
    d.set_item("icp_max_correspondence_distance", s.icp.and_then(|i| i.max_correspondence_distance))?;
    d.set_item("icp_max_iterations", s.icp.map(|i| i.max_iterations))?;
    let drop_zero_points = match s.zero_points {
        ZeroPoints::Auto => None,
        ZeroPoints::Drop => Some(true),
        ZeroPoints::Keep => Some(false),
    };
    d.set_item("drop_zero_points", drop_zero_points)?;
    d.set_item("seed", s.seed)?;
    d.set_item("backend", name_of(s.backend, BACKENDS))?;
    d.set_item("min_inliers", s.verdict.min_inliers)?;
    d.set_item("min_inlier_ratio", s.verdict.min_inlier_ratio)?;
    d.set_item("min_spread_over_threshold", s.verdict.min_spread_over_threshold)?;
    d.set_item("free_space_check", s.verdict.free_space_check)?;
    let context: Vec<(f32, f32)> = s.context_radii.iter().map(|c| (c.factor, c.weight)).collect();
    d.set_item("context_radii", context)?;
    d.set_item("context_when", name_of(s.context_when, CONTEXT_WHEN))?;
    d.set_item("pose_candidates", s.pose_candidates)?;
    Ok(d)
}

/// The library's default settings as a dict (for checking that the Python defaults follow them).
#[pyfunction]
pub(crate) fn _library_defaults(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    settings_dict(py, &RegistrationSettings::default())
}
