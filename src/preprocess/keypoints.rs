//! Keypoint selection: seeded random points, or spatially uniform farthest-point sampling.

use crate::cpu::farthest_point::farthest_point;
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
        KeypointMode::Uniform => farthest_point(points, count, rng.below(n)),
    }
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
