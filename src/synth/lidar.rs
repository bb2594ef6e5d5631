//! A spinning multi-beam LiDAR: `rings` lasers at fixed elevation angles turn through 360 degrees of azimuth in
//! `azimuth_steps` firings. Every ray is cast against an outdoor [`World`] (a height-field ground plus the
//! analytic solids of [`super::geometry`]); a return is reported along the laser's *nominal* direction at the
//! measured range, so beam divergence (the ray leaves within a small cone around that direction) smears depth
//! edges as a real beam footprint does. The measured range gets Gaussian noise growing with range, returns
//! thin out with range (drop probability rising to 1 at the maximum range) and at grazing incidence, porous
//! materials (vegetation) let part of the beam through, and rays that hit nothing (the sky) return nothing.
//!
//! Sensor frame: x forward, y left, z up (metres); azimuth 0 is +x, counter-clockwise. A sweep is de-skewed: the
//! whole revolution is taken from the pose at its start.

use super::geometry::{Object, cast_ray_object};
use crate::cloud::PointCloud;
use crate::rng::Rng;
use nalgebra::{Matrix3, Matrix4, Vector3};
use serde::Serialize;
use std::f64::consts::{PI, TAU};

/// The ground: `z = base + slope . (x, y) + sum_k amplitude_k sin(wave_k . (x, y) + phase_k)`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Ground {
    /// Height at the origin before the waves (metres).
    pub base: f64,
    /// Constant gradient (dz/dx, dz/dy).
    pub slope: [f64; 2],
    /// Undulations: (amplitude m, wave vector rad/m (x, y), phase rad).
    pub waves: Vec<(f64, [f64; 2], f64)>,
}

impl Ground {
    /// A flat ground at height `z`.
    pub fn flat(z: f64) -> Ground {
        Ground { base: z, slope: [0.0, 0.0], waves: Vec::new() }
    }

    /// Height at (x, y).
    pub fn height(&self, x: f64, y: f64) -> f64 {
        self.base
            + self.slope[0] * x
            + self.slope[1] * y
            + self.waves.iter().map(|(a, k, p)| a * (k[0] * x + k[1] * y + p).sin()).sum::<f64>()
    }

    /// Gradient (dz/dx, dz/dy) at (x, y).
    pub fn gradient(&self, x: f64, y: f64) -> [f64; 2] {
        let mut g = self.slope;
        for (a, k, p) in &self.waves {
            let c = a * (k[0] * x + k[1] * y + p).cos();
            g[0] += c * k[0];
            g[1] += c * k[1];
        }
        g
    }

    /// Upward unit normal at (x, y).
    pub fn normal(&self, x: f64, y: f64) -> Vector3<f64> {
        let [gx, gy] = self.gradient(x, y);
        Vector3::new(-gx, -gy, 1.0).normalize()
    }

    /// A bound on the gradient's norm everywhere.
    fn max_gradient(&self) -> f64 {
        self.slope[0].hypot(self.slope[1]) + self.waves.iter().map(|(a, k, _)| a.abs() * k[0].hypot(k[1])).sum::<f64>()
    }

    /// Where the ray `origin + t dir` (unit `dir`, origin above the ground) first meets the ground at
    /// `t < t_max`: sphere tracing with the height field's Lipschitz bound, so no crossing is stepped over.
    pub fn intersect(&self, origin: &Vector3<f64>, dir: &Vector3<f64>, t_max: f64) -> Option<f64> {
        let lipschitz = dir.z.abs() + self.max_gradient() * dir.x.hypot(dir.y);
        if lipschitz <= 0.0 {
            return None;
        }
        let wave_sum: f64 = self.waves.iter().map(|(a, _, _)| a.abs()).sum();
        let mut t = 0.0;
        for _ in 0..400 {
            let p = origin + dir * t;
            let f = p.z - self.height(p.x, p.y);
            // Rounding may land a step a hair below the surface: that is the crossing. An origin below the
            // ground sees nothing.
            if f < 1e-6 {
                return (t > 0.0 && t < t_max).then_some(t);
            }
            // Going up above every possible height: no crossing ahead.
            if dir.z >= 0.0 && f > 2.0 * wave_sum + self.slope[0].hypot(self.slope[1]) * (p.x.hypot(p.y) + 1.0) {
                return None;
            }
            t += f / lipschitz;
            if t >= t_max {
                return None;
            }
        }
        None
    }
}

/// How an object's surface answers the beam.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Material {
    /// Probability that the beam passes a hit on this object and goes on into it (foliage).
    pub pass_through: f64,
    /// Range noise multiplier.
    pub noise_scale: f64,
}

