//! Outdoor scenes for the LiDAR styles, the drive through them, and the sweeps' ground truth.
//!
//! `lidar` builds a street: an undulating ground, a road with raised sidewalks and curbs, buildings whose
//! facades have piers and floor bands around recessed bays, street lights and sign posts, parked cars (a body
//! with rounded ends, a cabin, wheels) and vegetation (trees with porous crowns, bushes); it is scanned by a
//! 32-ring scanner ([`street_scanner`]). `heldout-lidar` builds an industrial yard that `lidar` never builds:
//! stacks of ribbed shipping containers, storage tanks ringed by bollards, pipe racks, gable-roofed sheds,
//! parked semi-trailers, gravel heaps, jersey barriers and a fence line; it is scanned by a 64-ring scanner with
//! another vertical field of view ([`yard_scanner`]). Every object's kind is counted in `style.json`
//! (`families`).
//!
//! The vehicle drives a smooth curve (curvature varying sinusoidally along the way); each sweep is taken 1-3 m
//! after the previous one, with the sensor 1.7-2.1 m above the ground, tilted as the ground under it and by a
//! little vibration. A sweep is a fragment, in its sensor frame. gt.log keeps the pairs whose sensors are
//! [`MIN_PAIR_DISTANCE`]-[`MAX_PAIR_DISTANCE`] m apart and whose overlap passes the rule's `min_overlap`, with the
//! rule's distances times [`GT_SCALE`] (LiDAR points are centimetres to metres apart, where the 3DMatch rule's
//! 3 cm would count almost no point as overlapping).

use super::geometry::{Object, Primitive, Shape, rot_x, rot_y, rot_z};
use super::lidar::{Ground, Material, Scanner, World, sensor_pose};
use super::room::Room;
use super::style::{Overrides, Style};
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::eval::groundtruth::{GroundTruthRule, GtPair};
use crate::rng::Rng;
use nalgebra::{Matrix4, Vector3};
use rayon::prelude::*;
use serde::Serialize;
use std::collections::BTreeMap;
use std::f64::consts::{FRAC_PI_2, PI, TAU};

/// gt.log pairs need sensors at least this far apart (metres).
pub const MIN_PAIR_DISTANCE: f64 = 1.0;
/// gt.log pairs need sensors at most this far apart (metres).
pub const MAX_PAIR_DISTANCE: f64 = 10.0;
/// The ground-truth rule's distances (grid, overlap distance, information distance) are multiplied by this for
/// LiDAR sweeps: 0.1 m grid, 0.3 m overlap distance, 0.06 m correspondences.
pub const GT_SCALE: f64 = 10.0;

/// Random stream ids of a LiDAR scene (disjoint from the other styles' by construction: a scene draws from
/// one generator only).
const STREAM_RECIPE: u64 = 3;
const STREAM_SCENE: u64 = 4;
const STREAM_POSES: u64 = 5;
const STREAM_SWEEPS: u64 = 1 << 32;

/// The drive.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DriveRecord {
    /// Curvature = `curvature[0]` + `curvature[1]` sin(2 pi s / `wavelength` + `phase`) (1/m).
    pub curvature: [f64; 2],
    /// Wavelength of the curvature's variation (metres).
    pub wavelength: f64,
    /// Phase (radians).
    pub phase: f64,
    /// Heading at s = 0 (radians).
    pub heading: f64,
    /// The sensor's offset to the left of the centre line (metres).
    pub lane_offset: f64,
    /// Range of the distance driven between sweeps (metres).
    pub step: [f64; 2],
}

/// One sweep.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SweepRecord {
    /// Distance along the centre line (metres).
    pub s: f64,
    /// Sensor position (world).
    pub position: [f64; 3],
    /// Heading, pitch and roll (degrees).
    pub yaw_pitch_roll_deg: [f64; 3],
    /// Returns in the sweep.
    pub points: usize,
}

/// Every parameter a LiDAR scene drew (written as `style.json`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LidarRecipe {
    /// `lidar` or `heldout_lidar`.
    pub style: Style,
    /// The scene seed.
    pub seed: u64,
    /// "street" or "yard".
    pub kind: String,
    /// The scanner.
    pub scanner: Scanner,
    /// Sensor height above the ground (metres).
    pub mount_height: f64,
    /// The ground.
    pub ground: Ground,
    /// The drive.
    pub drive: DriveRecord,
    /// Number of objects of each kind.
    pub families: BTreeMap<String, usize>,
    /// gt.log rule: sensor distances (metres) and the factor on the rule's distances.
    pub pair_distance: [f64; 2],
    /// See [`GT_SCALE`].
    pub gt_scale: f64,
    /// Per sweep.
    pub sweeps: Vec<SweepRecord>,
}

/// A generated LiDAR scene.
pub struct LidarScene {
    /// The sweeps, each in its sensor frame.
    pub fragments: Vec<PointCloud>,
    /// x_world = world_from_fragment[k] x_sweep.
    pub world_from_fragment: Vec<Matrix4<f64>>,
    /// The scanned solids (the ground is in `recipe.ground`).
    pub room: Room,
    /// What was drawn.
    pub recipe: LidarRecipe,
}

/// The `lidar` scanner: 32 evenly spaced lasers (an HDL-32E-like field of view, about -30 to +10 degrees).
pub fn street_scanner(rng: &mut Rng) -> Scanner {
    Scanner {
        elevation_deg: Scanner::even_elevations(32, rng.uniform(-32.0, -28.0), rng.uniform(9.0, 12.0)),
        azimuth_steps: 1024 + 64 * rng.below(13),
        min_range: rng.uniform(1.0, 1.5),
        max_range: rng.uniform(80.0, 120.0),
        range_sigma: rng.uniform(0.01, 0.02),
        range_sigma_per_m: rng.uniform(0.0001, 0.0003),
        divergence_mrad: rng.uniform(1.5, 3.0),
        dropout: rng.uniform(0.01, 0.05),
        thinning_exponent: rng.uniform(1.5, 2.5),
        min_incidence_cos: rng.uniform(0.03, 0.08),
    }
}

