//! The handedness check: is one scan a mirror image of the other? No rigid motion aligns a reflection, yet the
//! point pair features are blind to it (distances and angles survive a mirror), so a mirrored scan still finds
//! correspondences, and some motion among them may gather enough inliers to pass the other rules.
//!
//! Seeded 3-point samples of the correspondences, each fitted as a reflection (det -1), give the reflection
//! that explains most correspondences. A mirror-symmetric object (the Stanford bunny seen
//! from above, a yard of boxes) makes left-right twins agree as a reflection too, and a reflection can lay a
//! part of the source the target never saw onto its symmetric twin, so neither the inlier counts nor one
//! overlap share tells them apart. So the pose is untrusted only when that reflection explains more
//! correspondences than the pose does and, refined on the clouds by the same point-to-point ICP as the pose
//! (each keeping its handedness), lays more of the source on the target at every distance from half the voxel
//! pitch to twice the inlier threshold: the true alignment of a mirrored scan coincides with the target and
//! covers its overlap, a symmetric twin at best one of the two. The count comes first because at low overlap
//! in a mirror-symmetric room a reflection can lay more of the source on the target than the true pose (whose
//! overlap is small), while the correspondences still favour the pose. docs/experiments/mirrored-scans.md has
//! the measurements.

use crate::estimate::required_iterations;
use crate::pose::{reflection_fit_f64, rigid_fit_f64, transform_point, v3};
use crate::result::{Correspondence, PoseEstimate};
use crate::rng::Rng;
use crate::spatial::PointIndex;
use nalgebra::{Matrix4, Vector3};

/// Source points (evenly strided) the dense comparison moves.
const MAX_DENSE_POINTS: usize = 5000;
/// Point-to-point ICP iterations of the dense comparison, for each handedness.
const DENSE_ITERATIONS: usize = 10;
/// The distances, as shares of the inlier threshold, at which the shares of the source on the target are
/// compared: from half the default voxel pitch (radius / 24; surfaces that coincide) to twice the threshold
/// (the overlap).
const ON_TARGET_OVER_THRESHOLD: [f32; 5] = [0.125, 0.25, 0.5, 1.0, 2.0];
/// The random stream of the samples under the registration's seed.
const REFLECTION_STREAM: u64 = 0x6d69_7272_6f72; // "mirror"

/// Why `estimate` is untrusted for a mirror image of the scans, or `None` (also when no sample fits a
/// reflection). `source_points` and `target_points` are the preprocessed clouds the correspondences' points
/// come from; `threshold` the inlier threshold; `max_draws` and `seed` as for [`sample`].
pub fn mirror_image(
    estimate: &PoseEstimate,
    correspondences: &[Correspondence],
    (source_points, target_points): (&[[f32; 3]], &[[f32; 3]]),
    threshold: f32,
    max_draws: usize,
    seed: u64,
) -> Option<String> {
    let (source, target): (Vec<_>, Vec<_>) =
        correspondences.iter().map(|c| (v3(c.source_point), v3(c.target_point))).unzip();
    let pose_inliers = estimate.inliers.min(source.len());
    let (explained, reflection) =
        best_reflection(&source, &target, f64::from(threshold), pose_inliers, max_draws, seed)?;
    if explained <= pose_inliers {
        // Point pair features cannot tell a part from its mirror twin, so in a mirror-symmetric scene some
        // correspondences pair twins, and a reflection can lay more of a low-overlap source on the target than
        // the true pose. A mirrored scan's correspondences are explained by the reflection first.
        return None;
    }
    let target_index = PointIndex::new(target_points).ok()?;
    let stride = source_points.len().div_ceil(MAX_DENSE_POINTS).max(1);
    let moved: Vec<[f32; 3]> = source_points.iter().step_by(stride).copied().collect();
    let on_target = |start: &Matrix4<f64>, fit: Fit| {
        let pose = refine_on_clouds(start, fit, &moved, (target_points, &target_index), threshold);
        ON_TARGET_OVER_THRESHOLD.map(|k| share_within(&pose, &moved, &target_index, k * threshold))
    };
    let motion = on_target(&estimate.target_from_source, rigid_fit_f64);
    let mirror = on_target(&reflection, reflection_fit_f64);
    let dominates = motion.iter().zip(&mirror).all(|(pose, reflected)| reflected > pose);
    dominates.then(|| {
        format!(
            "mirror image: a reflection lays more of the source on the target than the pose at every distance from \
             1/8 to 2 inlier thresholds ({:.0} % against {:.0} % within 1/8; it explains {explained} \
             correspondences, the pose {pose_inliers}): is one scan mirrored, an axis flipped?",
            100.0 * mirror[0],
            100.0 * motion[0],
        )
    })
}

