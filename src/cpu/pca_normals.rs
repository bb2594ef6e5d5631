//! CPU twin of `shaders/pca_normals.wgsl`: PCA normals from k-nearest-neighbour lists, oriented towards a
//! viewpoint, in f32 with a fixed cyclic Jacobi eigensolver that the kernel runs operation for operation.
//!
//! The definition is [`crate::preprocess::normals`]'s (the eigenvector of the smallest eigenvalue of the
//! neighbourhood's covariance, itself included; flipped so that `n . (viewpoint - p) >= 0`; the direction to
//! the viewpoint, or +z on it, for fewer than 3 neighbours or a degenerate neighbourhood), computed in f32:
//! the covariance is accumulated relative to the query point (so its rounding follows the neighbourhood's
//! size, not the coordinates' magnitude), and the eigenvectors come from [`JACOBI_SWEEPS`] sweeps of
//! rotations `(0,1), (0,2), (1,2)`. The CPU pipeline still uses the f64 `nalgebra` solver; both agree to f32
//! rounding on well-conditioned neighbourhoods (a test checks it).

use super::grid_knn::NO_NEIGHBOR;
use crate::error::{Error, Result};

/// Jacobi sweeps: a 3x3 symmetric matrix converges to f32 precision in 4 or 5; the rest are no-ops.
pub const JACOBI_SWEEPS: usize = 8;

/// The eigenvalues (diagonal) and eigenvectors (columns of `v`, row-major `v[row][col]`) of the symmetric
/// `a` by [`JACOBI_SWEEPS`] cyclic Jacobi sweeps.
pub fn jacobi_eigen(mut a: [[f32; 3]; 3]) -> ([f32; 3], [[f32; 3]; 3]) {
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _ in 0..JACOBI_SWEEPS {
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            let apq = a[p][q];
            if apq == 0.0 {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * apq);
            let t = if theta.abs() > 1e15 {
                0.5 / theta
            } else {
                let t = 1.0 / (theta.abs() + (theta * theta + 1.0).sqrt());
                if theta < 0.0 { -t } else { t }
            };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            // A <- J^T A J with J the rotation in the (p, q) plane; V <- V J.
            for row in &mut a {
                let (arp, arq) = (row[p], row[q]);
                row[p] = c * arp - s * arq;
                row[q] = s * arp + c * arq;
            }
            let (mut row_p, mut row_q) = (a[p], a[q]);
            for (apr, aqr) in row_p.iter_mut().zip(&mut row_q) {
                let (x, y) = (*apr, *aqr);
                *apr = c * x - s * y;
                *aqr = s * x + c * y;
            }
            (a[p], a[q]) = (row_p, row_q);
            for row in &mut v {
                let (vp, vq) = (row[p], row[q]);
                row[p] = c * vp - s * vq;
                row[q] = s * vp + c * vq;
            }
        }
    }
    ([a[0][0], a[1][1], a[2][2]], v)
}

/// The normal of `p` from its neighbours `nbrs` (indices into `points`), towards `viewpoint`.
pub fn pca_normal(points: &[[f32; 3]], p: &[f32; 3], nbrs: &[u32], viewpoint: [f32; 3]) -> [f32; 3] {
    let to_view = [viewpoint[0] - p[0], viewpoint[1] - p[1], viewpoint[2] - p[2]];
    let fallback = || {
        let len = (to_view[0] * to_view[0] + to_view[1] * to_view[1] + to_view[2] * to_view[2]).sqrt();
        if len > 0.0 { to_view.map(|c| c / len) } else { [0.0, 0.0, 1.0] }
    };
    if nbrs.len() < 3 {
        return fallback();
    }
    let rel = |j: u32| {
        let q = points[j as usize];
        [q[0] - p[0], q[1] - p[1], q[2] - p[2]]
    };
    let mut mean = [0.0f32; 3];
    for &j in nbrs {
        let d = rel(j);
        for (m, v) in mean.iter_mut().zip(d) {
            *m += v;
        }
    }
    let count = nbrs.len() as f32;
    mean = mean.map(|m| m / count);
    let mut cov = [[0.0f32; 3]; 3];
    for &j in nbrs {
        let r = rel(j);
        let d = [r[0] - mean[0], r[1] - mean[1], r[2] - mean[2]];
        for (row, da) in cov.iter_mut().zip(d) {
            for (c, db) in row.iter_mut().zip(d) {
                *c += da * db;
            }
        }
    }
    if cov.iter().flatten().all(|&c| c == 0.0) {
        return fallback();
    }
    let (values, v) = jacobi_eigen(cov);
    // The smallest eigenvalue, the lower index on ties.
    let imin = (1..3).fold(0, |m, i| if values[i] < values[m] { i } else { m });
    let n = [v[0][imin], v[1][imin], v[2][imin]];
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    if !(len > 0.0 && len.is_finite()) {
        return fallback();
    }
    let n = n.map(|c| c / len);
    if n[0] * to_view[0] + n[1] * to_view[1] + n[2] * to_view[2] < 0.0 { n.map(|c| -c) } else { n }
}