/// The `heldout-lidar` scanner: 64 lasers in two blocks (an HDL-64E-like field of view, about -25 to +2
/// degrees; the lower block twice as coarse as the upper).
pub fn yard_scanner(rng: &mut Rng) -> Scanner {
    let (low, mid, high) = (rng.uniform(-25.5, -24.0), rng.uniform(-9.0, -8.0), rng.uniform(1.5, 3.0));
    let mut elevation_deg = Scanner::even_elevations(32, low, mid - 0.5);
    elevation_deg.extend(Scanner::even_elevations(32, mid, high));
    Scanner {
        elevation_deg,
        azimuth_steps: 900 + 50 * rng.below(5),
        min_range: rng.uniform(2.0, 3.0),
        max_range: rng.uniform(90.0, 120.0),
        range_sigma: rng.uniform(0.015, 0.025),
        range_sigma_per_m: rng.uniform(0.0002, 0.0004),
        divergence_mrad: rng.uniform(2.0, 3.0),
        dropout: rng.uniform(0.02, 0.06),
        thinning_exponent: rng.uniform(1.2, 2.0),
        min_incidence_cos: rng.uniform(0.03, 0.08),
    }
}

/// The centre line, tabulated every [`Drive::DS`] metres from `s0`.
struct Drive {
    s0: f64,
    samples: Vec<[f64; 3]>,
}

impl Drive {
    const DS: f64 = 0.25;

    fn new(record: &DriveRecord, s0: f64, s1: f64) -> Drive {
        let curvature =
            |s: f64| record.curvature[0] + record.curvature[1] * (TAU * s / record.wavelength + record.phase).sin();
        // Integrate forwards and backwards from s = 0 (midpoint rule).
        let (n_back, n_fwd) = ((-s0 / Self::DS).ceil() as usize, (s1 / Self::DS).ceil() as usize);
        let mut back = vec![[0.0, 0.0, record.heading]];
        for k in 0..n_back {
            let [x, y, h] = back[k];
            let s = -(k as f64) * Self::DS;
            let hm = h - curvature(s - Self::DS / 2.0) * Self::DS / 2.0;
            back.push([x - hm.cos() * Self::DS, y - hm.sin() * Self::DS, h - curvature(s - Self::DS / 2.0) * Self::DS]);
        }
        let mut samples: Vec<[f64; 3]> = back.into_iter().rev().collect();
        for k in 0..n_fwd {
            let [x, y, h] = *samples.last().unwrap_or(&[0.0, 0.0, record.heading]);
            let s = k as f64 * Self::DS;
            let hm = h + curvature(s + Self::DS / 2.0) * Self::DS / 2.0;
            samples.push([
                x + hm.cos() * Self::DS,
                y + hm.sin() * Self::DS,
                h + curvature(s + Self::DS / 2.0) * Self::DS,
            ]);
        }
        Drive { s0: -(n_back as f64) * Self::DS, samples }
    }

    fn s_range(&self) -> (f64, f64) {
        (self.s0, self.s0 + (self.samples.len() - 1) as f64 * Self::DS)
    }

    /// (x, y, heading) at `s` (linear interpolation, clamped to the table).
    fn at(&self, s: f64) -> [f64; 3] {
        let f = ((s - self.s0) / Self::DS).clamp(0.0, (self.samples.len() - 1) as f64);
        let k = (f.floor() as usize).min(self.samples.len() - 2);
        let w = f - k as f64;
        let (a, b) = (self.samples[k], self.samples[k + 1]);
        [a[0] + (b[0] - a[0]) * w, a[1] + (b[1] - a[1]) * w, a[2] + (b[2] - a[2]) * w]
    }

    /// World (x, y) of the point `w` metres left of the centre line at `s`, and the heading there.
    fn point(&self, s: f64, w: f64) -> (f64, f64, f64) {
        let [x, y, h] = self.at(s);
        (x - w * h.sin(), y + w * h.cos(), h)
    }

    /// Distance from (x, y) to the centre line.
    fn distance(&self, x: f64, y: f64) -> f64 {
        self.samples.iter().map(|p| (p[0] - x).hypot(p[1] - y)).fold(f64::INFINITY, f64::min)
    }
}

/// Collects the objects of a scene with their materials.
struct Site<'a> {
    drive: &'a Drive,
    ground: &'a Ground,
    objects: Vec<Object>,
    materials: Vec<Material>,
}

impl Site<'_> {
    fn add(&mut self, kind: &'static str, primitives: Vec<Primitive>, material: Material) {
        if !primitives.is_empty() {
            self.objects.push(Object::new(kind, primitives));
            self.materials.push(material);
        }
    }

    /// `local` primitives (x along the road, y to its left, z up from the ground) placed at (s, w), turned
    /// by `yaw` more than the road; the local origin sits `sink` below the ground there.
    fn place(&self, local: &[Primitive], s: f64, w: f64, yaw: f64, sink: f64) -> Vec<Primitive> {
        let (x, y, h) = self.drive.point(s, w);
        let z = self.ground.height(x, y) - sink;
        let r = rot_z(h + yaw);
        local.iter().map(|p| p.placed(&r, &Vector3::new(x, y, z))).collect()
    }

    /// Adds a solid `kind` of `local` primitives (standing on local z 0) at (s, w), moved away from the road
    /// (`side` 1: to the left) in 0.5 m steps, up to 6 m, until it keeps `clearance` from the centre line; its
    /// boxes reach down to the lowest ground under it. Returns the offset it stands at.
    fn add_standing(
        &mut self,
        kind: &'static str,
        local: &[Primitive],
        s: f64,
        w: f64,
        side: f64,
        clearance: f64,
    ) -> f64 {
        let mut extra = 0.0;
        while extra < 6.0 && !self.clear(local, s, w + side * extra, 0.0, clearance) {
            extra += 0.5;
        }
        let w = w + side * extra;
        let sink = self.sink(local, s, w, 0.0);
        let grounded: Vec<Primitive> = local.iter().map(|p| sunk(p, sink)).collect();
        let placed = self.place(&grounded, s, w, 0.0, sink);
        self.add(kind, placed, Material::SOLID);
        w
    }

    /// True when the footprint of `local` primitives placed at (s, w, yaw) keeps `clearance` from the centre
    /// line.
    fn clear(&self, local: &[Primitive], s: f64, w: f64, yaw: f64, clearance: f64) -> bool {
        self.place(local, s, w, yaw, 0.0).iter().all(|p| {
            let b = p.aabb();
            let corners = [(b.min.x, b.min.y), (b.min.x, b.max.y), (b.max.x, b.min.y), (b.max.x, b.max.y)];
            let centre = ((b.min.x + b.max.x) / 2.0, (b.min.y + b.max.y) / 2.0);
            corners.iter().chain([&centre]).all(|&(x, y)| self.drive.distance(x, y) >= clearance)
        })
    }

    /// The lowest ground under the footprint of `local` placed at (s, w, yaw), relative to the ground at (s, w).
    fn sink(&self, local: &[Primitive], s: f64, w: f64, yaw: f64) -> f64 {
        let (x, y, _) = self.drive.point(s, w);
        let at = self.ground.height(x, y);
        let low = self
            .place(local, s, w, yaw, 0.0)
            .iter()
            .flat_map(|p| {
                let b = p.aabb();
                [(b.min.x, b.min.y), (b.min.x, b.max.y), (b.max.x, b.min.y), (b.max.x, b.max.y)]
            })
            .map(|(x, y)| self.ground.height(x, y))
            .fold(at, f64::min);
        at - low + 0.3
    }
}

