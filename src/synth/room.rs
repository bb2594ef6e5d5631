//! Procedural rooms: a rectangular or L-shaped shell (floor, walls, ceiling, baseboards, doors, windows,
//! radiators, pictures, a ceiling light, sometimes a pillar) furnished with random pieces from
//! [`super::furniture`], placed against the walls or free-standing with random yaw, without overlaps.
//!
//! World frame: z up, the floor is z = 0, the floor plan is a counter-clockwise rectilinear polygon.

use super::furniture::{self, Furniture};
use super::geometry::{Object, Primitive, rot_y, rot_z};
use crate::rng::Rng;
use nalgebra::Vector3;
use serde::Serialize;
use std::f64::consts::{FRAC_PI_2, PI};

/// A 2D oriented rectangle on the floor plan, with the height of what stands on it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Footprint {
    /// Centre (x, y).
    pub center: [f64; 2],
    /// Half extents along the rectangle's own axes.
    pub half: [f64; 2],
    /// Rotation of the rectangle about z (radians).
    pub yaw: f64,
    /// Height of the object standing on it (metres).
    pub height: f64,
}

impl Footprint {
    fn axes(&self) -> [[f64; 2]; 2] {
        let (s, c) = self.yaw.sin_cos();
        [[c, s], [-s, c]]
    }

    fn corners(&self) -> [[f64; 2]; 4] {
        let [a, b] = self.axes();
        let [hx, hy] = self.half;
        let [cx, cy] = self.center;
        let p = |sx: f64, sy: f64| [cx + sx * hx * a[0] + sy * hy * b[0], cy + sx * hx * a[1] + sy * hy * b[1]];
        [p(-1.0, -1.0), p(1.0, -1.0), p(1.0, 1.0), p(-1.0, 1.0)]
    }

    /// Distance from `p` to the rectangle (0 inside).
    pub fn distance_to(&self, p: [f64; 2]) -> f64 {
        let [a, b] = self.axes();
        let d = [p[0] - self.center[0], p[1] - self.center[1]];
        let u = (d[0] * a[0] + d[1] * a[1]).abs() - self.half[0];
        let w = (d[0] * b[0] + d[1] * b[1]).abs() - self.half[1];
        u.max(0.0).hypot(w.max(0.0))
    }

    /// True when the two rectangles, each grown by `clearance`, overlap (separating axis test).
    pub fn overlaps(&self, other: &Footprint, clearance: f64) -> bool {
        let (ca, cb) = (self.corners(), other.corners());
        for axis in self.axes().into_iter().chain(other.axes()) {
            let proj = |cs: &[[f64; 2]; 4]| {
                cs.iter()
                    .map(|c| c[0] * axis[0] + c[1] * axis[1])
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| (lo.min(x), hi.max(x)))
            };
            let ((a0, a1), (b0, b1)) = (proj(&ca), proj(&cb));
            if a1 + clearance < b0 || b1 + clearance < a0 {
                return false;
            }
        }
        true
    }
}

/// A furnished room.
#[derive(Clone, Debug)]
pub struct Room {
    /// Floor plan, counter-clockwise, axis-aligned edges.
    pub polygon: Vec<[f64; 2]>,
    /// Floor-to-ceiling height.
    pub height: f64,
    /// A point from which the whole floor plan is visible (the polygon is star-shaped around it).
    pub kernel_center: [f64; 2],
    /// Every solid in the room (shell first).
    pub objects: Vec<Object>,
    /// Floor-plan footprints of the furniture (for camera keep-out and placement).
    pub footprints: Vec<Footprint>,
}

impl Room {
    /// True when `p` is strictly inside the floor plan.
    pub fn contains(&self, p: [f64; 2]) -> bool {
        let mut inside = false;
        let n = self.polygon.len();
        for k in 0..n {
            let (a, b) = (self.polygon[k], self.polygon[(k + 1) % n]);
            if (a[1] > p[1]) != (b[1] > p[1]) {
                let x = a[0] + (p[1] - a[1]) / (b[1] - a[1]) * (b[0] - a[0]);
                if p[0] < x {
                    inside = !inside;
                }
            }
        }
        inside
    }

    /// Distance from `p` to the nearest wall line segment.
    pub fn distance_to_walls(&self, p: [f64; 2]) -> f64 {
        self.edges()
            .map(|(a, b)| {
                let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
                let t = (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / (dx * dx + dy * dy)).clamp(0.0, 1.0);
                (p[0] - a[0] - t * dx).hypot(p[1] - a[1] - t * dy)
            })
            .fold(f64::INFINITY, f64::min)
    }