impl Material {
    /// A solid, opaque surface.
    pub const SOLID: Material = Material { pass_through: 0.0, noise_scale: 1.0 };
}

/// What the scanner sees: an optional ground and solid objects with one material each.
#[derive(Clone, Debug, Default)]
pub struct World {
    /// The height-field ground, if any.
    pub ground: Option<Ground>,
    /// The solids.
    pub objects: Vec<Object>,
    /// One per object.
    pub materials: Vec<Material>,
}

/// The scanner's parameters (written to style.json).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Scanner {
    /// Elevation of each laser (degrees, positive up), in firing order; its length is the ring count.
    pub elevation_deg: Vec<f64>,
    /// Firings per revolution.
    pub azimuth_steps: usize,
    /// Returns closer than this are discarded (the vehicle itself).
    pub min_range: f64,
    /// No return beyond this range (metres); the drop probability reaches 1 there.
    pub max_range: f64,
    /// Range noise: sigma = `range_sigma` + `range_sigma_per_m` x range.
    pub range_sigma: f64,
    /// Growth of the range noise per metre.
    pub range_sigma_per_m: f64,
    /// Full beam divergence (milliradians): the ray leaves uniformly within a cone of half this angle.
    pub divergence_mrad: f64,
    /// Drop probability near the sensor.
    pub dropout: f64,
    /// Drop probability = dropout + (1 - dropout) (range / max_range)^`thinning_exponent`.
    pub thinning_exponent: f64,
    /// Returns whose incidence cosine is below this are lost (grazing angles).
    pub min_incidence_cos: f64,
}

impl Scanner {
    /// Number of lasers.
    pub fn rings(&self) -> usize {
        self.elevation_deg.len()
    }

    /// `rings` lasers evenly spaced from `lowest` to `highest` degrees.
    pub fn even_elevations(rings: usize, lowest: f64, highest: f64) -> Vec<f64> {
        (0..rings).map(|k| lowest + (highest - lowest) * k as f64 / (rings.max(2) - 1) as f64).collect()
    }

    /// Standard deviation of the range noise at `range`.
    pub fn sigma(&self, range: f64) -> f64 {
        self.range_sigma + self.range_sigma_per_m * range
    }

    /// Probability that a return at `range` is lost.
    pub fn drop_probability(&self, range: f64) -> f64 {
        let f = (range / self.max_range).clamp(0.0, 1.0);
        self.dropout + (1.0 - self.dropout) * f.powf(self.thinning_exponent)
    }

    /// Nominal unit direction of laser `ring` at firing `step` (sensor frame).
    pub fn direction(&self, ring: usize, step: usize) -> Vector3<f64> {
        let el = self.elevation_deg[ring].to_radians();
        let az = TAU * step as f64 / self.azimuth_steps as f64;
        Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin())
    }

    /// One sweep from `world_from_sensor`: points and normals (facing the sensor) in the sensor frame, firing
    /// by firing (azimuth-major, lasers in order within a firing).
    pub fn scan(&self, world: &World, world_from_sensor: &Matrix4<f64>, rng: &mut Rng) -> PointCloud {
        let r: Matrix3<f64> = world_from_sensor.fixed_view::<3, 3>(0, 0).into_owned();
        let origin: Vector3<f64> = world_from_sensor.fixed_view::<3, 1>(0, 3).into_owned();
        let sectors = Sectors::new(&world.objects, &origin, self.max_range);
        let half_cone = self.divergence_mrad * 1e-3 / 2.0;
        let mut points = Vec::new();
        let mut normals = Vec::new();
        for step in 0..self.azimuth_steps {
            for ring in 0..self.rings() {
                let nominal = self.direction(ring, step);
                let dir = r * jitter(&nominal, half_cone, rng);
                let Some((t, normal, material)) = self.first_return(world, &sectors, &origin, &dir, rng) else {
                    continue;
                };
                let cos_incidence = -normal.dot(&dir);
                if t < self.min_range || cos_incidence < self.min_incidence_cos {
                    continue;
                }
                if rng.unit_f64() < self.drop_probability(t) {
                    continue;
                }
                let range = t + self.sigma(t) * material.noise_scale * rng.normal();
                if range <= 0.0 {
                    continue;
                }
                let p = nominal * range;
                let n = r.transpose() * normal;
                points.push([p.x as f32, p.y as f32, p.z as f32]);
                normals.push([n.x as f32, n.y as f32, n.z as f32]);
            }
        }
        PointCloud { points, normals: Some(normals) }
    }

    /// The first surface the ray meets within range (passing through porous hits by chance): distance, outward
    /// unit normal (world) and material.
    fn first_return(
        &self,
        world: &World,
        sectors: &Sectors,
        origin: &Vector3<f64>,
        dir: &Vector3<f64>,
        rng: &mut Rng,
    ) -> Option<(f64, Vector3<f64>, Material)> {
        let candidates = sectors.objects_along(dir);
        let mut start = 0.0;
        // A beam passes at most a few porous layers before it is spent.
        for _ in 0..4 {
            let o = origin + dir * start;
            let limit = self.max_range - start;
            let ground = world.ground.as_ref().and_then(|g| g.intersect(&o, dir, limit));
            let mut best: Option<(f64, Vector3<f64>, usize)> = None;
            let mut t_max = ground.unwrap_or(limit);
            for &k in candidates {
                if let Some((hit, _)) = cast_ray_object(&world.objects[k..=k], &o, dir, t_max) {
                    t_max = hit.t;
                    best = Some((hit.t, hit.normal, k));
                }
            }
            match best {
                Some((t, normal, k)) => {
                    let material = world.materials.get(k).copied().unwrap_or(Material::SOLID);
                    if material.pass_through > 0.0 && rng.unit_f64() < material.pass_through {
                        // Into the foliage: the next layer starts a little deeper (from inside a solid the ray
                        // sees only what it enters next).
                        start += t + rng.uniform(0.05, 0.6);
                        continue;
                    }
                    return Some((start + t, normal, material));
                }
                None => {
                    return ground.map(|t| {
                        let p = o + dir * t;
                        let g = world.ground.as_ref().map_or(Vector3::z(), |g| g.normal(p.x, p.y));
                        (start + t, g, Material::SOLID)
                    });
                }
            }
        }
        None
    }
}