fn cuboid(x0: f64, x1: f64, y0: f64, y1: f64, z0: f64, z1: f64) -> Primitive {
    super::furniture::slab(x0.min(x1), x0.max(x1), y0.min(y1), y0.max(y1), z0, z1)
}

fn v(x: f64, y: f64, z: f64) -> Vector3<f64> {
    Vector3::new(x, y, z)
}

/// Foliage: porous, noisy.
fn foliage(rng: &mut Rng) -> Material {
    Material { pass_through: rng.uniform(0.25, 0.5), noise_scale: rng.uniform(3.0, 6.0) }
}

/// A building of `frontage` x `depth` x `height` whose facade faces the road (local -y for `side` = 1, the
/// left side): a core set back by `recess`, piers and floor bands reaching the facade plane.
fn building(rng: &mut Rng, side: f64, frontage: f64, depth: f64, floors: usize) -> Vec<Primitive> {
    let floor_h = rng.uniform(3.0, 3.6);
    let height = floors as f64 * floor_h + rng.uniform(0.3, 1.0);
    let recess = rng.uniform(0.25, 0.7);
    let hx = frontage / 2.0;
    // Local y of the facade plane is 0; the building extends away from the road.
    let (y_face, y_core, y_back) = (0.0, side * recess, side * depth);
    let mut parts = vec![cuboid(-hx, hx, y_core, y_back, 0.0, height)];
    let bays = (frontage / rng.uniform(2.5, 4.5)).round().max(1.0) as usize;
    let pier = rng.uniform(0.4, 0.9);
    for k in 0..=bays {
        let x = -hx + frontage * k as f64 / bays as f64;
        let (x0, x1) = ((x - pier / 2.0).max(-hx), (x + pier / 2.0).min(hx));
        parts.push(cuboid(x0, x1, y_face, y_core, 0.0, height));
    }
    let band = rng.uniform(0.3, 0.7);
    for f in 1..floors {
        let z = f as f64 * floor_h;
        parts.push(cuboid(-hx, hx, y_face, y_core, z - band / 2.0, z + band / 2.0));
    }
    // A ground-floor shop front is deeper set back, under a canopy, now and then.
    if rng.below(3) == 0 {
        parts.push(cuboid(-hx, hx, y_face - side * 1.2, y_face, floor_h - 0.25, floor_h));
    }
    parts
}

/// A parked car along the road: a body with rounded ends, a cabin and four wheels (local x along the car).
fn car(rng: &mut Rng) -> Vec<Primitive> {
    let (len, width) = (rng.uniform(3.9, 4.9), rng.uniform(1.7, 1.9));
    let (clearance, body_h) = (rng.uniform(0.25, 0.35), rng.uniform(0.6, 0.85));
    let r_end = body_h / 2.0;
    let hx = len / 2.0 - r_end;
    let zc = clearance + body_h / 2.0;
    let across = rot_x(FRAC_PI_2);
    let mut parts = vec![
        cuboid(-hx, hx, -width / 2.0, width / 2.0, clearance, clearance + body_h),
        Primitive::cylinder(v(hx, 0.0, zc), r_end, width / 2.0, across),
        Primitive::cylinder(v(-hx, 0.0, zc), r_end, width / 2.0, across),
    ];
    let cabin_len = len * rng.uniform(0.45, 0.6);
    let cabin_x = rng.uniform(-0.4, 0.1);
    let cabin_h = rng.uniform(0.45, 0.65);
    let top = clearance + body_h;
    parts.push(cuboid(
        cabin_x - cabin_len / 2.0,
        cabin_x + cabin_len / 2.0,
        -width * 0.44,
        width * 0.44,
        top,
        top + cabin_h,
    ));
    let wheel_r = rng.uniform(0.3, 0.36);
    for (sx, sy) in [(-1.0, -1.0), (-1.0, 1.0), (1.0, -1.0), (1.0, 1.0)] {
        parts.push(Primitive::cylinder(
            v(sx * (len / 2.0 - 0.8), sy * (width / 2.0 - 0.1), wheel_r),
            wheel_r,
            0.11,
            across,
        ));
    }
    parts
}

/// Spheres around `centre` (local) within `spread`, radii in `radius`.
fn blob_cluster(
    rng: &mut Rng,
    centre: Vector3<f64>,
    spread: [f64; 3],
    radius: [f64; 2],
    count: usize,
) -> Vec<Primitive> {
    (0..count)
        .map(|_| {
            let c = centre
                + v(
                    rng.uniform(-1.0, 1.0) * spread[0],
                    rng.uniform(-1.0, 1.0) * spread[1],
                    rng.uniform(-1.0, 1.0) * spread[2],
                );
            Primitive::sphere(c, rng.uniform(radius[0], radius[1]))
        })
        .collect()
}