    /// Distance from `p` along the unit direction `dir` to the first wall.
    pub fn distance_along(&self, p: [f64; 2], dir: [f64; 2]) -> f64 {
        let mut best = f64::INFINITY;
        for (a, b) in self.edges() {
            let e = [b[0] - a[0], b[1] - a[1]];
            let denom = dir[0] * e[1] - dir[1] * e[0];
            if denom.abs() < 1e-12 {
                continue;
            }
            let w = [a[0] - p[0], a[1] - p[1]];
            let t = (w[0] * e[1] - w[1] * e[0]) / denom;
            let s = (w[0] * dir[1] - w[1] * dir[0]) / denom;
            if t > 0.0 && (0.0..=1.0).contains(&s) {
                best = best.min(t);
            }
        }
        best
    }

    /// The wall segments (a, b) in polygon order; the room interior is on the left.
    pub fn edges(&self) -> impl Iterator<Item = ([f64; 2], [f64; 2])> + '_ {
        let n = self.polygon.len();
        (0..n).map(move |k| (self.polygon[k], self.polygon[(k + 1) % n]))
    }

    /// True when the camera may stand at `p` (height `z`): inside with `margin` from the walls and away from
    /// furniture it could hit.
    pub fn camera_allowed(&self, p: [f64; 2], z: f64, margin: f64) -> bool {
        self.contains(p)
            && self.distance_to_walls(p) >= margin
            && self.footprints.iter().all(|f| f.height < z - 0.25 || f.distance_to(p) > 0.3)
    }

    /// A footprint is valid when its corners are inside, no wall corner pokes into it, and it keeps
    /// `clearance` from the others.
    fn fits(&self, f: &Footprint, clearance: f64, ignore: Option<usize>) -> bool {
        f.corners().iter().all(|&c| self.contains(c) && self.distance_to_walls(c) > 0.005)
            && self.polygon.iter().all(|&v| f.distance_to(v) > 0.01)
            && self.footprints.iter().enumerate().all(|(k, o)| Some(k) == ignore || !f.overlaps(o, clearance))
    }

    /// Places `f` at (x, y) with `yaw` when it fits; returns its footprint index.
    pub(crate) fn place(
        &mut self,
        f: &Furniture,
        x: f64,
        y: f64,
        yaw: f64,
        clearance: f64,
        ignore: Option<usize>,
    ) -> Option<usize> {
        let fp = Footprint { center: [x, y], half: f.half, yaw, height: f.height };
        if !self.fits(&fp, clearance, ignore) {
            return None;
        }
        let r = rot_z(yaw);
        let t = Vector3::new(x, y, 0.0);
        self.objects.push(Object::new(f.kind, f.parts.iter().map(|p| p.placed(&r, &t)).collect()));
        self.footprints.push(fp);
        Some(self.footprints.len() - 1)
    }

    /// Places `f` with its back against a random wall (edges chosen by length); tries a few positions.
    pub(crate) fn place_against_wall(&mut self, rng: &mut Rng, f: &Furniture) -> Option<usize> {
        let edges: Vec<_> = self.edges().collect();
        let total: f64 = edges.iter().map(|(a, b)| (b[0] - a[0]).hypot(b[1] - a[1])).sum();
        for _ in 0..30 {
            let mut pick = rng.uniform(0.0, total);
            let &(a, b) = edges
                .iter()
                .find(|(a, b)| {
                    let len = (b[0] - a[0]).hypot(b[1] - a[1]);
                    pick -= len;
                    pick <= 0.0
                })
                .unwrap_or(&edges[0]);
            let len = (b[0] - a[0]).hypot(b[1] - a[1]);
            if len < 2.0 * f.half[0] + 0.1 {
                continue;
            }
            let e = [(b[0] - a[0]) / len, (b[1] - a[1]) / len];
            let n = [-e[1], e[0]];
            let t = rng.uniform(f.half[0] + 0.05, len - f.half[0] - 0.05);
            let off = f.half[1] + rng.uniform(0.01, 0.06);
            let (x, y) = (a[0] + e[0] * t + n[0] * off, a[1] + e[1] * t + n[1] * off);
            let yaw = n[0].atan2(-n[1]) + rng.uniform(-0.05, 0.05);
            if let Some(k) = self.place(f, x, y, yaw, 0.1, None) {
                return Some(k);
            }
        }
        None
    }

    /// Places `f` at a random free spot with random yaw.
    pub(crate) fn place_free(&mut self, rng: &mut Rng, f: &Furniture, wall_margin: f64) -> Option<usize> {
        let (lo, hi) = self.bounds();
        for _ in 0..40 {
            let p = [rng.uniform(lo[0], hi[0]), rng.uniform(lo[1], hi[1])];
            if !self.contains(p) || self.distance_to_walls(p) < wall_margin {
                continue;
            }
            if let Some(k) = self.place(f, p[0], p[1], rng.uniform(-PI, PI), 0.15, None) {
                return Some(k);
            }
        }
        None
    }

    /// The bounding rectangle of the floor plan (min, max).
    pub fn bounds(&self) -> ([f64; 2], [f64; 2]) {
        let lo = self.polygon.iter().fold([f64::INFINITY; 2], |m, p| [m[0].min(p[0]), m[1].min(p[1])]);
        let hi = self.polygon.iter().fold([f64::NEG_INFINITY; 2], |m, p| [m[0].max(p[0]), m[1].max(p[1])]);
        (lo, hi)
    }
}

