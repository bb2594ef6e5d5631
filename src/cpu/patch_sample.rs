//! CPU twin of `shaders/patch_sample.wgsl`, and the definition of a patch that every path uses: the points
//! within `radius` of a keypoint (the keypoint itself excluded), ranked by a counter-based hash, the first N
//! taken.
//!
//! **Membership.** Point `j` is in the patch of keypoint `k` when `j != k` and `d2 <= r2`, with
//! `d2 = dx*dx + dy*dy + dz*dz` (each product rounded, then summed left to right, in f32; the kernel fences
//! the products so that no FMA contraction changes a bit) and `r2 = radius * radius` in f32. The boundary is
//! therefore decided identically on the CPU and the GPU.
//!
//! **Sampling.** Each candidate `j` of keypoint `k` gets the hash [`candidate_hash`] of `(seed, k, j)`
//! (lowbias32 mixes of 32-bit words: WGSL has no 64-bit integers). Candidates are ranked ascending by
//! `(hash, j)`; slot `s` of the patch takes the candidate of rank `s mod count`. With at least N candidates
//! that is N distinct ones (a uniform sample without replacement); with fewer, every candidate is taken and
//! the ranking repeats (so a small patch covers all its points). The result depends on nothing but the seed,
//! the keypoint's cloud index and the candidate set: neither search order nor thread scheduling matter, and a
//! keypoint's patch is the same whichever batch or round describes it.
//!
//! **Search (the kernel's part).** On a uniform grid whose cells are at least `radius` wide, the candidates
//! of a keypoint lie in a block of at most 4 cells per axis: `floor((q -+ (radius + margin)) * inv_cell)`,
//! `margin = radius / 256 + (|q| + radius) * 2^-20` (which covers the rounding of `d2` and of the bounds). One
//! invocation per (keypoint, block cell) counts, then writes, that cell's candidates as sort keys
//! `[slot, hash, j, 0]`; sorting them (`bitonic_sort`) gives every patch's ranking, and `patch_gather` takes
//! slot `s mod count`. An invocation's work is one cell's points (lavapipe ends an invocation's loops after
//! 65,535 iterations). A keypoint whose block would span more than 4 cells (coordinates so far from the origin,
//! relative to the radius, that f32 cannot resolve the radius) is an error on both sides.

use super::cell_keys::{SortKey, grid_dims, offsets, pack};
use super::grid_knn::{CellGrid, distance_squared};
use crate::error::{Error, Result};

/// Cells per axis of a keypoint's search block.
pub const BLOCK: usize = 4;
/// Cells of a search block (`BLOCK^3`): the kernel's invocations per keypoint.
pub const BLOCK_CELLS: usize = BLOCK * BLOCK * BLOCK;
/// Relative part of the search margin (of the radius).
pub const MARGIN_REL: f32 = 1.0 / 256.0;
/// Part of the search margin per unit of coordinate magnitude (8 ulp).
pub const MARGIN_ULP: f32 = 1.0 / 1_048_576.0;
/// Largest magnitude of a cell coordinate (as [`super::cell_bounds::CELL_COORD_LIMIT`]).
const CELL_LIMIT: f32 = super::cell_bounds::CELL_COORD_LIMIT;

/// lowbias32 (Wellons): a 32-bit integer mix with full avalanche.
pub fn mix32(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846c_a68b);
    x ^= x >> 16;
    x
}

/// The two key words of a sampling seed.
pub fn stream_key(seed: u64) -> [u32; 2] {
    [seed as u32, (seed >> 32) as u32]
}

/// The hash of candidate `candidate` (cloud index) in the patch of keypoint `keypoint` (cloud index).
pub fn candidate_hash(key: [u32; 2], keypoint: u32, candidate: u32) -> u32 {
    let patch = mix32(key[0] ^ mix32(key[1] ^ keypoint));
    mix32(patch ^ mix32(candidate.wrapping_add(0x9e37_79b9)))
}

/// `radius * radius` in f32: the squared radius both sides compare against.
pub fn radius_squared(radius: f32) -> f32 {
    radius * radius
}

/// Whether `p` lies within the patch radius of `q` (`d2 <= r2`, see the module docs).
pub fn in_patch(p: &[f32; 3], q: &[f32; 3], r2: f32) -> bool {
    distance_squared(p, q) <= r2
}

/// A patch's candidates ranked ascending by `(hash, index)` (see the module docs).
pub fn rank_candidates(candidates: &[u32], keypoint: u32, key: [u32; 2]) -> Vec<u32> {
    let mut ranked: Vec<(u32, u32)> = candidates.iter().map(|&j| (candidate_hash(key, keypoint, j), j)).collect();
    ranked.sort_unstable();
    ranked.into_iter().map(|(_, j)| j).collect()
}

