//! SE(3) calculus for the pose graph, tangent vectors ordered translation first: ξ = [ρ; φ] with
//! Exp(ξ) = [exp(φ) | J_l(φ) ρ] (Barfoot, "State Estimation for Robotics", section 7.1; GTSAM orders the same
//! vector [φ; ρ]). Besides Exp and Log: the adjoint (T Exp(ξ) T⁻¹ = Exp(Ad(T) ξ)) and the inverse right Jacobian
//! (Log(Exp(ξ) Exp(δ)) ≈ ξ + J_r(ξ)⁻¹ δ), each exact, with series near zero.

use crate::pose::skew;
use crate::pose::so3;
use nalgebra::{Matrix3, Matrix4, Matrix6, Vector3, Vector6};

/// Below this angle (radians) the coefficients of [`q_matrix`] use their Taylor series.
const SMALL_ANGLE: f64 = 1e-2;

/// Rotation and translation of a rigid transform.
pub fn parts(m: &Matrix4<f64>) -> (Matrix3<f64>, Vector3<f64>) {
    (m.fixed_view::<3, 3>(0, 0).into_owned(), m.fixed_view::<3, 1>(0, 3).into_owned())
}

/// The translation part ρ and rotation part φ of a tangent vector.
pub fn split(xi: &Vector6<f64>) -> (Vector3<f64>, Vector3<f64>) {
    (xi.fixed_rows::<3>(0).into_owned(), xi.fixed_rows::<3>(3).into_owned())
}

/// Exp([ρ; φ]).
pub fn exp(xi: &Vector6<f64>) -> Matrix4<f64> {
    let (rho, phi) = split(xi);
    crate::pose::matrix_from_parts(&so3::exp(&phi), &(so3::left_jacobian(&phi) * rho))
}

/// Log(T) = [J_l(φ)⁻¹ t; φ] with φ = log R (angle in [0, π]).
pub fn log(m: &Matrix4<f64>) -> Vector6<f64> {
    let (r, t) = parts(m);
    let phi = so3::log(&r);
    let rho = so3::left_jacobian_inverse(&phi) * t;
    Vector6::new(rho.x, rho.y, rho.z, phi.x, phi.y, phi.z)
}

/// Ad(T) = [[R, [t]x R], [0, R]].
pub fn adjoint(m: &Matrix4<f64>) -> Matrix6<f64> {
    let (r, t) = parts(m);
    let mut ad = Matrix6::zeros();
    ad.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    ad.fixed_view_mut::<3, 3>(0, 3).copy_from(&(skew(&t) * r));
    ad.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    ad
}

/// The inverse of the right Jacobian of SE(3): J_r(ξ)⁻¹ = J_l(−ξ)⁻¹ = [[J⁻¹, −J⁻¹ Q J⁻¹], [0, J⁻¹]] with J the
/// SO(3) left Jacobian and Q the coupling block, both at −ξ.
pub fn right_jacobian_inverse(xi: &Vector6<f64>) -> Matrix6<f64> {
    let (rho, phi) = split(&(-xi));
    let j_inv = so3::left_jacobian_inverse(&phi);
    let q = q_matrix(&rho, &phi);
    let mut out = Matrix6::zeros();
    out.fixed_view_mut::<3, 3>(0, 0).copy_from(&j_inv);
    out.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-(j_inv * q * j_inv)));
    out.fixed_view_mut::<3, 3>(3, 3).copy_from(&j_inv);
    out
}

/// The upper-right block Q(ρ, φ) of the SE(3) left Jacobian (Barfoot eq. 7.86; Solà et al., "A micro Lie theory",
/// eq. 180).
pub fn q_matrix(rho: &Vector3<f64>, phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = phi.norm_squared();
    let theta = theta2.sqrt();
    let (a, b, c) = if theta < SMALL_ANGLE {
        (1.0 / 6.0 - theta2 / 120.0, 1.0 / 24.0 - theta2 / 720.0, 1.0 / 120.0 - theta2 / 2520.0)
    } else {
        let (s, co) = theta.sin_cos();
        (
            (theta - s) / (theta2 * theta),
            (theta2 + 2.0 * co - 2.0) / (2.0 * theta2 * theta2),
            (2.0 * theta - 3.0 * s + theta * co) / (2.0 * theta2 * theta2 * theta),
        )
    };
    let (p, r) = (skew(phi), skew(rho));
    let prp = p * r * p;
    0.5 * r + a * (p * r + r * p + prp) + b * (p * p * r + r * p * p - 3.0 * prp) + c * (prp * p + p * prp)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vectors() -> Vec<Vector6<f64>> {
        vec![
            Vector6::new(0.4, -1.2, 2.0, 0.3, -0.2, 0.9),
            Vector6::new(1.0, 0.5, -0.3, 1e-7, 2e-7, -1e-7),
            Vector6::new(-0.2, 0.1, 0.7, 5e-3, -2e-3, 1e-3),
            Vector6::new(3.0, -1.0, 0.0, -2.0, 1.0, 0.5),
            Vector6::new(0.0, 0.2, -0.1, 0.0, 0.0, 3.0),
        ]
    }

    #[test]
    fn log_inverts_exp_and_adjoint_moves_perturbations() {
        for xi in vectors() {
            assert!((log(&exp(&xi)) - xi).norm() < 1e-9, "{xi}");
            let t = exp(&Vector6::new(0.3, -0.4, 1.0, 0.2, 0.7, -0.1));
            let moved = t * exp(&xi) * crate::pose::rigid_inverse(&t);
            assert!((moved - exp(&(adjoint(&t) * xi))).abs().max() < 1e-12, "{xi}");
        }
    }

    #[test]
    fn right_jacobian_inverse_matches_central_differences() {
        // Column c of J_r(ξ)⁻¹: Log(Exp(ξ) Exp(h e_c)) differentiated at h = 0.
        let h = 1e-6;
        for xi in vectors() {
            let analytic = right_jacobian_inverse(&xi);
            for c in 0..6 {
                let mut d = Vector6::zeros();
                d[c] = h;
                let column = (log(&(exp(&xi) * exp(&d))) - log(&(exp(&xi) * exp(&(-d))))) / (2.0 * h);
                assert!(
                    (column - analytic.column(c)).norm() < 1e-7,
                    "{xi} column {c}: {column} vs {}",
                    analytic.column(c)
                );
            }
        }
    }
}
