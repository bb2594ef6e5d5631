//! Local patches: the points within radius r of each keypoint (the keypoint itself excluded), N sampled
//! without replacement when there are enough, with replacement otherwise.

use crate::rng::Rng;
use crate::spatial::PointIndex;
use rayon::prelude::*;

/// Sampled neighbourhoods of the keypoints that have at least one neighbour.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Patches {
    /// Cloud index of each kept keypoint.
    pub keypoints: Vec<usize>,
    /// `keypoints.len() x points_per_patch` cloud indices of the sampled neighbours.
    pub neighbors: Vec<u32>,
    /// N.
    pub points_per_patch: usize,
    /// Keypoints dropped because no other point lies within the radius.
    pub empty: Vec<usize>,
}

/// Gathers and samples one patch per keypoint. Patch `i` uses its own random stream derived from `seed` and
/// the keypoint's cloud index, so the result does not depend on thread scheduling.
pub fn extract_patches(
    points: &[[f32; 3]],
    index: &PointIndex,
    keypoints: &[usize],
    radius: f32,
    points_per_patch: usize,
    seed: u64,
) -> Patches {
    let sampled: Vec<Option<Vec<u32>>> = keypoints
        .par_iter()
        .map(|&k| {
            let candidates: Vec<u32> =
                index.within(&points[k], radius).iter().filter(|n| n.index != k).map(|n| n.index as u32).collect();
            if candidates.is_empty() {
                return None;
            }
            let mut rng = Rng::derived(seed, k as u64);
            let picked = if candidates.len() >= points_per_patch {
                rng.sample_without_replacement(candidates.len(), points_per_patch)
                    .into_iter()
                    .map(|i| candidates[i])
                    .collect()
            } else {
                (0..points_per_patch).map(|_| candidates[rng.below(candidates.len())]).collect()
            };
            Some(picked)
        })
        .collect();
    let mut out = Patches { points_per_patch, ..Patches::default() };
    for (&k, s) in keypoints.iter().zip(sampled) {
        match s {
            Some(nbrs) => {
                out.keypoints.push(k);
                out.neighbors.extend(nbrs);
            }
            None => out.empty.push(k),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_within_radius_excluding_centre_and_reports_isolated_points() {
        let mut pts: Vec<[f32; 3]> = (0..50).map(|i| [i as f32 * 0.01, 0.0, 0.0]).collect();
        pts.push([10.0, 10.0, 10.0]);
        let index = PointIndex::new(&pts).unwrap();
        let p = extract_patches(&pts, &index, &[0, 25, 50], 0.1, 8, 3);
        assert_eq!(p.keypoints, vec![0, 25]);
        assert_eq!(p.empty, vec![50]);
        for (slot, &k) in p.keypoints.iter().enumerate() {
            let nb = &p.neighbors[slot * 8..][..8];
            assert!(nb.iter().all(|&j| j as usize != k));
            assert!(nb.iter().all(|&j| (pts[j as usize][0] - pts[k][0]).abs() <= 0.1 + 1e-6));
        }
        // 0 has exactly 10 neighbours within 0.1 (0.01..0.10): 8 distinct ones are drawn.
        let mut first: Vec<u32> = p.neighbors[..8].to_vec();
        first.sort_unstable();
        first.dedup();
        assert_eq!(first.len(), 8);
        // Too few neighbours: sampled with replacement, still all valid.
        let q = extract_patches(&pts, &index, &[0], 0.025, 8, 3);
        assert!(q.neighbors.iter().all(|&j| j == 1 || j == 2));
        assert_eq!(p, extract_patches(&pts, &index, &[0, 25, 50], 0.1, 8, 3));
    }
}
