//! Making 3DMatch ground truth from fragments with known poses (spec 3.3, `getGtInfoLog.m`): which pairs
//! overlap enough to enter gt.log, and their gt.info information matrices.

use super::metrics::information_matrix;
use crate::cloud::PointCloud;
use crate::rng::Rng;
use crate::synth::fuse::grid_average;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Matrix4, Matrix6, Vector3};
use rayon::prelude::*;
use serde::Serialize;
use std::collections::HashSet;
use std::hash::{BuildHasherDefault, Hasher};

/// The constants of the ground-truth rule; the defaults are the official ones.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct GroundTruthRule {
    /// Grid-average downsampling cell before everything else (0.01 m).
    pub grid: f64,
    /// A fragment-i point overlaps when its nearest transformed fragment-j point is closer than this (0.03 m).
    pub overlap_distance: f64,
    /// Pairs with at least this overlap fraction enter gt.log (0.30).
    pub min_overlap: f64,
    /// Pairs with more overlap than this stay out (1: none; 0.30 with a `min_overlap` of 0.10 gives
    /// 3DLoMatch-style low-overlap pairs). Left out of serialised settings at its default, so earlier outputs
    /// keep their bytes.
    #[serde(skip_serializing_if = "is_one")]
    pub max_overlap: f64,
    /// Transformed fragment-j points closer than this to fragment i form the correspondence set (0.006 m).
    pub info_distance: f64,
    /// The correspondence set is randomly subsampled to at most this many points (5000).
    pub max_info_points: usize,
}

impl Default for GroundTruthRule {
    fn default() -> Self {
        GroundTruthRule {
            grid: 0.01,
            overlap_distance: 0.03,
            min_overlap: 0.30,
            max_overlap: 1.0,
            info_distance: 0.006,
            max_info_points: 5000,
        }
    }
}

fn is_one(v: &f64) -> bool {
    *v == 1.0
}

/// One ground-truth pair.
#[derive(Clone, Debug, PartialEq)]
pub struct GtPair {
    /// Fragment i (the target frame).
    pub i: usize,
    /// Fragment j > i (the source).
    pub j: usize,
    /// The pose of fragment j in fragment i's frame: x_i = i_from_j x_j.
    pub i_from_j: Matrix4<f64>,
    /// Fraction of (downsampled) fragment-i points within `overlap_distance` of transformed fragment j.
    pub overlap: f64,
    /// Σ Gᵀ G over the (subsampled) correspondence set, in fragment i's frame.
    pub information: Matrix6<f64>,
}

/// A fragment downsampled on the ground-truth grid, with a k-d tree over its points (own frame) and a coarse
/// occupancy grid that answers "nothing within `reach`" without a tree query (most queries of non-overlapping
/// parts are far from every point, where exact nearest-neighbour searches are slowest).
pub struct PreparedFragment {
    /// Grid-averaged points.
    pub points: Vec<[f64; 3]>,
    tree: Option<ImmutableKdTree<f64, 3>>,
    /// Cell size of `near`: the largest distance [`PreparedFragment::is_within`] can prefilter.
    reach: f64,
    /// Cells (of size `reach`) that hold a point or neighbour a cell that does.
    near: HashSet<u64, BuildHasherDefault<CellHasher>>,
}

/// A multiplicative hasher for packed cell keys (the default SipHash costs more than the lookups it guards).
#[derive(Default)]
struct CellHasher(u64);

impl Hasher for CellHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(self.0 ^ b as u64);
        }
    }

    fn write_u64(&mut self, x: u64) {
        let h = (x ^ (x >> 29)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        self.0 = h ^ (h >> 32);
    }
}

/// Cell coordinates packed into 21 bits each; distant cells may share a key, which only costs an exact query.
fn cell_key(p: &[f64; 3], cell: f64) -> [i64; 3] {
    [(p[0] / cell).floor() as i64, (p[1] / cell).floor() as i64, (p[2] / cell).floor() as i64]
}

fn pack(c: [i64; 3]) -> u64 {
    const M: i64 = (1 << 21) - 1;
    ((c[0] & M) as u64) | (((c[1] & M) as u64) << 21) | (((c[2] & M) as u64) << 42)
}

impl PreparedFragment {
    /// Downsamples `cloud` on a `grid` and indexes it for queries up to `reach`.
    pub fn new(cloud: &PointCloud, grid: f64, reach: f64) -> PreparedFragment {
        PreparedFragment::from_points(grid_average(&cloud.points, grid), reach)
    }

