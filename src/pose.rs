//! Rotations and rigid transforms, the one module every part of dpr-gpu uses for them: least-squares rigid fit
//! (Kabsch/Umeyama without scale), conversions between 4x4 matrices, hypotheses, quaternions and rotation
//! matrices, inverses, the skew matrix, projection onto SO(3), random rotations, rotations about a point, the
//! rotation / translation error measures, and ([`so3`]) the exponential, logarithm and Jacobians of SO(3).
//! Matrices are `target_from_source` (p_target = T p_source) unless a name says otherwise.

pub mod so3;

use crate::cpu::hypotheses::Hypothesis;
use crate::rng::Rng;
use nalgebra::{Matrix3, Matrix4, Rotation3, Unit, UnitQuaternion, Vector3};

/// f32 point to f64 vector.
pub fn v3(p: [f32; 3]) -> Vector3<f64> {
    Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64)
}

/// Applies a 4x4 rigid transform to a point.
pub fn transform_point(t: &Matrix4<f64>, p: [f32; 3]) -> [f32; 3] {
    let q = t.fixed_view::<3, 3>(0, 0) * v3(p) + t.fixed_view::<3, 1>(0, 3);
    [q.x as f32, q.y as f32, q.z as f32]
}

/// 4x4 matrix from rotation and translation.
pub fn matrix_from_parts(r: &Matrix3<f64>, t: &Vector3<f64>) -> Matrix4<f64> {
    let mut m = Matrix4::identity();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(r);
    m.fixed_view_mut::<3, 1>(0, 3).copy_from(t);
    m
}

/// The inverse of a rigid transform: [Rᵀ | −Rᵀ t] (`source_from_target` of a `target_from_source`).
pub fn rigid_inverse(t: &Matrix4<f64>) -> Matrix4<f64> {
    let r = t.fixed_view::<3, 3>(0, 0).transpose();
    matrix_from_parts(&r, &(-(r * t.fixed_view::<3, 1>(0, 3))))
}

/// The inverse of a 4x4 transform as the 3DMatch evaluation (MATLAB `inv`) computes it: the general inverse,
/// or [`rigid_inverse`] when the matrix is singular. For matrices read from files (gt.log, trajectories),
/// which are rigid only to the digits written, and everything derived from them; [`rigid_inverse`] is for
/// transforms built as rigid. (Both give the same matrix up to rounding for a rigid transform.)
pub fn inverse(t: &Matrix4<f64>) -> Matrix4<f64> {
    t.try_inverse().unwrap_or_else(|| rigid_inverse(t))
}

/// The skew matrix [q]x with [q]x v = q × v.
pub fn skew(q: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -q.z, q.y, q.z, 0.0, -q.x, -q.y, q.x, 0.0)
}

/// A unit quaternion `[w, x, y, z]` drawn uniformly from SO(3) restricted to angles up to `max_deg` (by
/// rejection on [`Rng::unit_quaternion`]; at most a few hundred draws for angles down to 20 degrees, and the
/// identity when `max_deg` is tiny and every draw fails). From 180 degrees up it is one draw, unrestricted.
pub fn random_rotation(rng: &mut Rng, max_deg: f64) -> [f64; 4] {
    if max_deg >= 180.0 {
        return rng.unit_quaternion();
    }
    let max_w = (max_deg.to_radians() / 2.0).cos();
    for _ in 0..100_000 {
        let q = rng.unit_quaternion();
        // angle = 2 acos(|w|) <= max  <=>  |w| >= cos(max / 2)
        if q[0].abs() >= max_w {
            return q;
        }
    }
    [1.0, 0.0, 0.0, 0.0]
}

/// True when rotating by `degrees` leaves every point in place (a multiple of 360).
pub fn is_identity_angle(degrees: f64) -> bool {
    degrees.rem_euclid(360.0) == 0.0
}

/// The rigid motion rotating by `degrees` about the unit `axis` through `center`: x ↦ R (x − c) + c.
/// Exactly the identity for multiples of 360 degrees.
pub fn rotation_about(axis: &Unit<Vector3<f64>>, center: &Vector3<f64>, degrees: f64) -> Matrix4<f64> {
    if is_identity_angle(degrees) {
        return Matrix4::identity();
    }
    let r = Rotation3::from_axis_angle(axis, degrees.to_radians()).into_inner();
    matrix_from_parts(&r, &(center - r * center))
}

