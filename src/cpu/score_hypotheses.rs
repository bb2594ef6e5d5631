//! CPU twin of `shaders/score_hypotheses.wgsl`: every hypothesis scored over every correspondence. A
//! correspondence is an inlier when |p_target - (R p_source + t)|^2 < threshold^2.

use super::hypotheses::{Hypothesis, rotate};

/// Support of one hypothesis.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct HypothesisScore {
    /// Correspondences within the threshold.
    pub inliers: u32,
    /// Sum of squared residuals of those inliers.
    pub residual_sum: f32,
}

/// Squared residual of one correspondence under one hypothesis.
pub fn squared_residual(h: &Hypothesis, ps: [f32; 3], pt: [f32; 3]) -> f32 {
    let rp = rotate(&h.rotation, ps);
    let d = [pt[0] - rp[0] - h.translation[0], pt[1] - rp[1] - h.translation[1], pt[2] - rp[2] - h.translation[2]];
    d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
}

/// Scores of all hypotheses.
pub fn score_hypotheses(
    hypotheses: &[Hypothesis],
    source_points: &[[f32; 3]],
    target_points: &[[f32; 3]],
    threshold: f32,
) -> Vec<HypothesisScore> {
    let t2 = threshold * threshold;
    hypotheses
        .iter()
        .map(|h| {
            let mut s = HypothesisScore::default();
            for (&ps, &pt) in source_points.iter().zip(target_points) {
                let r2 = squared_residual(h, ps, pt);
                if r2 < t2 {
                    s.inliers += 1;
                    s.residual_sum += r2;
                }
            }
            s
        })
        .collect()
}
