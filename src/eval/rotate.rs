//! The rotation sweep of `eval --rotate`: every source fragment is moved by a rigid motion M that rotates it
//! by exactly DEG degrees about a seeded random unit axis through its centroid, and every pair is registered
//! again on the moved source.
//!
//! Frames: gt.log record `i j` holds T_gt = target_from_source (x_i = T_gt x_j). The moved source is
//! x'_j = M x_j (M = `rotated_from_original`), so the ground truth on the moved data is
//! T'_gt = T_gt M⁻¹ ([`rotated_ground_truth`]), and an estimate T'_est on the moved data is T'_est M in the
//! original frames ([`original_frame_estimate`]). Registration is scored in the original frames (T'_est M
//! against T_gt with the unchanged gt.info matrix), so the protocol error of a result does not depend on M:
//! T_gt⁻¹ (T'_est M) = M⁻¹ (T'_gt⁻¹ T'_est) M exactly. Feature matches are counted on the moved data with T'_gt.
//!
//! Why not re-express gt.info in the moved frame instead: the protocol's error vector e = [t; q_xyz] of
//! ΔT = T_gt⁻¹ T_est is linear in the frame change only when M fixes the source origin. For a rotation about
//! the centroid c, the moved frame's translation part is R t + (I − R_Δ') (c − R c), which depends on the rotation
//! error itself, so no 6x6 matrix on e' reproduces eᵀΣe exactly; mapping the estimate back does, by construction.
//!
//! Axis: per scene and source fragment, drawn uniformly on the sphere from `Rng::derived(seed, stream)` with
//! `stream` = FNV-1a of `"<scene>/<fragment index>"`; it is the same for every angle of a sweep (only the angle
//! changes) and independent of scheduling. Centre: the mean of the fragment's points as loaded (after
//! `--drop-zero`). A multiple of 360 degrees gives M = identity exactly.

use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::pose::{rigid_inverse, rotation_about};
use crate::rng::Rng;
use nalgebra::{Matrix4, Unit, Vector3};
use serde::Serialize;

/// The angles and seed of a rotation sweep.
#[derive(Clone, Debug, PartialEq)]
pub struct RotationSweep {
    /// Rotation angles in degrees, in the order given (distinct).
    pub degrees: Vec<f64>,
    /// Seed of the rotation axes.
    pub seed: u64,
}

impl RotationSweep {
    /// A sweep over `degrees`; refuses an empty list, non-finite angles and repeated angles.
    pub fn new(degrees: Vec<f64>, seed: u64) -> Result<RotationSweep> {
        if degrees.is_empty() {
            return Err(Error::invalid("--rotate needs at least one angle"));
        }
        for (k, d) in degrees.iter().enumerate() {
            if !(d.is_finite() && d.abs() <= MAX_ROTATION_DEG) {
                let shown = if d.abs() < 1e6 { format!("{d}") } else { format!("{d:e}") };
                return Err(Error::invalid(format!(
                    "--rotate: angle {shown} is not a number of degrees within -{MAX_ROTATION_DEG}..={MAX_ROTATION_DEG}"
                )));
            }
            if degrees[..k].contains(d) {
                return Err(Error::invalid(format!("--rotate: angle {d} is given twice")));
            }
        }
        Ok(RotationSweep { degrees, seed })
    }
}

/// Largest angle of `--rotate`, in degrees either way (a full turn: larger angles repeat smaller ones, and
/// their labels make path names too long).
pub const MAX_ROTATION_DEG: f64 = 360.0;

/// How an angle appears in paths and in `{rotation}` (Rust's shortest form: `90`, `22.5`, `-45`).
pub fn angle_label(degrees: f64) -> String {
    format!("{degrees}")
}

/// The ground truth on the moved data: target_from_rotated_source = T_gt M⁻¹.
pub fn rotated_ground_truth(target_from_source: &Matrix4<f64>, rotated_from_original: &Matrix4<f64>) -> Matrix4<f64> {
    target_from_source * rigid_inverse(rotated_from_original)
}

/// An estimate on the moved data mapped back to the original source frame: target_from_source = T'_est M.
pub fn original_frame_estimate(
    target_from_rotated_source: &Matrix4<f64>,
    rotated_from_original: &Matrix4<f64>,
) -> Matrix4<f64> {
    target_from_rotated_source * rotated_from_original
}

