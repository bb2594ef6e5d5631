//! A simulated Kinect-like depth camera and the smooth hand-held trajectory it follows through a room.
//!
//! Camera frame: x right, y down, z forward (the optical axis); depth is the z coordinate.

use super::geometry::{Hit, Object, cast_ray_object};
use super::room::Room;
use crate::rng::Rng;
use nalgebra::{Matrix3, Matrix4, Vector3};
use serde::Serialize;

/// The image of a pinhole depth sensor ([`CameraModel`] and [`super::sensor::Sensor`] share it): its rays, fields
/// of view, the depth range that returns and the largest incidence angle that does.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PinholeImage {
    /// Rays per row.
    pub width: usize,
    /// Rays per column.
    pub height: usize,
    /// Horizontal field of view (degrees).
    pub hfov_deg: f64,
    /// Vertical field of view (degrees).
    pub vfov_deg: f64,
    /// Returns closer than this depth are missing (metres, or scene units).
    pub min_depth: f64,
    /// Returns farther than this depth are missing (metres, or scene units).
    pub max_depth: f64,
    /// Returns whose incidence angle (between the ray and the surface normal) exceeds this are missing
    /// (degrees).
    pub max_incidence_deg: f64,
}

/// Depth camera intrinsics and error model.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CameraModel {
    /// Rays, fields of view and the range that returns.
    #[serde(flatten)]
    pub image: PinholeImage,
    /// Probability that a return is randomly missing.
    pub dropout: f64,
    /// Depth noise sigma(z) = `noise[0] + noise[1] (z - noise[2])^2` metres, along the ray (Kinect-like).
    pub noise: [f64; 3],
}

impl Default for CameraModel {
    fn default() -> Self {
        CameraModel {
            image: PinholeImage {
                width: 160,
                height: 120,
                hfov_deg: 57.0,
                vfov_deg: 43.0,
                min_depth: 0.5,
                max_depth: 4.5,
                max_incidence_deg: 75.0,
            },
            dropout: 0.03,
            noise: [0.0012, 0.0019, 0.4],
        }
    }
}

impl CameraModel {
    /// The camera with `width` x `height` rays (fields of view unchanged).
    pub fn with_size(self, width: usize, height: usize) -> CameraModel {
        CameraModel { image: PinholeImage { width, height, ..self.image }, ..self }
    }

    /// Depth noise standard deviation at depth `z`.
    pub fn sigma(&self, z: f64) -> f64 {
        self.noise[0] + self.noise[1] * (z - self.noise[2]).powi(2)
    }

    /// Scans the scene from `world_from_camera` and returns (point, normal) pairs mapped by
    /// `out_from_camera` (e.g. into a fragment's frame). Normals come from the primitive that was hit and face
    /// the camera. Each ray is jittered inside its pixel.
    pub fn scan(
        &self,
        objects: &[Object],
        world_from_camera: &Matrix4<f64>,
        out_from_camera: &Matrix4<f64>,
        rng: &mut Rng,
    ) -> Vec<([f64; 3], [f64; 3])> {
        let rays = PinholeRays::new(&self.image, world_from_camera, out_from_camera);
        let pixel = |rng: &mut Rng, u: usize, v: usize| {
            let (ju, jv) = (rng.unit_f64(), rng.unit_f64());
            Some(([u as f64 + ju, v as f64 + jv], ()))
        };
        let measure = |rng: &mut Rng, _: &PinholeRays, (): (), hit: &PixelHit| {
            if rng.unit_f64() < self.dropout {
                return None;
            }
            Some(hit.z + self.sigma(hit.z) * rng.normal())
        };
        rays.scan(objects, rng, pixel, measure)
    }
}

/// A ray of a [`PinholeRays`] image that hit a surface within the depth range and incidence limit.
pub(super) struct PixelHit {
    /// Image position (pixels) the ray went through.
    pub pixel: [f64; 2],
    /// The hit (distance along the unit world direction, and the surface normal).
    pub hit: Hit,
    /// Index of the object hit.
    pub object: usize,
    /// Depth (camera z) of the hit.
    pub z: f64,
    /// Cosine of the incidence angle.
    pub cos_incidence: f64,
    /// Unit world direction of the ray.
    pub dir: Vector3<f64>,
}