/// The reflection explaining most correspondences `source[i] -> target[i]` (within `threshold`) among seeded
/// 3-point samples, with that count, refitted on the correspondences it explains; `None` when no sample fits
/// (fewer than 3 correspondences, `max_draws` 0, or all collinear). As many samples as find, with 99 %
/// confidence, a reflection explaining more than the pose's `pose_inliers`, at most `max_draws`.
pub fn best_reflection(
    source: &[Vector3<f64>],
    target: &[Vector3<f64>],
    threshold: f64,
    pose_inliers: usize,
    max_draws: usize,
    seed: u64,
) -> Option<(usize, Matrix4<f64>)> {
    let n = source.len().min(target.len());
    if n < 3 || max_draws == 0 {
        return None;
    }
    let inliers = |m: &Matrix4<f64>| -> Vec<usize> {
        let (r, t) = (m.fixed_view::<3, 3>(0, 0), m.fixed_view::<3, 1>(0, 3));
        (0..n).filter(|&i| (r * source[i] + t - target[i]).norm() < threshold).collect()
    };
    let draws = required_iterations(0.99, (pose_inliers + 1).min(n) as f64 / n as f64, max_draws);
    let mut rng = Rng::derived(seed, REFLECTION_STREAM);
    let mut best: Option<(usize, Matrix4<f64>)> = None;
    for _ in 0..draws {
        let idx = rng.sample_without_replacement(n, 3);
        let s: Vec<_> = idx.iter().map(|&i| source[i]).collect();
        let t: Vec<_> = idx.iter().map(|&i| target[i]).collect();
        let Some(m) = reflection_fit_f64(&s, &t) else { continue };
        let count = inliers(&m).len();
        if best.is_none_or(|(most, _)| count > most) {
            best = Some((count, m));
        }
    }
    best.map(|(count, m)| {
        let (s, t): (Vec<_>, Vec<_>) = inliers(&m).iter().map(|&i| (source[i], target[i])).unzip();
        (count, reflection_fit_f64(&s, &t).unwrap_or(m))
    })
}

/// A least-squares fit of one handedness ([`rigid_fit_f64`] or [`reflection_fit_f64`]).
type Fit = fn(&[Vector3<f64>], &[Vector3<f64>]) -> Option<Matrix4<f64>>;

/// Point-to-point ICP from `start` with `fit` (so keeping its handedness): each iteration pairs the moved
/// `points` with their nearest target point within `threshold` and refits.
fn refine_on_clouds(
    start: &Matrix4<f64>,
    fit: Fit,
    points: &[[f32; 3]],
    (target_points, target): (&[[f32; 3]], &PointIndex),
    threshold: f32,
) -> Matrix4<f64> {
    let mut pose = *start;
    for _ in 0..DENSE_ITERATIONS {
        let (s, t): (Vec<_>, Vec<_>) = points
            .iter()
            .filter_map(|&p| {
                let n = target.nearest_one(&transform_point(&pose, p));
                (n.distance_squared < threshold * threshold).then(|| (v3(p), v3(target_points[n.index])))
            })
            .unzip();
        match fit(&s, &t) {
            Some(next) => pose = next,
            None => break,
        }
    }
    pose
}

