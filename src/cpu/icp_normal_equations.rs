//! CPU twin of `shaders/icp_normal_equations.wgsl`: one point-to-plane ICP iteration's normal equations, in
//! f32 and in the kernel's fixed reduction shape, so that the kernel matches it bit for bit.
//!
//! Stage 0, per source point `p = source[i * stride]` (`i < used`): `m = R p + t` (the pose as f32 rows
//! `[R | t]`), the nearest target point `q` (by `(squared distance, index)`, lower index on ties) among those
//! with `d2 <= max_d2`, searched in the 3 x 3 x 3 cells around `m`'s cell of the target's cell table (cells at
//! least `max_distance` wide, so no point within the distance lies further out), and, when there is one, the
//! [`TERMS`] terms of the pair: the 21 upper-triangle entries of `J J^T` (row by row), the 6 of `-J r`, and
//! a count of 1, with `n` the target normal, `J = [m x n, n]` and `r = n . (m - q)`; zeros otherwise. Each
//! workgroup of [`WG_SIZE`] points then sums its lanes in a tree (halves: lane `l < s` adds lane `l + s`, `s` =
//! 32, 16, .., 1) into one partial. Stage 1 sums the partials: lane `l` adds partials `l, l + 64, ..` in order
//! from zero, then the same tree. Every product is rounded on its own (the kernel fences them against FMA
//! contraction) and sums run in the order written, so both sides do the same f32 operations.
//!
//! The host reads only the total (112 bytes) per iteration. The count is exact below 2^24 pairs (the pipeline
//! uses at most [`crate::estimate::icp::MAX_ICP_POINTS`]).

use super::cell_bounds::cell_of;
use super::cell_keys::{grid_dims, pack};
use super::grid_knn::{CellGrid, NO_NEIGHBOR, distance_squared};
use crate::error::{Error, Result};
use crate::estimate::icp::NormalEquations;
use nalgebra::{Matrix4, Matrix6, Vector6};

/// Lanes per workgroup: the width of the reduction tree.
pub const WG_SIZE: usize = 64;
/// Terms per pair, partial and total: 21 of `J J^T` (upper triangle, row by row), 6 of `-J r`, the count.
pub const TERMS: usize = 28;
/// One pair's terms, a workgroup's partial or the total.
pub type Terms = [f32; TERMS];
/// A rigid pose as f32 rows `[R | t]` (what the kernel's parameters hold).
pub type PoseRows = [[f32; 4]; 3];

/// The rows `[R | t]` of a 4x4 rigid transform, rounded to f32.
pub fn pose_rows(pose: &Matrix4<f64>) -> PoseRows {
    [0, 1, 2].map(|r| [0, 1, 2, 3].map(|c| pose[(r, c)] as f32))
}

/// `R p + t`, each coordinate `((r0 * p0 + r1 * p1) + r2 * p2) + t`, every product rounded on its own.
pub fn transform(pose: &PoseRows, p: &[f32; 3]) -> [f32; 3] {
    pose.map(|r| ((r[0] * p[0] + r[1] * p[1]) + r[2] * p[2]) + r[3])
}

/// `(d2, index)` lexicographic order.
fn before(a: (f32, u32), b: (f32, u32)) -> bool {
    a.0 < b.0 || (a.0 == b.0 && a.1 < b.1)
}