/// The one depth-camera ray caster ([`CameraModel`] and [`super::sensor::Sensor`] scan with it): a pinhole at
/// `world_from_camera`, rays through image positions, the first hit within range, and each return mapped by
/// `out_from_camera`. Camera frame: x right, y down, z forward.
pub(super) struct PinholeRays {
    world_from_camera: Matrix4<f64>,
    out_from_camera: Matrix4<f64>,
    size: (usize, usize),
    focal: (f64, f64),
    center: (f64, f64),
    depth: (f64, f64),
    cos_max: f64,
}

impl PinholeRays {
    pub fn new(image: &PinholeImage, world_from_camera: &Matrix4<f64>, out_from_camera: &Matrix4<f64>) -> PinholeRays {
        let (w, h) = (image.width as f64, image.height as f64);
        PinholeRays {
            world_from_camera: *world_from_camera,
            out_from_camera: *out_from_camera,
            size: (image.width, image.height),
            focal: (
                w / 2.0 / (image.hfov_deg.to_radians() / 2.0).tan(),
                h / 2.0 / (image.vfov_deg.to_radians() / 2.0).tan(),
            ),
            center: (w / 2.0, h / 2.0),
            depth: (image.min_depth, image.max_depth),
            cos_max: image.max_incidence_deg.to_radians().cos(),
        }
    }

    /// The camera rotation (world_from_camera's).
    pub fn rotation(&self) -> Matrix3<f64> {
        self.world_from_camera.fixed_view::<3, 3>(0, 0).into_owned()
    }

    /// The camera centre in the world.
    pub fn origin(&self) -> Vector3<f64> {
        self.world_from_camera.fixed_view::<3, 1>(0, 3).into_owned()
    }

    /// The ray through image position `pixel`: in the camera frame with z = 1, its length, and its unit world
    /// direction.
    pub fn ray(&self, pixel: [f64; 2]) -> (Vector3<f64>, f64, Vector3<f64>) {
        let ray =
            Vector3::new((pixel[0] - self.center.0) / self.focal.0, (pixel[1] - self.center.1) / self.focal.1, 1.0);
        let len = ray.norm();
        (ray, len, self.rotation() * (ray / len))
    }

    /// The image, pixel by pixel in row-major order: `pixel` draws what a pixel needs from `rng` and gives the
    /// image position its ray goes through (None: no return, e.g. a hole); a hit within the depth range and
    /// incidence limit goes to `measure`, which draws the measured depth (None: no return); each return is
    /// (point, normal facing the camera) in the output frame.
    pub fn scan<P>(
        &self,
        objects: &[Object],
        rng: &mut Rng,
        mut pixel: impl FnMut(&mut Rng, usize, usize) -> Option<([f64; 2], P)>,
        mut measure: impl FnMut(&mut Rng, &PinholeRays, P, &PixelHit) -> Option<f64>,
    ) -> Vec<([f64; 3], [f64; 3])> {
        let (r, origin) = (self.rotation(), self.origin());
        let r_out = self.out_from_camera.fixed_view::<3, 3>(0, 0).into_owned();
        let t_out = self.out_from_camera.fixed_view::<3, 1>(0, 3).into_owned();
        let mut out = Vec::with_capacity(self.size.0 * self.size.1);
        for v in 0..self.size.1 {
            for u in 0..self.size.0 {
                let Some((position, drawn)) = pixel(rng, u, v) else { continue };
                let (ray, len, dir) = self.ray(position);
                let Some((hit, object)) = cast_ray_object(objects, &origin, &dir, self.depth.1 * len) else {
                    continue;
                };
                let z = hit.t / len;
                let cos_incidence = -hit.normal.dot(&dir);
                if z < self.depth.0 || cos_incidence < self.cos_max {
                    continue;
                }
                let found = PixelHit { pixel: position, hit, object, z, cos_incidence, dir };
                let Some(zn) = measure(rng, self, drawn, &found) else { continue };
                let p = r_out * (ray * zn) + t_out;
                let n = r_out * (r.transpose() * found.hit.normal);
                out.push(([p.x, p.y, p.z], [n.x, n.y, n.z]));
            }
        }
        out
    }
}

