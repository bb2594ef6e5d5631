//! Local patches: the points within radius r of each keypoint (the keypoint itself excluded), N of them
//! sampled by the rule of [`crate::cpu::patch_sample`] (distinct when there are enough, every candidate
//! repeated in ranking order otherwise): the same definition the GPU kernels implement, so both paths pick the
//! same neighbours.

use crate::cpu::patch_sample::{
    candidate_hash, in_patch, radius_squared, sample_candidates, sample_hashed, stream_key,
};
use crate::spatial::PointIndex;
use rayon::prelude::*;

/// Relative widening of the k-d tree query, so that it returns every point the exact `d2 <= r2` test of
/// [`in_patch`] keeps (the tree rounds its distances its own way; f32 rounding is far below this).
const QUERY_SLACK: f32 = 1e-4;

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

/// Gathers and samples one patch per keypoint. Patch `i`'s ranking is keyed by `seed` and the keypoint's cloud
/// index, so the result depends neither on thread scheduling nor on the batch that holds the keypoint.
pub fn extract_patches(
    points: &[[f32; 3]],
    index: &PointIndex,
    keypoints: &[usize],
    radius: f32,
    points_per_patch: usize,
    seed: u64,
) -> Patches {
    let key = stream_key(seed);
    let r2 = radius_squared(radius);
    let sampled: Vec<Vec<u32>> = keypoints
        .par_iter()
        .map(|&k| {
            // The candidates hashed as the tree returns them (what `sample_candidates` of
            // `patch_candidates` computes, without the list in between).
            let q = &points[k];
            let hashed = index
                .within_unsorted_iter(q, radius * (1.0 + QUERY_SLACK))
                .filter(|n| n.index != k && in_patch(&points[n.index], q, r2))
                .map(|n| (candidate_hash(key, k as u32, n.index as u32), n.index as u32))
                .collect();
            sample_hashed(hashed, points_per_patch)
        })
        .collect();
    let mut out = Patches { points_per_patch, ..Patches::default() };
    for (&k, nbrs) in keypoints.iter().zip(sampled) {
        if nbrs.is_empty() {
            out.empty.push(k);
        } else {
            out.keypoints.push(k);
            out.neighbors.extend(nbrs);
        }
    }
    out
}

/// Cloud indices of the points within `radius` of keypoint `k`, the keypoint itself excluded, in no order
/// (the ranking by (hash, index) does not depend on the query's order).
fn patch_candidates(points: &[[f32; 3]], index: &PointIndex, k: usize, r2: f32, radius: f32) -> Vec<u32> {
    let q = &points[k];
    index
        .within_unsorted(q, radius * (1.0 + QUERY_SLACK))
        .iter()
        .filter(|n| n.index != k && in_patch(&points[n.index], q, r2))
        .map(|n| n.index as u32)
        .collect()
}

/// One keypoint's patch drawn, by the rule and stream [`extract_patches`] uses, from the candidates `keep` leaves
/// (the training sampler's occlusion cuts); `None` when `keep` gives `None` or leaves no candidate.
pub fn extract_patch_where(
    points: &[[f32; 3]],
    index: &PointIndex,
    keypoint: usize,
    radius: f32,
    points_per_patch: usize,
    seed: u64,
    keep: impl FnOnce(Vec<u32>) -> Option<Vec<u32>>,
) -> Option<Patches> {
    let candidates = keep(patch_candidates(points, index, keypoint, radius_squared(radius), radius))?;
    if candidates.is_empty() {
        return None;
    }
    let neighbors = sample_candidates(&candidates, keypoint as u32, stream_key(seed), points_per_patch);
    Some(Patches { keypoints: vec![keypoint], neighbors, points_per_patch, empty: Vec::new() })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_patch_drawn_from_kept_candidates_follows_the_same_rule() {
        let pts: Vec<[f32; 3]> = (0..400).map(|i| [(i % 20) as f32 * 0.01, (i / 20) as f32 * 0.01, 0.0]).collect();
        let index = PointIndex::new(&pts).unwrap();
        let all = extract_patches(&pts, &index, &[210], 0.05, 16, 7);
        assert_eq!(extract_patch_where(&pts, &index, 210, 0.05, 16, 7, Some), Some(all));
        let even = extract_patch_where(&pts, &index, 210, 0.05, 16, 7, |c| {
            Some(c.into_iter().filter(|j| j % 2 == 0).collect())
        })
        .unwrap();
        assert_eq!((even.keypoints.clone(), even.neighbors.len()), (vec![210], 16));
        assert!(even.neighbors.iter().all(|&j| j % 2 == 0 && in_patch(&pts[j as usize], &pts[210], 0.05 * 0.05)));
        assert_eq!(extract_patch_where(&pts, &index, 210, 0.05, 16, 7, |_| None), None);
        assert_eq!(extract_patch_where(&pts, &index, 210, 0.05, 16, 7, |_| Some(Vec::new())), None);
    }

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

    #[test]
    fn patches_are_the_twins_on_a_grid() {
        use crate::cpu::grid_knn::CellGrid;
        use crate::cpu::patch_gather::patch_gather;
        use crate::cpu::patch_sample::patch_sample;
        let mut rng = crate::rng::Rng::new(8);
        let pts: Vec<[f32; 3]> = (0..2000).map(|_| [0; 3].map(|_: i32| rng.uniform(-1.0, 1.0) as f32)).collect();
        let index = PointIndex::new(&pts).unwrap();
        let keypoints: Vec<usize> = (0..2000).step_by(13).collect();
        let (radius, n, seed) = (0.12, 24, 77);
        let p = extract_patches(&pts, &index, &keypoints, radius, n, seed);
        let grid = CellGrid::new(&pts, 1.0 / radius).unwrap();
        let ks: Vec<u32> = keypoints.iter().map(|&k| k as u32).collect();
        let c = patch_sample(&grid, &ks, radius, seed).unwrap();
        let (mut table, mut start, mut empty) = (Vec::new(), 0, Vec::new());
        for (slot, &count) in c.counts.iter().enumerate() {
            if count == 0 {
                empty.push(keypoints[slot]);
            } else {
                table.push([ks[slot], start, count, 0]);
            }
            start += count;
        }
        let (idx, _, _) = patch_gather(&pts, &pts, &c.sorted, &table, n, false).unwrap();
        assert_eq!(idx, p.neighbors);
        assert_eq!(empty, p.empty);
        assert!(p.keypoints.len() > 100 && c.counts.iter().any(|&c| (c as usize) < n));
    }
}