/// The street of `lidar` around the stretch [s0, s1] of the drive.
fn build_street(rng: &mut Rng, site: &mut Site, s0: f64, s1: f64) {
    let lane = rng.uniform(3.1, 3.6);
    let parking = [rng.below(10) < 7, rng.below(10) < 7].map(|p| if p { rng.uniform(2.0, 2.4) } else { 0.0 });
    let curb = rng.uniform(0.1, 0.18);
    let walk = [rng.uniform(2.0, 4.5), rng.uniform(2.0, 4.5)];
    for (k, side) in [1.0f64, -1.0].into_iter().enumerate() {
        let road_edge = lane + parking[k];
        let st =
            StreetSide { side, lane, parking: parking[k], curb, walk: walk[k], road_edge, outer: road_edge + walk[k] };
        street_curbs(site, &st, (s0, s1));
        street_buildings(rng, site, &st, (s0, s1));
        street_posts(rng, site, &st, (s0, s1));
        street_trees(rng, site, &st, (s0, s1));
        street_cars(rng, site, &st, (s0, s1));
    }
}

/// One side of a street: `side` (+1 left of the drive, -1 right), the lane and parking lane widths, curb
/// height, sidewalk width, and the distances of the road's edge and the sidewalk's outer edge from the centre.
struct StreetSide {
    side: f64,
    lane: f64,
    parking: f64,
    curb: f64,
    walk: f64,
    road_edge: f64,
    outer: f64,
}

/// Curb stone and sidewalk in 2 m pieces, tilted with the ground along the road.
fn street_curbs(site: &mut Site, st: &StreetSide, (s0, s1): (f64, f64)) {
    let mut s = s0;
    while s < s1 {
        let (x, y, h) = site.drive.point(s + 1.0, st.side * (st.road_edge + st.walk / 2.0));
        let g = site.ground.gradient(x, y);
        let pitch = -(g[0] * h.cos() + g[1] * h.sin()).atan();
        let z = site.ground.height(x, y);
        let r = rot_z(h) * rot_y(pitch);
        let stone = Primitive {
            shape: Shape::Cuboid { half: v(1.0, 0.12, (st.curb + 0.62) / 2.0) },
            center: v(0.0, -st.side * (st.walk / 2.0 - 0.12), (st.curb + 0.02 - 0.6) / 2.0),
            rotation: nalgebra::Matrix3::identity(),
        };
        let slab = Primitive {
            shape: Shape::Cuboid { half: v(1.0, st.walk / 2.0 - 0.12, (st.curb + 0.6) / 2.0) },
            center: v(0.0, st.side * 0.12, (st.curb - 0.6) / 2.0),
            rotation: nalgebra::Matrix3::identity(),
        };
        let parts = [stone, slab].iter().map(|p| p.placed(&r, &v(x, y, z))).collect();
        site.add("curb", parts, Material::SOLID);
        s += 2.0;
    }
}

/// Buildings behind the sidewalk, with alleys between them.
fn street_buildings(rng: &mut Rng, site: &mut Site, st: &StreetSide, (s0, s1): (f64, f64)) {
    let mut s = s0 + rng.uniform(-10.0, 0.0);
    while s < s1 {
        if rng.below(5) == 0 {
            s += rng.uniform(3.0, 8.0);
        }
        let frontage = rng.uniform(8.0, 25.0);
        let depth = rng.uniform(8.0, 18.0);
        let floors = 1 + rng.below(6);
        let setback = if rng.below(3) == 0 { rng.uniform(1.0, 5.0) } else { 0.0 };
        let local = building(rng, st.side, frontage, depth, floors);
        let mid = s + frontage / 2.0;
        // Off the road and the sidewalk, also on the inside of a bend.
        let w =
            site.add_standing("building", &local, mid, st.side * (st.outer + setback + 0.3), st.side, st.outer + 0.1);
        // A hedge or bushes in front of some buildings set back from the walk.
        if setback > 1.5 {
            let n = 3 + rng.below(6);
            let local =
                blob_cluster(rng, v(0.0, -st.side * setback / 2.0, 0.4), [frontage * 0.3, 0.3, 0.1], [0.4, 0.8], n);
            let m = foliage(rng);
            site.add("bush", site.place(&local, mid, w, 0.0, 0.0), m);
        }
        s += frontage + rng.uniform(0.0, 1.5);
    }
}

/// Street lights and sign posts near the curb.
fn street_posts(rng: &mut Rng, site: &mut Site, st: &StreetSide, (s0, s1): (f64, f64)) {
    let mut s = s0 + rng.uniform(0.0, 15.0);
    while s < s1 {
        let w = st.side * (st.road_edge + 0.5);
        if rng.below(3) == 0 {
            let h = rng.uniform(2.2, 3.0);
            let plate = if rng.below(2) == 0 {
                cuboid(-0.03, 0.03, -0.35, 0.35, h - 0.6, h)
            } else {
                Primitive::cylinder(v(0.0, 0.0, h - 0.35), 0.33, 0.02, rot_y(FRAC_PI_2))
            };
            let local = vec![Primitive::upright_cylinder(v(0.0, 0.0, h / 2.0), 0.035, h / 2.0 + 0.3), plate];
            site.add("sign", site.place(&local, s, w, 0.0, 0.3), Material::SOLID);
        } else {
            let (h, r, arm) = (rng.uniform(6.0, 9.0), rng.uniform(0.07, 0.12), rng.uniform(1.2, 2.5));
            let local = vec![
                Primitive::upright_cylinder(v(0.0, 0.0, h / 2.0), r, h / 2.0 + 0.3),
                Primitive::cylinder(v(0.0, -st.side * arm / 2.0, h), 0.05, arm / 2.0, rot_x(FRAC_PI_2)),
                cuboid(-0.2, 0.2, -st.side * (arm - 0.3), -st.side * (arm + 0.3), h - 0.25, h - 0.05),
            ];
            site.add("pole", site.place(&local, s, w, 0.0, 0.3), Material::SOLID);
        }
        s += rng.uniform(12.0, 35.0);
    }
}

