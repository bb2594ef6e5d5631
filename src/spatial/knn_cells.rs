//! The `k` nearest neighbours of many points of one cloud at once, cell by cell: the cloud sorted into cubic
//! cells about as wide as a typical k-th neighbour distance, and every query of a cell answered from the 27
//! cells around it, gathered once. A query whose k-th neighbour is not provably inside those 27 cells (an
//! isolated point, a thin spot) falls back to the k-d tree. Either way the answer is the exact `k` nearest by
//! `(squared distance, index)`: the cells only decide how much is searched, never which neighbours win.
//!
//! Squared distances are `dx*dx + dy*dy + dz*dz` in f32, left to right, as the k-d tree computes them, so
//! both paths agree to the bit.

use super::{Neighbor, PointIndex};
use crate::cpu::cell_bounds::face_gap;
use crate::cpu::cell_keys::{SortKey, grid_dims, pack, unpack};
use crate::cpu::segments::Segments;
use crate::cpu::voxel_average::sorted_cells;
use rayon::prelude::*;

/// Queries sampled to choose the cell size.
const SIZE_SAMPLES: usize = 128;
/// The cell size is this quantile of the sampled k-th neighbour distances: most queries are answered from
/// their 27 cells, few fall back.
const SIZE_QUANTILE: f64 = 0.9;

/// `f(query, its k nearest neighbours)` for every point index in `queries` (any order, repeats allowed), in
/// the order of `queries`. The neighbours include the query itself and come nearest first, ties broken towards
/// the lower index; fewer than `k` only when the cloud is smaller. `index` must index `points`.
pub fn map_nearest<T, F>(points: &[[f32; 3]], index: &PointIndex, queries: &[usize], k: usize, f: F) -> Vec<T>
where
    T: Send + Sync + Clone,
    F: Fn(usize, &[Neighbor]) -> T + Sync,
{
    let k = k.min(points.len());
    let slow = |&q: &usize| f(q, &nearest_by_index(points, index, q, k));
    if k == 0 || queries.len() < SIZE_SAMPLES {
        return queries.par_iter().map(slow).collect();
    }
    let Some(cells) = Cells::new(points, index, queries, k) else {
        return queries.par_iter().map(slow).collect();
    };
    let mut wanted = vec![false; points.len()];
    for &q in queries {
        wanted[q] = true;
    }
    let answered: Vec<Vec<(usize, T)>> = (0..cells.len())
        .into_par_iter()
        .with_min_len(8)
        .map_init(Scratch::default, |scratch, c| cells.answer_cell(points, index, c, k, &wanted, scratch, &f))
        .collect();
    let mut at: Vec<Option<T>> = vec![None; points.len()];
    for (q, value) in answered.into_iter().flatten() {
        at[q] = Some(value);
    }
    queries.iter().map(|&q| at[q].clone().expect("every wanted point is in a cell")).collect()
}

/// The `k` nearest points to point `q` from the k-d tree, ties at the k-th distance broken towards the lower
/// index like the cells' answer (the tree alone keeps whichever tied point it meets first).
fn nearest_by_index(points: &[[f32; 3]], index: &PointIndex, q: usize, k: usize) -> Vec<Neighbor> {
    let Some(kth) = index.nearest_n(&points[q], k).last().map(|n| n.distance_squared) else { return Vec::new() };
    // Every point at the k-th distance or nearer: a radius two ulps above its square root squares to at least
    // the k-th squared distance.
    let radius = if kth > 0.0 { f32::from_bits(kth.sqrt().to_bits() + 2) } else { 0.0 };
    let mut all = index.within(&points[q], radius);
    all.truncate(k);
    all
}

/// The cloud's points sorted by cell.
struct Cells {
    inv_cell: f32,
    /// Cells per axis.
    dims: [i32; 3],
    /// The points' keys sorted by (cell, index).
    sorted: Vec<SortKey>,
    /// One run of `sorted` per occupied cell.
    cells: Segments,
    /// Slack of the stopping rule, in cells: the rounding of `p * inv_cell` and of the comparison.
    slack: f32,
}

