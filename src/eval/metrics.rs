//! The 3DMatch registration metrics (spec 3.5, 3.6): the information-matrix error of an estimate, registration
//! recall and precision, feature-match inliers, and plain rotation / translation errors.

use crate::pose::{inverse, quaternion_from_matrix, skew};
use nalgebra::{Matrix3, Matrix4, Matrix6, Vector3, Vector6};

/// The protocol's error vector e = [t; x; y; z] of ΔT = T_gt⁻¹ T_est (translation, then the quaternion's vector
/// part with w >= 0).
pub fn error_vector(gt: &Matrix4<f64>, estimate: &Matrix4<f64>) -> Vector6<f64> {
    let delta = inverse(gt) * estimate;
    let q = quaternion_from_matrix(&delta.fixed_view::<3, 3>(0, 0).into_owned());
    Vector6::new(delta[(0, 3)], delta[(1, 3)], delta[(2, 3)], q[1], q[2], q[3])
}

/// The protocol's registration error e^T Σ e / Σ(0,0): approximately the mean squared displacement (m²) of the
/// ground-truth correspondence points. A pair is registered when this is <= 0.04 (0.2 m squared).
pub fn information_error(gt: &Matrix4<f64>, estimate: &Matrix4<f64>, information: &Matrix6<f64>) -> f64 {
    let e = error_vector(gt, estimate);
    (e.transpose() * information * e)[(0, 0)] / information[(0, 0)]
}

/// The information matrix Σ = Σ_q Gᵀ G with G = [I₃ | −[q]×] (spec 3.3 step 6); `points` are in fragment i's frame.
pub fn information_matrix(points: &[[f64; 3]]) -> Matrix6<f64> {
    let mut info = Matrix6::zeros();
    for p in points {
        let q = Vector3::new(p[0], p[1], p[2]);
        let mut g = nalgebra::Matrix3x6::zeros();
        g.fixed_view_mut::<3, 3>(0, 0).copy_from(&Matrix3::identity());
        g.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-skew(&q)));
        info += g.transpose() * g;
    }
    info
}

/// Root mean square distance between `a p` and `b p` over `points` (0 for no points).
pub fn rmse_between(points: &[[f32; 3]], a: &Matrix4<f64>, b: &Matrix4<f64>) -> f64 {
    if points.is_empty() {
        return 0.0;
    }
    let d = a - b;
    let (r, t) = (d.fixed_view::<3, 3>(0, 0), d.fixed_view::<3, 1>(0, 3));
    let sum: f64 =
        points.iter().map(|p| (r * Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64) + t).norm_squared()).sum();
    (sum / points.len() as f64).sqrt()
}