/// A camera pose as a 4x4 world_from_camera matrix whose optical axis looks along `forward` with image "up"
/// near world +z, rolled by `roll` radians.
pub fn look_pose(position: Vector3<f64>, yaw: f64, pitch: f64, roll: f64) -> Matrix4<f64> {
    let f = Vector3::new(pitch.cos() * yaw.cos(), pitch.cos() * yaw.sin(), pitch.sin());
    let right = f.cross(&Vector3::z()).normalize();
    let down = f.cross(&right);
    let (s, c) = roll.sin_cos();
    let (x, y) = (right * c + down * s, down * c - right * s);
    let r = Matrix3::from_columns(&[x, y, f]);
    let mut m = Matrix4::identity();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    m.fixed_view_mut::<3, 1>(0, 3).copy_from(&position);
    m
}

/// Uniform Catmull-Rom interpolation between `p1` and `p2` at `t` in [0, 1].
fn catmull_rom(p0: f64, p1: f64, p2: f64, p3: f64, t: f64) -> f64 {
    let (t2, t3) = (t * t, t * t * t);
    0.5 * (2.0 * p1 + (p2 - p0) * t + (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) * t2 + (3.0 * p1 - p0 - 3.0 * p2 + p3) * t3)
}

/// How the camera moves: per fragment the view direction turns by a random amount in this range (degrees),
/// so consecutive fragments overlap strongly and fragments a few steps apart sometimes do.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MotionModel {
    /// Range of the yaw change per fragment (degrees).
    pub yaw_per_fragment_deg: [f64; 2],
    /// Range of the camera pitch (degrees, negative looks down).
    pub pitch_deg: [f64; 2],
    /// Range of the camera height (metres).
    pub height: [f64; 2],
    /// The camera keeps at least this distance from walls (metres).
    pub wall_margin: f64,
    /// Range of the fraction of the free distance behind the room centre that the camera backs away by.
    pub back_fraction: [f64; 2],
    /// Sideways offset of the camera from the room centre, drawn in `[-lateral, lateral]` (metres).
    pub lateral: f64,
    /// Camera roll, drawn in `[-roll_deg, roll_deg]` (degrees).
    pub roll_deg: f64,
}

impl Default for MotionModel {
    fn default() -> Self {
        MotionModel {
            yaw_per_fragment_deg: [15.0, 40.0],
            pitch_deg: [-35.0, -5.0],
            height: [1.2, 1.8],
            wall_margin: 0.4,
            back_fraction: [0.15, 0.75],
            lateral: 0.4,
            roll_deg: 5.0,
        }
    }
}

/// Plans `frames` world_from_camera poses (`frames_per_fragment` per fragment) along a smooth path. Without an
/// orbit the camera pans around the room, backing away from the wall it looks at; with one it walks around the
/// room's centre ([`OrbitModel`]; `motion`'s yaw, back and lateral ranges are then unused). Height, pitch and
/// roll vary smoothly in `motion`'s ranges. Knots are placed twice per fragment and interpolated with
/// Catmull-Rom splines. The path avoids walls and tall furniture; up to 200 random paths are tried.
pub fn plan_trajectory(
    room: &Room,
    motion: &MotionModel,
    orbit: Option<&OrbitModel>,
    fragments: usize,
    frames_per_fragment: usize,
    rng: &mut Rng,
) -> Vec<Matrix4<f64>> {
    plan_from_knots(room, motion.wall_margin, fragments, frames_per_fragment, rng, |rng, shrink, knots| match orbit {
        None => turn_knots(room, motion, rng, shrink, knots),
        Some(orbit) => orbit_knots(room, motion, orbit, rng, shrink, knots),
    })
}

