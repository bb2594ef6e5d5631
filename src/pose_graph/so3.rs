//! Rotation-vector calculus for the pose graph: the exponential and logarithm of SO(3) and the left Jacobian
//! (exp(φ + δ) ≈ exp(J_l(φ) δ) exp(φ)) with its inverse, each with a series near zero so that tiny angles keep
//! full precision.

use crate::eval::metrics::skew;
use crate::pose::quaternion_from_matrix;
use nalgebra::{Matrix3, Vector3};

/// Below this angle (radians) the closed forms are replaced by their Taylor series.
const SMALL_ANGLE: f64 = 1e-4;

/// exp([φ]x): the rotation by |φ| radians about φ.
pub fn exp(phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = phi.norm_squared();
    let theta = theta2.sqrt();
    let (a, b) = if theta < SMALL_ANGLE {
        (1.0 - theta2 / 6.0, 0.5 - theta2 / 24.0)
    } else {
        (theta.sin() / theta, (1.0 - theta.cos()) / theta2)
    };
    let k = skew(phi);
    Matrix3::identity() + a * k + b * k * k
}

/// The rotation vector of `r` (angle in [0, π]), computed from the quaternion so it is accurate near 0 and π.
pub fn log(r: &Matrix3<f64>) -> Vector3<f64> {
    let q = quaternion_from_matrix(r);
    let v = Vector3::new(q[1], q[2], q[3]);
    let s = v.norm();
    if s < 1e-12 { 2.0 * v / q[0] } else { 2.0 * s.atan2(q[0]) * v / s }
}

/// The left Jacobian J_l(φ) = I + (1 - cos θ)/θ² [φ]x + (θ - sin θ)/θ³ [φ]x².
pub fn left_jacobian(phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = phi.norm_squared();
    let theta = theta2.sqrt();
    let (b, c) = if theta < SMALL_ANGLE {
        (0.5 - theta2 / 24.0, 1.0 / 6.0 - theta2 / 120.0)
    } else {
        ((1.0 - theta.cos()) / theta2, (theta - theta.sin()) / (theta2 * theta))
    };
    let k = skew(phi);
    Matrix3::identity() + b * k + c * k * k
}

/// The inverse left Jacobian J_l(φ)⁻¹ = I - ½[φ]x + (1/θ² - (1 + cos θ)/(2θ sin θ)) [φ]x².
pub fn left_jacobian_inverse(phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = phi.norm_squared();
    let theta = theta2.sqrt();
    let d = if theta < SMALL_ANGLE {
        1.0 / 12.0 + theta2 / 720.0
    } else {
        1.0 / theta2 - (1.0 + theta.cos()) / (2.0 * theta * theta.sin())
    };
    let k = skew(phi);
    Matrix3::identity() - 0.5 * k + d * k * k
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vectors() -> Vec<Vector3<f64>> {
        vec![
            Vector3::new(0.3, -0.2, 0.9),
            Vector3::new(1e-7, 2e-7, -1e-7),
            Vector3::new(5e-5, 0.0, 0.0),
            Vector3::new(-2.0, 1.0, 0.5),
            Vector3::new(0.0, 0.0, 3.1),
        ]
    }

    #[test]
    fn exp_matches_nalgebra_and_log_inverts_it() {
        for phi in vectors() {
            let r = exp(&phi);
            let reference = nalgebra::Rotation3::new(phi).into_inner();
            assert!((r - reference).abs().max() < 1e-12, "{phi}");
            assert!((log(&r) - phi).norm() < 1e-9 * phi.norm().max(1e-3), "{phi}: {}", log(&r));
        }
    }

    #[test]
    fn left_jacobian_matches_finite_differences_and_its_inverse() {
        let h = 1e-6;
        for phi in vectors() {
            let jl = left_jacobian(&phi);
            assert!((jl * left_jacobian_inverse(&phi) - Matrix3::identity()).abs().max() < 1e-9, "{phi}");
            // Column c: log(exp(φ + h e_c) exp(φ)ᵀ) / h.
            for c in 0..3 {
                let mut e = Vector3::zeros();
                e[c] = h;
                let plus = log(&(exp(&(phi + e)) * exp(&phi).transpose()));
                let minus = log(&(exp(&(phi - e)) * exp(&phi).transpose()));
                let numeric = (plus - minus) / (2.0 * h);
                assert!((numeric - jl.column(c)).norm() < 1e-7, "{phi} column {c}: {numeric} vs {}", jl.column(c));
            }
        }
    }
}
