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
    let mut n = smallest_eigenvector(&cov).unwrap_or_else(|| iterative_smallest_eigenvector(cov));
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

/// Smallest relative gap `(mid - min) / max |eigenvalue|` for which [`smallest_eigenvector`] answers: below it
/// the closed form's eigenvector loses digits the f32 normal keeps, and the iterative solver answers instead.
const MIN_RELATIVE_GAP: f64 = 1e-4;

/// The eigenvector of the smallest eigenvalue of the symmetric `a` in closed form (not normalised), or `None`
/// where the closed form is not accurate to f32 (a smallest eigenvalue within [`MIN_RELATIVE_GAP`] of the
/// next, a degenerate or non-finite matrix). The eigenvalues come from the trigonometric solution of the
/// characteristic cubic; the eigenvector is the longest cross product of two rows of `a - min I`, which spans
/// its null space. Where it answers it agrees with a full iterative decomposition to about `1e-12 / gap`
/// (a test checks it), far below the f32 rounding of the normal.
fn smallest_eigenvector(a: &Matrix3<f64>) -> Option<Vector3<f64>> {
    let mean = a.trace() / 3.0;
    let centred = a - Matrix3::from_diagonal_element(mean);
    // p: the mean square of the centred matrix's entries / 2 (its eigenvalues' spread); q: half its determinant.
    let p = centred.iter().map(|v| v * v).sum::<f64>() / 6.0;
    if !(p > 0.0 && p.is_finite()) {
        return None;
    }
    let q = centred.determinant() / 2.0;
    let sqrt_p = p.sqrt();
    // phi in [0, pi/3]: the eigenvalues are mean + 2 sqrt(p) cos(phi + 2 pi k / 3).
    let phi = ((p * p * p - q * q).max(0.0).sqrt()).atan2(q) / 3.0;
    let (sin, cos) = phi.sin_cos();
    let root3_sin = 3f64.sqrt() * sin;
    let max = mean + 2.0 * sqrt_p * cos;
    let min = mean - sqrt_p * (cos + root3_sin);
    let mid = mean - sqrt_p * (cos - root3_sin);
    let scale = max.abs().max(min.abs()).max(mid.abs());
    if !(mid - min > MIN_RELATIVE_GAP * scale) {
        return None;
    }
    let shifted = a - Matrix3::from_diagonal_element(min);
    let (r0, r1, r2) = (shifted.row(0).transpose(), shifted.row(1).transpose(), shifted.row(2).transpose());
    let candidates = [r0.cross(&r1), r0.cross(&r2), r1.cross(&r2)];
    let best = candidates.iter().max_by(|x, y| x.norm_squared().total_cmp(&y.norm_squared()))?;
    // The rows of a - min I span a plane whose area is at least gap^2 / 2-ish; a cross product far smaller is
    // rounding, not the null space.
    let gap = mid - min;
    (best.norm_squared() > (1e-3 * gap * gap).powi(2)).then_some(*best)
}

/// The eigenvector of the smallest eigenvalue of the symmetric `cov` by `nalgebra`'s iterative solver.
fn iterative_smallest_eigenvector(cov: Matrix3<f64>) -> Vector3<f64> {
    let eig = SymmetricEigen::new(cov);
    let (imin, _) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .fold((0, f64::INFINITY), |best, (i, &v)| if v < best.1 { (i, v) } else { best });
    eig.eigenvectors.column(imin).into_owned()
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

    /// The closed form against the iterative solver on random covariances of every shape: planes, lines,
    /// blobs, near-repeated eigenvalues; the same direction wherever it answers, and it answers on surfaces.
    #[test]
    fn the_closed_form_eigenvector_is_the_iterative_one() {
        let mut rng = Rng::new(9);
        let (mut answered, mut planes) = (0, 0);
        for case in 0..20_000 {
            let rotation = nalgebra::Rotation3::from_scaled_axis(Vector3::new(
                rng.uniform(-3.0, 3.0),
                rng.uniform(-3.0, 3.0),
                rng.uniform(-3.0, 3.0),
            ));
            let big = 10f64.powf(rng.uniform(-8.0, 4.0));
            let mut eigenvalues = [big, big * rng.uniform(0.0, 1.0), big * rng.uniform(0.0, 1.0)];
            match case % 4 {
                // A surface: the smallest far below the other two.
                0 => eigenvalues[2] = big * 10f64.powf(rng.uniform(-9.0, -1.0)),
                // The two smallest nearly equal (a line, or a blob).
                1 => eigenvalues[2] = eigenvalues[1] * (1.0 + 10f64.powf(rng.uniform(-12.0, -2.0))),
                // The two largest equal (a disc).
                2 => eigenvalues[1] = eigenvalues[0],
                _ => {}
            }
            let cov =
                rotation.matrix() * Matrix3::from_diagonal(&Vector3::from(eigenvalues)) * rotation.matrix().transpose();
            let cov = (cov + cov.transpose()) / 2.0;
            let iterative = iterative_smallest_eigenvector(cov).normalize();
            let Some(closed) = smallest_eigenvector(&cov) else { continue };
            let closed = closed.normalize();
            let mut sorted = eigenvalues;
            sorted.sort_by(f64::total_cmp);
            let relative_gap = (sorted[1] - sorted[0]) / sorted[2];
            let sine = closed.cross(&iterative).norm();
            assert!(sine < 1e-11 / relative_gap.min(1.0), "case {case}: {eigenvalues:?}, sine {sine}");
            answered += 1;
            planes += usize::from(case % 4 == 0);
        }
        // Every surface-like case (gap far above the threshold) is answered in closed form.
        assert!(planes > 4_900, "{planes} of 5000 surfaces answered");
        assert!(answered > 12_000, "{answered}");
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