/// Trees on the sidewalk, between the lights.
fn street_trees(rng: &mut Rng, site: &mut Site, st: &StreetSide, (s0, s1): (f64, f64)) {
    let mut s = s0 + rng.uniform(0.0, 10.0);
    while s < s1 {
        if rng.below(4) != 0 {
            let w = st.side * (st.road_edge + st.walk * rng.uniform(0.5, 0.8));
            let trunk_h = rng.uniform(2.0, 3.5);
            let r = rng.uniform(0.12, 0.25);
            site.add(
                "tree",
                site.place(
                    &[Primitive::upright_cylinder(v(0.0, 0.0, trunk_h / 2.0), r, trunk_h / 2.0 + 0.3)],
                    s,
                    w,
                    0.0,
                    0.3,
                ),
                Material::SOLID,
            );
            let crown = rng.uniform(1.2, 2.5);
            let n = 4 + rng.below(6);
            let local = blob_cluster(
                rng,
                v(0.0, 0.0, trunk_h + crown),
                [crown * 0.6, crown * 0.6, crown * 0.5],
                [crown * 0.4, crown * 0.8],
                n,
            );
            let m = foliage(rng);
            site.add("crown", site.place(&local, s, w, 0.0, 0.0), m);
        }
        s += rng.uniform(7.0, 20.0);
    }
}

/// Parked cars in the parking lane, if the side has one.
fn street_cars(rng: &mut Rng, site: &mut Site, st: &StreetSide, (s0, s1): (f64, f64)) {
    if st.parking > 0.0 {
        let mut s = s0 + rng.uniform(0.0, 8.0);
        while s < s1 {
            if rng.below(4) != 0 {
                let local = car(rng);
                let w = st.side * (st.lane + st.parking / 2.0 + rng.uniform(-0.15, 0.15));
                site.add("car", site.place(&local, s, w, rng.uniform(-0.04, 0.04), 0.0), Material::SOLID);
            }
            s += rng.uniform(5.5, 9.0);
        }
    }
}

/// `p` lifted by `dz`, except that a box standing on local z = 0 keeps its bottom there (it grows down by `dz`):
/// placed `dz` below the ground, it stands on the lowest ground under it.
fn sunk(p: &Primitive, dz: f64) -> Primitive {
    match p.shape {
        Shape::Cuboid { half } if (p.center.z - half.z).abs() < 0.05 && p.rotation[(2, 2)] > 1.0 - 1e-9 => Primitive {
            shape: Shape::Cuboid { half: v(half.x, half.y, half.z + dz / 2.0) },
            center: p.center + v(0.0, 0.0, dz / 2.0),
            rotation: p.rotation,
        },
        _ => Primitive { center: p.center + v(0.0, 0.0, dz), ..p.clone() },
    }
}

/// A shipping container (local x along it) with ribbed long sides, its bottom at `z0`.
fn container(length: f64, z0: f64) -> Vec<Primitive> {
    let (hx, hy, h) = (length / 2.0, 1.22, 2.59);
    let mut parts = vec![cuboid(-hx, hx, -hy, hy, z0, z0 + h)];
    let ribs = (length / 1.0).round() as usize;
    for k in 1..ribs {
        let x = -hx + length * k as f64 / ribs as f64;
        for s in [-1.0, 1.0] {
            parts.push(cuboid(x - 0.06, x + 0.06, s * hy, s * (hy + 0.04), z0 + 0.1, z0 + h - 0.1));
        }
    }
    parts
}

/// The industrial yard of `heldout-lidar` around the stretch [s0, s1] of the drive.
fn build_yard(rng: &mut Rng, site: &mut Site, s0: f64, s1: f64) {
    let corridor = rng.uniform(5.0, 7.5);
    for side in [1.0f64, -1.0] {
        let mut s = s0 + rng.uniform(-10.0, 0.0);
        while s < s1 {
            let w0 = side * (corridor + rng.uniform(0.5, 3.0));
            s = match rng.below(6) {
                0 | 1 => yard_containers(rng, site, s, (w0, side)),
                2 => yard_tank(rng, site, s, (w0, side)),
                3 => yard_shed(rng, site, s, (w0, side), corridor),
                4 => yard_trailer(rng, site, s, (w0, side)),
                _ => yard_heap(rng, site, s, (w0, side)),
            };
        }
        yard_fence(rng, site, (s0, s1), side);
    }
}

/// A row of container stacks, end to end. Returns where the next piece may start.
fn yard_containers(rng: &mut Rng, site: &mut Site, s: f64, (w0, side): (f64, f64)) -> f64 {
    let length = if rng.below(2) == 0 { 6.06 } else { 12.19 };
    let count = 1 + rng.below(4);
    for c in 0..count {
        let mid = s + (c as f64 + 0.5) * (length + 0.3);
        let mut stack = Vec::new();
        for level in 0..1 + rng.below(3) {
            stack.extend(container(length, level as f64 * 2.6 + 0.01).into_iter().map(|p| {
                p.placed(&rot_z(rng.uniform(-0.02, 0.02)), &v(rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), 0.0))
            }));
        }
        site.add_standing("container", &stack, mid, w0 + side * 1.3, side, 0.0);
    }
    s + (count as f64 * (length + 0.3) + rng.uniform(2.0, 8.0))
}

