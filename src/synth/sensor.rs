//! The depth sensors of the styled generators: a pinhole depth camera with a choice of noise models, random
//! dropouts, image-space holes and per-object absorbing materials; optionally a structured-light model
//! (projector shadows and quantised disparity) that the `heldout` style alone uses, and a time-of-flight model
//! (noise growing with depth squared over the incidence cosine, a periodic "wiggling" depth bias, and mixed
//! pixels where a pixel straddles a depth edge) that the `heldout-tof` style alone uses.
//!
//! Camera frame as in [`super::camera`]: x right, y down, z forward; depth is the z coordinate. Noise moves a
//! return along its ray.

use super::camera::{PinholeImage, PinholeRays, PixelHit};
use super::geometry::{Object, cast_ray_object};
use crate::rng::Rng;
use nalgebra::{Matrix4, Vector3};
use serde::Serialize;

/// How the depth error grows with depth z (metres, or scene units for object scenes).
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(tag = "model", rename_all = "snake_case")]
pub enum DepthNoise {
    /// sigma = `sigma`.
    Constant {
        /// Standard deviation.
        sigma: f64,
    },
    /// sigma = `per_unit` z.
    Proportional {
        /// Standard deviation per unit of depth.
        per_unit: f64,
    },
    /// sigma = `a + b (z - z0)^2` (the Kinect fit).
    Quadratic {
        /// Constant term.
        a: f64,
        /// Quadratic coefficient.
        b: f64,
        /// Depth of the smallest error.
        z0: f64,
    },
    /// Structured light: disparity d = `focal_px` `baseline` / z gets Gaussian noise of `sigma_px` pixels and is
    /// rounded to 1 / `subpixel` pixels, so depth falls on quantisation steps that widen as z^2.
    Disparity {
        /// Focal length of the native sensor (pixels).
        focal_px: f64,
        /// Projector-camera baseline.
        baseline: f64,
        /// Disparity noise (pixels).
        sigma_px: f64,
        /// Disparity steps per pixel.
        subpixel: f64,
    },
    /// Time of flight: the returned amplitude falls as cos(incidence) / z^2, so sigma = `sigma_at_1m` z^2 /
    /// cos(incidence); the phase measurement adds a periodic bias `wiggle_amplitude` sin(2 pi z /
    /// `wiggle_period` + `wiggle_phase`).
    TimeOfFlight {
        /// Standard deviation at 1 unit of depth, head-on.
        sigma_at_1m: f64,
        /// Amplitude of the periodic depth bias.
        wiggle_amplitude: f64,
        /// Period of the bias in depth.
        wiggle_period: f64,
        /// Phase of the bias (radians).
        wiggle_phase: f64,
    },
}

impl DepthNoise {
    /// The measured depth for a true depth `z` seen at incidence cosine `cos_incidence` (in (0, 1]; only
    /// the time-of-flight model uses it).
    pub fn apply(&self, z: f64, cos_incidence: f64, rng: &mut Rng) -> f64 {
        match *self {
            DepthNoise::Constant { sigma } => z + sigma * rng.normal(),
            DepthNoise::Proportional { per_unit } => z + per_unit * z * rng.normal(),
            DepthNoise::Quadratic { a, b, z0 } => z + (a + b * (z - z0).powi(2)) * rng.normal(),
            DepthNoise::Disparity { focal_px, baseline, sigma_px, subpixel } => {
                let d = focal_px * baseline / z + sigma_px * rng.normal();
                let dq = (d * subpixel).round().max(1.0) / subpixel;
                focal_px * baseline / dq
            }
            DepthNoise::TimeOfFlight { sigma_at_1m, wiggle_amplitude, wiggle_period, wiggle_phase } => {
                let bias = wiggle_amplitude * (std::f64::consts::TAU * z / wiggle_period + wiggle_phase).sin();
                z + bias + sigma_at_1m * z * z / cos_incidence.max(1e-3) * rng.normal()
            }
        }
    }
}

/// A pinhole depth sensor and its error model.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Sensor {
    /// Rays, fields of view and the range that returns.
    #[serde(flatten)]
    pub image: PinholeImage,
    /// Probability that a return is randomly missing.
    pub dropout: f64,
    /// The depth error.
    pub noise: DepthNoise,
    /// Each frame has `0..=max_holes` elliptic holes (missing returns) at random places in the image.
    pub max_holes: usize,
    /// Range of a hole's semi-axes as a fraction of the image width.
    pub hole_radius: [f64; 2],
    /// Structured light: the projector sits this far along camera +x; points it cannot see are missing.
    pub projector_baseline: Option<f64>,
    /// Time of flight: a pixel integrates light over this many pixels around its ray; where that footprint
    /// straddles a depth edge (a second ray inside it hits more than [`MIXED_PIXEL_EDGE`] deeper or
    /// shallower), the return is a random mix of the two depths: a "flying pixel" between the surfaces.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mixed_pixel_footprint: Option<f64>,
}

