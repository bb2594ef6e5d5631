//! RelativeNet's hypothesize-and-verify: every correspondence gives one full pose (R predicted for it by
//! RelativeNet, t = p_target - R p_source); all are scored in parallel on the backend; the best (most inliers,
//! then smallest residual sum, then lowest index) is refined on its inliers.

use super::refine::refine;
use crate::backend::{Backend, Verified};
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

/// Hypothesize and verify from per-correspondence rotations (row-major, target_from_source): `rotations` holds
/// `m` consecutive candidates per correspondence (m = 1 but for the angle-bin head), each one hypothesis; all
/// are scored over the correspondences.
pub fn verify(
    backend: &dyn Backend,
    rotations: &[[f32; 9]],
    source: &[[f32; 3]],
    target: &[[f32; 3]],
    threshold: f32,
) -> Result<PoseEstimate> {
    if source.is_empty() || source.len() != target.len() || !rotations.len().is_multiple_of(source.len()) {
        return Err(crate::Error::invalid(format!(
            "verify: {} rotations for {} source and {} target points",
            rotations.len(),
            source.len(),
            target.len()
        )));
    }
    let m = rotations.len() / source.len();
    let repeat = |p: &[[f32; 3]]| p.iter().flat_map(|&q| std::iter::repeat_n(q, m)).collect::<Vec<_>>();
    let hypotheses = if m == 1 {
        backend.hypotheses(rotations, source, target)?
    } else {
        backend.hypotheses(rotations, &repeat(source), &repeat(target))?
    };
    let scores = backend.score_hypotheses(&hypotheses, source, target, threshold)?;
    let best = best_hypothesis(&scores).ok_or_else(|| crate::Error::invalid("no hypotheses to verify"))?;
    Ok(refine(matrix_from_hypothesis(&hypotheses[best]), source, target, threshold, hypotheses.len()))
}

/// The pose of [`Backend::verify`]'s best hypothesis, refined on its inliers among the correspondences
/// (`source`, `target`: the matched keypoints).
pub fn refine_best(
    verified: &Verified,
    source: &[[f32; 3]],
    target: &[[f32; 3]],
    threshold: f32,
) -> Result<PoseEstimate> {
    let best = verified.best.first().ok_or_else(|| crate::Error::invalid("no hypotheses to verify"))?;
    Ok(refine(matrix_from_hypothesis(&best.hypothesis), source, target, threshold, verified.hypotheses))
}
