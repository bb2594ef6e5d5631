//! Scenes of the `heldout-tof` style: attic flats under a pitched roof (knee walls, two sloped ceilings meeting
//! at a ridge, skylight frames in the slopes, a chimney breast) furnished with families that no other style
//! builds (bathtubs, pedestal washbasins, toilets, wardrobes, armchairs, upright pianos). Never train or tune
//! on them: with the time-of-flight sensor they are the second generalisation check.
//!
//! World frame as in [`super::room`]: z up, floor z = 0. The floor plan is `[0, width] x [0, depth]`; the knee
//! walls stand at y = 0 and y = depth, the ridge runs along x at y = depth / 2.

use super::furniture::{Furniture, post, slab, v};
use super::geometry::{Object, Primitive, rot_x, rot_y, rot_z};
use super::room::{Footprint, Room};
use crate::rng::Rng;
use nalgebra::{Matrix3, Vector3};
use serde::Serialize;
use std::f64::consts::{FRAC_PI_2, PI};

/// What was drawn for an attic (written to style.json).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct AtticRecord {
    /// Extent along x, between the gable walls (metres).
    pub width: f64,
    /// Extent along y, between the knee walls (metres).
    pub depth: f64,
    /// Height of the knee walls (metres).
    pub knee_height: f64,
    /// Height of the ridge (metres).
    pub ridge_height: f64,
    /// Skylight frames in the slopes.
    pub skylights: usize,
    /// Pieces of furniture placed, by kind.
    pub pieces: Vec<&'static str>,
}

/// The roof's shape: the ceiling height over any floor point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Roof {
    /// Extent along y (metres).
    pub depth: f64,
    /// Height of the knee walls (metres).
    pub knee_height: f64,
    /// Height of the ridge (metres).
    pub ridge_height: f64,
}

impl Roof {
    /// The ceiling height above floor point `(_, y)`.
    pub fn height_at(&self, y: f64) -> f64 {
        let from_wall = y.min(self.depth - y).clamp(0.0, self.depth / 2.0);
        self.knee_height + (self.ridge_height - self.knee_height) * from_wall / (self.depth / 2.0)
    }

    /// The slope angle (radians).
    fn pitch(&self) -> f64 {
        (self.ridge_height - self.knee_height).atan2(self.depth / 2.0)
    }

    /// world_from_slope for the slope rising from the knee wall at y = 0 (`near`) or y = depth: the slope
    /// frame's x runs along the ridge, y up the slope, z out of the room.
    fn slope_rotation(&self, near: bool) -> Matrix3<f64> {
        if near { rot_x(self.pitch()) } else { rot_z(PI) * rot_x(self.pitch()) }
    }

    /// The point of the inner roof surface at `x`, a distance `s` up the slope from the knee wall.
    fn on_slope(&self, near: bool, x: f64, s: f64) -> Vector3<f64> {
        let (sin, cos) = self.pitch().sin_cos();
        let y = s * cos;
        v(x, if near { y } else { self.depth - y }, self.knee_height + s * sin)
    }

    /// A box on the inner roof surface: `half` in the slope frame, standing `half.z` proud of the surface.
    fn slope_box(&self, near: bool, x: f64, s: f64, half: Vector3<f64>) -> Primitive {
        let r = self.slope_rotation(near);
        let center = self.on_slope(near, x, s) - r.column(2) * half.z;
        Primitive { shape: super::geometry::Shape::Cuboid { half }, center, rotation: r }
    }
}

/// A bathtub: an outer shell of four walls and a floor, a rim, and a tap at the head end (+x).
fn bathtub(rng: &mut Rng) -> Furniture {
    let (w, d, h) = (rng.uniform(1.5, 1.8), rng.uniform(0.7, 0.8), rng.uniform(0.5, 0.6));
    let (hx, hy) = (w / 2.0, d / 2.0);
    let t = 0.06;
    let parts = vec![
        slab(-hx, hx, -hy, hy, 0.0, 0.15),
        slab(-hx, -hx + t, -hy, hy, 0.0, h),
        slab(hx - t, hx, -hy, hy, 0.0, h),
        slab(-hx + t, hx - t, -hy, -hy + t, 0.0, h),
        slab(-hx + t, hx - t, hy - t, hy, 0.0, h),
        post(hx - 0.15, hy - 0.12, h, 0.02, 0.18),
        Primitive::cylinder(v(hx - 0.2, hy - 0.12, h + 0.17), 0.015, 0.06, rot_y(FRAC_PI_2)),
    ];
    Furniture { kind: "bathtub", parts, half: [hx, hy], height: h + 0.2 }
}