/// `dir` tilted by an angle uniform over the disc of radius `half_cone` (radians) around it.
fn jitter(dir: &Vector3<f64>, half_cone: f64, rng: &mut Rng) -> Vector3<f64> {
    if half_cone <= 0.0 {
        return *dir;
    }
    let a = half_cone * rng.unit_f64().sqrt();
    let phi = rng.uniform(0.0, TAU);
    let u = if dir.z.abs() < 0.9 { dir.cross(&Vector3::z()) } else { dir.cross(&Vector3::x()) }.normalize();
    let w = dir.cross(&u);
    (dir * a.cos() + (u * phi.cos() + w * phi.sin()) * a.sin()).normalize()
}

/// Objects binned by the world azimuth (seen from the sensor) that their bounding boxes cover, so a ray tests
/// only the objects of its sector.
struct Sectors {
    bins: Vec<Vec<usize>>,
}

const SECTORS: usize = 720;

impl Sectors {
    fn new(objects: &[Object], origin: &Vector3<f64>, max_range: f64) -> Sectors {
        let mut bins = vec![Vec::new(); SECTORS];
        let width = TAU / SECTORS as f64;
        for (k, o) in objects.iter().enumerate() {
            let (lo, hi) = (o.aabb.min - origin, o.aabb.max - origin);
            // Nearest point of the box in the horizontal plane: out of range, skip.
            let gap = |a: f64, b: f64| {
                if a > 0.0 { a } else { (-b).max(0.0) }
            };
            let (dx, dy) = (gap(lo.x, hi.x), gap(lo.y, hi.y));
            if dx.hypot(dy) > max_range {
                continue;
            }
            if dx == 0.0 && dy == 0.0 {
                bins.iter_mut().for_each(|b| b.push(k));
                continue;
            }
            let corners = [(lo.x, lo.y), (lo.x, hi.y), (hi.x, lo.y), (hi.x, hi.y)];
            let mid = ((lo.y + hi.y) / 2.0).atan2((lo.x + hi.x) / 2.0);
            let (mut a0, mut a1) = (0.0f64, 0.0f64);
            for (x, y) in corners {
                let d = wrap(y.atan2(x) - mid);
                a0 = a0.min(d);
                a1 = a1.max(d);
            }
            // One sector of margin either side covers the divergence jitter and rounding.
            let first = ((mid + a0) / width).floor() as i64 - 1;
            let last = ((mid + a1) / width).floor() as i64 + 1;
            for s in first..=last {
                bins[s.rem_euclid(SECTORS as i64) as usize].push(k);
            }
        }
        for b in &mut bins {
            b.sort_unstable();
            b.dedup();
        }
        Sectors { bins }
    }