/// The floor-plan family of a room.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RoomShape {
    /// A rectangle.
    Rectangle,
    /// A rectangle with one corner cut away.
    LShape,
    /// A long narrow rectangle (the width range is replaced by [`RoomSpec::corridor_width`]).
    Corridor,
}

/// The ranges a room is drawn from. The default is the `kinect` style's room.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RoomSpec {
    /// Range of the extent along x (metres).
    pub width: [f64; 2],
    /// Range of the extent along y (metres).
    pub depth: [f64; 2],
    /// Range of the floor-to-ceiling height (metres).
    pub height: [f64; 2],
    /// The floor plan; `None` draws a rectangle or an L-shape with equal odds.
    pub shape: Option<RoomShape>,
    /// Width range of a corridor (metres).
    pub corridor_width: [f64; 2],
    /// Multiplies the number of furniture pieces.
    pub density: f64,
    /// Also use the furniture families that the `kinect` style lacks ([`furniture::EXTRA_FAMILIES`]).
    pub extra_families: bool,
    /// First furnish rows of identical pieces ([`furnish_repeated`]): the repetition that makes local patches
    /// ambiguous.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub repeated: bool,
}

impl Default for RoomSpec {
    fn default() -> Self {
        RoomSpec {
            width: [3.5, 7.0],
            depth: [3.0, 6.0],
            height: [2.4, 3.0],
            shape: None,
            corridor_width: [1.6, 2.4],
            density: 1.0,
            extra_families: false,
            repeated: false,
        }
    }
}

/// A random furnished room (the `kinect` style's room: [`RoomSpec::default`]).
pub fn generate_room(rng: &mut Rng) -> Room {
    generate_room_with(rng, &RoomSpec::default())
}

/// A random furnished room drawn from `spec`.
pub fn generate_room_with(rng: &mut Rng, spec: &RoomSpec) -> Room {
    let (mut w, d) = (rng.uniform(spec.width[0], spec.width[1]), rng.uniform(spec.depth[0], spec.depth[1]));
    let height = rng.uniform(spec.height[0], spec.height[1]);
    let shape = match spec.shape {
        Some(shape) => shape,
        None if rng.below(2) == 0 => RoomShape::Rectangle,
        None => RoomShape::LShape,
    };
    let (polygon, kernel_center) = match shape {
        RoomShape::Rectangle | RoomShape::Corridor => {
            if shape == RoomShape::Corridor {
                w = rng.uniform(spec.corridor_width[0], spec.corridor_width[1]);
            }
            (vec![[0.0, 0.0], [w, 0.0], [w, d], [0.0, d]], [w / 2.0, d / 2.0])
        }
        RoomShape::LShape => {
            let (a, b) = (w * rng.uniform(0.3, 0.5), d * rng.uniform(0.3, 0.5));
            (
                vec![[0.0, 0.0], [w, 0.0], [w, d - b], [w - a, d - b], [w - a, d], [0.0, d]],
                [(w - a) / 2.0, (d - b) / 2.0],
            )
        }
    };
    let mut room = Room { polygon, height, kernel_center, objects: Vec::new(), footprints: Vec::new() };
    build_shell(&mut room, rng);
    if spec.repeated {
        furnish_repeated(&mut room, rng);
    }
    furnish(&mut room, rng, spec);
    room
}

/// Floor, ceiling, walls and the things fixed to them.
fn build_shell(room: &mut Room, rng: &mut Rng) {
    let mut shell = build_walls(room, rng);
    add_doors(room, &mut shell, rng);
    add_windows(room, &mut shell, rng);
    add_pictures(room, &mut shell, rng);
    add_pillar(room, &mut shell, rng);
    add_wall_shelves(room, &mut shell, rng);
    add_ceiling_light(room, rng);
}

/// Wall thickness (and the floor's and ceiling's), metres.
const WALL_THICKNESS: f64 = 0.15;

/// One wall edge from `a` to `b` (floor-plan corners, the room on the left).
#[derive(Clone, Copy)]
struct WallEdge {
    a: [f64; 2],
    b: [f64; 2],
}

impl WallEdge {
    fn len(&self) -> f64 {
        (self.b[0] - self.a[0]).hypot(self.b[1] - self.a[1])
    }

    fn yaw(&self) -> f64 {
        (self.b[1] - self.a[1]).atan2(self.b[0] - self.a[0])
    }

    /// Wall-local placement: position s along the edge, offset o into the room, height z.
    fn at(&self, s: f64, o: f64, z: f64) -> Vector3<f64> {
        let (a, b) = (self.a, self.b);
        let len = (b[0] - a[0]).hypot(b[1] - a[1]);
        let e = [(b[0] - a[0]) / len, (b[1] - a[1]) / len];
        Vector3::new(a[0] + e[0] * s - e[1] * o, a[1] + e[1] * s + e[0] * o, z)
    }