/// Depth difference (scene units) between the two rays of a pixel footprint above which a time-of-flight
/// pixel returns a mixed depth.
pub const MIXED_PIXEL_EDGE: f64 = 0.05;

/// An elliptic hole in the image (pixel units).
struct Hole {
    center: [f64; 2],
    radius: [f64; 2],
}

impl Sensor {
    /// Scans `objects` from `world_from_camera` and returns (point, normal) pairs mapped by `out_from_camera`.
    /// `object_dropout[k]` is the extra probability that a return from object k is missing (dark or shiny
    /// material); missing entries count as 0.
    pub fn scan(
        &self,
        objects: &[Object],
        object_dropout: &[f64],
        world_from_camera: &Matrix4<f64>,
        out_from_camera: &Matrix4<f64>,
        rng: &mut Rng,
    ) -> Vec<([f64; 3], [f64; 3])> {
        let rays = PinholeRays::new(&self.image, world_from_camera, out_from_camera);
        let (w, h) = (self.image.width as f64, self.image.height as f64);
        let holes: Vec<Hole> = (0..rng.below(self.max_holes + 1))
            .map(|_| Hole {
                center: [rng.uniform(0.0, w), rng.uniform(0.0, h)],
                radius: [
                    rng.uniform(self.hole_radius[0], self.hole_radius[1]) * w,
                    rng.uniform(self.hole_radius[0], self.hole_radius[1]) * w,
                ],
            })
            .collect();
        let projector = self.projector_baseline.map(|b| rays.origin() + rays.rotation() * Vector3::new(b, 0.0, 0.0));
        let pixel = |rng: &mut Rng, u: usize, v: usize| {
            let (ju, jv) = (rng.unit_f64(), rng.unit_f64());
            let (pu, pv) = (u as f64 + ju, v as f64 + jv);
            let draws = PixelDraws { drop: rng.unit_f64(), material: rng.unit_f64(), noise_seed: rng.next_u64() };
            let in_hole = holes.iter().any(|hole| {
                ((pu - hole.center[0]) / hole.radius[0]).powi(2) + ((pv - hole.center[1]) / hole.radius[1]).powi(2)
                    < 1.0
            });
            (!in_hole).then_some(([pu, pv], draws))
        };
        let measure = |_: &mut Rng, rays: &PinholeRays, draws: PixelDraws, hit: &PixelHit| {
            if draws.drop < self.dropout
                || draws.material < object_dropout.get(hit.object).copied().unwrap_or(0.0)
                || projector.is_some_and(|p| !lit_by_projector(objects, rays, &p, hit))
            {
                return None;
            }
            let mut noise_rng = Rng::new(draws.noise_seed);
            let z = match self.mixed_pixel_footprint {
                Some(footprint) => self.mixed_depth(objects, rays, footprint, hit, &mut noise_rng),
                None => hit.z,
            };
            Some(self.noise.apply(z, hit.cos_incidence, &mut noise_rng))
        };
        rays.scan(objects, rng, pixel, measure)
    }

    /// Time of flight: the depth of a pixel whose `footprint` (pixels) may straddle a depth edge: a second ray
    /// at a random offset inside the footprint; where its depth differs by more than [`MIXED_PIXEL_EDGE`], a
    /// random mix of the two depths.
    fn mixed_depth(
        &self,
        objects: &[Object],
        rays: &PinholeRays,
        footprint: f64,
        hit: &PixelHit,
        rng: &mut Rng,
    ) -> f64 {
        let (du, dv) = (rng.uniform(-0.5, 0.5) * footprint, rng.uniform(-0.5, 0.5) * footprint);
        let mix = rng.unit_f64();
        let (_, len2, dir2) = rays.ray([hit.pixel[0] + du, hit.pixel[1] + dv]);
        let far = self.image.max_depth * len2 * 2.0;
        match cast_ray_object(objects, &rays.origin(), &dir2, far) {
            Some((hit2, _)) if (hit2.t / len2 - hit.z).abs() > MIXED_PIXEL_EDGE => {
                mix * hit.z + (1.0 - mix) * hit2.t / len2
            }
            _ => hit.z,
        }
    }
}

/// What a structured-light or styled pixel draws before its ray is cast (so every pixel draws the same).
struct PixelDraws {
    drop: f64,
    material: f64,
    noise_seed: u64,
}

