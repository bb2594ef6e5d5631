//! CPU twin of `shaders/grid_knn.wgsl`: exact k nearest neighbours on a uniform cell grid (the sorted cell
//! table of [`super::voxel_average::sorted_cells`]), ordered by `(squared distance, index)` so ties break
//! towards the lower index, exactly as a brute-force search sorted the same way.
//!
//! The search visits shells of cells at Chebyshev distance `r = 0, 1, ..` from the query's cell (clipped to
//! the grid) and stops after shell `r` once it holds `k` neighbours and the k-th is nearer than anything
//! outside the visited block can be: `r + min(f, 1 - f)` cells, `f` the query's position within its cell per axis, less a slack
//! that covers the rounding of the cell assignment (`floor(p * inv_cell)` in f32) and of the comparison.
//! The stopping rule only decides how much is visited, never which neighbours win, so any safe rule gives
//! the same result. Squared distances are `dx*dx + dy*dy + dz*dz` in f32, left to right.
//!
//! Cost: a query visits every cell within its k-th neighbour's distance, so the cell size should be about
//! that distance ([`crate::gpu::preprocess::knn_cell`]); an isolated point far from the rest visits many
//! empty cells (binary searches). Lavapipe (the CI's software Vulkan) also ends every loop of an invocation
//! after 65,535 iterations in all, so tests keep searches short.

use super::cell_bounds::{CellBox, cell_of, face_gap};
use super::cell_keys::{SortKey, grid_dims, offsets, pack};
use super::segments::Segments;
use crate::error::{Error, Result};

/// Most neighbours per query the kernel keeps (its private list length).
pub const K_MAX: usize = 64;
/// Index of an unused neighbour slot.
pub const NO_NEIGHBOR: u32 = u32::MAX;

/// A point set and its cell table (what the GPU builds with [`crate::cpu::voxel_average::sorted_cells`]'s
/// kernels).
#[derive(Clone, Debug)]
pub struct CellGrid {
    /// The indexed points.
    pub points: Vec<[f32; 3]>,
    /// 1 / cell size.
    pub inv_cell: f32,
    /// Box of the occupied cells.
    pub bounds: CellBox,
    /// Keys sorted by (cell, index).
    pub sorted: Vec<SortKey>,
    /// One run per occupied cell.
    pub cells: Segments,
}

impl CellGrid {
    /// Indexes `points` on cells of size `1 / inv_cell`.
    pub fn new(points: &[[f32; 3]], inv_cell: f32) -> Result<CellGrid> {
        let (bounds, sorted, cells) = super::voxel_average::sorted_cells(points, inv_cell)?;
        Ok(CellGrid { points: points.to_vec(), inv_cell, bounds, sorted, cells })
    }

    /// The slack of the stopping rule, in cells ([`CellBox::search_slack`]; the kernel computes the same from
    /// the grid words).
    pub fn slack(&self) -> f32 {
        self.bounds.search_slack()
    }
}

/// `(d2, index)` lexicographic order.
fn before(a: (f32, u32), b: (f32, u32)) -> bool {
    a.0 < b.0 || (a.0 == b.0 && a.1 < b.1)
}