    /// Box on the wall: centred at s along the edge, `half_w` wide each way, from offset o0 to o1 into the
    /// room, between heights z0 and z1.
    fn boxed(&self, s: f64, half_w: f64, o0: f64, o1: f64, z0: f64, z1: f64) -> Primitive {
        Primitive::cuboid(
            self.at(s, (o0 + o1) / 2.0, (z0 + z1) / 2.0),
            Vector3::new(half_w, (o1 - o0) / 2.0, (z1 - z0) / 2.0),
            self.yaw(),
        )
    }
}

/// The walls of a room and, per wall, the stretches (along the edge) its fixtures already take.
struct Shell {
    edges: Vec<([f64; 2], [f64; 2])>,
    fixtures: Vec<Vec<(f64, f64)>>,
}

impl Shell {
    fn edge(&self, k: usize) -> WallEdge {
        let (a, b) = self.edges[k];
        WallEdge { a, b }
    }

    /// Whether the stretch s0..s1 of wall k is free.
    fn free(&self, k: usize, s0: f64, s1: f64) -> bool {
        self.fixtures[k].iter().all(|&(a, b)| s1 < a || s0 > b)
    }

    /// A random wall, if it is at least `min_len` long.
    fn pick_edge(&self, rng: &mut Rng, min_len: f64) -> Option<usize> {
        let k = rng.below(self.edges.len());
        (self.edge(k).len() >= min_len).then_some(k)
    }
}

/// Floor, ceiling and the walls with their skirting boards.
fn build_walls(room: &mut Room, rng: &mut Rng) -> Shell {
    let (lo, hi) = room.bounds();
    let h = room.height;
    let t = WALL_THICKNESS;
    let v = Vector3::new;
    let slab = |x0: f64, x1: f64, y0: f64, y1: f64, z0: f64, z1: f64| {
        Primitive::cuboid(
            v((x0 + x1) / 2.0, (y0 + y1) / 2.0, (z0 + z1) / 2.0),
            v((x1 - x0) / 2.0, (y1 - y0) / 2.0, (z1 - z0) / 2.0),
            0.0,
        )
    };
    room.objects.push(Object::new("floor", vec![slab(lo[0] - t, hi[0] + t, lo[1] - t, hi[1] + t, -t, 0.0)]));
    room.objects.push(Object::new("ceiling", vec![slab(lo[0] - t, hi[0] + t, lo[1] - t, hi[1] + t, h, h + t)]));
    let edges: Vec<_> = room.edges().collect();
    let base_h = rng.uniform(0.06, 0.12);
    let base_t = rng.uniform(0.01, 0.02);
    let mut fixtures: Vec<Vec<(f64, f64)>> = vec![Vec::new(); edges.len()];
    for (k, &(a, b)) in edges.iter().enumerate() {
        let e = WallEdge { a, b };
        let len = e.len();
        let mut parts = vec![e.boxed(len / 2.0, len / 2.0 + t, -t, 0.0, -t, h + t)];
        parts.push(e.boxed(len / 2.0, len / 2.0, 0.0, base_t, 0.0, base_h));
        room.objects.push(Object::new("wall", parts));
        fixtures[k].push((-1.0, 0.05));
        fixtures[k].push((len - 0.05, len + 1.0));
    }
    Shell { edges, fixtures }
}

/// Doors: panel, frame and handle; keep the floor in front free.
fn add_doors(room: &mut Room, shell: &mut Shell, rng: &mut Rng) {
    let h = room.height;
    for _ in 0..1 + rng.below(2) {
        let Some(k) = shell.pick_edge(rng, 1.4) else { continue };
        let e = shell.edge(k);
        let len = e.len();
        let (dw, dh) = (rng.uniform(0.8, 0.95), rng.uniform(2.0, 2.1).min(h - 0.15));
        let s = rng.uniform(dw / 2.0 + 0.15, len - dw / 2.0 - 0.15);
        if !shell.free(k, s - dw / 2.0 - 0.1, s + dw / 2.0 + 0.1) {
            continue;
        }
        shell.fixtures[k].push((s - dw / 2.0 - 0.1, s + dw / 2.0 + 0.1));
        let p = rng.uniform(0.01, 0.04);
        let fw = rng.uniform(0.05, 0.08);
        let parts = vec![
            e.boxed(s, dw / 2.0, 0.0, p, 0.0, dh),
            e.boxed(s - dw / 2.0 - fw / 2.0, fw / 2.0, 0.0, p + 0.015, 0.0, dh + fw),
            e.boxed(s + dw / 2.0 + fw / 2.0, fw / 2.0, 0.0, p + 0.015, 0.0, dh + fw),
            e.boxed(s, dw / 2.0 + fw, 0.0, p + 0.015, dh, dh + fw),
            Primitive::cylinder(
                e.at(s + dw / 2.0 - 0.08, p + 0.03, 1.0),
                0.01,
                0.06,
                rot_z(e.yaw()) * rot_y(FRAC_PI_2),
            ),
        ];
        room.objects.push(Object::new("door", parts));
        let c = e.at(s, 0.45, 0.0);
        let yaw = e.yaw();
        room.footprints.push(Footprint { center: [c.x, c.y], half: [dw / 2.0 + 0.1, 0.45], yaw, height: 0.0 });
    }
}