/// Storage tanks with a roof cap, and bollards in front. Returns where the next piece may start.
fn yard_tank(rng: &mut Rng, site: &mut Site, s: f64, (w0, side): (f64, f64)) -> f64 {
    let r = rng.uniform(2.0, 6.0);
    let h = rng.uniform(5.0, 14.0);
    let w = w0 + side * (r + 1.5);
    let local = vec![
        Primitive::upright_cylinder(v(0.0, 0.0, h / 2.0 - 0.5), r, h / 2.0 + 0.5),
        Primitive::upright_cylinder(v(0.0, 0.0, h + 0.3), r * 0.6, 0.3),
    ];
    site.add("tank", site.place(&local, s + r, w, 0.0, 0.3), Material::SOLID);
    for b in 0..3 + rng.below(4) {
        let x = s + r * (b as f64 * 0.6 - 0.8);
        let local = [Primitive::upright_cylinder(v(0.0, 0.0, 0.3), 0.12, 0.9)];
        site.add("bollard", site.place(&local, x, w0, 0.0, 0.3), Material::SOLID);
    }
    s + (2.0 * r + rng.uniform(3.0, 8.0))
}

/// A gable-roofed shed, ridge along the drive. Returns where the next piece may start.
fn yard_shed(rng: &mut Rng, site: &mut Site, s: f64, (w0, side): (f64, f64), corridor: f64) -> f64 {
    let (length, depth) = (rng.uniform(15.0, 35.0), rng.uniform(10.0, 20.0));
    let eave = rng.uniform(4.0, 7.0);
    let pitch = rng.uniform(0.2, 0.4);
    let hx = length / 2.0;
    let yc = side * depth / 2.0;
    let half_span = depth / 2.0;
    let rafter = half_span / pitch.cos();
    let rise = half_span * pitch.tan();
    let mut local = vec![cuboid(-hx, hx, 0.0, side * depth, 0.0, eave)];
    for s2 in [-1.0, 1.0] {
        let centre = v(0.0, yc + s2 * half_span / 2.0, eave + rise / 2.0);
        let tilt = rot_x(-s2 * pitch);
        local.push(Primitive {
            shape: Shape::Cuboid { half: v(hx + 0.3, rafter / 2.0 + 0.2, 0.1) },
            center: centre,
            rotation: tilt,
        });
    }
    // Roll-up doors: shallow recesses framed by posts on the drive side.
    for d in 0..(length / 8.0) as usize {
        let x = -hx + 4.0 + d as f64 * 8.0;
        local.push(cuboid(x - 2.2, x - 1.9, 0.0, -side * 0.3, 0.0, eave * 0.7));
        local.push(cuboid(x + 1.9, x + 2.2, 0.0, -side * 0.3, 0.0, eave * 0.7));
    }
    site.add_standing("shed", &local, s + hx, w0, side, corridor + 0.2);
    s + (length + rng.uniform(3.0, 10.0))
}

/// A parked semi-trailer: a long box on a raised frame, wheels at the rear, legs at the front. Returns where the next piece may start.
fn yard_trailer(rng: &mut Rng, site: &mut Site, s: f64, (w0, side): (f64, f64)) -> f64 {
    let (len, floor) = (rng.uniform(12.0, 13.6), rng.uniform(1.1, 1.3));
    let hx = len / 2.0;
    let mut local = vec![cuboid(-hx, hx, -1.27, 1.27, floor, floor + 2.7)];
    for a in 0..3 {
        let x = hx - 1.5 - a as f64 * 1.3;
        local.push(Primitive::cylinder(v(x, 0.0, 0.5), 0.5, 1.25, rot_x(FRAC_PI_2)));
    }
    for sy in [-1.0, 1.0] {
        local.push(cuboid(-hx + 2.5, -hx + 2.7, sy * 1.0, sy * 1.2, 0.0, floor));
    }
    let w = w0 + side * 1.5;
    site.add("trailer", site.place(&local, s + hx, w, rng.uniform(-0.1, 0.1), 0.0), Material::SOLID);
    s + (len + rng.uniform(2.0, 6.0))
}

/// A gravel heap (a buried sphere) behind a line of jersey barriers. Returns where the next piece may start.
fn yard_heap(rng: &mut Rng, site: &mut Site, s: f64, (w0, side): (f64, f64)) -> f64 {
    let r = rng.uniform(3.0, 7.0);
    let h = rng.uniform(1.5, 3.5);
    let w = w0 + side * (r + 2.0);
    let local = [Primitive::sphere(v(0.0, 0.0, h - r), r)];
    site.add("heap", site.place(&local, s + r, w, 0.0, 0.0), Material::SOLID);
    let barriers = 1 + rng.below(4);
    for b in 0..barriers {
        let local = [cuboid(-1.5, 1.5, -0.3, 0.3, 0.0, 0.3), cuboid(-1.5, 1.5, -0.12, 0.12, 0.3, 0.81)];
        let local: Vec<Primitive> = local.iter().map(|p| sunk(p, 0.3)).collect();
        site.add("barrier", site.place(&local, s + 1.6 + b as f64 * 3.1, w0, 0.0, 0.3), Material::SOLID);
    }
    s + (2.0 * r + rng.uniform(2.0, 6.0))
}

/// A fence line far out: posts every 3 m and a top rail, in 30 m pieces.
fn yard_fence(rng: &mut Rng, site: &mut Site, (s0, s1): (f64, f64), side: f64) {
    let w = side * rng.uniform(25.0, 40.0);
    let mut s = s0;
    while s < s1 {
        let mut local = Vec::new();
        for p in 0..10 {
            local.push(Primitive::upright_cylinder(v(p as f64 * 3.0, 0.0, 0.9), 0.03, 1.2));
        }
        local.push(Primitive::cylinder(v(13.5, 0.0, 2.0), 0.025, 13.5, rot_y(FRAC_PI_2)));
        site.add("fence", site.place(&local, s, w, 0.0, 0.3), Material::SOLID);
        s += 30.0;
    }
}

