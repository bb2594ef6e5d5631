//! RelativeNet's hypothesize-and-verify: every correspondence gives one full pose (R predicted for it by
//! RelativeNet, t = p_target - R p_source); all are scored in parallel on the backend; the best (most inliers,
//! then smallest residual sum, then lowest index) is refined on its inliers.

use super::refine::refine;
use crate::backend::Backend;
use crate::cpu::score_hypotheses::HypothesisScore;
use crate::error::Result;
use crate::pose::matrix_from_hypothesis;
use crate::settings::PoseEstimate;

/// The order of hypotheses `a` and `b` by their scores, better first: most inliers, then smallest residual sum,
/// then lowest index.
pub fn compare_hypotheses(scores: &[HypothesisScore], a: usize, b: usize) -> std::cmp::Ordering {
    let (sa, sb) = (&scores[a], &scores[b]);
    sb.inliers.cmp(&sa.inliers).then(sa.residual_sum.total_cmp(&sb.residual_sum)).then(a.cmp(&b))
}

/// Index of the best score ([`compare_hypotheses`]).
pub fn best_hypothesis(scores: &[HypothesisScore]) -> Option<usize> {
    (0..scores.len()).min_by(|&a, &b| compare_hypotheses(scores, a, b))
}

/// Each point repeated `candidates` times: the points of the hypotheses when every correspondence has
/// `candidates` consecutive rotations.
pub fn repeat_per_candidate(points: &[[f32; 3]], candidates: usize) -> Vec<[f32; 3]> {
    points.iter().flat_map(|&q| std::iter::repeat_n(q, candidates)).collect()
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
    let hypotheses = hypotheses_of(backend, rotations, source, target, m)?;
    let scores = backend.score_hypotheses(&hypotheses, source, target, threshold)?;
    let best = best_hypothesis(&scores).ok_or_else(|| crate::Error::invalid("no hypotheses to verify"))?;
    Ok(refine(matrix_from_hypothesis(&hypotheses[best]), source, target, threshold, hypotheses.len()))
}

/// One hypothesis per rotation (`candidates` consecutive rotations per correspondence of `source` / `target`).
pub fn hypotheses_of<B: Backend + ?Sized>(
    backend: &B,
    rotations: &[[f32; 9]],
    source: &[[f32; 3]],
    target: &[[f32; 3]],
    candidates: usize,
) -> Result<Vec<crate::cpu::hypotheses::Hypothesis>> {
    if candidates == 1 {
        backend.hypotheses(rotations, source, target)
    } else {
        backend.hypotheses(
            rotations,
            &repeat_per_candidate(source, candidates),
            &repeat_per_candidate(target, candidates),
        )
    }
}