/// Structured light: whether the projector at `projector` sees the surface point of `hit`.
fn lit_by_projector(objects: &[Object], rays: &PinholeRays, projector: &Vector3<f64>, hit: &PixelHit) -> bool {
    let target = rays.origin() + hit.dir * hit.hit.t;
    let to = target - projector;
    let dist = to.norm();
    match cast_ray_object(objects, projector, &(to / dist), dist + 1.0) {
        Some((h2, _)) => h2.t > dist - 1e-3 * dist.max(1.0),
        None => true,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::camera::look_pose;
    use crate::synth::geometry::Primitive;

    fn sensor(noise: DepthNoise) -> Sensor {
        Sensor {
            image: PinholeImage {
                width: 40,
                height: 30,
                hfov_deg: 60.0,
                vfov_deg: 45.0,
                min_depth: 0.3,
                max_depth: 6.0,
                max_incidence_deg: 80.0,
            },
            dropout: 0.0,
            noise,
            max_holes: 0,
            hole_radius: [0.05, 0.1],
            projector_baseline: None,
            mixed_pixel_footprint: None,
        }
    }

    fn wall_at(x: f64) -> Object {
        Object::new("wall", vec![Primitive::cuboid(Vector3::new(x + 0.5, 0.0, 0.0), Vector3::new(0.5, 9.0, 9.0), 0.0)])
    }

    #[test]
    fn noise_models_have_their_spread() {
        let pose = look_pose(Vector3::zeros(), 0.0, 0.0, 0.0);
        for (noise, sigma) in [
            (DepthNoise::Constant { sigma: 0.01 }, 0.01),
            (DepthNoise::Proportional { per_unit: 0.005 }, 0.015),
            (DepthNoise::Quadratic { a: 0.001, b: 0.002, z0: 1.0 }, 0.009),
        ] {
            let pts = sensor(noise).scan(&[wall_at(3.0)], &[], &pose, &Matrix4::identity(), &mut Rng::new(4));
            assert_eq!(pts.len(), 1200);
            let mean = pts.iter().map(|(p, _)| p[2]).sum::<f64>() / 1200.0;
            let sd = (pts.iter().map(|(p, _)| (p[2] - mean).powi(2)).sum::<f64>() / 1199.0).sqrt();
            assert!((mean - 3.0).abs() < 3.0 * sigma / 30.0, "{mean}");
            assert!((sd / sigma - 1.0).abs() < 0.1, "sd {sd} vs {sigma}");
        }
    }

    #[test]
    fn disparity_noise_quantises_depth() {
        let noise = DepthNoise::Disparity { focal_px: 500.0, baseline: 0.075, sigma_px: 0.0, subpixel: 8.0 };
        let pose = look_pose(Vector3::zeros(), 0.0, 0.0, 0.0);
        let pts = sensor(noise).scan(&[wall_at(3.0)], &[], &pose, &Matrix4::identity(), &mut Rng::new(5));
        // d = 37.5 / 3 = 12.5 px is a multiple of 1/8: the depth is exact; the steps there are about 3 cm.
        assert!(pts.iter().all(|(p, _)| (p[2] - 3.0).abs() < 1e-9));
    }

    #[test]
    fn time_of_flight_noise_grows_with_depth_squared_and_carries_the_wiggle_bias() {
        let pose = look_pose(Vector3::zeros(), 0.0, 0.0, 0.0);
        let tof = |sigma_at_1m: f64, wiggle_amplitude: f64| DepthNoise::TimeOfFlight {
            sigma_at_1m,
            wiggle_amplitude,
            wiggle_period: 0.8,
            wiggle_phase: 0.3,
        };
        // Pure noise: at 2 m the spread is four times that at 1 m (head-on rays: cos(incidence) ~ 1 near the
        // image centre, at most 1 / cos(30 deg) off at the corners).
        let spread = |depth: f64| {
            let pts =
                sensor(tof(0.003, 0.0)).scan(&[wall_at(depth)], &[], &pose, &Matrix4::identity(), &mut Rng::new(8));
            let mean = pts.iter().map(|(p, _)| p[2]).sum::<f64>() / pts.len() as f64;
            (pts.iter().map(|(p, _)| (p[2] - mean).powi(2)).sum::<f64>() / (pts.len() - 1) as f64).sqrt()
        };
        let (s1, s2) = (spread(1.0), spread(2.0));
        assert!(s1 > 0.003 && s1 < 0.0036, "{s1}");
        assert!((s2 / s1 - 4.0).abs() < 0.4, "{s1} {s2}");
        // Pure bias: every return of a wall at depth z is moved by a sin(2 pi z / period + phase) along z.
        for depth in [1.0, 1.3, 2.1] {
            let pts =
                sensor(tof(0.0, 0.01)).scan(&[wall_at(depth)], &[], &pose, &Matrix4::identity(), &mut Rng::new(9));
            let bias = 0.01 * (std::f64::consts::TAU * depth / 0.8 + 0.3).sin();
            assert!(pts.iter().all(|(p, _)| (p[2] - depth - bias).abs() < 1e-9), "{depth}");
        }
    }

    #[test]
    fn mixed_pixels_float_between_the_surfaces_of_a_depth_edge() {
        // A post 1 m in front of a wall 3 m away: without mixed pixels every return lies on one of the two
        // surfaces; with them, pixels whose footprint straddles the post's silhouette return depths between.
        let pose = look_pose(Vector3::zeros(), 0.0, 0.0, 0.0);
        let post = Object::new("post", vec![Primitive::upright_cylinder(Vector3::new(2.0, 0.0, 0.0), 0.2, 5.0)]);
        let scene = [wall_at(3.0), post];
        let none = DepthNoise::Constant { sigma: 0.0 };
        let between = |pts: &[([f64; 3], [f64; 3])]| {
            pts.iter().filter(|(p, _)| p[2] > 2.0 + MIXED_PIXEL_EDGE && p[2] < 3.0 - MIXED_PIXEL_EDGE).count()
        };
        let plain = sensor(none.clone()).scan(&scene, &[], &pose, &Matrix4::identity(), &mut Rng::new(10));
        let mixed = Sensor { mixed_pixel_footprint: Some(3.0), ..sensor(none) };
        let flying = mixed.scan(&scene, &[], &pose, &Matrix4::identity(), &mut Rng::new(10));
        assert_eq!(plain.len(), flying.len());
        // The post's visible surface spans depths 1.8-2.0 m.
        assert_eq!(between(&plain), 0);
        // Its two silhouette edges run down all 30 rows; a footprint of 3 pixels straddles an edge in about
        // 1.5 columns per edge (0.75 of them expected to mix), and 90 % of the mixes land between.
        let n = between(&flying);
        assert!((20..=120).contains(&n), "{n} mixed pixels");
        // Away from the edges the returns are untouched.
        let moved = plain.iter().zip(&flying).filter(|(a, b)| a.0 != b.0).count();
        assert!(moved >= n && moved < 200, "{moved}");
    }

    #[test]
    fn holes_materials_and_projector_shadows_remove_returns() {
        let pose = look_pose(Vector3::zeros(), 0.0, 0.0, 0.0);
        let none = DepthNoise::Constant { sigma: 0.0 };
        let full = sensor(none.clone()).scan(&[wall_at(3.0)], &[], &pose, &Matrix4::identity(), &mut Rng::new(6));
        let dark = sensor(none.clone()).scan(&[wall_at(3.0)], &[1.0], &pose, &Matrix4::identity(), &mut Rng::new(6));
        assert_eq!((full.len(), dark.len()), (1200, 0));
        let holed = Sensor { max_holes: 3, hole_radius: [0.1, 0.2], ..sensor(none.clone()) };
        let counts: Vec<usize> = (0..8)
            .map(|s| holed.scan(&[wall_at(3.0)], &[], &pose, &Matrix4::identity(), &mut Rng::new(s)).len())
            .collect();
        assert!(counts.iter().any(|&c| c < 1100) && counts.iter().all(|&c| c <= 1200), "{counts:?}");
        // A post 1 m in front of the wall, seen from a camera with the projector 0.3 m to its right: the wall
        // behind the post's left edge is lit by no projector ray, so fewer wall points come back.
        let post = Object::new("post", vec![Primitive::upright_cylinder(Vector3::new(2.0, 0.0, 0.0), 0.1, 5.0)]);
        let scene = [wall_at(3.0), post];
        let plain = sensor(none.clone()).scan(&scene, &[], &pose, &Matrix4::identity(), &mut Rng::new(7));
        let sl = Sensor { projector_baseline: Some(0.3), ..sensor(none) };
        let shadowed = sl.scan(&scene, &[], &pose, &Matrix4::identity(), &mut Rng::new(7));
        let far = |pts: &[([f64; 3], [f64; 3])]| pts.iter().filter(|(p, _)| p[2] > 2.5).count();
        assert_eq!(plain.len() - far(&plain), shadowed.len() - far(&shadowed));
        assert!(far(&shadowed) + 20 < far(&plain), "{} vs {}", far(&shadowed), far(&plain));
    }
}
