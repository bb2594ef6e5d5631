//! The paper's baseline: RANSAC over 3-point samples of the same correspondences, with the same scoring and
//! refinement as the RelativeNet verifier.

use super::candidates::same_pose;
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

/// RANSAC: seeded 3-point samples, early exit on confidence, best by (inliers, then lower RMSE), refined on its
/// inliers.
pub fn ransac(
    source: &[[f32; 3]],
    target: &[[f32; 3]],
    threshold: f32,
    settings: &RansacSettings,
    seed: u64,
) -> Result<PoseEstimate> {
    let (best, iterations) = ransac_candidates(source, target, threshold, settings, seed, 1)?;
    Ok(refine(best[0].target_from_source, source, target, threshold, iterations))
}

/// Whether `a` scores better than `b`: more inliers, then lower RMSE.
fn better(a: &PoseEstimate, b: &PoseEstimate) -> bool {
    a.inliers > b.inliers || (a.inliers == b.inliers && a.inlier_rmse < b.inlier_rmse)
}

/// RANSAC's `keep` best distinct sample poses (unrefined, best first; two poses that are one by
/// [`same_pose`] at the inlier threshold count once, the better kept) and the iterations run. The samples
/// and the early exit are those of [`ransac`] (they follow the best pose alone), whose pose is the first of
/// these refined.
pub fn ransac_candidates(
    source: &[[f32; 3]],
    target: &[[f32; 3]],
    threshold: f32,
    settings: &RansacSettings,
    seed: u64,
    keep: usize,
) -> Result<(Vec<PoseEstimate>, usize)> {
    let n = source.len();
    if n < 3 {
        return Err(Error::invalid(format!("RANSAC needs at least 3 correspondences, got {n}")));
    }
    let keep = keep.max(1);
    let mut rng = Rng::new(seed);
    let mut best: Vec<PoseEstimate> = Vec::with_capacity(keep);
    let mut needed = settings.max_iterations;
    let mut iterations = 0;
    while iterations < needed.min(settings.max_iterations) {
        iterations += 1;
        let idx = rng.sample_without_replacement(n, 3);
        let s: Vec<[f32; 3]> = idx.iter().map(|&i| source[i]).collect();
        let t: Vec<[f32; 3]> = idx.iter().map(|&i| target[i]).collect();
        let Some(pose) = rigid_fit(&s, &t) else { continue };
        let candidate = evaluate(pose, source, target, threshold, 0);
        if best.first().is_none_or(|b| better(&candidate, b)) {
            needed =
                required_iterations(settings.confidence, candidate.inliers as f64 / n as f64, settings.max_iterations);
        }
        if best.len() == keep && !better(&candidate, &best[keep - 1]) {
            continue; // not better than any kept pose, so neither than a twin of one
        }
        let twin = (keep > 1)
            .then(|| {
                best.iter()
                    .position(|b| same_pose(&b.target_from_source, &candidate.target_from_source, f64::from(threshold)))
            })
            .flatten();
        match twin {
            Some(i) if better(&candidate, &best[i]) => best[i] = candidate,
            Some(_) => continue,
            None if best.len() < keep => best.push(candidate),
            None => best[keep - 1] = candidate,
        }
        // Stable: equal scores keep their order of arrival.
        best.sort_by(|a, b| b.inliers.cmp(&a.inliers).then(a.inlier_rmse.total_cmp(&b.inlier_rmse)));
    }
    if best.is_empty() {
        return Err(Error::invalid("RANSAC found no non-degenerate sample"));
    }
    Ok((best, iterations))
}