/// Squared distance `dx*dx + dy*dy + dz*dz`, left to right.
pub fn distance_squared(p: &[f32; 3], q: &[f32; 3]) -> f32 {
    let d = [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
    d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
}

/// The `k` nearest points to `q` (ascending by `(d2, index)`; fewer when the set is smaller).
pub fn knn_query(grid: &CellGrid, q: &[f32; 3], k: usize) -> Result<Vec<(f32, u32)>> {
    let dims = grid_dims(&grid.bounds)?;
    let c =
        cell_of(q, grid.inv_cell).ok_or_else(|| Error::invalid(format!("grid_knn: query {q:?} is out of range")))?;
    let oq = offsets(c, &grid.bounds).map(|o| o as i32);
    let frac_gap = face_gap(q, grid.inv_cell);
    let slack = grid.slack();
    let rmax = (0..3).map(|a| oq[a].max(dims[a] as i32 - 1 - oq[a])).max().unwrap_or(0).max(0);
    let mut best: Vec<(f32, u32)> = Vec::with_capacity(k + 1);
    let visit = |o: [i32; 3], best: &mut Vec<(f32, u32)>| {
        if (0..3).any(|a| o[a] < 0 || o[a] >= dims[a] as i32) {
            return;
        }
        let Some(s) = grid.cells.find(pack(o.map(|v| v as u32))) else { return };
        for key in &grid.sorted[grid.cells.starts[s] as usize..grid.cells.starts[s + 1] as usize] {
            let cand = (distance_squared(&grid.points[key[2] as usize], q), key[2]);
            if best.len() == k && !before(cand, best[k - 1]) {
                continue;
            }
            let pos = best.iter().position(|&b| before(cand, b)).unwrap_or(best.len());
            best.insert(pos, cand);
            best.truncate(k);
        }
    };
    for r in 0..=rmax {
        // The shell, clipped to the grid: full rows where |dy| or |dz| is r, else its two ends.
        let lo: [i32; 3] = [0, 1, 2].map(|a| (-r).max(-oq[a]));
        let hi: [i32; 3] = [0, 1, 2].map(|a| r.min(dims[a] as i32 - 1 - oq[a]));
        for dz in lo[2]..=hi[2] {
            for dy in lo[1]..=hi[1] {
                if r == 0 || dy.abs() == r || dz.abs() == r {
                    for dx in lo[0]..=hi[0] {
                        visit([oq[0] + dx, oq[1] + dy, oq[2] + dz], &mut best);
                    }
                } else {
                    for dx in [-r, r].into_iter().filter(|&dx| (lo[0]..=hi[0]).contains(&dx)) {
                        visit([oq[0] + dx, oq[1] + dy, oq[2] + dz], &mut best);
                    }
                }
            }
        }
        if best.len() == k && best[k - 1].0.sqrt() * grid.inv_cell < r as f32 + frac_gap - slack {
            break;
        }
    }
    Ok(best)
}

/// The `k` nearest neighbours (itself included) of each query point `grid.points[queries[i]]`: `k` slots per
/// query of indices and squared distances, ascending, unused slots [`NO_NEIGHBOR`] and infinity.
pub fn grid_knn(grid: &CellGrid, queries: &[u32], k: usize) -> Result<(Vec<u32>, Vec<f32>)> {
    if k == 0 || k > K_MAX {
        return Err(Error::invalid(format!("grid_knn: k = {k} must be 1..={K_MAX}")));
    }
    let mut index = vec![NO_NEIGHBOR; queries.len() * k];
    let mut d2 = vec![f32::INFINITY; queries.len() * k];
    for (i, &qi) in queries.iter().enumerate() {
        let q = grid
            .points
            .get(qi as usize)
            .ok_or_else(|| Error::invalid(format!("grid_knn: query {qi} is not a point")))?;
        for (slot, (d, j)) in knn_query(grid, q, k)?.into_iter().enumerate() {
            index[i * k + slot] = j;
            d2[i * k + slot] = d;
        }
    }
    Ok((index, d2))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn brute(points: &[[f32; 3]], q: &[f32; 3], k: usize) -> Vec<(f32, u32)> {
        let mut all: Vec<(f32, u32)> =
            points.iter().enumerate().map(|(i, p)| (distance_squared(p, q), i as u32)).collect();
        all.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        all.truncate(k);
        all
    }

    #[test]
    fn matches_brute_force_with_ties_sparse_points_and_any_cell_size() {
        let mut rng = Rng::new(9);
        // Random points, a lattice (exact distances, heavy ties), a far outlier and duplicates.
        let mut pts: Vec<[f32; 3]> = (0..400).map(|_| [0; 3].map(|_: i32| rng.uniform(-1.0, 1.0) as f32)).collect();
        pts.extend((0..125).map(|i| [(i % 5) as f32 * 0.25, ((i / 5) % 5) as f32 * 0.25, (i / 25) as f32 * 0.25]));
        pts.push([9.0, -7.0, 3.0]);
        pts.extend_from_slice(&[[0.5, 0.5, 0.5]; 3]);
        for (inv_cell, k) in [(4.0, 8), (1.0, 20), (13.0, 5), (0.1, 64), (4.0, 1)] {
            let grid = CellGrid::new(&pts, inv_cell).unwrap();
            for q in 0..pts.len() as u32 {
                let got = knn_query(&grid, &pts[q as usize], k).unwrap();
                assert_eq!(got, brute(&pts, &pts[q as usize], k), "query {q}, inv_cell {inv_cell}, k {k}");
            }
        }
        let grid = CellGrid::new(&pts[..3], 4.0).unwrap();
        let (idx, d2) = grid_knn(&grid, &[0, 2], 5).unwrap();
        assert_eq!(idx[3..5], [NO_NEIGHBOR; 2]);
        assert!(d2[4].is_infinite());
        assert!(grid_knn(&grid, &[0], 65).is_err());
        assert!(grid_knn(&grid, &[3], 2).is_err());
    }
}
