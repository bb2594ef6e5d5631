//! Evaluating a trajectory against ground truth: absolute trajectory error after the best rigid alignment,
//! rotation errors, which loop closures were true and which were kept, and pairwise relative-pose errors.

use crate::error::{Error, Result};
use crate::eval::gtlog::LogRecord;
use crate::eval::metrics::information_error;
use crate::pose::inverse;
use crate::pose::{nearest_rotation, rigid_fit_f64, rotation_error_deg, translation_error};
use nalgebra::{Matrix3, Matrix4, Matrix6, Vector3};
use serde::Serialize;

use super::trajectory::Trajectory;

/// The 3DMatch criterion: a relative pose is correct when eᵀΣe / Σ(0,0) (about the mean squared displacement of
/// the overlap's points) is at most 0.2² (cloud units squared).
pub const REGISTERED_MAX_INFORMATION_ERROR: f64 = 0.04;
/// Without an information i_from_j: a relative pose is correct within this rotation error (degrees)...
pub const REGISTERED_MAX_ROTATION_DEG: f64 = 15.0;
/// ... and this translation error (cloud units).
pub const REGISTERED_MAX_TRANSLATION: f64 = 0.3;

/// How the estimated trajectory was aligned to the ground truth.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Alignment {
    /// The rigid transform minimising the squared distances of the scan origins (Kabsch / Umeyama, no scale).
    Kabsch,
    /// The first scans' poses made equal (fewer than three scans, or origins on a line).
    FirstScan,
}

/// Absolute trajectory errors.
#[derive(Clone, Debug, Serialize)]
pub struct TrajectoryErrors {
    /// Scans compared.
    pub scans: usize,
    /// Root mean square distance of the aligned scan origins from the true ones (cloud units).
    pub ate_rmse: f64,
    /// Largest such distance.
    pub ate_max: f64,
    /// Mean rotation error (degrees) after the best rotation alignment of the orientations alone (the chordal
    /// mean of R_gt R_estᵀ), which stays well defined when the scan origins lie nearly on a line.
    pub rotation_mean_deg: f64,
    /// Largest rotation error (degrees).
    pub rotation_max_deg: f64,
    /// How the trajectories were aligned.
    pub alignment: Alignment,
}

fn origin(m: &Matrix4<f64>) -> Vector3<f64> {
    m.fixed_view::<3, 1>(0, 3).into_owned()
}

/// ATE and rotation errors of `estimate` against `truth` (same scan count) after aligning `estimate` rigidly.
pub fn trajectory_errors(estimate: &Trajectory, truth: &Trajectory) -> Result<TrajectoryErrors> {
    if estimate.len() != truth.len() || estimate.is_empty() {
        return Err(Error::invalid(format!(
            "the trajectory has {} scans and the ground truth {}; they must match (and be at least 1)",
            estimate.len(),
            truth.len()
        )));
    }
    let est: Vec<Vector3<f64>> = estimate.world_from_scan.iter().map(origin).collect();
    let gt: Vec<Vector3<f64>> = truth.world_from_scan.iter().map(origin).collect();
    let (truth_from_estimate, alignment) = match rigid_fit_f64(&est, &gt) {
        Some(a) => (a, Alignment::Kabsch),
        None => (truth.world_from_scan[0] * inverse(&estimate.world_from_scan[0]), Alignment::FirstScan),
    };
    let rotation = |m: &Matrix4<f64>| m.fixed_view::<3, 3>(0, 0).into_owned();
    let chordal: Matrix3<f64> = estimate
        .world_from_scan
        .iter()
        .zip(&truth.world_from_scan)
        .map(|(e, g)| rotation(g) * rotation(e).transpose())
        .sum();
    let rotation_alignment = crate::pose::matrix_from_parts(&nearest_rotation(&chordal), &Vector3::zeros());
    let mut sum_sq = 0.0;
    let (mut ate_max, mut rot_sum, mut rot_max) = (0.0f64, 0.0, 0.0f64);
    for (e, g) in estimate.world_from_scan.iter().zip(&truth.world_from_scan) {
        let d = translation_error(&(truth_from_estimate * e), g);
        sum_sq += d * d;
        ate_max = ate_max.max(d);
        let r = rotation_error_deg(&(rotation_alignment * e), g);
        rot_sum += r;
        rot_max = rot_max.max(r);
    }
    let n = estimate.len() as f64;
    Ok(TrajectoryErrors {
        scans: estimate.len(),
        ate_rmse: (sum_sq / n).sqrt(),
        ate_max,
        rotation_mean_deg: rot_sum / n,
        rotation_max_deg: rot_max,
        alignment,
    })
}