/// A pedestal washbasin with a mirror cabinet above it (against the wall at +y).
fn washbasin(rng: &mut Rng) -> Furniture {
    let (w, d) = (rng.uniform(0.5, 0.7), rng.uniform(0.4, 0.5));
    let (hx, hy) = (w / 2.0, d / 2.0);
    let top = rng.uniform(0.8, 0.9);
    let mut parts = vec![
        post(0.0, hy - 0.18, 0.0, rng.uniform(0.07, 0.1), top - 0.15),
        slab(-hx, hx, -hy, hy, top - 0.17, top - 0.12),
        slab(-hx, hx, -hy, -hy + 0.04, top - 0.12, top),
        slab(-hx, hx, hy - 0.06, hy, top - 0.12, top + 0.05),
        slab(-hx, -hx + 0.04, -hy, hy, top - 0.12, top),
        slab(hx - 0.04, hx, -hy, hy, top - 0.12, top),
        post(0.0, hy - 0.08, top + 0.05, 0.015, 0.12),
    ];
    let mut height = top + 0.2;
    if rng.below(2) == 0 {
        let (z0, z1) = (top + 0.35, top + 0.35 + rng.uniform(0.5, 0.7));
        parts.push(slab(-hx, hx, hy - 0.14, hy, z0, z1));
        height = z1;
    }
    Furniture { kind: "washbasin", parts, half: [hx, hy], height }
}

/// A toilet: bowl (an upright cylinder on a narrower foot), seat, lid raised or closed, cistern at +y.
fn toilet(rng: &mut Rng) -> Furniture {
    let (hx, hy) = (0.2, rng.uniform(0.32, 0.36));
    let seat = rng.uniform(0.4, 0.44);
    let mut parts = vec![
        post(0.0, -0.02, 0.0, 0.13, seat - 0.15),
        Primitive::cylinder(v(0.0, -0.05, seat - 0.09), 0.19, 0.07, Matrix3::identity()),
        Primitive::cylinder(v(0.0, -0.05, seat - 0.01), 0.19, 0.01, Matrix3::identity()),
        slab(-hx, hx, hy - 0.18, hy, seat - 0.02, seat + rng.uniform(0.35, 0.45)),
    ];
    if rng.below(2) == 0 {
        parts.push(slab(-0.18, 0.18, hy - 0.2, hy - 0.18, seat, seat + 0.4));
    } else {
        parts.push(Primitive::cylinder(v(0.0, -0.05, seat + 0.01), 0.18, 0.01, Matrix3::identity()));
    }
    Furniture { kind: "toilet", parts, half: [hx, hy], height: seat + 0.45 }
}

/// A wardrobe: a tall body on a plinth with a cornice, two or three doors with long bar handles.
fn wardrobe(rng: &mut Rng) -> Furniture {
    let (w, d, h) = (rng.uniform(0.9, 1.8), rng.uniform(0.55, 0.65), rng.uniform(1.8, 2.1));
    let (hx, hy) = (w / 2.0, d / 2.0);
    let mut parts = vec![
        slab(-hx + 0.02, hx - 0.02, -hy + 0.05, hy, 0.0, 0.08),
        slab(-hx, hx, -hy + 0.02, hy, 0.08, h),
        slab(-hx - 0.03, hx + 0.03, -hy - 0.01, hy, h, h + 0.05),
    ];
    let doors = if w > 1.3 { 3 } else { 2 };
    let dw = w / doors as f64;
    for k in 0..doors {
        let x0 = -hx + k as f64 * dw;
        parts.push(slab(x0 + 0.004, x0 + dw - 0.004, -hy, -hy + 0.02, 0.1, h - 0.02));
        let hxk = if k % 2 == 0 { x0 + dw - 0.06 } else { x0 + 0.06 };
        parts.push(Primitive::upright_cylinder(v(hxk, -hy - 0.02, h * 0.55), 0.01, 0.15));
    }
    Furniture { kind: "wardrobe", parts, half: [hx + 0.03, hy], height: h + 0.05 }
}