/// The nearest point of `grid` to `m` with squared distance `<= max_d2`, ties to the lower index, searched in
/// the 3 x 3 x 3 cells around `m`'s cell (exact when the cells are at least `sqrt(max_d2)` wide); `None` when
/// there is none (or `m`'s cell is out of range).
pub fn nearest_within(grid: &CellGrid, m: &[f32; 3], max_d2: f32) -> Result<Option<(f32, u32)>> {
    let dims = grid_dims(&grid.bounds)?.map(|d| d as i64);
    let Some(c) = cell_of(m, grid.inv_cell) else { return Ok(None) };
    let oq = [0, 1, 2].map(|a| i64::from(c[a]) - i64::from(grid.bounds.min[a]));
    let mut best = (f32::INFINITY, NO_NEIGHBOR);
    for dz in -1..=1 {
        for dy in -1..=1 {
            for dx in -1..=1 {
                let o = [oq[0] + dx, oq[1] + dy, oq[2] + dz];
                if (0..3).any(|a| o[a] < 0 || o[a] >= dims[a]) {
                    continue;
                }
                let Some(s) = grid.cells.find(pack(o.map(|v| v as u32))) else { continue };
                for key in &grid.sorted[grid.cells.starts[s] as usize..grid.cells.starts[s + 1] as usize] {
                    let cand = (distance_squared(&grid.points[key[2] as usize], m), key[2]);
                    if cand.0 <= max_d2 && before(cand, best) {
                        best = cand;
                    }
                }
            }
        }
    }
    Ok((best.1 != NO_NEIGHBOR).then_some(best))
}

/// The terms of the pair (moved source point `m`, target point `q` with normal `n`); see the module docs.
pub fn pair_terms(m: &[f32; 3], q: &[f32; 3], n: &[f32; 3]) -> Terms {
    let d = [m[0] - q[0], m[1] - q[1], m[2] - q[2]];
    let r = (n[0] * d[0] + n[1] * d[1]) + n[2] * d[2];
    let j = [m[1] * n[2] - m[2] * n[1], m[2] * n[0] - m[0] * n[2], m[0] * n[1] - m[1] * n[0], n[0], n[1], n[2]];
    let mut t = [0.0f32; TERMS];
    let mut at = 0;
    for a in 0..6 {
        for b in a..6 {
            t[at] = j[a] * j[b];
            at += 1;
        }
    }
    for a in 0..6 {
        t[21 + a] = -(j[a] * r);
    }
    t[27] = 1.0;
    t
}

/// Sums `lanes` (exactly [`WG_SIZE`]) in the kernel's tree: for `s` = 32, 16, .., 1, lane `l < s` adds lane
/// `l + s`; the result is lane 0.
fn tree(lanes: &mut [Terms]) -> Terms {
    let mut s = WG_SIZE / 2;
    while s > 0 {
        let (low, high) = lanes.split_at_mut(s);
        for (a, b) in low.iter_mut().zip(&high[..s]) {
            for (x, y) in a.iter_mut().zip(b) {
                *x += *y;
            }
        }
        s /= 2;
    }
    lanes[0]
}

/// What one iteration's two stages produce: each workgroup's partial, and their total.
#[derive(Clone, Debug, PartialEq)]
pub struct IcpSums {
    /// The total (stage 1).
    pub total: Terms,
    /// One partial per workgroup of [`WG_SIZE`] source points (stage 0).
    pub partials: Vec<Terms>,
}

/// The target of an ICP iteration: its points' cell table (cells at least the distance wide) and unit
/// normals.
#[derive(Clone, Copy, Debug)]
pub struct IcpTarget<'a> {
    /// Target points and their cell table.
    pub grid: &'a CellGrid,
    /// One normal per target point.
    pub normals: &'a [[f32; 3]],
}

/// Source points used at `stride`: `ceil(points / stride)`.
pub fn used_points(points: usize, stride: usize) -> usize {
    points.div_ceil(stride.max(1))
}

/// Workgroups of stage 0 for `used` source points.
pub fn partial_count(used: usize) -> usize {
    used.div_ceil(WG_SIZE)
}

/// Checks the inputs both sides share: a positive stride, positive finite `max_distance`, cells at least
/// `max_distance` wide, one normal per target point.
pub fn check(target: &IcpTarget<'_>, stride: usize, max_distance: f32) -> Result<()> {
    if stride == 0 {
        return Err(Error::invalid("icp_normal_equations: the stride must be positive"));
    }
    if !(max_distance.is_finite() && max_distance > 0.0) {
        return Err(Error::invalid(format!("icp_normal_equations: max distance {max_distance} must be positive")));
    }
    if max_distance * target.grid.inv_cell > 1.0 {
        return Err(Error::invalid(format!(
            "icp_normal_equations: cells of {} are narrower than the max distance {max_distance}",
            1.0 / target.grid.inv_cell
        )));
    }
    if target.normals.len() != target.grid.points.len() {
        return Err(Error::invalid(format!(
            "icp_normal_equations: {} normals for {} target points",
            target.normals.len(),
            target.grid.points.len()
        )));
    }
    Ok(())
}

