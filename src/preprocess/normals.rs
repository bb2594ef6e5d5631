//! Normals by PCA over the k nearest neighbours, oriented towards a viewpoint.

use crate::spatial::{Neighbor, PointIndex, map_nearest};
use nalgebra::{Matrix3, SymmetricEigen, Vector3};

/// The unit normal of each point: the eigenvector of the smallest eigenvalue of the covariance of its `k`
/// nearest neighbours (itself included; ties at the k-th distance broken towards the lower index), flipped to
/// face `viewpoint`. Points with fewer than 3 neighbours or a degenerate neighbourhood get the direction to the
/// viewpoint (or +z when they sit on it).
pub fn estimate_normals(points: &[[f32; 3]], index: &PointIndex, k: usize, viewpoint: [f32; 3]) -> Vec<[f32; 3]> {
    let all: Vec<usize> = (0..points.len()).collect();
    estimate_normals_at(points, index, &all, k, viewpoint)
}

/// [`estimate_normals`] for the points `ids` only, in that order: each is exactly the normal
/// `estimate_normals` gives that point.
pub fn estimate_normals_at(
    points: &[[f32; 3]],
    index: &PointIndex,
    ids: &[usize],
    k: usize,
    viewpoint: [f32; 3],
) -> Vec<[f32; 3]> {
    map_nearest(points, index, ids, k.max(3), |i, neighbors| normal_of(points, &points[i], neighbors, viewpoint))
}

/// The normal of the point at `p` from its `neighbors` (see [`estimate_normals`]).
fn normal_of(points: &[[f32; 3]], p: &[f32; 3], neighbors: &[Neighbor], viewpoint: [f32; 3]) -> [f32; 3] {
    let to_view = Vector3::new(viewpoint[0] - p[0], viewpoint[1] - p[1], viewpoint[2] - p[2]);
    let fallback = || {
        let n = to_view.norm();
        if n > 0.0 { (to_view / n).into() } else { [0.0, 0.0, 1.0] }
    };
    if neighbors.len() < 3 {
        return fallback();
    }
    let at = |n: &Neighbor| {
        let q = points[n.index];
        Vector3::new(q[0] as f64, q[1] as f64, q[2] as f64)
    };
    let mean = neighbors.iter().map(at).fold(Vector3::zeros(), |sum, q| sum + q) / neighbors.len() as f64;
    let cov = neighbors.iter().map(at).fold(Matrix3::zeros(), |acc, q| {
        let d = q - mean;
        acc + d * d.transpose()
    });
    if cov.norm() == 0.0 {
        return fallback();
    }
    let eig = SymmetricEigen::new(cov);
    let (imin, _) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .fold((0, f64::INFINITY), |best, (i, &v)| if v < best.1 { (i, v) } else { best });
    let mut n: Vector3<f64> = eig.eigenvectors.column(imin).into_owned();
    let len = n.norm();
    if len <= 0.0 || !len.is_finite() {
        return fallback();
    }
    n /= len;
    if n.dot(&to_view.cast::<f64>()) < 0.0 {
        n = -n;
    }
    [n.x as f32, n.y as f32, n.z as f32]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn plane_normals_point_to_viewpoint() {
        let mut rng = Rng::new(2);
        let pts: Vec<[f32; 3]> =
            (0..400).map(|_| [rng.uniform(-1.0, 1.0) as f32, rng.uniform(-1.0, 1.0) as f32, 2.0]).collect();
        let index = PointIndex::new(&pts).unwrap();
        for n in estimate_normals(&pts, &index, 10, [0.0; 3]) {
            assert!((n[2] + 1.0).abs() < 1e-4, "{n:?}");
        }
        for n in estimate_normals(&pts, &index, 10, [0.0, 0.0, 5.0]) {
            assert!((n[2] - 1.0).abs() < 1e-4, "{n:?}");
        }
    }

    #[test]
    fn normals_at_a_subset_are_exactly_the_full_ones() {
        let mut rng = Rng::new(4);
        let pts: Vec<[f32; 3]> = (0..500).map(|_| [0; 3].map(|_: i32| rng.uniform(-1.0, 1.0) as f32)).collect();
        let index = PointIndex::new(&pts).unwrap();
        let all = estimate_normals(&pts, &index, 12, [0.0, 0.0, 3.0]);
        let ids = [499, 3, 250, 3, 0];
        let some = estimate_normals_at(&pts, &index, &ids, 12, [0.0, 0.0, 3.0]);
        for (n, &i) in some.iter().zip(&ids) {
            assert_eq!(n, &all[i]);
        }
    }
}