/// Buffers one task reuses across cells.
struct Scratch {
    xyz: [Vec<f32>; 3],
    ids: Vec<u32>,
    d2: Vec<f32>,
    found: Vec<u64>,
    neighbors: Vec<Neighbor>,
    /// The k-th squared distance of the last query answered from a block (infinite before the first).
    last_kth: f32,
}

impl Default for Scratch {
    fn default() -> Self {
        Scratch {
            xyz: Default::default(),
            ids: Vec::new(),
            d2: Vec::new(),
            found: Vec::new(),
            neighbors: Vec::new(),
            last_kth: f32::INFINITY,
        }
    }
}

impl Cells {
    /// The cells of `points`, sized from the k-th neighbour distance of sampled `queries`; `None` when that
    /// distance is zero (many duplicates) or the cloud spans too many cells for the keys.
    fn new(points: &[[f32; 3]], index: &PointIndex, queries: &[usize], k: usize) -> Option<Cells> {
        let step = queries.len() / SIZE_SAMPLES;
        let mut kth: Vec<f32> = (0..SIZE_SAMPLES)
            .map(|i| index.nearest_n(&points[queries[i * step]], k).last().map_or(0.0, |n| n.distance_squared))
            .collect();
        kth.sort_by(f32::total_cmp);
        let size = kth[((SIZE_SAMPLES - 1) as f64 * SIZE_QUANTILE) as usize].sqrt();
        if !(size > 0.0 && size.is_finite()) {
            return None;
        }
        let inv_cell = 1.0 / size;
        // The grid's cell table (`grid_knn` and voxel downsampling use the same): keys sorted by (cell, index).
        let (bounds, sorted, cells) = sorted_cells(points, inv_cell).ok()?;
        let dims = grid_dims(&bounds).ok()?.map(|d| d as i32);
        Some(Cells { inv_cell, dims, sorted, cells, slack: bounds.search_slack() })
    }

    /// Occupied cells.
    fn len(&self) -> usize {
        self.cells.len()
    }