/// Draws and scans a LiDAR scene (`lidar` or `heldout-lidar`) with `sweeps` sweeps.
pub fn generate_lidar_scene(seed: u64, style: Style, sweeps: usize, overrides: &Overrides) -> Result<LidarScene> {
    let yard = check_lidar_request(style, sweeps, overrides)?;
    let mut rng = Rng::derived(seed, STREAM_RECIPE);
    let mut scanner = if yard { yard_scanner(&mut rng) } else { street_scanner(&mut rng) };
    if let Some(w) = overrides.width {
        scanner.azimuth_steps = w;
    }
    let mount_height = if yard { rng.uniform(1.8, 2.1) } else { rng.uniform(1.7, 2.0) };
    let n_waves = if yard { 1 } else { 2 + rng.below(2) };
    let ground = draw_ground(&mut rng, yard, n_waves);
    let drive = draw_drive(&mut rng, yard);
    // Sweep positions along the centre line.
    let mut pose_rng = Rng::derived(seed, STREAM_POSES);
    let mut along = vec![0.0];
    for _ in 1..sweeps {
        let last = *along.last().unwrap_or(&0.0);
        along.push(last + pose_rng.uniform(drive.step[0], drive.step[1]));
    }
    let travelled = *along.last().unwrap_or(&0.0);
    let reach = 0.8 * scanner.max_range;
    let path = Drive::new(&drive, -reach - 20.0, travelled + reach + 20.0);
    let (s_lo, s_hi) = path.s_range();
    let mut site = Site { drive: &path, ground: &ground, objects: Vec::new(), materials: Vec::new() };
    let mut scene_rng = Rng::derived(seed, STREAM_SCENE);
    if yard {
        build_yard(&mut scene_rng, &mut site, s_lo + 10.0, s_hi - 10.0);
    } else {
        build_street(&mut scene_rng, &mut site, s_lo + 10.0, s_hi - 10.0);
    }
    let Site { objects, materials, .. } = site;
    let mut families = BTreeMap::new();
    for o in &objects {
        *families.entry(o.kind.to_string()).or_insert(0) += 1;
    }
    let poses = sweep_poses(&path, &ground, (&along, drive.lane_offset, mount_height), &mut pose_rng);
    let world = World { ground: Some(ground.clone()), objects, materials };
    let fragments: Vec<PointCloud> = poses
        .par_iter()
        .enumerate()
        .map(|(k, (pose, _))| scanner.scan(&world, pose, &mut Rng::derived(seed, STREAM_SWEEPS + k as u64)))
        .collect();
    let sweeps_record = along
        .iter()
        .zip(&poses)
        .zip(&fragments)
        .map(|((&s, (pose, ypr)), cloud)| SweepRecord {
            s,
            position: [pose[(0, 3)], pose[(1, 3)], pose[(2, 3)]],
            yaw_pitch_roll_deg: *ypr,
            points: cloud.len(),
        })
        .collect();
    let recipe = LidarRecipe {
        style,
        seed,
        kind: if yard { "yard" } else { "street" }.to_string(),
        scanner,
        mount_height,
        ground,
        drive,
        families,
        pair_distance: [MIN_PAIR_DISTANCE, MAX_PAIR_DISTANCE],
        gt_scale: GT_SCALE,
        sweeps: sweeps_record,
    };
    let room = Room {
        polygon: Vec::new(),
        height: 0.0,
        kernel_center: [0.0, 0.0],
        objects: world.objects,
        footprints: Vec::new(),
    };
    Ok(LidarScene { fragments, world_from_fragment: poses.into_iter().map(|(p, _)| p).collect(), room, recipe })
}

/// Refuses requests the LiDAR styles cannot honour; true for `heldout-lidar` (the yard).
fn check_lidar_request(style: Style, sweeps: usize, overrides: &Overrides) -> Result<bool> {
    let yard = match style {
        Style::Lidar => false,
        Style::HeldoutLidar => true,
        _ => return Err(Error::invalid("synth: not a LiDAR style")),
    };
    if sweeps == 0 {
        return Err(Error::invalid("synth: fragments must be at least 1"));
    }
    if overrides.voxel.is_some()
        || overrides.frames_per_fragment.is_some()
        || overrides.object_scenes.is_some()
        || overrides.repeated
        || overrides.orbit
    {
        return Err(Error::invalid(
            "synth: the LiDAR styles take no voxel, frames, scene kind, repeated rooms or orbit (one sweep per \
             fragment, no fusion); --width sets the azimuth steps per revolution",
        ));
    }
    if overrides.width.is_some_and(|w| w < 4) {
        return Err(Error::invalid("synth: the scanner needs at least 4 azimuth steps"));
    }
    Ok(yard)
}

/// The ground under a LiDAR scene: a gentle slope and `n_waves` long waves (flatter in the yard).
fn draw_ground(rng: &mut Rng, yard: bool, n_waves: usize) -> Ground {
    let max_slope = if yard { 0.01 } else { 0.03 };
    Ground {
        base: 0.0,
        slope: [rng.uniform(-max_slope, max_slope), rng.uniform(-max_slope, max_slope)],
        waves: (0..n_waves)
            .map(|_| {
                let (len, dir) = (rng.uniform(25.0, 80.0), rng.uniform(0.0, TAU));
                let k = TAU / len;
                (
                    rng.uniform(0.03, if yard { 0.08 } else { 0.2 }),
                    [k * dir.cos(), k * dir.sin()],
                    rng.uniform(0.0, TAU),
                )
            })
            .collect(),
    }
}

/// The drive's centre line: curvature, its waves, heading, the lane the vehicle keeps and the sweep spacing.
fn draw_drive(rng: &mut Rng, yard: bool) -> DriveRecord {
    DriveRecord {
        curvature: if yard {
            [rng.uniform(-0.015, 0.015), rng.uniform(0.01, 0.04)]
        } else {
            [rng.uniform(-0.008, 0.008), rng.uniform(0.0, 0.02)]
        },
        wavelength: rng.uniform(40.0, 120.0),
        phase: rng.uniform(0.0, TAU),
        heading: rng.uniform(-PI, PI),
        lane_offset: if yard { rng.uniform(-0.5, 0.5) } else { -rng.uniform(1.4, 2.0) },
        step: if yard { [1.2, 3.0] } else { [1.0, 2.5] },
    }
}