/// The mean of `points` (the origin for none).
pub fn centroid(points: &[[f32; 3]]) -> Vector3<f64> {
    if points.is_empty() {
        return Vector3::zeros();
    }
    let sum: Vector3<f64> = points.iter().map(|p| Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64)).sum();
    sum / points.len() as f64
}

/// FNV-1a, 64 bit: a hash that is the same on every platform and in every release.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xCBF2_9CE4_8422_2325, |h, &b| (h ^ b as u64).wrapping_mul(0x0100_0000_01B3))
}

/// The sweep's axis for fragment `index` of `scene`: uniform on the unit sphere (z uniform in [−1, 1], azimuth
/// uniform), from `Rng::derived(seed, fnv1a("<scene>/<index>"))`.
pub fn rotation_axis(seed: u64, scene: &str, index: usize) -> Unit<Vector3<f64>> {
    let mut rng = Rng::derived(seed, fnv1a(format!("{scene}/{index}").as_bytes()));
    let z = rng.uniform(-1.0, 1.0);
    let phi = rng.uniform(0.0, std::f64::consts::TAU);
    let s = (1.0 - z * z).max(0.0).sqrt();
    Unit::new_normalize(Vector3::new(s * phi.cos(), s * phi.sin(), z))
}

/// How the sweep moves one source fragment (the angle aside): its axis and centre, in its own frame.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FragmentRotation {
    /// Scene name.
    pub scene: String,
    /// Fragment index.
    pub index: usize,
    /// Unit rotation axis.
    pub axis: [f64; 3],
    /// Centre of rotation: the mean of the fragment's points as loaded.
    pub center: [f64; 3],
}

impl FragmentRotation {
    /// The rotation of fragment `index` of `scene`, whose points as loaded are `cloud`.
    pub fn for_fragment(seed: u64, scene: &str, index: usize, cloud: &PointCloud) -> FragmentRotation {
        let axis = rotation_axis(seed, scene, index);
        let c = centroid(&cloud.points);
        FragmentRotation { scene: scene.to_string(), index, axis: [axis.x, axis.y, axis.z], center: [c.x, c.y, c.z] }
    }