/// `take_cyclic(&rank_candidates(candidates, keypoint, key), n)` without ranking more than the first `n`
/// (a selection, then a sort of those): what the CPU path runs.
pub fn sample_candidates(candidates: &[u32], keypoint: u32, key: [u32; 2], n: usize) -> Vec<u32> {
    sample_hashed(candidates.iter().map(|&j| (candidate_hash(key, keypoint, j), j)).collect(), n)
}

/// [`sample_candidates`] from the candidates already paired with their hashes, `(candidate_hash, index)`.
pub fn sample_hashed(mut ranked: Vec<(u32, u32)>, n: usize) -> Vec<u32> {
    if n > 0 && ranked.len() > n {
        ranked.select_nth_unstable(n - 1);
        ranked.truncate(n);
    }
    ranked.sort_unstable();
    let ranked: Vec<u32> = ranked.into_iter().map(|(_, j)| j).collect();
    take_cyclic(&ranked, n)
}

/// The `n` sampled neighbours of a patch from its ranked candidates: slot `s` takes rank `s mod count`
/// (empty when there is no candidate).
pub fn take_cyclic(ranked: &[u32], n: usize) -> Vec<u32> {
    if ranked.is_empty() {
        return Vec::new();
    }
    (0..n).map(|s| ranked[s % ranked.len()]).collect()
}

/// The cells (inclusive, per axis) searched for the patch of a keypoint at `q`, or `None` when a bound is not
/// finite, out of range, or the block spans more than [`BLOCK`] cells on an axis.
pub fn search_block(q: &[f32; 3], radius: f32, inv_cell: f32) -> Option<([i32; 3], [i32; 3])> {
    let (mut lo, mut hi) = ([0i32; 3], [0i32; 3]);
    for a in 0..3 {
        let margin = radius * MARGIN_REL + (q[a].abs() + radius) * MARGIN_ULP;
        let l = (((q[a] - radius) - margin) * inv_cell).floor();
        let h = (((q[a] + radius) + margin) * inv_cell).floor();
        if !(l.abs() < CELL_LIMIT && h.abs() < CELL_LIMIT) || h - l >= BLOCK as f32 {
            return None;
        }
        (lo[a], hi[a]) = (l as i32, h as i32);
    }
    Some((lo, hi))
}

/// The error for a keypoint whose search block is too wide.
pub fn block_error(keypoint: u32, radius: f32, inv_cell: f32) -> Error {
    Error::invalid(format!(
        "patch_sample: keypoint {keypoint}: the patch radius {radius} is not resolved at its coordinates on a \
         grid of cells {} wide (the cells must be at least the radius, and the coordinates within about 2^18 \
         radii of the origin)",
        1.0 / inv_cell
    ))
}

/// Every keypoint's candidates on a grid: the kernel's output, sorted as `bitonic_sort` sorts it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PatchCandidates {
    /// Candidates per keypoint slot.
    pub counts: Vec<u32>,
    /// `[slot, hash, index, 0]` of every candidate, ascending: slot by slot, each patch's ranking.
    pub sorted: Vec<SortKey>,
}

/// The candidates of each keypoint `keypoints[slot]` (cloud indices into `grid.points`) within `radius`,
/// hashed with `seed`'s key: the twin of the kernel's count and write stages followed by the sort. The grid's
/// cells must be at least `radius` wide.
pub fn patch_sample(grid: &CellGrid, keypoints: &[u32], radius: f32, seed: u64) -> Result<PatchCandidates> {
    check_radius(radius)?;
    let key = stream_key(seed);
    let r2 = radius_squared(radius);
    let dims = grid_dims(&grid.bounds)?;
    let mut out = PatchCandidates::default();
    for (slot, &k) in keypoints.iter().enumerate() {
        let q = grid
            .points
            .get(k as usize)
            .ok_or_else(|| Error::invalid(format!("patch_sample: keypoint {k} is not a point")))?;
        let (lo, hi) = search_block(q, radius, grid.inv_cell).ok_or_else(|| block_error(k, radius, grid.inv_cell))?;
        let mut count = 0u32;
        for c in 0..BLOCK_CELLS {
            let cell = [lo[0] + (c % BLOCK) as i32, lo[1] + (c / BLOCK % BLOCK) as i32, lo[2] + (c / 16) as i32];
            if (0..3).any(|a| cell[a] > hi[a] || cell[a] < grid.bounds.min[a] || cell[a] > grid.bounds.max[a]) {
                continue;
            }
            let o = offsets(cell, &grid.bounds);
            debug_assert!((0..3).all(|a| o[a] < dims[a]));
            let Some(s) = grid.cells.find(pack(o)) else { continue };
            for e in &grid.sorted[grid.cells.starts[s] as usize..grid.cells.starts[s + 1] as usize] {
                let j = e[2];
                if j != k && in_patch(&grid.points[j as usize], q, r2) {
                    out.sorted.push([slot as u32, candidate_hash(key, k, j), j, 0]);
                    count += 1;
                }
            }
        }
        out.counts.push(count);
    }
    out.sorted.sort_unstable();
    Ok(out)
}