/// 4x4 matrix of a hypothesis.
pub fn matrix_from_hypothesis(h: &Hypothesis) -> Matrix4<f64> {
    let r = Matrix3::from_row_slice(&h.rotation.map(|v| v as f64));
    matrix_from_parts(&r, &v3(h.translation))
}

/// Hypothesis of a 4x4 matrix.
pub fn hypothesis_from_matrix(m: &Matrix4<f64>) -> Hypothesis {
    let mut rotation = [0f32; 9];
    for r in 0..3 {
        for c in 0..3 {
            rotation[r * 3 + c] = m[(r, c)] as f32;
        }
    }
    Hypothesis { rotation, translation: [m[(0, 3)] as f32, m[(1, 3)] as f32, m[(2, 3)] as f32] }
}

/// The unit quaternion `[w, x, y, z]` (Hamilton) of a rotation matrix, with `w >= 0`.
///
/// Equal to the protocol's w = sqrt(1 + trace R) / 2, x = (R32 - R23) / (4w), ... wherever that formula is well
/// conditioned, but computed with Shepperd's method (largest of w, x, y, z first) so that rotations near 180
/// degrees (w near 0) stay accurate. The sign is then chosen so that `w >= 0`.
pub fn quaternion_from_matrix(r: &Matrix3<f64>) -> [f64; 4] {
    let trace = r[(0, 0)] + r[(1, 1)] + r[(2, 2)];
    let q = if trace >= r[(0, 0)].max(r[(1, 1)]).max(r[(2, 2)]) {
        let w = 0.5 * (1.0 + trace).max(0.0).sqrt();
        let s = 0.25 / w;
        [w, (r[(2, 1)] - r[(1, 2)]) * s, (r[(0, 2)] - r[(2, 0)]) * s, (r[(1, 0)] - r[(0, 1)]) * s]
    } else if r[(0, 0)] >= r[(1, 1)] && r[(0, 0)] >= r[(2, 2)] {
        let x = 0.5 * (1.0 + r[(0, 0)] - r[(1, 1)] - r[(2, 2)]).max(0.0).sqrt();
        let s = 0.25 / x;
        [(r[(2, 1)] - r[(1, 2)]) * s, x, (r[(0, 1)] + r[(1, 0)]) * s, (r[(0, 2)] + r[(2, 0)]) * s]
    } else if r[(1, 1)] >= r[(2, 2)] {
        let y = 0.5 * (1.0 - r[(0, 0)] + r[(1, 1)] - r[(2, 2)]).max(0.0).sqrt();
        let s = 0.25 / y;
        [(r[(0, 2)] - r[(2, 0)]) * s, (r[(0, 1)] + r[(1, 0)]) * s, y, (r[(1, 2)] + r[(2, 1)]) * s]
    } else {
        let z = 0.5 * (1.0 - r[(0, 0)] - r[(1, 1)] + r[(2, 2)]).max(0.0).sqrt();
        let s = 0.25 / z;
        [(r[(1, 0)] - r[(0, 1)]) * s, (r[(0, 2)] + r[(2, 0)]) * s, (r[(1, 2)] + r[(2, 1)]) * s, z]
    };
    if q[0] < 0.0 { q.map(|c| -c) } else { q }
}

/// The rotation nearest to `r` (SVD projection onto SO(3), reflection-corrected), so slightly non-orthonormal
/// ground truth can be used as a rotation. The identity when the SVD fails.
pub fn nearest_rotation(r: &Matrix3<f64>) -> Matrix3<f64> {
    let svd = r.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else { return Matrix3::identity() };
    let d = (u * v_t).determinant().signum();
    u * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * v_t
}

/// Rotation matrix of a unit quaternion `[w, x, y, z]`.
pub fn matrix_from_quaternion(q: [f64; 4]) -> Matrix3<f64> {
    UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3])).to_rotation_matrix().into_inner()
}