    /// Indexes `points` as they are (no downsampling) for queries up to `reach`.
    pub fn from_points(points: Vec<[f64; 3]>, reach: f64) -> PreparedFragment {
        let tree = (!points.is_empty()).then(|| ImmutableKdTree::new_from_slice(&points).ok()).flatten();
        let mut near = HashSet::default();
        if reach > 0.0 && reach.is_finite() {
            let mut cells: Vec<[i64; 3]> = points.iter().map(|p| cell_key(p, reach)).collect();
            cells.sort_unstable();
            cells.dedup();
            for c in cells {
                for dx in -1..=1 {
                    for dy in -1..=1 {
                        for dz in -1..=1 {
                            near.insert(pack([c[0] + dx, c[1] + dy, c[2] + dz]));
                        }
                    }
                }
            }
        }
        PreparedFragment { points, tree, reach, near }
    }

    /// Squared distance from `p` (this fragment's frame) to the nearest point (infinite when empty).
    pub fn nearest_sq(&self, p: &[f64; 3]) -> f64 {
        match &self.tree {
            Some(t) => t.query(p).nearest_one::<SquaredEuclidean<f64>>().execute().distance,
            None => f64::INFINITY,
        }
    }

    /// True when some point is closer than `distance` (strict) to `p`.
    pub fn is_within(&self, p: &[f64; 3], distance: f64) -> bool {
        if distance <= self.reach && !self.near.contains(&pack(cell_key(p, self.reach))) {
            return false;
        }
        self.nearest_sq(p) < distance * distance
    }
}

fn apply(t: &Matrix4<f64>, p: &[f64; 3]) -> [f64; 3] {
    let q = t.fixed_view::<3, 3>(0, 0) * Vector3::new(p[0], p[1], p[2]) + t.fixed_view::<3, 1>(0, 3);
    [q.x, q.y, q.z]
}

/// Fraction of fragment-i points whose nearest point of fragment j mapped by `i_from_j` (x_i = i_from_j x_j) is
/// closer than `distance` (strict). Distances are computed in fragment j's frame via j_from_i = i_from_j⁻¹, which is equivalent.
pub fn overlap_fraction(
    frag_i: &PreparedFragment,
    frag_j: &PreparedFragment,
    i_from_j: &Matrix4<f64>,
    distance: f64,
) -> f64 {
    if frag_i.points.is_empty() {
        return 0.0;
    }
    let j_from_i = crate::pose::inverse(i_from_j);
    let hits = frag_i.points.iter().filter(|p| frag_j.is_within(&apply(&j_from_i, p), distance)).count();
    hits as f64 / frag_i.points.len() as f64
}

/// The correspondence set Q of spec 3.3 step 5: fragment-j points mapped into fragment i's frame that lie closer
/// than `distance` to fragment i, subsampled to at most `max_points` with `rng` (in drawn order).
pub fn correspondence_points(
    frag_i: &PreparedFragment,
    frag_j: &PreparedFragment,
    i_from_j: &Matrix4<f64>,
    distance: f64,
    max_points: usize,
    rng: &mut Rng,
) -> Vec<[f64; 3]> {
    let q: Vec<[f64; 3]> =
        frag_j.points.iter().map(|p| apply(i_from_j, p)).filter(|q| frag_i.is_within(q, distance)).collect();
    if q.len() <= max_points {
        return q;
    }
    rng.sample_without_replacement(q.len(), max_points).into_iter().map(|k| q[k]).collect()
}

/// The information matrix of one pair (steps 5-6), given x_i = i_from_j x_j.
pub fn pair_information(
    frag_i: &PreparedFragment,
    frag_j: &PreparedFragment,
    i_from_j: &Matrix4<f64>,
    rule: &GroundTruthRule,
    rng: &mut Rng,
) -> Matrix6<f64> {
    information_matrix(&correspondence_points(frag_i, frag_j, i_from_j, rule.info_distance, rule.max_info_points, rng))
}