/// Knots of a camera that turns near the room's centre, backing away from the wall it looks at.
fn turn_knots(room: &Room, motion: &MotionModel, rng: &mut Rng, shrink: f64, knots: usize) -> Vec<[f64; 6]> {
    let (mut yaw, sense) = draw_start_and_sense(rng);
    let mut k = Vec::with_capacity(knots);
    for _ in 0..knots {
        let u = [yaw.cos(), yaw.sin()];
        let perp = [-u[1], u[0]];
        let back = (room.distance_along(room.kernel_center, [-u[0], -u[1]]) - motion.wall_margin - 0.2).max(0.0);
        let f = rng.uniform(motion.back_fraction[0], motion.back_fraction[1]) * shrink;
        let lat = rng.uniform(-motion.lateral, motion.lateral) * shrink;
        let x = room.kernel_center[0] - f * back * u[0] + lat * perp[0];
        let y = room.kernel_center[1] - f * back * u[1] + lat * perp[1];
        let (z, pitch, roll) = draw_height_pitch_roll(motion, rng);
        k.push([x, y, z, yaw, pitch, roll]);
        let [lo, hi] = motion.yaw_per_fragment_deg;
        yaw += sense * rng.uniform(lo, hi).to_radians() / 2.0;
    }
    k
}

/// A trajectory that walks around the room instead of turning near its centre: the camera circles the room's
/// kernel centre and looks across the room, roughly towards that centre, so fragments a quarter turn apart see
/// the same surfaces from directions far apart (the view changes that repeated turns in place never give).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct OrbitModel {
    /// Range of the angle the camera advances around the centre per fragment (degrees).
    pub arc_per_fragment_deg: [f64; 2],
    /// Range of the camera's distance from the centre, as a fraction of the free distance (less the wall
    /// margin) from the centre to the wall behind the camera.
    pub radius_fraction: [f64; 2],
    /// The view direction turns away from the centre by up to this angle either way (degrees).
    pub aim_deg: f64,
}

/// Knots of a camera that circles the room's centre ([`OrbitModel`]).
fn orbit_knots(
    room: &Room,
    motion: &MotionModel,
    orbit: &OrbitModel,
    rng: &mut Rng,
    shrink: f64,
    knots: usize,
) -> Vec<[f64; 6]> {
    let (mut angle, sense) = draw_start_and_sense(rng);
    let c = room.kernel_center;
    let mut k = Vec::with_capacity(knots);
    for _ in 0..knots {
        let u = [angle.cos(), angle.sin()];
        let free = (room.distance_along(c, u) - motion.wall_margin - 0.2).max(0.0);
        let r = rng.uniform(orbit.radius_fraction[0], orbit.radius_fraction[1]) * shrink * free;
        let yaw = angle + std::f64::consts::PI + rng.uniform(-orbit.aim_deg, orbit.aim_deg).to_radians();
        let (z, pitch, roll) = draw_height_pitch_roll(motion, rng);
        k.push([c[0] + r * u[0], c[1] + r * u[1], z, yaw, pitch, roll]);
        let [lo, hi] = orbit.arc_per_fragment_deg;
        angle += sense * rng.uniform(lo, hi).to_radians() / 2.0;
    }
    k
}

/// A path's starting angle (radians) and the sense it turns in (+1 or -1).
fn draw_start_and_sense(rng: &mut Rng) -> (f64, f64) {
    let start = rng.uniform(-std::f64::consts::PI, std::f64::consts::PI);
    (start, if rng.below(2) == 0 { 1.0 } else { -1.0 })
}

/// A knot's camera height, pitch and roll (radians) drawn from `motion`'s ranges.
fn draw_height_pitch_roll(motion: &MotionModel, rng: &mut Rng) -> (f64, f64, f64) {
    let z = rng.uniform(motion.height[0], motion.height[1]);
    let pitch = rng.uniform(motion.pitch_deg[0], motion.pitch_deg[1]).to_radians();
    let roll = rng.uniform(-motion.roll_deg, motion.roll_deg).to_radians();
    (z, pitch, roll)
}