/// The normal equations of every `stride`-th point of `source` moved by `pose` against `target`, pairs within
/// `max_distance` (compared as `d2 <= max_distance * max_distance` in f32): both stages' results.
pub fn icp_normal_equations(
    source: &[[f32; 3]],
    stride: usize,
    target: &IcpTarget<'_>,
    pose: &PoseRows,
    max_distance: f32,
) -> Result<IcpSums> {
    check(target, stride, max_distance)?;
    let max_d2 = max_distance * max_distance;
    let used = used_points(source.len(), stride);
    let mut partials = Vec::with_capacity(partial_count(used));
    for w in 0..partial_count(used) {
        let mut lanes = [[0.0f32; TERMS]; WG_SIZE];
        for (l, lane) in lanes.iter_mut().enumerate() {
            let i = w * WG_SIZE + l;
            if i >= used {
                continue;
            }
            let m = transform(pose, &source[i * stride]);
            if let Some((_, j)) = nearest_within(target.grid, &m, max_d2)? {
                *lane = pair_terms(&m, &target.grid.points[j as usize], &target.normals[j as usize]);
            }
        }
        partials.push(tree(&mut lanes));
    }
    let mut lanes = [[0.0f32; TERMS]; WG_SIZE];
    for (l, lane) in lanes.iter_mut().enumerate() {
        for p in partials.iter().skip(l).step_by(WG_SIZE) {
            for (x, y) in lane.iter_mut().zip(p) {
                *x += *y;
            }
        }
    }
    Ok(IcpSums { total: tree(&mut lanes), partials })
}