/// Geodesic angle between the rotations of two transforms, in degrees (atan2 form, accurate near 0 and 180).
pub fn rotation_error_deg(a: &Matrix4<f64>, b: &Matrix4<f64>) -> f64 {
    let r = a.fixed_view::<3, 3>(0, 0).transpose() * b.fixed_view::<3, 3>(0, 0);
    let sin = 0.5 * Vector3::new(r[(2, 1)] - r[(1, 2)], r[(0, 2)] - r[(2, 0)], r[(1, 0)] - r[(0, 1)]).norm();
    sin.atan2((r.trace() - 1.0) / 2.0).to_degrees()
}

/// Distance between the translations of two transforms.
pub fn translation_error(a: &Matrix4<f64>, b: &Matrix4<f64>) -> f64 {
    (a.fixed_view::<3, 1>(0, 3) - b.fixed_view::<3, 1>(0, 3)).norm()
}

/// Least-squares rigid transform mapping `source[i]` onto `target[i]` (SVD, reflection-corrected).
/// `None` with fewer than 3 pairs or a degenerate (collinear) configuration.
pub fn rigid_fit(source: &[[f32; 3]], target: &[[f32; 3]]) -> Option<Matrix4<f64>> {
    let n = source.len().min(target.len());
    let source: Vec<Vector3<f64>> = source[..n].iter().map(|&p| v3(p)).collect();
    let target: Vec<Vector3<f64>> = target[..n].iter().map(|&p| v3(p)).collect();
    rigid_fit_f64(&source, &target)
}

/// [`rigid_fit`] in double precision (Kabsch / Umeyama without scale): the rigid `T` minimising
/// sum |T source[i] - target[i]|^2. `None` with fewer than 3 pairs or a degenerate (collinear) configuration.
pub fn rigid_fit_f64(source: &[Vector3<f64>], target: &[Vector3<f64>]) -> Option<Matrix4<f64>> {
    orthogonal_fit(source, target, 1.0)
}

/// The reflection twin of [`rigid_fit_f64`]: the `T = [R t]` with det R = -1 (a rotation composed with a mirror)
/// minimising sum |T source[i] - target[i]|^2, used to ask whether a mirror image explains the correspondences
/// better than any motion (the verdict's handedness check). `None` as for [`rigid_fit_f64`].
pub fn reflection_fit_f64(source: &[Vector3<f64>], target: &[Vector3<f64>]) -> Option<Matrix4<f64>> {
    orthogonal_fit(source, target, -1.0)
}

/// The orthogonal `T` with det R = `determinant` (+1 or -1) fitting `source` onto `target` in least squares.
fn orthogonal_fit(source: &[Vector3<f64>], target: &[Vector3<f64>], determinant: f64) -> Option<Matrix4<f64>> {
    let n = source.len().min(target.len());
    if n < 3 {
        return None;
    }
    let cs = source[..n].iter().sum::<Vector3<f64>>() / n as f64;
    let ct = target[..n].iter().sum::<Vector3<f64>>() / n as f64;
    let mut h = Matrix3::zeros();
    for i in 0..n {
        h += (source[i] - cs) * (target[i] - ct).transpose();
    }
    let svd = h.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let sv = svd.singular_values;
    // Collinear or coincident points leave the rotation about the line undetermined.
    if sv[1].is_nan() || sv[1] <= 1e-12 * sv[0].max(1e-300) {
        return None;
    }
    let mut d = Matrix3::identity();
    if (v_t.transpose() * u.transpose()).determinant() * determinant < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = v_t.transpose() * d * u.transpose();
    let t = ct - r * cs;
    Some(matrix_from_parts(&r, &t))
}

/// Largest deviation of a pose read from a file from a rigid motion: of R^T R from the identity (entrywise),
/// of det R from 1 and of the bottom row from (0, 0, 0, 1). Files written with 8 significant digits (the
/// 3DMatch logs) are within 1e-7.
pub const RIGID_TOLERANCE: f64 = 1e-3;

/// Largest translation of a pose read from a file, in file units (georeferenced coordinates reach 1e7).
pub const MAX_TRANSLATION: f64 = 1e9;

