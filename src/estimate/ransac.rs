//! The paper's baseline: RANSAC over 3-point samples of the same correspondences, with the same scoring and
//! refinement as the RelativeNet verifier.

use super::refine::{evaluate, refine};
use crate::error::{Error, Result};
use crate::pose::rigid_fit;
use crate::rng::Rng;
use crate::settings::{PoseEstimate, RansacSettings};

/// Iterations needed to draw one all-inlier 3-sample with probability `confidence` at inlier ratio `w`.
pub fn required_iterations(confidence: f64, w: f64, max_iterations: usize) -> usize {
    let p_good = w.powi(3);
    if p_good <= 0.0 {
        return max_iterations;
    }
    if p_good >= 1.0 {
        return 1;
    }
    let n = (1.0 - confidence).ln() / (1.0 - p_good).ln();
    if n.is_finite() { (n.ceil() as usize).clamp(1, max_iterations) } else { max_iterations }
}

/// RANSAC: seeded 3-point samples, early exit on confidence, best by (inliers, then lower RMSE).
pub fn ransac(
    source: &[[f32; 3]],
    target: &[[f32; 3]],
    threshold: f32,
    settings: &RansacSettings,
    seed: u64,
) -> Result<PoseEstimate> {
    let n = source.len();
    if n < 3 {
        return Err(Error::invalid(format!("RANSAC needs at least 3 correspondences, got {n}")));
    }
    let mut rng = Rng::new(seed);
    let mut best: Option<PoseEstimate> = None;
    let mut needed = settings.max_iterations;
    let mut iterations = 0;
    while iterations < needed.min(settings.max_iterations) {
        iterations += 1;
        let idx = rng.sample_without_replacement(n, 3);
        let s: Vec<[f32; 3]> = idx.iter().map(|&i| source[i]).collect();
        let t: Vec<[f32; 3]> = idx.iter().map(|&i| target[i]).collect();
        let Some(pose) = rigid_fit(&s, &t) else { continue };
        let candidate = evaluate(pose, source, target, threshold, 0);
        let better = match &best {
            None => true,
            Some(b) => {
                candidate.inliers > b.inliers
                    || (candidate.inliers == b.inliers && candidate.inlier_rmse < b.inlier_rmse)
            }
        };
        if better {
            needed =
                required_iterations(settings.confidence, candidate.inliers as f64 / n as f64, settings.max_iterations);
            best = Some(candidate);
        }
    }
    let best = best.ok_or_else(|| Error::invalid("RANSAC found no non-degenerate sample"))?;
    Ok(refine(best.target_from_source, source, target, threshold, iterations))
}