/// The total as the normal equations of [`crate::estimate::icp::iterate`] (f64, `J J^T` mirrored).
pub fn normal_equations(total: &Terms) -> NormalEquations {
    let mut ata = Matrix6::<f64>::zeros();
    let mut at = 0;
    for a in 0..6 {
        for b in a..6 {
            ata[(a, b)] = f64::from(total[at]);
            ata[(b, a)] = f64::from(total[at]);
            at += 1;
        }
    }
    let atb = Vector6::from_fn(|a, _| f64::from(total[21 + a]));
    NormalEquations { ata, atb, used: total[27] as usize }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pose::{matrix_from_parts, v3};
    use crate::rng::Rng;
    use nalgebra::{Rotation3, Vector3};

    fn brute_nearest(points: &[[f32; 3]], m: &[f32; 3], max_d2: f32) -> Option<(f32, u32)> {
        points
            .iter()
            .enumerate()
            .map(|(i, p)| (distance_squared(p, m), i as u32))
            .filter(|c| c.0 <= max_d2)
            .min_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)))
    }

    /// The cell walk finds the brute-force nearest point within the distance (ties to the lower index, none
    /// beyond it), and the reduced sums equal the f64 normal equations of those pairs within f32 rounding.
    #[test]
    fn matches_brute_force_pairs_and_f64_sums() {
        let mut rng = Rng::new(21);
        let unit = |rng: &mut Rng| {
            let v = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
            [v.x as f32, v.y as f32, v.z as f32]
        };
        // Random points, a dyadic lattice (exact ties for sources at midpoints) and a far cluster.
        let mut target: Vec<[f32; 3]> = (0..600).map(|_| [0; 3].map(|_: i32| rng.uniform(-1.0, 1.0) as f32)).collect();
        target.extend((0..64).map(|i| [(i % 4) as f32 * 0.25, ((i / 4) % 4) as f32 * 0.25, (i / 16) as f32 * 0.25]));
        target.extend((0..50).map(|_| [0; 3].map(|_: i32| (5.0 + rng.uniform(0.0, 0.5)) as f32)));
        let normals: Vec<[f32; 3]> = (0..target.len()).map(|_| unit(&mut rng)).collect();
        let max_distance = 0.2f32;
        let grid = CellGrid::new(&target, 1.0 / (max_distance * 1.001)).unwrap();
        let mut source: Vec<[f32; 3]> = (0..900).map(|_| [0; 3].map(|_: i32| rng.uniform(-1.3, 1.3) as f32)).collect();
        source.extend((0..27).map(|i| [(i % 3) as f32 * 0.25 + 0.125, ((i / 3) % 3) as f32 * 0.25, 0.25]));
        source.extend((0..40).map(|_| [0; 3].map(|_: i32| (3.0 + rng.uniform(0.0, 1.0)) as f32)));
        let pose = matrix_from_parts(
            &Rotation3::new(Vector3::new(0.02, -0.03, 0.01)).into_inner(),
            &Vector3::new(0.01, 0.0, -0.02),
        );
        let identity = Matrix4::identity();
        let max_d2 = max_distance * max_distance;
        for (pose, stride) in [(pose, 1), (identity, 1), (pose, 3)] {
            let rows = pose_rows(&pose);
            let (mut ata, mut atb, mut used, mut sum_abs) = (Matrix6::zeros(), Vector6::zeros(), 0, 0.0);
            let mut ties = 0;
            for p in source.iter().step_by(stride) {
                let m = transform(&rows, p);
                let got = nearest_within(&grid, &m, max_d2).unwrap();
                assert_eq!(got, brute_nearest(&target, &m, max_d2), "{m:?}");
                let Some((d2, j)) = got else { continue };
                ties += target.iter().filter(|q| distance_squared(q, &m) == d2).count() - 1;
                let (q, n, mm) = (v3(target[j as usize]), v3(normals[j as usize]), v3(m));
                let r = n.dot(&(mm - q));
                let c = mm.cross(&n);
                let jac = Vector6::new(c.x, c.y, c.z, n.x, n.y, n.z);
                ata += jac * jac.transpose();
                atb -= jac * r;
                sum_abs += jac.abs().sum().powi(2) + (jac.abs() * r.abs()).sum();
                used += 1;
            }
            if stride == 1 && pose == identity {
                assert!(ties > 0, "the lattice midpoints give ties");
            }
            let sums = icp_normal_equations(
                &source,
                stride,
                &IcpTarget { grid: &grid, normals: &normals },
                &rows,
                max_distance,
            )
            .unwrap();
            assert_eq!(sums.partials.len(), partial_count(used_points(source.len(), stride)));
            let eq = normal_equations(&sums.total);
            assert!(used > 100 && used < source.len() / stride, "some pairs, not all: {used}");
            assert_eq!(eq.used, used);
            // Each term is an f32 rounding of a few products (relative 8 eps of the f64 value, m in f32), summed
            // in at most 64 + 64 + 12 steps (each adding eps of the running sum): 2^-16 of sum |terms| covers it.
            let tol = sum_abs * 2f64.powi(-16);
            assert!((eq.ata - ata).abs().max() <= tol, "{} vs {tol}", (eq.ata - ata).abs().max());
            assert!((eq.atb - atb).abs().max() <= tol, "{} vs {tol}", (eq.atb - atb).abs().max());
        }
        let bad = IcpTarget { grid: &grid, normals: &normals[1..] };
        assert!(icp_normal_equations(&source, 1, &bad, &pose_rows(&identity), max_distance).is_err());
        let target_ok = IcpTarget { grid: &grid, normals: &normals };
        assert!(icp_normal_equations(&source, 1, &target_ok, &pose_rows(&identity), 0.3).is_err());
        assert!(icp_normal_equations(&source, 0, &target_ok, &pose_rows(&identity), 0.1).is_err());
    }
}