/// Checks the inputs of [`pca_normals`] (and of its kernel): `queries x k` neighbour slots, every index a point
/// or [`NO_NEIGHBOR`].
pub fn check_inputs(points: &[[f32; 3]], queries: &[u32], knn_index: &[u32], k: usize) -> Result<()> {
    if k == 0 || knn_index.len() != queries.len() * k {
        return Err(Error::invalid("pca_normals: the neighbour lists are not queries x k"));
    }
    let bad = |j: u32| j != NO_NEIGHBOR && j as usize >= points.len();
    if queries.iter().any(|&q| q as usize >= points.len()) || knn_index.iter().any(|&j| bad(j)) {
        return Err(Error::invalid("pca_normals: an index is not a point"));
    }
    Ok(())
}

/// The normal of each query point `points[queries[i]]` from its `k` neighbour slots in `knn_index`
/// (`queries x k`, unused slots [`NO_NEIGHBOR`]), towards `viewpoint`.
pub fn pca_normals(
    points: &[[f32; 3]],
    queries: &[u32],
    knn_index: &[u32],
    k: usize,
    viewpoint: [f32; 3],
) -> Result<Vec<[f32; 3]>> {
    check_inputs(points, queries, knn_index, k)?;
    Ok(queries
        .iter()
        .zip(knn_index.chunks_exact(k))
        .map(|(&q, slots)| {
            let used = slots.iter().position(|&j| j == NO_NEIGHBOR).unwrap_or(k);
            pca_normal(points, &points[q as usize], &slots[..used], viewpoint)
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cpu::grid_knn::{CellGrid, grid_knn};
    use crate::preprocess::estimate_normals;
    use crate::rng::Rng;
    use crate::spatial::PointIndex;

    #[test]
    fn jacobi_diagonalises() {
        let a = [[4.0, 1.0, 0.5], [1.0, 3.0, 0.25], [0.5, 0.25, 1.0]];
        let (w, v) = jacobi_eigen(a);
        for c in 0..3 {
            for r in 0..3 {
                let av: f32 = (0..3).map(|k| a[r][k] * v[k][c]).sum();
                assert!((av - w[c] * v[r][c]).abs() < 1e-5, "column {c}");
            }
        }
    }

    /// On curved, noisy surfaces the f32 twin agrees with the f64 CPU definition wherever the smallest
    /// eigenvalue is well separated (error ~ eps * largest / gap).
    #[test]
    fn agrees_with_the_cpu_definition_on_well_conditioned_points() {
        let mut rng = Rng::new(12);
        let pts: Vec<[f32; 3]> = (0..600)
            .map(|_| {
                let (x, y) = (rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0));
                [x as f32 + 30.0, y as f32, (0.3 * x * x - 0.2 * y + 0.01 * rng.normal()) as f32]
            })
            .collect();
        let k = 12;
        let view = [30.0, 0.0, 5.0];
        let want = estimate_normals(&pts, &PointIndex::new(&pts).unwrap(), k, view);
        let grid = CellGrid::new(&pts, 6.0).unwrap();
        let queries: Vec<u32> = (0..pts.len() as u32).collect();
        let (idx, _) = grid_knn(&grid, &queries, k).unwrap();
        let got = pca_normals(&pts, &queries, &idx, k, view).unwrap();
        let mut checked = 0;
        for (i, (g, w)) in got.iter().zip(&want).enumerate() {
            let slots: Vec<u32> = idx[i * k..][..k].to_vec();
            if gap_ratio(&pts, &pts[i], &slots) < 0.05 {
                continue;
            }
            checked += 1;
            let err = (0..3).map(|a| (g[a] - w[a]).powi(2)).sum::<f32>().sqrt();
            assert!(err < 1e-3, "point {i}: {g:?} vs {w:?}");
        }
        assert!(checked > 400, "{checked}");
    }

    /// (second smallest - smallest) / largest eigenvalue of the neighbourhood (f64).
    fn gap_ratio(points: &[[f32; 3]], p: &[f32; 3], nbrs: &[u32]) -> f64 {
        let pts: Vec<nalgebra::Vector3<f64>> =
            nbrs.iter().map(|&j| nalgebra::Vector3::from(points[j as usize].map(f64::from))).collect();
        let mean = pts.iter().sum::<nalgebra::Vector3<f64>>() / pts.len() as f64;
        let cov = pts.iter().fold(nalgebra::Matrix3::zeros(), |acc, q| acc + (q - mean) * (q - mean).transpose());
        let mut w: Vec<f64> = nalgebra::SymmetricEigen::new(cov).eigenvalues.iter().copied().collect();
        w.sort_by(f64::total_cmp);
        let _ = p;
        (w[1] - w[0]) / w[2].max(1e-300)
    }
}