/// An armchair: a deep seat cushion, a back, and rolled arms (lying cylinders) on a low base with feet.
fn armchair(rng: &mut Rng) -> Furniture {
    let (w, d) = (rng.uniform(0.75, 0.95), rng.uniform(0.8, 0.9));
    let (hx, hy) = (w / 2.0, d / 2.0);
    let seat = rng.uniform(0.4, 0.46);
    let arm_r = rng.uniform(0.09, 0.12);
    let arm_top = seat + rng.uniform(0.15, 0.22);
    let mut parts = vec![
        slab(-hx + 0.02, hx - 0.02, -hy + 0.02, hy - 0.02, 0.1, seat - 0.12),
        slab(-hx + 2.0 * arm_r, hx - 2.0 * arm_r, -hy + 0.04, hy - 0.2, seat - 0.12, seat),
        slab(-hx + 0.02, hx - 0.02, hy - 0.2, hy, seat - 0.12, seat + rng.uniform(0.45, 0.6)),
    ];
    for sx in [-1.0, 1.0] {
        let x = sx * (hx - arm_r);
        parts.push(slab(x - arm_r, x + arm_r, -hy + 0.02, hy - 0.02, seat - 0.12, arm_top - arm_r));
        parts.push(Primitive::cylinder(v(x, 0.0, arm_top - arm_r), arm_r, hy - 0.02, rot_x(FRAC_PI_2)));
        for sy in [-1.0, 1.0] {
            parts.push(post(sx * (hx - 0.06), sy * (hy - 0.06), 0.0, 0.025, 0.1));
        }
    }
    Furniture { kind: "armchair", parts, half: [hx, hy], height: seat + 0.6 }
}

/// An upright piano: the case, the keyboard shelf with a fall board, side cheeks, a pedal box, and its bench.
fn piano(rng: &mut Rng) -> Furniture {
    let (w, h) = (rng.uniform(1.4, 1.55), rng.uniform(1.1, 1.3));
    let (hx, hy) = (w / 2.0, 0.45);
    let keys = 0.72;
    let parts = vec![
        slab(-hx + 0.05, hx - 0.05, hy - 0.3, hy, 0.0, h),
        slab(-hx + 0.05, hx - 0.05, hy - 0.55, hy - 0.3, keys - 0.05, keys),
        slab(-hx + 0.05, hx - 0.05, hy - 0.42, hy - 0.3, keys, keys + 0.1),
        slab(-hx, -hx + 0.05, hy - 0.6, hy, 0.0, keys + 0.05),
        slab(hx - 0.05, hx, hy - 0.6, hy, 0.0, keys + 0.05),
        slab(-0.25, 0.25, hy - 0.38, hy - 0.3, 0.0, 0.12),
        slab(-0.35, 0.35, -hy, -hy + 0.35, 0.45, 0.5),
        slab(-0.33, -0.29, -hy + 0.02, -hy + 0.33, 0.0, 0.45),
        slab(0.29, 0.33, -hy + 0.02, -hy + 0.33, 0.0, 0.45),
    ];
    Furniture { kind: "piano", parts, half: [hx, hy], height: h }
}

/// True when the footprint `f` lies entirely under a roof at least `clearance` above its furniture.
fn under_roof(roof: &Roof, f: &Footprint, clearance: f64) -> bool {
    let (s, c) = f.yaw.sin_cos();
    [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)].iter().all(|&(sx, sy)| {
        let y = f.center[1] + sx * f.half[0] * s + sy * f.half[1] * c;
        roof.height_at(y) >= f.height + clearance
    })
}

/// Places `f` against a wall or free-standing, where it fits under the roof; returns whether it was placed.
fn place_under_roof(room: &mut Room, roof: &Roof, rng: &mut Rng, f: &Furniture, against_wall: bool) -> bool {
    for _ in 0..20 {
        let before = room.objects.len();
        let placed = if against_wall { room.place_against_wall(rng, f) } else { room.place_free(rng, f, 0.6) };
        let Some(k) = placed else { return false };
        if under_roof(roof, &room.footprints[k], 0.02) {
            return true;
        }
        room.objects.truncate(before);
        room.footprints.truncate(k);
    }
    false
}

