//! Refinement shared by both estimators: re-fit on the inliers of a pose until the inlier set stops changing.

use crate::cpu::score_hypotheses::squared_residual;
use crate::pose::{hypothesis_from_matrix, rigid_fit};
use crate::settings::PoseEstimate;
use nalgebra::Matrix4;

/// Upper bound on refit rounds (the inlier set almost always settles in 2-4).
pub const MAX_REFINE_ROUNDS: usize = 30;

/// Indices of correspondences within `threshold` under `pose`.
pub fn inlier_set(pose: &Matrix4<f64>, source: &[[f32; 3]], target: &[[f32; 3]], threshold: f32) -> Vec<usize> {
    let h = hypothesis_from_matrix(pose);
    let t2 = threshold * threshold;
    (0..source.len()).filter(|&i| squared_residual(&h, source[i], target[i]) < t2).collect()
}

/// The estimate of `pose` over the correspondences: inliers, their RMSE, fitness.
pub fn evaluate(
    pose: Matrix4<f64>,
    source: &[[f32; 3]],
    target: &[[f32; 3]],
    threshold: f32,
    hypotheses_scored: usize,
) -> PoseEstimate {
    let h = hypothesis_from_matrix(&pose);
    let inliers = inlier_set(&pose, source, target, threshold);
    let sum: f64 = inliers.iter().map(|&i| squared_residual(&h, source[i], target[i]) as f64).sum();
    PoseEstimate {
        target_from_source: pose,
        inliers: inliers.len(),
        inlier_rmse: if inliers.is_empty() { 0.0 } else { (sum / inliers.len() as f64).sqrt() },
        fitness: if source.is_empty() { 0.0 } else { inliers.len() as f64 / source.len() as f64 },
        hypotheses_scored,
    }
}

/// Least-squares refit on the inliers of `pose`, repeated while the inlier set changes. A refit that would lose
/// inliers is not taken.
pub fn refine(
    pose: Matrix4<f64>,
    source: &[[f32; 3]],
    target: &[[f32; 3]],
    threshold: f32,
    hypotheses_scored: usize,
) -> PoseEstimate {
    let mut current = pose;
    let mut inliers = inlier_set(&current, source, target, threshold);
    for _ in 0..MAX_REFINE_ROUNDS {
        let s: Vec<[f32; 3]> = inliers.iter().map(|&i| source[i]).collect();
        let t: Vec<[f32; 3]> = inliers.iter().map(|&i| target[i]).collect();
        let Some(next) = rigid_fit(&s, &t) else { break };
        let next_inliers = inlier_set(&next, source, target, threshold);
        if next_inliers.len() < inliers.len() {
            break;
        }
        let settled = next_inliers == inliers;
        current = next;
        inliers = next_inliers;
        if settled {
            break;
        }
    }
    evaluate(current, source, target, threshold, hypotheses_scored)
}