/// Feature-match inliers (spec 3.6): correspondences `(x_i, x_j)` (target / fragment-i point, source /
/// fragment-j point) with |x_i − T_ij x_j| < `tau1` (strict).
pub fn count_feature_inliers(
    pairs: impl IntoIterator<Item = ([f32; 3], [f32; 3])>,
    gt: &Matrix4<f64>,
    tau1: f64,
) -> usize {
    let (r, t) = (gt.fixed_view::<3, 3>(0, 0).into_owned(), gt.fixed_view::<3, 1>(0, 3).into_owned());
    pairs
        .into_iter()
        .filter(|(xi, xj)| {
            let mapped = r * Vector3::new(xj[0] as f64, xj[1] as f64, xj[2] as f64) + t;
            (Vector3::new(xi[0] as f64, xi[1] as f64, xi[2] as f64) - mapped).norm() < tau1
        })
        .count()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pose::rotation_error_deg;
    use nalgebra::{Rotation3, Unit};

    fn transform(axis: [f64; 3], angle_deg: f64, t: [f64; 3]) -> Matrix4<f64> {
        let r = Rotation3::from_axis_angle(&Unit::new_normalize(Vector3::from(axis)), angle_deg.to_radians());
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(r.matrix());
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&Vector3::from(t));
        m
    }

    #[test]
    fn quaternion_matches_the_protocol_formula_and_keeps_w_non_negative() {
        for (axis, deg) in [([1.0, 2.0, 3.0], 10.0), ([0.0, 0.0, 1.0], 90.0), ([1.0, -1.0, 0.5], 170.0)] {
            let m = transform(axis, deg, [0.0; 3]);
            let r = m.fixed_view::<3, 3>(0, 0).into_owned();
            let q = quaternion_from_matrix(&r);
            let w = 0.5 * (1.0 + r.trace()).sqrt();
            let expected = [
                w,
                (r[(2, 1)] - r[(1, 2)]) / (4.0 * w),
                (r[(0, 2)] - r[(2, 0)]) / (4.0 * w),
                (r[(1, 0)] - r[(0, 1)]) / (4.0 * w),
            ];
            for k in 0..4 {
                assert!((q[k] - expected[k]).abs() < 1e-12, "{deg}: {q:?} vs {expected:?}");
            }
        }
        // 350 degrees about z is -10 degrees: nalgebra gives w = cos(175°) < 0; ours flips to w >= 0 and the vector
        // part becomes sin(5°) * (-z).
        let r = transform([0.0, 0.0, 1.0], 350.0, [0.0; 3]).fixed_view::<3, 3>(0, 0).into_owned();
        let q = quaternion_from_matrix(&r);
        assert!(q[0] > 0.0 && (q[3] + 5f64.to_radians().sin()).abs() < 1e-12, "{q:?}");
        // Near 180 degrees (w ~ 0.0009): the vector part is still a unit axis.
        let r = transform([0.0, 1.0, 0.0], 179.9, [0.0; 3]).fixed_view::<3, 3>(0, 0).into_owned();
        let q = quaternion_from_matrix(&r);
        assert!(q[0] >= 0.0 && q[0] < 1e-3 && (q[2].abs() - 1.0).abs() < 1e-6, "{q:?}");
        assert!((q.iter().map(|c| c * c).sum::<f64>() - 1.0).abs() < 1e-12);
        // Exactly 180 degrees: w = 0, vector part +-axis.
        let r = transform([1.0, 0.0, 0.0], 180.0, [0.0; 3]).fixed_view::<3, 3>(0, 0).into_owned();
        let q = quaternion_from_matrix(&r);
        assert!(q[0].abs() < 1e-12 && (q[1].abs() - 1.0).abs() < 1e-12, "{q:?}");
    }

    #[test]
    fn information_matrix_equals_the_hand_expanded_sum() {
        // Two points; Gᵀ G = [[I, -[q]x], [[q]x, |q|² I - q qᵀ]] summed by hand.
        let pts = [[1.0, 2.0, 3.0], [-1.0, 0.5, 0.0]];
        let info = information_matrix(&pts);
        #[rustfmt::skip]
        let expected = Matrix6::new(
            2.0, 0.0, 0.0,   0.0,  3.0, -2.5,
            0.0, 2.0, 0.0,  -3.0,  0.0,  0.0,
            0.0, 0.0, 2.0,   2.5,  0.0,  0.0,
            0.0, -3.0, 2.5, 13.25, -1.5, -3.0,
            3.0, 0.0, 0.0,  -1.5, 11.0, -6.0,
            -2.5, 0.0, 0.0, -3.0, -6.0,  6.25,
        );
        assert!((info - expected).norm() < 1e-12, "{info}");
        // e^T Σ e / N is the mean of |t + r × q|².
        let e = Vector6::new(0.1, -0.2, 0.05, 0.01, 0.02, -0.03);
        let (t, r) = (Vector3::new(0.1, -0.2, 0.05), Vector3::new(0.01, 0.02, -0.03));
        let mean = pts.iter().map(|p| (t + r.cross(&Vector3::from(*p))).norm_squared()).sum::<f64>() / 2.0;
        assert!(((e.transpose() * info * e)[(0, 0)] / info[(0, 0)] - mean).abs() < 1e-12);
    }

    #[test]
    fn estimate_equal_to_gt_has_zero_error_and_its_inverse_is_large() {
        let gt = transform([0.3, 1.0, -0.2], 40.0, [0.5, -0.2, 1.0]);
        let pts: Vec<[f64; 3]> = (0..50).map(|k| [k as f64 * 0.05, (k % 7) as f64 * 0.3, 2.0]).collect();
        let info = information_matrix(&pts);
        assert!(information_error(&gt, &gt, &info) < 1e-20);
        assert!(information_error(&gt, &inverse(&gt), &info) > 0.04);
        assert!(rotation_error_deg(&gt, &gt) < 1e-6 && (rotation_error_deg(&gt, &inverse(&gt)) - 80.0).abs() < 1e-6);
        // The error vector's quaternion uses w >= 0 even when ΔT rotates by more than 180 degrees' equivalent.
        let est = gt * transform([0.0, 0.0, 1.0], -10.0, [0.0; 3]);
        let e = error_vector(&gt, &est);
        assert!((e[5] + 5f64.to_radians().sin()).abs() < 1e-12, "{e}");
    }

    #[test]
    fn feature_inliers_use_the_gt_direction_and_a_strict_threshold() {
        let gt = transform([0.0, 0.0, 1.0], 90.0, [1.0, 0.0, 0.0]);
        let xj = [1.0f32, 0.0, 0.0];
        let xi = [1.0f32, 1.0, 0.0]; // gt * xj
        assert_eq!(count_feature_inliers([(xi, xj)], &gt, 0.1), 1);
        assert_eq!(count_feature_inliers([(xj, xi)], &gt, 0.1), 0);
        assert_eq!(count_feature_inliers([([1.0f32, 1.5, 0.0], xj)], &gt, 0.5), 0);
    }
}
