//! Choosing among an estimator's best distinct poses by free-space consistency.
//!
//! Both estimators rank poses by their inliers among the correspondences. Where repeated or symmetric
//! structure makes wrong correspondences agree with each other (a row of identical desks, a nearly symmetric
//! room), a wrong pose can gather as many inliers as the right one. So each estimator hands over its best few
//! poses; each is refined on its inliers and near-duplicates are merged. The first (the estimator's choice)
//! stays when the verdict trusts its result (the pipeline asks before anything here), or unless another with
//! at least [`MIN_INLIER_SHARE`] of its inliers puts clearly fewer points in space that the other scan saw
//! empty ([`super::visibility`], [`MIN_VIOLATION_DROP`]); then the most consistent of those wins. With one
//! candidate this is the estimator's own choice.

use super::refine::refine;
use super::visibility::PairViews;
use crate::pose::{rotation_error_deg, transform_point, translation_error};
use crate::settings::PoseEstimate;
use nalgebra::Matrix4;

/// A candidate competes with the first only with at least this share of the first's inliers.
pub const MIN_INLIER_SHARE: f64 = 0.5;

/// A candidate also needs a violating share ([`super::visibility::Consistency::violate`], a share of the
/// checked points) at least this much below the first's. Chosen on the repetition tuning set (docs/experiments/pose-candidates.md,
/// "Choosing among the best poses by what both scans saw"): the wrong first poses that were replaced put 8-27 %
/// of the points in seen-empty space, the right first poses that were lost under 5 % (a 180-degree turn of a
/// nearly symmetric room agrees as well as the right pose), so only a clear drop overrides.
pub const MIN_VIOLATION_DROP: f64 = 0.05;

/// Two poses within this rotation angle (degrees) and within the inlier threshold in translation are one.
pub const SAME_POSE_DEG: f64 = 5.0;

/// Whether `a` and `b` are the same pose up to [`SAME_POSE_DEG`] and `distance` (cloud units).
pub fn same_pose(a: &Matrix4<f64>, b: &Matrix4<f64>, distance: f64) -> bool {
    rotation_error_deg(a, b) < SAME_POSE_DEG && translation_error(a, b) < distance
}

/// Each of `poses` (best first) refined on its inliers among the correspondences, dropping those that refine
/// to the same pose as an earlier one. The first is always kept: it is the estimator's own result.
pub fn distinct_refined(
    poses: &[Matrix4<f64>],
    source: &[[f32; 3]],
    target: &[[f32; 3]],
    threshold: f32,
    hypotheses_scored: usize,
) -> Vec<PoseEstimate> {
    let mut out: Vec<PoseEstimate> = Vec::with_capacity(poses.len());
    for pose in poses {
        let estimate = refine(*pose, source, target, threshold, hypotheses_scored);
        let twin =
            out.iter().any(|o| same_pose(&o.target_from_source, &estimate.target_from_source, f64::from(threshold)));
        if !twin {
            out.push(estimate);
        }
    }
    out
}

/// The index of the estimator's choice (0), or of a candidate that puts markedly fewer points in seen-empty
/// space: among the candidates (best first, as [`distinct_refined`] gives them) with at least
/// [`MIN_INLIER_SHARE`] of the first's inliers and a violating share at least [`MIN_VIOLATION_DROP`] below the
/// first's, the one with the highest consistency score ([`PairViews::score`]; ties keep the earlier); 0 when
/// there is none. The pipeline asks only when the verdict does not trust the first.
pub fn choose(candidates: &[PoseEstimate], views: &PairViews<'_>) -> usize {
    let Some(first) = candidates.first() else { return 0 };
    let floor = MIN_INLIER_SHARE * first.inliers as f64;
    let contenders: Vec<usize> = (1..candidates.len()).filter(|&k| candidates[k].inliers as f64 >= floor).collect();
    if contenders.is_empty() {
        return 0;
    }
    let ceiling = views.consistency(&first.target_from_source).violate - MIN_VIOLATION_DROP;
    let mut best: Option<(f64, usize)> = None;
    for k in contenders {
        let c = views.consistency(&candidates[k].target_from_source);
        let score = PairViews::score_of(c);
        if c.violate <= ceiling && best.is_none_or(|(s, _)| score > s) {
            best = Some((score, k));
        }
    }
    best.map_or(0, |(_, k)| k)
}

/// Another candidate explaining at least this share of a pose's inliers makes the pose ambiguous ([`rival`]).
pub const RIVAL_INLIER_SHARE: f64 = 0.7;

/// A rival is another alignment, not the same one refined elsewhere, when it moves the pose's inliers by more
/// than this many inlier thresholds on average: beyond the threshold and ICP's reach (half a threshold), short of
/// the pitch of repeated furniture (4 thresholds and more at the default radius).
pub const RIVAL_MIN_SHIFT_OVER_THRESHOLD: f64 = 3.0;