    /// The points of occupied cell `c`, ascending.
    fn run(&self, c: usize) -> impl Iterator<Item = u32> + '_ {
        let (start, end) = (self.cells.starts[c] as usize, self.cells.starts[c + 1] as usize);
        self.sorted[start..end].iter().map(|key| key[2])
    }

    /// The cell coordinates (offsets from the grid's first cell) of occupied cell `c`.
    fn offsets(&self, c: usize) -> [i32; 3] {
        unpack(self.cells.keys[c]).map(|o| o as i32)
    }

    /// `f` for every wanted point of occupied cell `c`.
    #[expect(clippy::too_many_arguments, reason = "one cell's share of map_nearest's inputs")]
    fn answer_cell<T>(
        &self,
        points: &[[f32; 3]],
        index: &PointIndex,
        c: usize,
        k: usize,
        wanted: &[bool],
        scratch: &mut Scratch,
        f: &(impl Fn(usize, &[Neighbor]) -> T + Sync),
    ) -> Vec<(usize, T)> {
        if !self.run(c).any(|q| wanted[q as usize]) {
            return Vec::new();
        }
        self.gather(points, c, scratch);
        let mut out = Vec::new();
        for q in self.run(c).map(|q| q as usize).filter(|&q| wanted[q]) {
            let value = if self.nearest_in_block(&points[q], k, scratch) {
                f(q, &scratch.neighbors)
            } else {
                f(q, &nearest_by_index(points, index, q, k))
            };
            out.push((q, value));
        }
        out
    }

    /// The points of the 27 cells around occupied cell `c` into `scratch`'s coordinate and index lists.
    fn gather(&self, points: &[[f32; 3]], c: usize, scratch: &mut Scratch) {
        for list in &mut scratch.xyz {
            list.clear();
        }
        scratch.ids.clear();
        let o = self.offsets(c);
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let n = [o[0] + dx, o[1] + dy, o[2] + dz];
                    if (0..3).any(|a| n[a] < 0 || n[a] >= self.dims[a]) {
                        continue;
                    }
                    let Some(s) = self.cells.find(pack(n.map(|v| v as u32))) else { continue };
                    for i in self.run(s) {
                        for (list, &v) in scratch.xyz.iter_mut().zip(&points[i as usize]) {
                            list.push(v);
                        }
                        scratch.ids.push(i);
                    }
                }
            }
        }
    }

    /// The `k` nearest of the gathered points to `q` into `scratch.neighbors`, and whether they are provably
    /// the `k` nearest of the whole cloud: the k-th is nearer than any point outside the 27 cells can be.
    fn nearest_in_block(&self, q: &[f32; 3], k: usize, scratch: &mut Scratch) -> bool {
        // Any point outside the block is at least 1 + min(f, 1 - f) cells away along some axis (f: the
        // query's position within its cell), less the slack.
        let gap = 1.0 + face_gap(q, self.inv_cell) - self.slack;
        let reach = gap / self.inv_cell;
        // A little beyond the reach, so that no point the rule accepts is filtered out by rounding.
        let keep = reach * reach * 1.001;
        let [xs, ys, zs] = &scratch.xyz;
        scratch.d2.clear();
        scratch.d2.extend(xs.iter().zip(ys).zip(zs).map(|((x, y), z)| {
            let d = [x - q[0], y - q[1], z - q[2]];
            d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
        }));
        // First only the candidates within twice the previous query's k-th squared distance (a neighbour in
        // the same or the next cell has about the same): when k of them are, they hold the k nearest, for
        // every point left out is further than all k. Else every candidate within reach.
        let guess = scratch.last_kth * GUESS_FACTOR;
        if !(guess < keep && collect_within(scratch, guess) >= k) && collect_within(scratch, keep) < k {
            return false;
        }
        scratch.found.select_nth_unstable(k - 1);
        scratch.found.truncate(k);
        scratch.found.sort_unstable();
        scratch.neighbors.clear();
        scratch.neighbors.extend(scratch.found.iter().map(|&v| Neighbor {
            index: (v & u64::from(u32::MAX)) as usize,
            distance_squared: f32::from_bits((v >> 32) as u32),
        }));
        let kth = scratch.neighbors[k - 1].distance_squared;
        scratch.last_kth = kth;
        kth.sqrt() * self.inv_cell < gap
    }
}

/// How far beyond the previous query's k-th squared distance the first pass of
/// [`Cells::nearest_in_block`] looks.
const GUESS_FACTOR: f32 = 2.0;