/// The share of `points` that `pose` brings within `distance` of the target.
fn share_within(pose: &Matrix4<f64>, points: &[[f32; 3]], target: &PointIndex, distance: f32) -> f64 {
    let near = points
        .iter()
        .filter(|&&p| target.nearest_one(&transform_point(pose, p)).distance_squared < distance * distance)
        .count();
    near as f64 / points.len().max(1) as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix4;

    /// A grid of points (pitch 0.05) on a 2 x 2 floor, a wall at x = -1 and, when `symmetric`, its mirror twin
    /// at x = +1, and a box (0.4 wide, 0.3 high) off the centre line at x = 0.5.
    fn scene(symmetric: bool) -> Vec<[f32; 3]> {
        let steps = |lo: f32, hi: f32| (0..=((hi - lo) / 0.05).round() as i32).map(move |i| lo + 0.05 * i as f32);
        let mut p: Vec<[f32; 3]> = steps(-1.0, 1.0).flat_map(|x| steps(-1.0, 1.0).map(move |y| [x, y, 0.0])).collect();
        let walls: &[f32] = if symmetric { &[-1.0, 1.0] } else { &[-1.0] };
        for &x in walls {
            p.extend(steps(-1.0, 1.0).flat_map(|y| steps(0.05, 1.0).map(move |z| [x, y, z])));
        }
        p.extend(steps(0.3, 0.7).flat_map(|x| steps(-0.2, 0.2).map(move |y| [x, y, 0.3])));
        p.extend(steps(-0.2, 0.2).flat_map(|y| steps(0.05, 0.25).map(move |z| [0.3, y, z])));
        p
    }

    fn mirrored(p: [f32; 3]) -> [f32; 3] {
        [-p[0], p[1], p[2]]
    }

    /// `moved` correspondences related by the identity and `mirror` by x -> -x, each spread evenly over the
    /// points.
    fn correspondences(source: &[[f32; 3]], moved: usize, mirror: usize) -> Vec<Correspondence> {
        let pair = |(i, s): (usize, [f32; 3]), t: [f32; 3]| Correspondence {
            source_index: i as u32,
            target_index: i as u32,
            source_point: s,
            target_point: t,
            feature_distance: 0.0,
        };
        let same = source.iter().copied().enumerate().step_by(source.len() / moved).take(moved);
        let twins = source.iter().copied().enumerate().skip(3).step_by(source.len() / mirror).take(mirror);
        same.map(|(i, s)| pair((i, s), s)).chain(twins.map(|(i, s)| pair((i, s), mirrored(s)))).collect()
    }

    fn identity(inliers: usize) -> PoseEstimate {
        PoseEstimate {
            target_from_source: Matrix4::identity(),
            inliers,
            inlier_rmse: 0.0,
            fitness: 1.0,
            hypotheses_scored: 1,
        }
    }

    #[test]
    fn a_mirrored_scan_is_a_mirror_image() {
        // The source is the target mirrored; the pose (identity) explains 30 correspondences, the true
        // reflection 80, and it lays all of the source on the target where the identity lays the floor.
        let target = scene(false);
        let source: Vec<[f32; 3]> = target.iter().map(|&p| mirrored(p)).collect();
        let c = correspondences(&source, 30, 80);
        let reason = mirror_image(&identity(30), &c, (&source, &target), 0.1, 20_000, 0);
        assert!(reason.as_deref().is_some_and(|r| r.starts_with("mirror image")), "{reason:?}");
        // The same seed gives the same answer; no draws, no check.
        assert_eq!(mirror_image(&identity(30), &c, (&source, &target), 0.1, 20_000, 0), reason);
        assert_eq!(mirror_image(&identity(30), &c, (&source, &target), 0.1, 0, 0), None);
    }

    #[test]
    fn a_reflection_fewer_correspondences_support_than_the_pose_is_not_a_mirror_image() {
        // The clouds of the mirrored-scan case, where the reflection lays all of the source on the target, but
        // 80 correspondences support the pose and 30 the reflection (a low-overlap pair in a mirror-symmetric
        // room: the twins' share of the clouds may favour the reflection, the correspondences do not).
        let target = scene(false);
        let source: Vec<[f32; 3]> = target.iter().map(|&p| mirrored(p)).collect();
        let c = correspondences(&source, 80, 30);
        assert_eq!(mirror_image(&identity(80), &c, (&source, &target), 0.1, 20_000, 0), None);
        // With the counts the other way round the same clouds are a mirror image.
        let c = correspondences(&source, 30, 80);
        assert!(mirror_image(&identity(30), &c, (&source, &target), 0.1, 20_000, 0).is_some());
    }

    #[test]
    fn a_symmetric_object_is_not_a_mirror_image() {
        // The source is the target (the pose, identity, is right), but the scene is mirror-symmetric except for
        // the box: left-right twins make a reflection explain 80 correspondences against the pose's 30, yet on
        // the clouds the reflection leaves the box off the target and the pose does not.
        let target = scene(true);
        let c = correspondences(&target, 30, 80);
        let (explained, _) = best_reflection(
            &c.iter().map(|c| v3(c.source_point)).collect::<Vec<_>>(),
            &c.iter().map(|c| v3(c.target_point)).collect::<Vec<_>>(),
            0.1,
            30,
            20_000,
            0,
        )
        .unwrap();
        assert!(explained >= 80, "the reflection explains {explained}, the pose 30");
        assert_eq!(mirror_image(&identity(30), &c, (&target, &target), 0.1, 20_000, 0), None);
    }

    #[test]
    fn a_planar_scene_is_not_a_mirror_image() {
        // Every reflection across the plane has a motion twin: the twins (x -> -x) make a reflection explain all
        // 50 correspondences and the pose (identity) none, yet on the clouds both lay the whole source on the
        // target, so the reflection is not ahead at every distance.
        let plane: Vec<[f32; 3]> = (0..50).map(|i| [(i % 10) as f32 * 0.1, (i / 10) as f32 * 0.1, 0.0]).collect();
        let twins: Vec<Correspondence> = plane
            .iter()
            .enumerate()
            .map(|(i, &p)| Correspondence {
                source_index: i as u32,
                target_index: i as u32,
                source_point: p,
                target_point: mirrored(p),
                feature_distance: 0.0,
            })
            .collect();
        let (source, target): (Vec<_>, Vec<_>) = plane.iter().map(|&p| (v3(p), v3(mirrored(p)))).unzip();
        assert_eq!(best_reflection(&source, &target, 0.01, 0, 500, 1).map(|(n, _)| n), Some(50));
        let mirrored_plane: Vec<[f32; 3]> = plane.iter().map(|&p| mirrored(p)).collect();
        let both: Vec<[f32; 3]> = plane.iter().chain(&mirrored_plane).copied().collect();
        assert_eq!(mirror_image(&identity(0), &twins, (&both, &both), 0.01, 500, 1), None);
    }
}