/// An attic: floor, gable and knee walls, two roof slopes, a chimney breast, skylight frames, and held-out
/// furniture families where they fit under the slopes. Also returns the roof, for keeping cameras under it.
pub fn generate_attic(rng: &mut Rng) -> (Room, Roof, AtticRecord) {
    let (w, d) = (rng.uniform(5.0, 10.0), rng.uniform(4.5, 7.0));
    let knee = rng.uniform(0.8, 1.4);
    let ridge = rng.uniform(2.6, 3.4);
    let roof = Roof { depth: d, knee_height: knee, ridge_height: ridge };
    let polygon = vec![[0.0, 0.0], [w, 0.0], [w, d], [0.0, d]];
    let mut room =
        Room { polygon, height: ridge, kernel_center: [w / 2.0, d / 2.0], objects: Vec::new(), footprints: Vec::new() };
    let t = 0.2;
    room.objects.push(Object::new("floor", vec![slab(-t, w + t, -t, d + t, -t, 0.0)]));
    for p in [slab(-t, 0.0, -t, d + t, 0.0, ridge), slab(w, w + t, -t, d + t, 0.0, ridge)] {
        room.objects.push(Object::new("gable wall", vec![p]));
    }
    for p in [slab(-t, w + t, -t, 0.0, 0.0, knee), slab(-t, w + t, d, d + t, 0.0, knee)] {
        room.objects.push(Object::new("knee wall", vec![p]));
    }
    // Each slope: a slab whose inner face is the sloped ceiling, long enough to meet the other at the ridge.
    let slope_len = (d / 2.0).hypot(ridge - knee);
    for near in [true, false] {
        let half = v(w / 2.0 + t, slope_len / 2.0 + 0.3, t / 2.0);
        let p = roof.slope_box(near, w / 2.0, slope_len / 2.0, half);
        let r = p.rotation;
        let outward = Primitive { center: p.center + r.column(2) * t, ..p };
        room.objects.push(Object::new("roof", vec![outward]));
    }
    // Skylight frames: four bars standing proud of the slope, with a recessed glazing bar across.
    let skylights = rng.below(4);
    let mut placed_skylights = 0;
    for _ in 0..skylights {
        let near = rng.below(2) == 0;
        let (sw, sl) = (rng.uniform(0.55, 0.8), rng.uniform(0.8, 1.2));
        if slope_len < sl + 0.6 {
            continue;
        }
        let x = rng.uniform(sw, w - sw);
        let s = rng.uniform(0.3 + sl / 2.0, slope_len - 0.3 - sl / 2.0);
        let depth = rng.uniform(0.12, 0.2);
        let bar = 0.05;
        let bars = vec![
            roof.slope_box(near, x - sw / 2.0, s, v(bar, sl / 2.0 + bar, depth / 2.0)),
            roof.slope_box(near, x + sw / 2.0, s, v(bar, sl / 2.0 + bar, depth / 2.0)),
            roof.slope_box(near, x, s - sl / 2.0, v(sw / 2.0, bar, depth / 2.0)),
            roof.slope_box(near, x, s + sl / 2.0, v(sw / 2.0, bar, depth / 2.0)),
            roof.slope_box(near, x, s, v(sw / 2.0, 0.015, 0.015)),
        ];
        room.objects.push(Object::new("skylight", bars));
        placed_skylights += 1;
    }
    // A chimney breast against one gable wall, from the floor through the roof.
    let cw = rng.uniform(0.5, 0.9);
    let cd = rng.uniform(0.3, 0.45);
    let cy = rng.uniform(d / 2.0 - 1.0, d / 2.0 + 1.0);
    let (x0, x1) = if rng.below(2) == 0 { (0.0, cd) } else { (w - cd, w) };
    room.objects.push(Object::new("chimney", vec![slab(x0, x1, cy - cw / 2.0, cy + cw / 2.0, 0.0, ridge + t)]));
    room.footprints.push(Footprint {
        center: [(x0 + x1) / 2.0, cy],
        half: [cd / 2.0, cw / 2.0],
        yaw: 0.0,
        height: ridge,
    });
    let mut pieces = Vec::new();
    for _ in 0..(2.0 * (w + d) / 2.2) as usize {
        let f = match rng.below(6) {
            0 => bathtub(rng),
            1 => washbasin(rng),
            2 => toilet(rng),
            3 => wardrobe(rng),
            4 => piano(rng),
            _ => armchair(rng),
        };
        if place_under_roof(&mut room, &roof, rng, &f, true) {
            pieces.push(f.kind);
        }
    }
    for _ in 0..(w * d / 9.0) as usize {
        let f = if rng.below(3) == 0 { bathtub(rng) } else { armchair(rng) };
        if place_under_roof(&mut room, &roof, rng, &f, false) {
            pieces.push(f.kind);
        }
    }
    let record =
        AtticRecord { width: w, depth: d, knee_height: knee, ridge_height: ridge, skylights: placed_skylights, pieces };
    (room, roof, record)
}