    /// M = rotated_from_original for `degrees`.
    pub fn rotated_from_original(&self, degrees: f64) -> Matrix4<f64> {
        let axis = Unit::new_normalize(Vector3::from(self.axis));
        rotation_about(&axis, &Vector3::from(self.center), degrees)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pose::rotation_error_deg;
    use crate::pose::{rigid_fit, transform_point};
    use nalgebra::Rotation3;

    fn cloud(seed: u64) -> PointCloud {
        let mut rng = Rng::new(seed);
        PointCloud::from_points(
            (0..200)
                .map(|_| [rng.uniform(1.0, 3.0) as f32, rng.uniform(-2.0, 0.5) as f32, rng.uniform(0.5, 4.0) as f32])
                .collect(),
        )
    }

    #[test]
    fn motion_rotates_by_exactly_the_angle_and_fixes_the_centroid() {
        let c = cloud(5);
        let rot = FragmentRotation::for_fragment(7, "scene", 3, &c);
        let center = Vector3::from(rot.center);
        // The centroid, recomputed independently in f64.
        let n = c.len() as f64;
        for k in 0..3 {
            let mean = c.points.iter().map(|p| p[k] as f64).sum::<f64>() / n;
            assert!((center[k] - mean).abs() < 1e-12);
        }
        for deg in [0.0, 1.0, 30.0, 90.0, 135.0, 179.0, 180.0] {
            let m = rot.rotated_from_original(deg);
            // Geodesic angle of M's rotation part.
            let angle = rotation_error_deg(&Matrix4::identity(), &m);
            assert!((angle - deg).abs() < 1e-9, "{deg}: {angle}");
            // Rigid, proper rotation.
            let r = m.fixed_view::<3, 3>(0, 0).into_owned();
            assert!((r.transpose() * r - nalgebra::Matrix3::identity()).norm() < 1e-12);
            assert!((r.determinant() - 1.0).abs() < 1e-12);
            // M fixes the centroid and every point on the axis through it.
            let fixed = (m * center.push(1.0)).xyz();
            assert!((fixed - center).norm() < 1e-12, "{deg}: {fixed}");
            let on_axis = center + 2.5 * Vector3::from(rot.axis);
            assert!(((m * on_axis.push(1.0)).xyz() - on_axis).norm() < 1e-12);
            // The cloud it moves: a rigid fit from the original to the moved points recovers M (f32 points).
            let moved = c.transformed(&m);
            let fit = rigid_fit(&c.points, &moved.points).unwrap();
            assert!((rotation_error_deg(&Matrix4::identity(), &fit) - deg).abs() < 1e-3);
            assert!((centroid(&moved.points) - center).norm() < 1e-5);
            // Points off the axis move on a circle about it, by the angle.
            let p = c.points[17];
            let q = transform_point(&m, p);
            let axis = Vector3::from(rot.axis);
            let radial = |x: [f32; 3]| {
                let v = Vector3::new(x[0] as f64, x[1] as f64, x[2] as f64) - center;
                v - axis * axis.dot(&v)
            };
            let (a, b) = (radial(p), radial(q));
            assert!((a.angle(&b).to_degrees() - deg).abs() < 1e-3, "{deg}");
        }
        assert_eq!(rot.rotated_from_original(0.0), Matrix4::identity());
        assert_eq!(rot.rotated_from_original(-720.0), Matrix4::identity());
        // Beyond 180 degrees the geodesic angle folds: 270 about a is 90 about -a.
        assert!((rotation_error_deg(&Matrix4::identity(), &rot.rotated_from_original(270.0)) - 90.0).abs() < 1e-9);
    }

    #[test]
    fn axis_is_seeded_per_scene_and_fragment_and_unit() {
        let a = rotation_axis(0, "s", 1);
        assert_eq!(a, rotation_axis(0, "s", 1));
        assert!((a.norm() - 1.0).abs() < 1e-12);
        assert_ne!(a, rotation_axis(0, "s", 2));
        assert_ne!(a, rotation_axis(0, "t", 1));
        assert_ne!(a, rotation_axis(1, "s", 1));
        // Roughly uniform: the mean of many axes is near the origin.
        let mean: Vector3<f64> =
            (0..2000).map(|k| rotation_axis(3, "u", k).into_inner()).sum::<Vector3<f64>>() / 2000.0;
        assert!(mean.norm() < 0.08, "{mean}");
    }

    #[test]
    fn rotated_ground_truth_maps_moved_source_points_onto_the_target_and_estimates_map_back() {
        let c = cloud(9);
        let rot = FragmentRotation::for_fragment(2, "x", 0, &c);
        let t_gt = crate::pose::matrix_from_parts(
            &Rotation3::from_axis_angle(&Vector3::y_axis(), 0.4).into_inner(),
            &Vector3::new(0.3, -1.0, 2.0),
        );
        for deg in [0.0, 90.0, 180.0] {
            let m = rot.rotated_from_original(deg);
            let t_rot = rotated_ground_truth(&t_gt, &m);
            let moved = c.transformed(&m);
            for (p, q) in c.points.iter().zip(&moved.points) {
                let (a, b) = (transform_point(&t_gt, *p), transform_point(&t_rot, *q));
                assert!((0..3).all(|k| (a[k] - b[k]).abs() < 1e-5), "{deg}: {a:?} {b:?}");
            }
            assert!((original_frame_estimate(&t_rot, &m) - t_gt).norm() < 1e-12);
            assert!((rigid_inverse(&m) * m - Matrix4::identity()).norm() < 1e-12);
        }
    }

    #[test]
    fn sweeps_refuse_empty_repeated_and_non_finite_angles() {
        assert!(RotationSweep::new(vec![0.0, 90.0], 0).is_ok());
        assert!(RotationSweep::new(vec![], 0).is_err());
        assert!(RotationSweep::new(vec![90.0, 90.0], 0).unwrap_err().to_string().contains("twice"));
        assert!(RotationSweep::new(vec![f64::NAN], 0).is_err());
        assert_eq!(angle_label(90.0), "90");
        assert_eq!(angle_label(22.5), "22.5");
        assert_eq!(angle_label(-45.0), "-45");
    }
}