/// Windows (sill and frame), sometimes a radiator underneath.
fn add_windows(room: &mut Room, shell: &mut Shell, rng: &mut Rng) {
    let h = room.height;
    for _ in 0..rng.below(3) {
        let Some(k) = shell.pick_edge(rng, 1.5) else { continue };
        let e = shell.edge(k);
        let len = e.len();
        let ww = rng.uniform(0.8, 1.6).min(len - 0.4);
        let s = rng.uniform(ww / 2.0 + 0.15, len - ww / 2.0 - 0.15);
        if !shell.free(k, s - ww / 2.0 - 0.1, s + ww / 2.0 + 0.1) {
            continue;
        }
        shell.fixtures[k].push((s - ww / 2.0 - 0.1, s + ww / 2.0 + 0.1));
        let z0 = rng.uniform(0.8, 1.0);
        let z1 = (z0 + rng.uniform(1.0, 1.4)).min(h - 0.2);
        let f = 0.05;
        let mut parts = vec![
            e.boxed(s, ww / 2.0 + 0.05, 0.0, rng.uniform(0.1, 0.2), z0 - 0.03, z0),
            e.boxed(s - ww / 2.0, f / 2.0, 0.0, 0.03, z0, z1),
            e.boxed(s + ww / 2.0, f / 2.0, 0.0, 0.03, z0, z1),
            e.boxed(s, ww / 2.0, 0.0, 0.03, z1 - f, z1),
            e.boxed(s, f / 4.0, 0.0, 0.02, z0, z1),
        ];
        let yaw = e.yaw();
        if rng.below(2) == 0 {
            let rw = ww / 2.0 * rng.uniform(0.6, 0.9);
            let (r0, r1) = (0.15, (z0 - 0.15).max(0.4));
            let depth = rng.uniform(0.06, 0.1);
            parts.push(e.boxed(s, rw, 0.03, depth - 0.02, r0, r1));
            let fins = (rw * 2.0 / 0.06) as usize;
            for i in 0..fins {
                let fs = s - rw + (i as f64 + 0.5) * (2.0 * rw / fins as f64);
                parts.push(e.boxed(fs, 0.012, depth - 0.02, depth, r0, r1));
            }
            let c = e.at(s, depth / 2.0, 0.0);
            room.footprints.push(Footprint { center: [c.x, c.y], half: [rw, depth / 2.0 + 0.05], yaw, height: r1 });
        }
        room.objects.push(Object::new("window", parts));
    }
}

/// Pictures: thin boards on the walls.
fn add_pictures(room: &mut Room, shell: &mut Shell, rng: &mut Rng) {
    let h = room.height;
    for _ in 0..rng.below(4) {
        let Some(k) = shell.pick_edge(rng, 1.0) else { continue };
        let e = shell.edge(k);
        let len = e.len();
        let pw = rng.uniform(0.3, 1.0).min(len - 0.3);
        let s = rng.uniform(pw / 2.0 + 0.1, len - pw / 2.0 - 0.1);
        if !shell.free(k, s - pw / 2.0, s + pw / 2.0) {
            continue;
        }
        shell.fixtures[k].push((s - pw / 2.0, s + pw / 2.0));
        let ph = pw * rng.uniform(0.5, 1.2);
        let z = rng.uniform(1.3, 1.8).min(h - ph / 2.0 - 0.15);
        let depth = rng.uniform(0.01, 0.04);
        room.objects.push(Object::new("picture", vec![e.boxed(s, pw / 2.0, 0.0, depth, z - ph / 2.0, z + ph / 2.0)]));
    }
}

/// Sometimes a pillar in a wall.
fn add_pillar(room: &mut Room, shell: &mut Shell, rng: &mut Rng) {
    let h = room.height;
    if rng.below(4) == 0
        && let Some(k) = shell.pick_edge(rng, 2.5)
    {
        let e = shell.edge(k);
        let len = e.len();
        let (pw, pd) = (rng.uniform(0.25, 0.5), rng.uniform(0.15, 0.4));
        let s = rng.uniform(pw + 0.3, len - pw - 0.3);
        if shell.free(k, s - pw, s + pw) {
            shell.fixtures[k].push((s - pw, s + pw));
            room.objects.push(Object::new("pillar", vec![e.boxed(s, pw / 2.0, 0.0, pd, 0.0, h)]));
            let c = e.at(s, pd / 2.0, 0.0);
            let yaw = e.yaw();
            room.footprints.push(Footprint { center: [c.x, c.y], half: [pw / 2.0, pd / 2.0], yaw, height: h });
        }
    }
}