/// Whether an estimated relative pose is within the 3DMatch criterion of the true one: with a usable information
/// matrix (Σ(0,0) > 0) the information error is at most [`REGISTERED_MAX_INFORMATION_ERROR`]; without one, the
/// rotation and translation errors are within [`REGISTERED_MAX_ROTATION_DEG`] and
/// [`REGISTERED_MAX_TRANSLATION`]. Also returns the information error when it was used.
pub fn is_correct(
    estimate: &Matrix4<f64>,
    truth: &Matrix4<f64>,
    information: Option<&Matrix6<f64>>,
) -> (bool, Option<f64>) {
    match information.filter(|s| s[(0, 0)] > 0.0) {
        Some(s) => {
            let err = information_error(truth, estimate, s);
            (err <= REGISTERED_MAX_INFORMATION_ERROR, Some(err))
        }
        None => (
            rotation_error_deg(estimate, truth) <= REGISTERED_MAX_ROTATION_DEG
                && translation_error(estimate, truth) <= REGISTERED_MAX_TRANSLATION,
            None,
        ),
    }
}

/// Loop-closure counts: how many candidates were true and false, and how many of each the optimisation kept.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct LoopClosureCounts {
    /// Loop-closure candidates whose estimate is correct.
    pub true_total: usize,
    /// Of those, kept (in the graph and surviving the line processes).
    pub true_kept: usize,
    /// Loop-closure candidates whose estimate is wrong.
    pub false_total: usize,
    /// Of those, kept: each one bends the trajectory.
    pub false_kept: usize,
}

impl LoopClosureCounts {
    /// Adds one candidate.
    pub fn add(&mut self, correct: bool, kept: bool) {
        if correct {
            self.true_total += 1;
            self.true_kept += usize::from(kept);
        } else {
            self.false_total += 1;
            self.false_kept += usize::from(kept);
        }
    }
}

/// The error of one relative pose against ground truth.
#[derive(Clone, Debug, Serialize)]
pub struct PairError {
    /// Target scan (ground-truth numbering).
    pub i: usize,
    /// Source scan (ground-truth numbering).
    pub j: usize,
    /// Rotation error of the trajectory's relative pose (degrees).
    pub rotation_deg: f64,
    /// Translation error of the trajectory's relative pose (cloud units).
    pub translation: f64,
    /// Whether it meets the criterion of [`is_correct`].
    pub correct: bool,
}

/// The trajectory's relative poses against the pairs of a pairwise ground-truth log. `ids[k]` is the
/// ground-truth fragment number of trajectory scan k; pairs naming a fragment outside `ids` are skipped.
/// `information` looks up a pair's gt.info matrix.
pub fn pairwise_errors(
    estimate: &Trajectory,
    truth: &[LogRecord],
    ids: &[usize],
    information: &dyn Fn(usize, usize) -> Option<Matrix6<f64>>,
) -> Vec<PairError> {
    let scan_of = |id: usize| ids.iter().position(|&x| x == id);
    truth
        .iter()
        .filter_map(|r| {
            let (a, b) = (scan_of(r.i)?, scan_of(r.j)?);
            if a >= estimate.len() || b >= estimate.len() {
                return None;
            }
            let t = estimate.i_from_j(a, b);
            let (correct, _) = is_correct(&t, &r.i_from_j, information(r.i, r.j).as_ref());
            Some(PairError {
                i: r.i,
                j: r.j,
                rotation_deg: rotation_error_deg(&t, &r.i_from_j),
                translation: translation_error(&t, &r.i_from_j),
                correct,
            })
        })
        .collect()
}