/// The attic with keep-out footprints along both knee walls wherever the roof is lower than `camera_top` plus
/// `clearance`, for planning camera paths that stay under the slopes.
pub fn camera_room(room: &Room, roof: &Roof, camera_top: f64, clearance: f64) -> Room {
    let need = camera_top + clearance;
    let ramp = roof.ridge_height - roof.knee_height;
    let band =
        if need <= roof.knee_height { 0.0 } else { (need - roof.knee_height) / ramp.max(1e-9) * roof.depth / 2.0 };
    let mut planning = room.clone();
    if band > 0.0 {
        let (lo, hi) = room.bounds();
        let half = [(hi[0] - lo[0]) / 2.0, band.min(roof.depth / 2.0) / 2.0];
        for y in [lo[1] + half[1], hi[1] - half[1]] {
            planning.footprints.push(Footprint {
                center: [(lo[0] + hi[0]) / 2.0, y],
                half,
                yaw: 0.0,
                height: f64::INFINITY,
            });
        }
    }
    planning
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::geometry::cast_ray;

    #[test]
    fn the_roof_is_where_its_height_says() {
        for seed in 0..6 {
            let (room, roof, _) = generate_attic(&mut Rng::new(seed));
            let walls_and_roof: Vec<Object> = room
                .objects
                .iter()
                .filter(|o| matches!(o.kind, "roof" | "floor" | "gable wall" | "knee wall"))
                .cloned()
                .collect();
            // Straight up from floor points away from the gable walls: the first hit is the ceiling height.
            let (lo, hi) = room.bounds();
            for k in 1..10 {
                let y = lo[1] + (hi[1] - lo[1]) * k as f64 / 10.0;
                let o = Vector3::new((lo[0] + hi[0]) / 2.0, y, 0.05);
                let hit = cast_ray(&walls_and_roof, &o, &Vector3::z(), 10.0).expect("a roof above");
                assert!((o.z + hit.t - roof.height_at(y)).abs() < 1e-6, "seed {seed}, y {y}: {}", o.z + hit.t);
                assert!(hit.normal.z < 0.0);
            }
        }
    }

    #[test]
    fn attics_are_furnished_inside_their_walls_and_under_the_roof() {
        for seed in 0..8 {
            let (room, roof, record) = generate_attic(&mut Rng::new(seed));
            assert!(!record.pieces.is_empty(), "seed {seed}");
            assert!(record.knee_height < record.ridge_height);
            for f in &room.footprints {
                assert!(room.contains(f.center), "seed {seed}: {f:?}");
                assert!(f.height.is_infinite() || under_roof(&roof, f, 0.0) || f.height >= roof.ridge_height);
            }
            for o in room.objects.iter().filter(|o| !matches!(o.kind, "roof" | "chimney" | "skylight")) {
                assert!(o.aabb.min.z > -0.21 && o.aabb.max.z < room.height + 0.21, "{}: {:?}", o.kind, o.aabb);
            }
        }
    }

    #[test]
    fn camera_room_keeps_cameras_where_the_roof_is_high_enough() {
        let (room, roof, _) = generate_attic(&mut Rng::new(3));
        let planning = camera_room(&room, &roof, 1.2, 0.3);
        let (lo, hi) = room.bounds();
        for k in 1..40 {
            let y = lo[1] + (hi[1] - lo[1]) * k as f64 / 40.0;
            let p = [(lo[0] + hi[0]) / 2.0, y];
            if planning.camera_allowed(p, 1.2, 0.0) {
                assert!(roof.height_at(y) >= 1.5 - 1e-9, "y {y}: roof {}", roof.height_at(y));
            }
        }
    }
}