/// Interpolates knots `[x, y, z, yaw, pitch, roll]` drawn by `draw(rng, shrink, count)` (two per fragment and
/// three more) with Catmull-Rom splines into `frames_per_fragment` poses per fragment. A path whose camera
/// leaves the allowed space (walls within `wall_margin`, tall furniture) is drawn again, up to 200 times with
/// `shrink` falling from 1 towards 0 (draws should pull towards the centre with it); the first path is the
/// fallback.
fn plan_from_knots(
    room: &Room,
    wall_margin: f64,
    fragments: usize,
    frames_per_fragment: usize,
    rng: &mut Rng,
    mut draw: impl FnMut(&mut Rng, f64, usize) -> Vec<[f64; 6]>,
) -> Vec<Matrix4<f64>> {
    let knots = 2 * fragments + 3;
    let mut fallback = Vec::new();
    for attempt in 0..200 {
        // Later attempts stay closer to the kernel centre.
        let shrink = 1.0 - attempt as f64 / 200.0;
        let k = draw(rng, shrink, knots);
        let total = fragments * frames_per_fragment;
        let mut poses = Vec::with_capacity(total);
        let mut ok = true;
        for n in 0..total {
            let s = n as f64 / frames_per_fragment as f64 * 2.0;
            let i = (s.floor() as usize).min(knots - 4);
            let t = s - i as f64;
            let c: [f64; 6] = std::array::from_fn(|d| catmull_rom(k[i][d], k[i + 1][d], k[i + 2][d], k[i + 3][d], t));
            ok &= room.camera_allowed([c[0], c[1]], c[2], wall_margin);
            poses.push(look_pose(Vector3::new(c[0], c[1], c[2]), c[3], c[4], c[5]));
        }
        if ok {
            return poses;
        }
        if attempt == 0 {
            fallback = poses;
        }
    }
    fallback
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::geometry::Primitive;

    #[test]
    fn look_pose_is_a_right_handed_rotation_looking_forward() {
        let m = look_pose(Vector3::new(1.0, 2.0, 1.5), 0.3, -0.4, 0.05);
        let r = m.fixed_view::<3, 3>(0, 0).into_owned();
        assert!((r.transpose() * r - Matrix3::identity()).norm() < 1e-12);
        assert!((r.determinant() - 1.0).abs() < 1e-12);
        let f = r.column(2);
        assert!((f.z - (-0.4f64).sin()).abs() < 1e-12);
        // Image "down" points roughly to world -z.
        assert!(r.column(1).z < -0.8);
    }

    #[test]
    fn an_orbit_circles_the_centre_and_looks_across_the_room() {
        // An empty 8 x 6 m room: every first draw is allowed, so the fragments' first poses are the drawn knots.
        let room = Room {
            polygon: vec![[0.0, 0.0], [8.0, 0.0], [8.0, 6.0], [0.0, 6.0]],
            height: 3.0,
            kernel_center: [4.0, 3.0],
            objects: Vec::new(),
            footprints: Vec::new(),
        };
        let motion = MotionModel::default();
        let orbit = OrbitModel { arc_per_fragment_deg: [30.0, 50.0], radius_fraction: [0.5, 0.9], aim_deg: 20.0 };
        let (fragments, frames) = (12, 5);
        let poses = plan_trajectory(&room, &motion, Some(&orbit), fragments, frames, &mut Rng::new(7));
        assert_eq!(poses.len(), fragments * frames);
        let c = room.kernel_center;
        let mut azimuths = Vec::new();
        for (n, pose) in poses.iter().enumerate() {
            let (x, y, z) = (pose[(0, 3)], pose[(1, 3)], pose[(2, 3)]);
            assert!(room.camera_allowed([x, y], z, motion.wall_margin), "frame {n} at ({x}, {y})");
            if n % frames != 0 {
                continue;
            }
            // Radius within the drawn fraction of the free distance along the camera's direction from the centre.
            let (dx, dy) = (x - c[0], y - c[1]);
            let azimuth = dy.atan2(dx);
            let free = room.distance_along(c, [azimuth.cos(), azimuth.sin()]) - motion.wall_margin - 0.2;
            let r = dx.hypot(dy);
            assert!(r >= 0.5 * free - 1e-9 && r <= 0.9 * free + 1e-9, "fragment {}: radius {r} of {free}", n / frames);
            // The optical axis, seen from above, points at the centre within the aim range.
            let (fx, fy) = (pose[(0, 2)], pose[(1, 2)]);
            let off = ((fx * -dx + fy * -dy) / (fx.hypot(fy) * r)).clamp(-1.0, 1.0).acos().to_degrees();
            assert!(off <= 20.0 + 1e-6, "fragment {}: {off} deg off the centre", n / frames);
            azimuths.push(azimuth);
        }
        // Each fragment moves on around the centre, always the same way, by the drawn arc.
        let steps: Vec<f64> = azimuths
            .windows(2)
            .map(|w| {
                (w[1] - w[0] + 3.0 * std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
            })
            .map(f64::to_degrees)
            .collect();
        let sense = steps[0].signum();
        for s in &steps {
            assert!((30.0 - 1e-6..=50.0 + 1e-6).contains(&(s * sense)), "{steps:?}");
        }
        // So fragments a few apart stand on opposite sides of the room: a fixed point between them is seen from
        // directions far apart.
        assert!(steps.iter().map(|s| s.abs()).sum::<f64>() > 330.0);
    }

    #[test]
    fn a_wall_in_front_is_seen_at_its_depth_with_noise_and_facing_normals() {
        // A big wall 2 m in front of a camera at the origin looking along +x.
        let wall =
            Object::new("wall", vec![Primitive::cuboid(Vector3::new(2.5, 0.0, 0.0), Vector3::new(0.5, 5.0, 5.0), 0.0)]);
        let cam = CameraModel::default().with_size(40, 30);
        let pose = look_pose(Vector3::zeros(), 0.0, 0.0, 0.0);
        let pts = cam.scan(&[wall], &pose, &Matrix4::identity(), &mut Rng::new(1));
        assert!(pts.len() > 1000 && pts.len() <= 1200, "{}", pts.len());
        let mean_z = pts.iter().map(|(p, _)| p[2]).sum::<f64>() / pts.len() as f64;
        assert!((mean_z - 2.0).abs() < 0.003, "{mean_z}");
        assert!(pts.iter().all(|(p, n)| (p[2] - 2.0).abs() < 10.0 * cam.sigma(2.0) && n[2] < -0.999));
    }

    #[test]
    fn grazing_and_out_of_range_returns_are_missing() {
        // A floor seen almost edge-on beyond the incidence limit, and a wall beyond the range.
        let floor = Object::new(
            "floor",
            vec![Primitive::cuboid(Vector3::new(0.0, 0.0, -0.35), Vector3::new(20.0, 20.0, 0.05), 0.0)],
        );
        let cam = CameraModel { dropout: 0.0, ..CameraModel::default().with_size(40, 30) };
        let pose = look_pose(Vector3::zeros(), 0.0, 0.0, 0.0);
        let pts = cam.scan(std::slice::from_ref(&floor), &pose, &Matrix4::identity(), &mut Rng::new(2));
        // The floor is 0.3 m below the camera: camera y ("down") is 0.3 and the cosine of the incidence angle
        // is y / |p|. Only the lowest rows are steep enough; the other 600 - n rays that hit the floor graze it.
        let cos_max = 75f64.to_radians().cos();
        assert!(!pts.is_empty() && pts.len() < 300, "{}", pts.len());
        for (p, n) in &pts {
            let norm = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            assert!(p[1] / norm > cos_max - 0.01, "{p:?}");
            assert!(n[1] < -0.999, "{n:?}");
        }
        let far =
            Object::new("wall", vec![Primitive::cuboid(Vector3::new(6.0, 0.0, 0.0), Vector3::new(0.5, 5.0, 5.0), 0.0)]);
        assert!(cam.scan(&[far], &pose, &Matrix4::identity(), &mut Rng::new(3)).is_empty());
    }
}