/// Every pair i < j whose overlap passes the rule, with T_ij = E_i⁻¹ E_j (E = `world_from_fragment`) and its
/// information matrix. Pair k (in i-major order over all i < j) subsamples with `Rng::derived(seed, k)`, so the
/// result does not depend on thread scheduling.
pub fn ground_truth_pairs(
    fragments: &[PointCloud],
    world_from_fragment: &[Matrix4<f64>],
    rule: &GroundTruthRule,
    seed: u64,
) -> Vec<GtPair> {
    let prepared: Vec<PreparedFragment> =
        fragments.par_iter().map(|c| PreparedFragment::new(c, rule.grid, rule.overlap_distance)).collect();
    let n = fragments.len().min(world_from_fragment.len());
    let pairs: Vec<(usize, usize)> = (0..n).flat_map(|i| (i + 1..n).map(move |j| (i, j))).collect();
    pairs
        .par_iter()
        .enumerate()
        .filter_map(|(k, &(i, j))| {
            let i_from_j = crate::pose::inverse(&world_from_fragment[i]) * world_from_fragment[j];
            let overlap = overlap_fraction(&prepared[i], &prepared[j], &i_from_j, rule.overlap_distance);
            if overlap < rule.min_overlap || overlap > rule.max_overlap {
                return None;
            }
            let mut rng = Rng::derived(seed, k as u64);
            let information = pair_information(&prepared[i], &prepared[j], &i_from_j, rule, &mut rng);
            Some(GtPair { i, j, i_from_j, overlap, information })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid_cloud(n: usize, step: f32, z: f32) -> PointCloud {
        PointCloud::from_points((0..n * n).map(|k| [(k % n) as f32 * step, (k / n) as f32 * step, z]).collect())
    }

    #[test]
    fn overlap_counts_fragment_i_points_near_transformed_j() {
        // Fragment i: a 1 m x 1 m plane on a 2 cm grid; fragment j: the same samples in its own frame, placed
        // 0.5 m further along x (T_ij = translate(0.5, 0, 0)), so it covers the right half of i and beyond.
        let i = grid_cloud(50, 0.02, 0.0);
        let j = grid_cloud(50, 0.02, 0.0);
        let mut t = Matrix4::identity();
        t[(0, 3)] = 0.5;
        let rule = GroundTruthRule::default();
        let (pi, pj) = (PreparedFragment::new(&i, rule.grid, 0.03), PreparedFragment::new(&j, rule.grid, 0.03));
        let overlap = overlap_fraction(&pi, &pj, &t, rule.overlap_distance);
        // Columns x >= 0.5 - 0.03 overlap: x = 0.48 .. 0.98, 26 of 50 columns.
        assert!((overlap - 26.0 / 50.0).abs() < 1e-9, "{overlap}");
        let pairs = ground_truth_pairs(&[i.clone(), j.clone()], &[Matrix4::identity(), t], &rule, 1);
        assert_eq!(pairs.len(), 1);
        assert!((pairs[0].overlap - 0.52).abs() < 1e-9 && pairs[0].i_from_j == t);
        // Q: the 25 x 50 coincident points, all within 6 mm; information (0,0) counts them.
        assert!((pairs[0].information[(0, 0)] - 1250.0).abs() < 1e-9);
        // Low-overlap lists: 0.52 is above a 0.30 cap and within a 0.60 one.
        let low = GroundTruthRule { min_overlap: 0.1, max_overlap: 0.3, ..GroundTruthRule::default() };
        assert!(ground_truth_pairs(&[i.clone(), j.clone()], &[Matrix4::identity(), t], &low, 1).is_empty());
        let capped = GroundTruthRule { max_overlap: 0.6, ..low };
        assert_eq!(ground_truth_pairs(&[i.clone(), j.clone()], &[Matrix4::identity(), t], &capped, 1).len(), 1);
        // Far apart: no pair.
        let mut far = t;
        far[(0, 3)] = 5.0;
        assert!(ground_truth_pairs(&[i, j], &[Matrix4::identity(), far], &rule, 1).is_empty());
    }

    #[test]
    fn correspondence_set_is_capped_and_seeded() {
        let c = grid_cloud(100, 0.01, 1.0);
        let p = PreparedFragment::new(&c, 0.01, 0.03);
        let a = correspondence_points(&p, &p, &Matrix4::identity(), 0.006, 5000, &mut Rng::new(3));
        let b = correspondence_points(&p, &p, &Matrix4::identity(), 0.006, 5000, &mut Rng::new(3));
        assert_eq!(a.len(), 5000);
        assert_eq!(a, b);
    }
}