    fn objects_along(&self, dir: &Vector3<f64>) -> &[usize] {
        let a = dir.y.atan2(dir.x).rem_euclid(TAU);
        &self.bins[((a / TAU * SECTORS as f64) as usize).min(SECTORS - 1)]
    }
}

/// `a` wrapped to (-pi, pi].
fn wrap(a: f64) -> f64 {
    let w = a.rem_euclid(TAU);
    if w > PI { w - TAU } else { w }
}

/// The pose of a sensor at `position` heading `yaw` (radians about z), pitched and rolled by `pitch`, `roll`.
pub fn sensor_pose(position: Vector3<f64>, yaw: f64, pitch: f64, roll: f64) -> Matrix4<f64> {
    use super::geometry::{rot_x, rot_y, rot_z};
    let mut m = Matrix4::identity();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&(rot_z(yaw) * rot_y(pitch) * rot_x(roll)));
    m.fixed_view_mut::<3, 1>(0, 3).copy_from(&position);
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::geometry::Primitive;

    /// A noiseless, lossless scanner with `rings` lasers from -30 to -2 degrees.
    fn ideal(rings: usize, steps: usize) -> Scanner {
        Scanner {
            elevation_deg: Scanner::even_elevations(rings, -30.0, -2.0),
            azimuth_steps: steps,
            min_range: 0.5,
            max_range: 1000.0,
            range_sigma: 0.0,
            range_sigma_per_m: 0.0,
            divergence_mrad: 0.0,
            dropout: 0.0,
            thinning_exponent: 1e9,
            min_incidence_cos: 0.0,
        }
    }

    fn point(cloud: &PointCloud, k: usize) -> Vector3<f64> {
        Vector3::from(cloud.points[k].map(f64::from))
    }

    #[test]
    fn flat_ground_gives_the_ranges_of_the_ring_angles() {
        let h = 1.8;
        let scanner = ideal(16, 90);
        let world = World { ground: Some(Ground::flat(0.0)), ..World::default() };
        let pose = sensor_pose(Vector3::new(3.0, -2.0, h), 0.7, 0.0, 0.0);
        let cloud = scanner.scan(&world, &pose, &mut Rng::new(1));
        assert_eq!(cloud.len(), 16 * 90, "every downward ray hits the ground");
        for (k, n) in cloud.normals.as_ref().unwrap().iter().enumerate() {
            let (ring, p) = (k % 16, point(&cloud, k));
            let el = scanner.elevation_deg[ring].to_radians();
            // Range h / sin(-elevation); horizontal distance h / tan(-elevation); every z at -h.
            // Stored as f32: micrometres off at 50 m.
            assert!((p.norm() - h / (-el).sin()).abs() < 1e-5, "{k}");
            assert!((p.x.hypot(p.y) - h / (-el).tan()).abs() < 1e-5, "{k}");
            assert!((p.z + h).abs() < 1e-5, "{k}: {p}");
            assert!((n[2] - 1.0).abs() < 1e-6);
        }
        // With noise, divergence and dropouts: z stays within what they explain, and returns thin with range.
        let noisy = Scanner {
            range_sigma: 0.02,
            range_sigma_per_m: 0.001,
            divergence_mrad: 2.0,
            dropout: 0.05,
            max_range: 40.0,
            thinning_exponent: 2.0,
            ..ideal(16, 360)
        };
        let cloud = noisy.scan(&world, &pose, &mut Rng::new(2));
        let mut kept = [0usize; 2];
        for k in 0..cloud.len() {
            let p = point(&cloud, k);
            let el = (p.z / p.norm()).asin();
            // Range noise moves z by sin(el) sigma; divergence by at most cot(el) (half cone) h relative.
            let bound = 5.0 * noisy.sigma(p.norm()) * el.sin().abs() + h * 1e-3 / el.tan().abs() * 1.01 + 1e-6;
            assert!((p.z + h).abs() < bound, "{p}: {} > {bound}", (p.z + h).abs());
            kept[usize::from(p.norm() > 8.0)] += 1;
        }
        // Rays below -12.6 degrees land within 8 m (probability of a drop ~0.1), the rest further (up to 0.8).
        let near_rays = noisy.elevation_deg.iter().filter(|e| h / (-e.to_radians()).sin() <= 8.0).count() * 360;
        let far_rays = 16 * 360 - near_rays;
        assert!(kept[0] as f64 > 0.85 * near_rays as f64, "{kept:?} of {near_rays}");
        assert!((kept[1] as f64) < 0.75 * far_rays as f64, "{kept:?} of {far_rays}");
    }

    #[test]
    fn a_wall_gives_ranges_over_the_cosine_of_the_azimuth_offset() {
        let d = 6.0;
        let scanner = Scanner { elevation_deg: vec![-1.0, 0.0, 3.0], ..ideal(3, 720) };
        let wall = Object::new(
            "wall",
            vec![Primitive::cuboid(Vector3::new(d + 0.5, 0.0, 0.0), Vector3::new(0.5, 50.0, 50.0), 0.0)],
        );
        let world = World { ground: None, materials: vec![Material::SOLID], objects: vec![wall] };
        let cloud = scanner.scan(&world, &Matrix4::identity(), &mut Rng::new(3));
        // Only the half facing the wall returns (no sky, nothing behind).
        let mut seen = 0;
        for k in 0..cloud.len() {
            let p = point(&cloud, k);
            let (az, el) = (p.y.atan2(p.x), (p.z / p.norm()).asin());
            assert!(az.abs() < PI / 2.0);
            assert!((p.norm() - d / (az.cos() * el.cos())).abs() < 1e-6, "{p}");
            assert!((p.x - d).abs() < 1e-6);
            seen += 1;
        }
        // Azimuths within atan(50 / 6) of the wall's normal hit it.
        let expected = (0..720).filter(|s| (TAU * *s as f64 / 720.0).cos() > (50f64).atan2(d).cos()).count() * 3;
        assert!((seen as i64 - expected as i64).abs() <= 6, "{seen} vs {expected}");
    }

    #[test]
    fn undulating_ground_is_met_exactly_and_sky_returns_nothing() {
        let ground =
            Ground { base: 0.2, slope: [0.02, -0.01], waves: vec![(0.3, [0.2, 0.1], 0.4), (0.1, [0.0, 0.5], 1.0)] };
        let origin = Vector3::new(1.0, 2.0, 2.5);
        let mut rng = Rng::new(4);
        for _ in 0..500 {
            let d = Vector3::new(rng.normal(), rng.normal(), -rng.unit_f64() * 0.5).normalize();
            if let Some(t) = ground.intersect(&origin, &d, 500.0) {
                let p = origin + d * t;
                assert!((p.z - ground.height(p.x, p.y)).abs() < 1e-5);
                // No earlier crossing: the ray stays above the ground before t.
                for s in 1..50 {
                    let q = origin + d * (t * s as f64 / 50.0);
                    assert!(q.z >= ground.height(q.x, q.y) - 1e-6);
                }
            }
        }
        let scanner = Scanner { elevation_deg: vec![5.0, 15.0], ..ideal(2, 100) };
        let world = World { ground: Some(Ground::flat(0.0)), ..World::default() };
        assert!(scanner.scan(&world, &sensor_pose(origin, 0.0, 0.0, 0.0), &mut rng).is_empty());
    }

    #[test]
    fn porous_objects_return_from_inside_and_behind() {
        // A crown of three overlapping spheres along the beam (entries at 3.7, 4.7 and 5.7 m), a wall behind.
        let bush =
            Object::new("bush", [4.5, 5.5, 6.5].map(|x| Primitive::sphere(Vector3::new(x, 0.0, 0.0), 0.8)).to_vec());
        let wall = Object::new(
            "wall",
            vec![Primitive::cuboid(Vector3::new(9.0, 0.0, 0.0), Vector3::new(0.5, 20.0, 20.0), 0.0)],
        );
        let world = World {
            ground: None,
            objects: vec![bush, wall],
            materials: vec![Material { pass_through: 0.5, noise_scale: 1.0 }, Material::SOLID],
        };
        let scanner = Scanner { elevation_deg: vec![0.0], divergence_mrad: 30.0, ..ideal(1, 1) };
        let mut ranges = Vec::new();
        let mut rng = Rng::new(5);
        for _ in 0..400 {
            ranges.extend(scanner.scan(&world, &Matrix4::identity(), &mut rng).points.iter().map(|p| p[0] as f64));
        }
        assert_eq!(ranges.len(), 400);
        let (front, inside, behind) = (
            ranges.iter().filter(|&&r| r < 3.71).count(),
            ranges.iter().filter(|&&r| r > 3.71 && r < 8.0).count(),
            ranges.iter().filter(|&&r| r > 8.4).count(),
        );
        assert!(front > 150 && inside > 60 && behind > 10, "{front} {inside} {behind}");
    }
}