/// The gathered candidates with squared distance at most `threshold` into `scratch.found`, as `(d2 bits,
/// index)` keys; returns how many. Every candidate is written and the length advanced only for those kept: no
/// branch to mispredict on a coin-flip test.
fn collect_within(scratch: &mut Scratch, threshold: f32) -> usize {
    scratch.found.clear();
    scratch.found.resize(scratch.d2.len(), 0);
    let mut len = 0;
    for (&d2, &id) in scratch.d2.iter().zip(&scratch.ids) {
        // Non-negative floats order as their bits: one integer sort orders by (d2, index).
        scratch.found[len] = (u64::from(d2.to_bits()) << 32) | u64::from(id);
        len += usize::from(d2 <= threshold);
    }
    scratch.found.truncate(len);
    len
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn brute(points: &[[f32; 3]], q: usize, k: usize) -> Vec<(usize, f32)> {
        let p = points[q];
        let mut all: Vec<(usize, f32)> = points
            .iter()
            .enumerate()
            .map(|(i, r)| {
                let d = [r[0] - p[0], r[1] - p[1], r[2] - p[2]];
                (i, d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
            })
            .collect();
        all.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        all.truncate(k);
        all
    }

    /// A surface-like cloud (a noisy wavy sheet), a lattice (exact ties), a far outlier and duplicates.
    fn cloud(rng: &mut Rng) -> Vec<[f32; 3]> {
        let mut pts: Vec<[f32; 3]> = (0..3000)
            .map(|_| {
                let (x, y) = (rng.uniform(-1.0, 1.0) as f32, rng.uniform(-1.0, 1.0) as f32);
                [x, y, 0.2 * (3.0 * x).sin() + 0.01 * rng.uniform(-1.0, 1.0) as f32]
            })
            .collect();
        pts.extend(
            (0..216).map(|i| [(i % 6) as f32 * 0.05 + 2.0, ((i / 6) % 6) as f32 * 0.05, (i / 36) as f32 * 0.05]),
        );
        pts.push([40.0, -30.0, 7.0]);
        pts.extend_from_slice(&[[0.5, 0.5, 0.5]; 4]);
        pts
    }

    #[test]
    fn every_query_gets_the_brute_force_neighbours_in_order() {
        let mut rng = Rng::new(21);
        let pts = cloud(&mut rng);
        let index = PointIndex::new(&pts).unwrap();
        let queries: Vec<usize> = (0..pts.len()).rev().step_by(3).chain([0, 0, pts.len() - 1]).collect();
        for k in [1, 7, 30, 64] {
            let got = map_nearest(&pts, &index, &queries, k, |q, n| {
                (q, n.iter().map(|n| (n.index, n.distance_squared)).collect::<Vec<_>>())
            });
            for (&q, (gq, neighbors)) in queries.iter().zip(&got) {
                assert_eq!(q, *gq);
                assert_eq!(neighbors, &brute(&pts, q, k), "query {q}, k {k}");
            }
        }
    }

    #[test]
    fn both_paths_are_taken_and_agree() {
        // A dense sheet with sparse points off it: most queries are answered from their cells, the sparse ones
        // fall back to the tree (the first test checks those).
        let mut rng = Rng::new(5);
        let mut pts = cloud(&mut rng);
        pts.extend((0..40).map(|i| [i as f32 * 0.3 - 6.0, 3.0, 1.0]));
        let index = PointIndex::new(&pts).unwrap();
        let queries: Vec<usize> = (0..pts.len()).collect();
        let cells = Cells::new(&pts, &index, &queries, 12).expect("a cell size");
        let mut scratch = Scratch::default();
        let (mut inside, mut outside) = (0, 0);
        for c in 0..cells.len() {
            cells.gather(&pts, c, &mut scratch);
            for q in cells.run(c) {
                if cells.nearest_in_block(&pts[q as usize], 12, &mut scratch) {
                    inside += 1;
                    let want = brute(&pts, q as usize, 12);
                    let got: Vec<(usize, f32)> =
                        scratch.neighbors.iter().map(|n| (n.index, n.distance_squared)).collect();
                    assert_eq!(got, want, "query {q}");
                } else {
                    outside += 1;
                }
            }
        }
        assert!(inside > pts.len() / 2 && outside > 0, "{inside} answered in cells, {outside} by the tree");
    }

    #[test]
    fn few_queries_and_a_cloud_of_duplicates_use_the_tree() {
        let pts = vec![[1.0, 2.0, 3.0]; 300];
        let index = PointIndex::new(&pts).unwrap();
        let queries: Vec<usize> = (0..300).collect();
        let got = map_nearest(&pts, &index, &queries, 5, |_, n| n.iter().map(|n| n.index).collect::<Vec<_>>());
        assert!(got.iter().all(|n| n == &[0, 1, 2, 3, 4]));
        let one = map_nearest(&pts, &index, &[7], 400, |_, n| n.len());
        assert_eq!(one, [300]);
    }
}