/// Wall shelves: a board on two brackets holding clutter, or a wall cabinet.
fn add_wall_shelves(room: &mut Room, shell: &mut Shell, rng: &mut Rng) {
    let h = room.height;
    for _ in 0..rng.below(4) {
        let Some(k) = shell.pick_edge(rng, 1.0) else { continue };
        let e = shell.edge(k);
        let len = e.len();
        let sw = rng.uniform(0.5, 1.2).min(len - 0.3);
        let s = rng.uniform(sw / 2.0 + 0.1, len - sw / 2.0 - 0.1);
        if !shell.free(k, s - sw / 2.0, s + sw / 2.0) {
            continue;
        }
        let depth = rng.uniform(0.18, 0.32);
        let z = rng.uniform(1.1, 1.7).min(h - 0.5);
        let yaw = e.yaw();
        let mut parts = Vec::new();
        let top = if rng.below(3) == 0 {
            // A closed wall cabinet.
            let ch = rng.uniform(0.35, 0.6);
            parts.push(e.boxed(s, sw / 2.0, 0.0, depth, z, z + ch));
            parts.push(e.boxed(s - sw / 4.0, sw / 4.0 - 0.005, depth, depth + 0.015, z + 0.01, z + ch - 0.01));
            parts.push(e.boxed(s + sw / 4.0, sw / 4.0 - 0.005, depth, depth + 0.015, z + 0.01, z + ch - 0.01));
            z + ch
        } else {
            let t = rng.uniform(0.018, 0.03);
            parts.push(e.boxed(s, sw / 2.0, 0.0, depth, z - t, z));
            for side in [-1.0, 1.0] {
                parts.push(e.boxed(s + side * sw * 0.35, 0.01, 0.0, depth * 0.8, z - t - 0.12, z - t));
            }
            // Clutter in the board's frame: local x along the wall, local y into the room.
            let rot = rot_z(yaw);
            let origin = e.at(s, depth / 2.0, 0.0);
            let count = 1 + rng.below(5);
            for p in furniture::clutter(rng, sw / 2.0, depth / 2.0, z, count, 0.3) {
                parts.push(p.placed(&rot, &origin));
            }
            z + 0.3
        };
        shell.fixtures[k].push((s - sw / 2.0, s + sw / 2.0));
        room.objects.push(Object::new("wall shelf", parts));
        let c = e.at(s, depth / 2.0, 0.0);
        room.footprints.push(Footprint { center: [c.x, c.y], half: [sw / 2.0, depth / 2.0], yaw, height: top });
    }
}

/// A ceiling light: a flat disc or a pendant sphere on a cord.
fn add_ceiling_light(room: &mut Room, rng: &mut Rng) {
    let h = room.height;
    let v = Vector3::new;
    let c = room.kernel_center;
    let light = if rng.below(2) == 0 {
        let r = rng.uniform(0.15, 0.3);
        vec![Primitive::upright_cylinder(v(c[0], c[1], h - 0.04), r, 0.04)]
    } else {
        let r = rng.uniform(0.1, 0.2);
        let drop = rng.uniform(0.15, 0.35);
        vec![
            Primitive::upright_cylinder(v(c[0], c[1], h - drop / 2.0), 0.005, drop / 2.0),
            Primitive::sphere(v(c[0], c[1], h - drop - r), r),
        ]
    };
    room.objects.push(Object::new("light", light));
}

/// Fewest copies of a piece that make a group of [`furnish_repeated`].
const MIN_COPIES: usize = 3;