/// The sensor pose of each sweep at arc lengths `along` (the vehicle on the ground at `lane_offset`, the
/// scanner `mount_height` above it, with small attitude jitter from `rng`), and its yaw, pitch and roll in degrees.
fn sweep_poses(
    path: &Drive,
    ground: &Ground,
    (along, lane_offset, mount_height): (&[f64], f64, f64),
    rng: &mut Rng,
) -> Vec<(Matrix4<f64>, [f64; 3])> {
    along
        .iter()
        .map(|&s| {
            let (x, y, heading) = path.point(s, lane_offset);
            let g = ground.gradient(x, y);
            let (c, sn) = (heading.cos(), heading.sin());
            let pitch = -(g[0] * c + g[1] * sn).atan() + rng.normal() * 0.2f64.to_radians();
            let roll = (-g[0] * sn + g[1] * c).atan() + rng.normal() * 0.2f64.to_radians();
            let yaw = heading + rng.normal() * 0.3f64.to_radians();
            let position = v(x, y, ground.height(x, y) + mount_height);
            (sensor_pose(position, yaw, pitch, roll), [yaw.to_degrees(), pitch.to_degrees(), roll.to_degrees()])
        })
        .collect()
}

/// The ground-truth rule for LiDAR sweeps: `rule` with its distances times [`GT_SCALE`].
pub fn lidar_rule(rule: &GroundTruthRule) -> GroundTruthRule {
    GroundTruthRule {
        grid: rule.grid * GT_SCALE,
        overlap_distance: rule.overlap_distance * GT_SCALE,
        info_distance: rule.info_distance * GT_SCALE,
        ..rule.clone()
    }
}

/// The gt.log pairs of a LiDAR scene from the pairs of [`crate::eval::groundtruth::ground_truth_pairs`] under
/// [`lidar_rule`]: those whose sensors are [`MIN_PAIR_DISTANCE`]-[`MAX_PAIR_DISTANCE`] m apart.
pub fn within_pair_distance(pairs: Vec<GtPair>, world_from_fragment: &[Matrix4<f64>]) -> Vec<GtPair> {
    let position = |k: usize| world_from_fragment[k].fixed_view::<3, 1>(0, 3).into_owned();
    pairs
        .into_iter()
        .filter(|p| (MIN_PAIR_DISTANCE..=MAX_PAIR_DISTANCE).contains(&(position(p.i) - position(p.j)).norm()))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::geometry::cast_ray;

    /// Fraction of the sweep's returns (mapped to the world by `pose`) that lie where the ray from the sensor
    /// first meets the scene's solids or ground (within 0.1 m), and the median offset: an oracle of the pose
    /// that uses only the scene and the ray caster.
    fn on_surfaces(scene: &LidarScene, cloud: &PointCloud, pose: &Matrix4<f64>) -> (f64, f64) {
        let origin: Vector3<f64> = pose.fixed_view::<3, 1>(0, 3).into_owned();
        let mut offsets: Vec<f64> = cloud
            .points
            .iter()
            .step_by(7)
            .map(|p| {
                let q = pose.fixed_view::<3, 3>(0, 0) * Vector3::from(p.map(f64::from)) + origin;
                let (dir, range) = ((q - origin).normalize(), (q - origin).norm());
                let ground = scene.recipe.ground.intersect(&origin, &dir, 1e4).unwrap_or(f64::INFINITY);
                let solid = cast_ray(&scene.room.objects, &origin, &dir, 1e4).map_or(f64::INFINITY, |h| h.t);
                (ground.min(solid) - range).abs()
            })
            .collect();
        offsets.sort_by(f64::total_cmp);
        let within = offsets.iter().filter(|&&d| d < 0.1).count() as f64 / offsets.len() as f64;
        (within, offsets[offsets.len() / 2])
    }

    #[test]
    fn sweeps_lie_on_the_scene_at_their_poses_and_off_it_at_the_next_pose() {
        let overrides = Overrides { width: Some(256), ..Overrides::default() };
        for (style, seed) in [(Style::Lidar, 3), (Style::HeldoutLidar, 4)] {
            let scene = generate_lidar_scene(seed, style, 3, &overrides).unwrap();
            for k in 0..3 {
                let cloud = &scene.fragments[k];
                assert!(cloud.len() > 3000, "{style:?} sweep {k}: {} points", cloud.len());
                let (within, median) = on_surfaces(&scene, cloud, &scene.world_from_fragment[k]);
                // Foliage returns come from inside crowns, divergence smears edges: most, not all, are exact.
                assert!(within > 0.9 && median < 0.03, "{style:?} sweep {k}: {within} within 0.1 m, median {median}");
                let wrong = &scene.world_from_fragment[(k + 1) % 3];
                let (within_wrong, _) = on_surfaces(&scene, cloud, wrong);
                assert!(within_wrong < 0.6, "{style:?} sweep {k} at the wrong pose: {within_wrong}");
            }
            // Consecutive sweeps are 1-3 m apart along the drive, the sensor 1.7-2.1 m above the ground.
            for (k, s) in scene.recipe.sweeps.iter().enumerate() {
                let p = s.position;
                let above = p[2] - scene.recipe.ground.height(p[0], p[1]);
                assert!((1.7..=2.1).contains(&above), "{above}");
                if k > 0 {
                    let q = scene.recipe.sweeps[k - 1].position;
                    let d = ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt();
                    assert!((0.9..=3.1).contains(&d), "{d}");
                }
            }
        }
    }

    #[test]
    fn lidar_styles_reject_camera_overrides() {
        for overrides in [
            Overrides { voxel: Some(0.01), ..Overrides::default() },
            Overrides { frames_per_fragment: Some(2), ..Overrides::default() },
            Overrides { orbit: true, ..Overrides::default() },
            Overrides { width: Some(2), ..Overrides::default() },
        ] {
            assert!(generate_lidar_scene(0, Style::Lidar, 2, &overrides).is_err(), "{overrides:?}");
        }
        assert!(generate_lidar_scene(0, Style::Randomized, 2, &Overrides::default()).is_err());
        assert!(generate_lidar_scene(0, Style::HeldoutLidar, 0, &Overrides::default()).is_err());
    }
}