/// An error unless the radius is positive and finite.
pub fn check_radius(radius: f32) -> Result<()> {
    if radius.is_finite() && radius > 0.0 {
        Ok(())
    } else {
        Err(Error::invalid(format!("patch_sample: the radius must be positive and finite, got {radius}")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    /// Brute-force candidates of `k`, ascending by index.
    fn brute(points: &[[f32; 3]], k: usize, r2: f32) -> Vec<u32> {
        (0..points.len()).filter(|&j| j != k && in_patch(&points[j], &points[k], r2)).map(|j| j as u32).collect()
    }

    #[test]
    fn candidates_are_the_brute_force_set_on_any_grid_and_rank_by_hash() {
        let mut rng = Rng::new(5);
        let mut pts: Vec<[f32; 3]> = (0..600).map(|_| [0; 3].map(|_: i32| rng.uniform(-1.0, 1.0) as f32)).collect();
        // A point exactly at the radius along an axis (0.25 is exact) and a duplicate of a keypoint.
        pts.push([0.25, 0.0, 0.0]);
        pts.push([0.0, 0.0, 0.0]);
        pts.push([0.0, 0.0, 0.0]);
        let radius = 0.25;
        let keypoints: Vec<u32> = (0..pts.len() as u32).step_by(7).chain([601, 602]).collect();
        for cell in [radius, radius * 1.5, 1.9] {
            let grid = CellGrid::new(&pts, 1.0 / cell).unwrap();
            let got = patch_sample(&grid, &keypoints, radius, 11).unwrap();
            let mut at = 0;
            for (slot, &k) in keypoints.iter().enumerate() {
                let want = brute(&pts, k as usize, radius_squared(radius));
                let n = got.counts[slot] as usize;
                let run = &got.sorted[at..at + n];
                at += n;
                assert!(run.iter().all(|e| e[0] == slot as u32));
                let mut ids: Vec<u32> = run.iter().map(|e| e[2]).collect();
                assert_eq!(ids, rank_candidates(&want, k, stream_key(11)), "keypoint {k}, cell {cell}");
                ids.sort_unstable();
                assert_eq!(ids, want);
            }
        }
        // The keypoint at the origin has the boundary point (d2 == r2) and the duplicate (d2 == 0).
        let grid = CellGrid::new(&pts, 4.0).unwrap();
        let c = patch_sample(&grid, &[602], radius, 1).unwrap();
        let ids: Vec<u32> = c.sorted.iter().map(|e| e[2]).collect();
        assert!(ids.contains(&600) && ids.contains(&601) && !ids.contains(&602), "{ids:?}");
        // Cells narrower than the radius: a clear error, not a partial patch.
        let fine = CellGrid::new(&pts, 1.0 / (radius / 3.0)).unwrap();
        assert!(patch_sample(&fine, &[0], radius, 1).is_err());
        assert!(patch_sample(&grid, &[9999], radius, 1).is_err());
        assert!(patch_sample(&grid, &[0], 0.0, 1).is_err());
    }

    #[test]
    fn partial_ranking_samples_exactly_what_the_full_ranking_samples() {
        let mut rng = crate::rng::Rng::new(12);
        for (len, n) in [(0, 5), (1, 5), (4, 5), (5, 5), (6, 5), (300, 7), (1000, 256), (257, 256), (40, 0)] {
            let candidates: Vec<u32> = (0..len).map(|_| rng.below(1 << 20) as u32).collect();
            let key = stream_key(rng.next_u64());
            let k = rng.below(1 << 20) as u32;
            let want = take_cyclic(&rank_candidates(&candidates, k, key), n);
            assert_eq!(sample_candidates(&candidates, k, key, n), want, "{len} candidates, {n} slots");
        }
    }

    #[test]
    fn sampling_is_distinct_when_enough_and_covers_all_when_fewer() {
        let cands: Vec<u32> = (100..140).collect();
        let key = stream_key(3);
        let ranked = rank_candidates(&cands, 7, key);
        let mut shuffled = cands.clone();
        shuffled.reverse();
        assert_eq!(ranked, rank_candidates(&shuffled, 7, key), "independent of the search order");
        assert_ne!(ranked, rank_candidates(&cands, 8, key), "each keypoint its own stream");
        let picked = take_cyclic(&ranked, 16);
        let mut distinct = picked.clone();
        distinct.sort_unstable();
        distinct.dedup();
        assert_eq!(distinct.len(), 16);
        let few = take_cyclic(&ranked[..5], 12);
        let mut covered = few.clone();
        covered.sort_unstable();
        covered.dedup();
        assert_eq!(covered.len(), 5);
        assert_eq!(few[5..10], few[..5]);
        assert!(take_cyclic(&[], 4).is_empty());
    }
}