/// One or two groups of identical pieces on a regular grid, aligned with the room's axes: classroom desks with
/// their chairs, library shelves in parallel rows, rows of chairs, canteen tables, or cabinets side by side.
/// Every copy of a group is the same drawn piece, so its patches differ only by what surrounds them. Copies
/// that do not fit (walls, other pieces) are left out, and a group with fewer than [`MIN_COPIES`] copies is
/// drawn again (a few tries).
fn furnish_repeated(room: &mut Room, rng: &mut Rng) {
    let wanted = 1 + rng.below(2);
    let mut groups = 0;
    for _ in 0..4 * wanted {
        if groups == wanted {
            break;
        }
        let before = (room.objects.len(), room.footprints.len());
        // The piece, the gap range between neighbours along its width (local x) and depth (local y), and a
        // companion placed in front of every copy (a desk's chair).
        let (piece, gap_x, gap_y, companion) = match rng.below(5) {
            0 => (furniture::desk(rng), [0.3, 0.9], [0.9, 1.4], Some(furniture::chair(rng))),
            1 => (furniture::shelf(rng), [0.02, 0.1], [0.9, 1.5], None),
            2 => (furniture::chair(rng), [0.1, 0.4], [0.4, 0.8], None),
            3 => (furniture::table(rng), [0.8, 1.5], [0.8, 1.5], None),
            _ => (furniture::cabinet(rng), [0.02, 0.08], [1.0, 1.6], None),
        };
        let pitch_x = 2.0 * piece.half[0] + rng.uniform(gap_x[0], gap_x[1]);
        let pitch_y = 2.0 * piece.half[1] + rng.uniform(gap_y[0], gap_y[1]);
        // Quarter-turn yaws only, so the grid stays aligned with the walls of the rectilinear plan: local x runs
        // along world x, or along world y when the piece is turned.
        let yaw = rng.below(4) as f64 * FRAC_PI_2;
        let r = rot_z(yaw);
        let along_x = r * Vector3::new(pitch_x, 0.0, 0.0);
        let along_y = r * Vector3::new(0.0, pitch_y, 0.0);
        let turned = yaw.sin().abs() > 0.5;
        let world_axis = |local: usize| local ^ usize::from(turned);
        // Half extents of one copy (with its companion) along local x and y.
        let half = [piece.half[0], piece.half[1] + companion.as_ref().map_or(0.0, |c| c.half[1] * 1.2)];
        // As many columns and rows as drawn, fewer where the room is too small (0.3 m from the walls), the
        // grid's centre drawn where the whole grid fits.
        let (lo, hi) = room.bounds();
        let room_extent = [hi[0] - lo[0] - 0.6, hi[1] - lo[1] - 0.6];
        let fit = |local: usize, pitch: f64, drawn: usize| {
            drawn.min(((room_extent[world_axis(local)] - 2.0 * half[local]) / pitch).floor().max(0.0) as usize + 1)
        };
        let columns = fit(0, pitch_x, 2 + rng.below(5));
        let rows = fit(1, pitch_y, 1 + rng.below(4));
        let span = along_x * (columns - 1) as f64 + along_y * (rows - 1) as f64;
        let half_world = [half[world_axis(0)], half[world_axis(1)]];
        let slack = [
            (room_extent[0] - span.x.abs() - 2.0 * half_world[0]).max(0.0) / 2.0,
            (room_extent[1] - span.y.abs() - 2.0 * half_world[1]).max(0.0) / 2.0,
        ];
        let centre = [
            (lo[0] + hi[0]) / 2.0 + rng.uniform(-slack[0], slack[0] + 1e-9),
            (lo[1] + hi[1]) / 2.0 + rng.uniform(-slack[1], slack[1] + 1e-9),
        ];
        let origin = [centre[0] - span.x / 2.0, centre[1] - span.y / 2.0];
        let mut copies = 0;
        for row in 0..rows {
            for column in 0..columns {
                let offset = along_x * column as f64 + along_y * row as f64;
                let (x, y) = (origin[0] + offset.x, origin[1] + offset.y);
                let Some(k) = room.place(&piece, x, y, yaw, 0.01, None) else { continue };
                copies += 1;
                if let Some(chair) = &companion {
                    // In front of the desk (its -y side), facing it.
                    let reach = piece.half[1] + chair.half[1] * 0.6;
                    let front = r * Vector3::new(0.0, -reach, 0.0);
                    room.place(chair, x + front.x, y + front.y, yaw + PI, 0.01, Some(k));
                }
            }
        }
        if copies >= MIN_COPIES {
            groups += 1;
        } else {
            room.objects.truncate(before.0);
            room.footprints.truncate(before.1);
        }
    }
}