/// How many of the correspondences (`source[i] -> target[i]`) lie within `threshold` under `pose`.
fn inliers(pose: &Matrix4<f64>, (source, target): (&[[f32; 3]], &[[f32; 3]]), threshold: f32) -> Vec<[f32; 3]> {
    let near = |s: [f32; 3], t: [f32; 3]| {
        let m = transform_point(pose, s);
        (0..3).map(|k| f64::from(m[k] - t[k]).powi(2)).sum::<f64>() < f64::from(threshold).powi(2)
    };
    source.iter().zip(target).filter(|&(&s, &t)| near(s, t)).map(|(&s, _)| s).collect()
}

/// Why `estimate` is ambiguous, or `None`: another of `candidates` (the estimator's distinct poses,
/// [`distinct_refined`]) moves the estimate's inliers by more than [`RIVAL_MIN_SHIFT_OVER_THRESHOLD`] thresholds
/// on average and explains at least [`RIVAL_INLIER_SHARE`] as many of the correspondences within `threshold`:
/// two readings of the correspondences, a turn or a slide apart. At low overlap in repeated structure the
/// correspondences cannot tell two copies apart, and a wrong copy passes every other rule; the right pose of such
/// a pair is then reported untrusted too (docs/experiments/ambiguous-poses.md).
pub fn rival(
    estimate: &PoseEstimate,
    candidates: &[PoseEstimate],
    pair: (&[[f32; 3]], &[[f32; 3]]),
    threshold: f32,
) -> Option<String> {
    let pose = &estimate.target_from_source;
    let own = inliers(pose, pair, threshold);
    let floor = RIVAL_INLIER_SHARE * own.len() as f64;
    let shift = |other: &Matrix4<f64>| {
        let moved = own.iter().map(|&p| {
            let (a, b) = (transform_point(pose, p), transform_point(other, p));
            (0..3).map(|k| f64::from(a[k] - b[k]).powi(2)).sum::<f64>().sqrt()
        });
        moved.sum::<f64>() / own.len().max(1) as f64
    };
    let readings = candidates.iter().filter_map(|c| {
        let moved = shift(&c.target_from_source);
        let count = inliers(&c.target_from_source, pair, threshold).len();
        let far = moved > RIVAL_MIN_SHIFT_OVER_THRESHOLD * f64::from(threshold);
        (far && count > 0 && count as f64 >= floor).then_some((count, moved, c))
    });
    let (count, moved, best) = readings.max_by_key(|(count, _, _)| *count)?;
    Some(format!(
        "ambiguous: another pose, {:.0} degrees away and moving this pose's inliers by {moved:.3} on average, \
         explains {count} correspondences (this pose {}): repeated or symmetric structure the overlap cannot tell \
         apart",
        rotation_error_deg(pose, &best.target_from_source),
        own.len()
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pose::{matrix_from_parts, transform_point};
    use nalgebra::{Matrix3, Rotation3, Vector3};

    #[test]
    fn near_duplicates_merge_and_the_first_stays_first() {
        // 40 correspondences under a known pose, 10 of them consistent with a second pose.
        let truth = matrix_from_parts(
            &Rotation3::from_euler_angles(0.1, 0.4, -0.3).into_inner(),
            &Vector3::new(1.0, -0.5, 0.2),
        );
        let other = matrix_from_parts(&Rotation3::from_euler_angles(0.0, 0.0, 2.0).into_inner(), &Vector3::zeros());
        let source: Vec<[f32; 3]> = (0..40)
            .map(|i| [(i % 5) as f32 * 0.7, (i / 5 % 4) as f32 * 0.9, (i / 20) as f32 * 1.3 + 0.1 * i as f32])
            .collect();
        let target: Vec<[f32; 3]> =
            source.iter().enumerate().map(|(i, &p)| transform_point(if i < 30 { &truth } else { &other }, p)).collect();
        let nudged = matrix_from_parts(&Matrix3::identity(), &Vector3::new(0.01, 0.0, 0.0)) * truth;
        let out = distinct_refined(&[truth, nudged, other], &source, &target, 0.05, 7);
        assert_eq!(out.len(), 2, "the nudged pose refines onto the first");
        assert_eq!((out[0].inliers, out[1].inliers), (30, 10));
        assert!(rotation_error_deg(&out[0].target_from_source, &truth) < 1e-6);
        assert!(rotation_error_deg(&out[1].target_from_source, &other) < 1e-6);
        assert!(out.iter().all(|o| o.hypotheses_scored == 7));
    }

    fn estimate(target_from_source: Matrix4<f64>, inliers: usize) -> PoseEstimate {
        PoseEstimate { target_from_source, inliers, inlier_rmse: 0.01, fitness: 0.1, hypotheses_scored: 1 }
    }

    #[test]
    fn the_pose_consistent_with_both_views_wins_among_those_with_enough_inliers() {
        // One room scanned from two sensors; the wrong pose is the true one shifted by 0.8 m (a desk's pitch).
        let world = crate::synth::geometry::box_room_grid([3.0, 2.0, 1.5], 0.02);
        let truth =
            matrix_from_parts(&Rotation3::from_euler_angles(0.0, 0.1, 2.0).into_inner(), &Vector3::new(0.3, 0.2, 0.0));
        let target_from_world = matrix_from_parts(&Matrix3::identity(), &Vector3::new(-0.4, 0.1, 0.2));
        let source_from_world = crate::pose::rigid_inverse(&truth) * target_from_world;
        let source: Vec<[f32; 3]> = world.iter().map(|&p| transform_point(&source_from_world, p)).collect();
        let target: Vec<[f32; 3]> = world.iter().map(|&p| transform_point(&target_from_world, p)).collect();
        let wrong = matrix_from_parts(&Matrix3::identity(), &Vector3::new(0.8, 0.0, 0.0)) * truth;
        let views = PairViews::new((&source, [0.0; 3]), (&target, [0.0; 3]), 0.1);
        let pick = |candidates: Vec<PoseEstimate>| candidates[choose(&candidates, &views)].target_from_source;

        assert_eq!(pick(vec![estimate(wrong, 20), estimate(truth, 10)]), truth, "half the inliers is enough");
        assert_eq!(pick(vec![estimate(wrong, 20), estimate(truth, 9)]), wrong, "under half the inliers is not");
        assert_eq!(pick(vec![estimate(truth, 20), estimate(wrong, 20)]), truth);
        // A first pose 4 cm off violates no more than the truth by the margin: it stays.
        let near = matrix_from_parts(&Matrix3::identity(), &Vector3::new(0.04, 0.0, 0.0)) * truth;
        assert_eq!(pick(vec![estimate(near, 20), estimate(truth, 20)]), near, "no clear drop, no override");
        assert_eq!(pick(vec![estimate(wrong, 20)]), wrong, "one candidate: the estimator's choice");
        assert_eq!(choose(&[], &views), 0);
    }

    #[test]
    fn another_reading_of_the_correspondences_a_slide_away_is_a_rival() {
        // 20 correspondences fit the truth, 14 others (70 %) a pose `other`, 6 more neither; threshold 0.05.
        let truth =
            matrix_from_parts(&Rotation3::from_euler_angles(0.0, 0.1, 2.0).into_inner(), &Vector3::new(0.3, 0.2, 0.0));
        let slid = |metres: f64| matrix_from_parts(&Matrix3::identity(), &Vector3::new(metres, 0.0, 0.0)) * truth;
        let nowhere = Matrix4::zeros();
        let source: Vec<[f32; 3]> =
            (0..40).map(|i| [(i % 5) as f32 * 0.3, (i / 5 % 4) as f32 * 0.3, (i / 20) as f32 * 0.3]).collect();
        let target_with = |other: &Matrix4<f64>, others: usize| -> Vec<[f32; 3]> {
            let under = |i: usize| {
                if i < 20 {
                    &truth
                } else if i < 20 + others {
                    other
                } else {
                    &nowhere
                }
            };
            source.iter().enumerate().map(|(i, &p)| transform_point(under(i), p)).collect()
        };
        let pose = estimate(truth, 20);
        let slide = slid(0.8);
        let target = target_with(&slide, 14);
        let reason = rival(&pose, &[pose.clone(), estimate(slide, 14)], (&source, &target), 0.05);
        assert!(
            reason.is_some_and(|r| r.starts_with("ambiguous") && r.contains("explains 14")),
            "a slide of 16 thresholds"
        );
        // The slide judged against the truth: the truth is its rival.
        assert!(rival(&estimate(slide, 14), &[pose.clone()], (&source, &target), 0.05).is_some());
        // 13 are under 70 %.
        let target = target_with(&slide, 13);
        assert_eq!(rival(&pose, &[estimate(slide, 13)], (&source, &target), 0.05), None);
        // 2 thresholds away is the same alignment refined elsewhere, 4 another.
        let target = target_with(&slid(0.1), 14);
        assert_eq!(rival(&pose, &[estimate(slid(0.1), 14)], (&source, &target), 0.05), None);
        let target = target_with(&slid(0.2), 14);
        assert!(rival(&pose, &[estimate(slid(0.2), 14)], (&source, &target), 0.05).is_some());
    }
}
