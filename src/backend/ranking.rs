//! Ranking RelativeNet's pose hypotheses, shared by every backend's verify step: every correspondence gives
//! one full pose per rotation candidate (R predicted for it by RelativeNet, t = p_target - R p_source); all are
//! scored, and the best is the one with the most inliers, then the smallest residual sum, then the lowest index.

use super::Backend;
use crate::cpu::hypotheses::Hypothesis;
use crate::cpu::score_hypotheses::HypothesisScore;
use crate::error::Result;

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

/// One hypothesis per rotation (`candidates` consecutive rotations per correspondence of `source` / `target`).
pub async fn hypotheses_of<B: Backend + ?Sized>(
    backend: &B,
    rotations: &[[f32; 9]],
    source: &[[f32; 3]],
    target: &[[f32; 3]],
    candidates: usize,
) -> Result<Vec<Hypothesis>> {
    if candidates == 1 {
        backend.hypotheses(rotations, source, target).await
    } else {
        backend
            .hypotheses(rotations, &repeat_per_candidate(source, candidates), &repeat_per_candidate(target, candidates))
            .await
    }
}