/// Furniture against the walls, then table groups and small free-standing things.
fn furnish(room: &mut Room, rng: &mut Rng, spec: &RoomSpec) {
    let perimeter: f64 = room.edges().map(|(a, b)| (b[0] - a[0]).hypot(b[1] - a[1])).sum();
    let wall_items = (perimeter / 1.5 * spec.density) as usize + rng.below(3);
    let extra = if spec.extra_families { furniture::EXTRA_FAMILIES.len() } else { 0 };
    for _ in 0..wall_items {
        let pick = rng.below(10 + extra);
        if pick >= 10 {
            let f = furniture::EXTRA_FAMILIES[pick - 10](rng);
            room.place_against_wall(rng, &f);
            continue;
        }
        let f = match pick {
            0..=2 => furniture::shelf(rng),
            3..=4 => furniture::cabinet(rng),
            5 => furniture::sofa(rng),
            6 => furniture::desk(rng),
            7 => furniture::bed(rng),
            8 => furniture::plant(rng),
            _ => furniture::box_stack(rng),
        };
        room.place_against_wall(rng, &f);
    }
    // One or two table groups with chairs around.
    for _ in 0..1 + rng.below(2) {
        let table = if rng.below(3) == 0 { furniture::round_table(rng) } else { furniture::table(rng) };
        let Some(ti) = room.place_free(rng, &table, 0.5) else { continue };
        let fp = room.footprints[ti];
        let r = rot_z(fp.yaw);
        let n_chairs = rng.below(5);
        for k in 0..n_chairs {
            let chair = furniture::chair(rng);
            let angle = k as f64 * FRAC_PI_2 + rng.uniform(-0.15, 0.15);
            let dir = r * Vector3::new(angle.cos(), angle.sin(), 0.0);
            let reach = (fp.half[0] * angle.cos().abs() + fp.half[1] * angle.sin().abs()).max(0.2);
            let dist = reach + chair.half[1] * rng.uniform(0.3, 1.2) + rng.uniform(0.0, 0.2);
            let (x, y) = (fp.center[0] + dir.x * dist, fp.center[1] + dir.y * dist);
            let yaw = (-dir.x).atan2(dir.y) + rng.uniform(-0.35, 0.35);
            // A chair may tuck under its own table.
            room.place(&chair, x, y, yaw, 0.05, Some(ti));
        }
    }
    let (lo, hi) = room.bounds();
    let area = (hi[0] - lo[0]) * (hi[1] - lo[1]);
    for _ in 0..(area / 2.5 * spec.density) as usize + rng.below(4) {
        let pick = rng.below(7 + extra);
        let f = match pick {
            7.. => furniture::EXTRA_FAMILIES[pick - 7](rng),
            0 | 1 => furniture::box_stack(rng),
            2 => furniture::bin(rng),
            3 => furniture::ball(rng),
            4 => furniture::floor_lamp(rng),
            5 => furniture::plant(rng),
            _ => furniture::chair(rng),
        };
        if rng.below(2) == 0 {
            room.place_against_wall(rng, &f);
        } else {
            room.place_free(rng, &f, 0.3);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn polygon_queries_on_an_l_shape() {
        let room = Room {
            polygon: vec![[0.0, 0.0], [4.0, 0.0], [4.0, 2.0], [2.0, 2.0], [2.0, 4.0], [0.0, 4.0]],
            height: 2.5,
            kernel_center: [1.0, 1.0],
            objects: Vec::new(),
            footprints: Vec::new(),
        };
        assert!(room.contains([1.0, 3.0]) && room.contains([3.0, 1.0]) && !room.contains([3.0, 3.0]));
        assert!((room.distance_to_walls([1.0, 1.0]) - 1.0).abs() < 1e-12);
        assert!((room.distance_along([1.0, 1.0], [1.0, 0.0]) - 3.0).abs() < 1e-12);
        assert!((room.distance_along([1.0, 1.0], [0.0, 1.0]) - 3.0).abs() < 1e-12);
        let diag = std::f64::consts::FRAC_1_SQRT_2;
        assert!((room.distance_along([1.0, 1.0], [diag, diag]) - 2.0f64.sqrt()).abs() < 1e-9);
    }

    #[test]
    fn footprint_overlap_is_symmetric_and_respects_rotation() {
        let a = Footprint { center: [0.0, 0.0], half: [1.0, 0.2], yaw: 0.0, height: 1.0 };
        let b = Footprint { center: [0.0, 0.5], half: [1.0, 0.2], yaw: 0.0, height: 1.0 };
        let c = Footprint { center: [0.0, 0.5], half: [1.0, 0.2], yaw: FRAC_PI_2, height: 1.0 };
        assert!(!a.overlaps(&b, 0.0) && !b.overlaps(&a, 0.0));
        assert!(a.overlaps(&b, 0.2));
        assert!(a.overlaps(&c, 0.0) && c.overlaps(&a, 0.0));
        assert!((a.distance_to([2.0, 0.0]) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn generated_rooms_have_furniture_inside_the_walls() {
        for seed in 0..10 {
            let room = generate_room(&mut Rng::new(seed));
            assert!(room.objects.len() > 8, "seed {seed}: {} objects", room.objects.len());
            assert!(room.contains(room.kernel_center));
            for f in &room.footprints {
                assert!(room.contains(f.center), "seed {seed}: {f:?}");
            }
        }
    }

    /// The most copies of one drawn piece in `room`: objects of the same kind whose solids have the same shapes
    /// in the same order (placement aside).
    fn most_copies(room: &Room) -> usize {
        let mut most = 0;
        for (k, a) in room.objects.iter().enumerate() {
            let same = |b: &Object| {
                b.kind == a.kind
                    && b.primitives.len() == a.primitives.len()
                    && b.primitives.iter().zip(&a.primitives).all(|(p, q)| p.shape == q.shape)
            };
            most = most.max(room.objects[k..].iter().filter(|b| same(b)).count());
        }
        most
    }

    #[test]
    fn repeated_rooms_hold_rows_of_identical_pieces_and_others_do_not() {
        let repeated = RoomSpec { repeated: true, extra_families: true, ..RoomSpec::default() };
        for seed in 0..12 {
            let room = generate_room_with(&mut Rng::new(seed), &repeated);
            assert!(most_copies(&room) >= MIN_COPIES, "seed {seed}: at most {} copies", most_copies(&room));
            for f in &room.footprints {
                assert!(room.contains(f.center), "seed {seed}: {f:?}");
            }
            let plain = generate_room_with(&mut Rng::new(seed), &RoomSpec::default());
            assert!(most_copies(&plain) < MIN_COPIES, "seed {seed}: a plain room has {} copies", most_copies(&plain));
        }
    }
}
