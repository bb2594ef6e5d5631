//! RelativeNet's hypothesize-and-verify: every correspondence gives one full pose (R predicted for it by
//! RelativeNet, t = p_target - R p_source); all are scored in parallel on the backend; the best (most inliers,
//! then smallest residual sum, then lowest index) is refined on its inliers.

use super::refine::refine;
use crate::backend::Backend;
use crate::cpu::score_hypotheses::HypothesisScore;
use crate::error::Result;
use crate::pose::matrix_from_hypothesis;
use crate::settings::PoseEstimate;

/// Index of the best score: most inliers, then smallest residual sum, then lowest index.
pub fn best_hypothesis(scores: &[HypothesisScore]) -> Option<usize> {
    (0..scores.len()).min_by(|&a, &b| {
        let (sa, sb) = (&scores[a], &scores[b]);
        sb.inliers.cmp(&sa.inliers).then(sa.residual_sum.total_cmp(&sb.residual_sum)).then(a.cmp(&b))
    })
}

/// Hypothesize and verify from per-correspondence rotations (row-major, target_from_source).
pub fn verify(
    backend: &dyn Backend,
    rotations: &[[f32; 9]],
    source: &[[f32; 3]],
    target: &[[f32; 3]],
    threshold: f32,
) -> Result<PoseEstimate> {
    let hypotheses = backend.hypotheses(rotations, source, target)?;
    let scores = backend.score_hypotheses(&hypotheses, source, target, threshold)?;
    let best = best_hypothesis(&scores).ok_or_else(|| crate::Error::invalid("no hypotheses to verify"))?;
    Ok(refine(matrix_from_hypothesis(&hypotheses[best]), source, target, threshold, hypotheses.len()))
}
