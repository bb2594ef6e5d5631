//! Keypoint selection: seeded random points, or spatially uniform farthest-point sampling.

use crate::rng::Rng;
use crate::settings::KeypointMode;

/// Indices of `count` keypoints among `points` (all points when `count >= points.len()`).
pub fn select_keypoints(points: &[[f32; 3]], count: usize, mode: KeypointMode, rng: &mut Rng) -> Vec<usize> {
    let n = points.len();
    if count >= n {
        return (0..n).collect();
    }
    match mode {
        KeypointMode::Random => rng.sample_without_replacement(n, count),
        KeypointMode::Uniform => farthest_point_sampling(points, count, rng.below(n)),
    }
}

/// Greedy farthest-point sampling from `start`; ties go to the lower index.
fn farthest_point_sampling(points: &[[f32; 3]], count: usize, start: usize) -> Vec<usize> {
    let d2 = |a: &[f32; 3], b: &[f32; 3]| (0..3).map(|i| (a[i] - b[i]) * (a[i] - b[i])).sum::<f32>();
    let mut nearest = vec![f32::INFINITY; points.len()];
    let mut chosen = Vec::with_capacity(count);
    let mut current = start;
    for _ in 0..count {
        chosen.push(current);
        let c = points[current];
        let mut best = (0, -1.0f32);
        for (i, p) in points.iter().enumerate() {
            let d = d2(p, &c).min(nearest[i]);
            nearest[i] = d;
            if d > best.1 {
                best = (i, d);
            }
        }
        current = best.0;
    }
    chosen
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn random_is_seeded_and_distinct_and_uniform_spreads_out() {
        let pts: Vec<[f32; 3]> = (0..100).map(|i| [i as f32, 0.0, 0.0]).collect();
        let a = select_keypoints(&pts, 10, KeypointMode::Random, &mut Rng::new(1));
        assert_eq!(a, select_keypoints(&pts, 10, KeypointMode::Random, &mut Rng::new(1)));
        let mut s = a.clone();
        s.sort_unstable();
        s.dedup();
        assert_eq!(s.len(), 10);
        let u = select_keypoints(&pts, 3, KeypointMode::Uniform, &mut Rng::new(1));
        assert!(u.contains(&0) || u.contains(&99), "{u:?}");
        assert_eq!(select_keypoints(&pts, 500, KeypointMode::Random, &mut Rng::new(1)).len(), 100);
    }
}