/// Why `m` is not a rigid motion (a rotation and a bounded translation), or `None` when it is one: the check
/// every reader of poses (trajectories, logs, pairs files) applies, so a scaled, sheared, reflected or zero
/// block is refused instead of scored as a pose.
pub fn rigidity_problem(m: &Matrix4<f64>) -> Option<String> {
    if let Some(v) = m.iter().find(|v| !v.is_finite()) {
        return Some(format!("non-finite matrix entry {v}"));
    }
    let bottom = m.fixed_view::<1, 4>(3, 0) - nalgebra::RowVector4::new(0.0, 0.0, 0.0, 1.0);
    if bottom.abs().max() > RIGID_TOLERANCE {
        return Some(format!(
            "bottom row ({}, {}, {}, {}) is not (0, 0, 0, 1)",
            m[(3, 0)],
            m[(3, 1)],
            m[(3, 2)],
            m[(3, 3)]
        ));
    }
    let r: Matrix3<f64> = m.fixed_view::<3, 3>(0, 0).into();
    let det = r.determinant();
    if det < 0.0 {
        return Some(format!("the 3x3 block is a reflection (determinant {det:.4}), not a rotation"));
    }
    let off = (r.transpose() * r - Matrix3::identity()).abs().max();
    if off > RIGID_TOLERANCE || (det - 1.0).abs() > RIGID_TOLERANCE {
        return Some(format!(
            "the 3x3 block is not a rotation (R^T R differs from the identity by {off:.3e}, determinant {det:.4}): \
             a scaled, sheared or degenerate matrix is not a pose"
        ));
    }
    let t = m.fixed_view::<3, 1>(0, 3).norm();
    if t > MAX_TRANSLATION {
        return Some(format!("translation {t:e} is beyond {MAX_TRANSLATION:e} units"));
    }
    None
}

/// A 4x4 transform as plain text: four rows of four numbers (9 decimals), one row per line, the format `register
/// --out` writes and `Display` of [`crate::PoseEstimate`] prints.
pub fn matrix_text(m: &Matrix4<f64>) -> String {
    (0..4).map(|r| (0..4).map(|c| format!("{:.9}", m[(r, c)])).collect::<Vec<_>>().join(" ") + "\n").collect()
}

/// `shifted` (a pose between clouds shifted by `-origin`) in the unshifted frames:
/// T = translate(o) * T' * translate(-o).
pub fn unshift_pose(shifted: &Matrix4<f64>, origin: [i64; 3]) -> Matrix4<f64> {
    let o = Vector3::new(origin[0] as f64, origin[1] as f64, origin[2] as f64);
    let (shift, unshift) = (Matrix4::new_translation(&-o), Matrix4::new_translation(&o));
    unshift * shifted * shift
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn rigid_fit_recovers_a_known_transform() {
        let mut rng = Rng::new(11);
        for _ in 0..20 {
            let r = matrix_from_quaternion(rng.unit_quaternion());
            let t = Vector3::new(rng.uniform(-5.0, 5.0), rng.uniform(-5.0, 5.0), rng.uniform(-5.0, 5.0));
            let truth = matrix_from_parts(&r, &t);
            let src: Vec<[f32; 3]> = (0..30).map(|_| [0; 3].map(|_: i32| rng.uniform(-1.0, 1.0) as f32)).collect();
            let tgt: Vec<[f32; 3]> = src.iter().map(|&p| transform_point(&truth, p)).collect();
            let est = rigid_fit(&src, &tgt).unwrap();
            assert!(rotation_error_deg(&est, &truth) < 1e-3);
            assert!(translation_error(&est, &truth) < 1e-4);
        }
        let line: Vec<[f32; 3]> = (0..5).map(|i| [i as f32, 0.0, 0.0]).collect();
        assert!(rigid_fit(&line, &line).is_none());
        assert!(rigid_fit(&line[..2], &line[..2]).is_none());
    }

    #[test]
    fn quaternion_round_trip_keeps_w_non_negative() {
        let mut rng = Rng::new(3);
        for _ in 0..50 {
            let r = matrix_from_quaternion(rng.unit_quaternion());
            let q = quaternion_from_matrix(&r);
            assert!(q[0] >= 0.0);
            assert!((matrix_from_quaternion(q) - r).norm() < 1e-9);
        }
    }
}
