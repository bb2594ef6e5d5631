//! Analytic scene primitives (oriented cuboids, cylinders, spheres) and ray casting against them.
//!
//! Every primitive is a closed solid. A ray reports only the point where it *enters* a solid, so a camera that
//! happens to sit inside one simply does not see it (no back faces), and the reported normal always points
//! out of the solid, towards the ray origin.

use nalgebra::{Matrix3, Vector3};

/// Rays closer than this to their origin are ignored (metres).
const T_EPS: f64 = 1e-6;

/// The solid's shape, in its local frame (centred on the local origin).
#[derive(Clone, Debug, PartialEq)]
pub enum Shape {
    /// An axis-aligned box in the local frame with these half extents (metres).
    Cuboid {
        /// Half extents along local x, y, z.
        half: Vector3<f64>,
    },
    /// A capped cylinder along local z.
    Cylinder {
        /// Radius (metres).
        radius: f64,
        /// Half of the length along local z (metres).
        half_height: f64,
    },
    /// A sphere.
    Sphere {
        /// Radius (metres).
        radius: f64,
    },
}

/// A shape placed in the world: `x_world = rotation * x_local + center`.
#[derive(Clone, Debug, PartialEq)]
pub struct Primitive {
    /// The shape in its local frame.
    pub shape: Shape,
    /// World position of the local origin.
    pub center: Vector3<f64>,
    /// world_from_local rotation.
    pub rotation: Matrix3<f64>,
}

/// A ray hit: distance along the (unit) ray direction and the outward unit normal of the surface (world frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Distance from the ray origin (metres, for a unit direction).
    pub t: f64,
    /// Outward surface normal at the hit (unit, world frame).
    pub normal: Vector3<f64>,
}

/// An axis-aligned bounding box (world frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Minimum corner.
    pub min: Vector3<f64>,
    /// Maximum corner.
    pub max: Vector3<f64>,
}

impl Aabb {
    /// The empty box (grows with [`Aabb::union`]).
    pub fn empty() -> Aabb {
        Aabb { min: Vector3::repeat(f64::INFINITY), max: Vector3::repeat(f64::NEG_INFINITY) }
    }

    /// The smallest box containing both.
    pub fn union(&self, other: &Aabb) -> Aabb {
        Aabb { min: self.min.inf(&other.min), max: self.max.sup(&other.max) }
    }

    /// True when the ray `origin + t dir`, `t` in `[0, t_max]`, touches the box (slab test).
    pub fn hit_by(&self, origin: &Vector3<f64>, inv_dir: &Vector3<f64>, t_max: f64) -> bool {
        let mut t0 = 0.0f64;
        let mut t1 = t_max;
        for a in 0..3 {
            let ta = (self.min[a] - origin[a]) * inv_dir[a];
            let tb = (self.max[a] - origin[a]) * inv_dir[a];
            let (lo, hi) = if ta <= tb { (ta, tb) } else { (tb, ta) };
            // NaN (0 * inf on a slab boundary) compares false and leaves the interval unchanged.
            if lo > t0 {
                t0 = lo;
            }
            if hi < t1 {
                t1 = hi;
            }
            if t0 > t1 {
                return false;
            }
        }
        true
    }
}

impl Primitive {
    /// A box with the given centre and half extents, rotated by `yaw` (radians) about the world z axis.
    pub fn cuboid(center: Vector3<f64>, half: Vector3<f64>, yaw: f64) -> Primitive {
        Primitive { shape: Shape::Cuboid { half }, center, rotation: rot_z(yaw) }
    }

    /// A cylinder with its axis along the world z axis.
    pub fn upright_cylinder(center: Vector3<f64>, radius: f64, half_height: f64) -> Primitive {
        Primitive { shape: Shape::Cylinder { radius, half_height }, center, rotation: Matrix3::identity() }
    }

    /// A cylinder whose axis is the local z axis mapped by `rotation`.
    pub fn cylinder(center: Vector3<f64>, radius: f64, half_height: f64, rotation: Matrix3<f64>) -> Primitive {
        Primitive { shape: Shape::Cylinder { radius, half_height }, center, rotation }
    }

    /// A sphere.
    pub fn sphere(center: Vector3<f64>, radius: f64) -> Primitive {
        Primitive { shape: Shape::Sphere { radius }, center, rotation: Matrix3::identity() }
    }

    /// The primitive moved by `rotation` then `translation` (world_from_local of a piece of furniture).
    pub fn placed(&self, rotation: &Matrix3<f64>, translation: &Vector3<f64>) -> Primitive {
        Primitive {
            shape: self.shape.clone(),
            center: rotation * self.center + translation,
            rotation: rotation * self.rotation,
        }
    }

    /// The primitive scaled by `s` about the world origin (centre and every size multiplied by `s > 0`).
    pub fn scaled(&self, s: f64) -> Primitive {
        let shape = match &self.shape {
            Shape::Cuboid { half } => Shape::Cuboid { half: half * s },
            Shape::Cylinder { radius, half_height } => {
                Shape::Cylinder { radius: radius * s, half_height: half_height * s }
            }
            Shape::Sphere { radius } => Shape::Sphere { radius: radius * s },
        };
        Primitive { shape, center: self.center * s, rotation: self.rotation }
    }

    /// World-frame bounding box.
    pub fn aabb(&self) -> Aabb {
        let half = match &self.shape {
            Shape::Cuboid { half } => self.rotation.abs() * half,
            Shape::Cylinder { radius, half_height } => {
                // Extent of a disc of radius r with axis a along world axis k: r sqrt(1 - a_k^2).
                let axis = self.rotation.column(2);
                Vector3::from_fn(|k, _| {
                    radius * (1.0 - axis[k] * axis[k]).max(0.0).sqrt() + half_height * axis[k].abs()
                })
            }
            Shape::Sphere { radius } => Vector3::repeat(*radius),
        };
        Aabb { min: self.center - half, max: self.center + half }
    }

    /// Where the ray `origin + t dir` (unit `dir`) enters the solid, if it does at `t < t_max`.
    pub fn intersect(&self, origin: &Vector3<f64>, dir: &Vector3<f64>, t_max: f64) -> Option<Hit> {
        let o = self.rotation.transpose() * (origin - self.center);
        let d = self.rotation.transpose() * dir;
        let (t, n_local) = match &self.shape {
            Shape::Cuboid { half } => intersect_cuboid(&o, &d, half)?,
            Shape::Cylinder { radius, half_height } => intersect_cylinder(&o, &d, *radius, *half_height)?,
            Shape::Sphere { radius } => {
                let t = entry_root(d.norm_squared(), 2.0 * o.dot(&d), o.norm_squared() - radius * radius)?;
                (t, (o + d * t) / *radius)
            }
        };
        (t > T_EPS && t < t_max).then(|| Hit { t, normal: (self.rotation * n_local).normalize() })
    }
}

/// Points on a `step` grid over the inside faces (walls, floor, ceiling) of an axis-aligned box centred on the
/// origin with half extents `half`: a closed room as seen from its centre, for tests and examples of checks that
/// reason about lines of sight.
pub fn box_room_grid(half: [f32; 3], step: f32) -> Vec<[f32; 3]> {
    let mut out = Vec::new();
    let n = |h: f32| (2.0 * h / step) as i32;
    for axis in 0..3 {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        for side in [-1.0f32, 1.0] {
            for i in 0..=n(half[u]) {
                for j in 0..=n(half[v]) {
                    let mut p = [0.0f32; 3];
                    p[axis] = side * half[axis];
                    p[u] = -half[u] + i as f32 * step;
                    p[v] = -half[v] + j as f32 * step;
                    out.push(p);
                }
            }
        }
    }
    out
}

/// Rotation by `yaw` radians about the z axis.
pub fn rot_z(yaw: f64) -> Matrix3<f64> {
    let (s, c) = yaw.sin_cos();
    Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
}

/// Rotation by `angle` radians about the x axis.
pub fn rot_x(angle: f64) -> Matrix3<f64> {
    let (s, c) = angle.sin_cos();
    Matrix3::new(1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c)
}

/// Rotation by `angle` radians about the y axis.
pub fn rot_y(angle: f64) -> Matrix3<f64> {
    let (s, c) = angle.sin_cos();
    Matrix3::new(c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c)
}

/// The smaller root of `a t^2 + b t + c` (the entry point of a ray into a quadric), if real.
fn entry_root(a: f64, b: f64, c: f64) -> Option<f64> {
    if a <= 0.0 {
        return None;
    }
    let disc = b * b - 4.0 * a * c;
    (disc >= 0.0).then(|| (-b - disc.sqrt()) / (2.0 * a))
}

/// Slab test; returns the entry distance and the local normal of the entry face.
fn intersect_cuboid(o: &Vector3<f64>, d: &Vector3<f64>, half: &Vector3<f64>) -> Option<(f64, Vector3<f64>)> {
    let mut t_near = f64::NEG_INFINITY;
    let mut t_far = f64::INFINITY;
    let mut axis = 0;
    for a in 0..3 {
        if d[a].abs() < 1e-15 {
            if o[a].abs() > half[a] {
                return None;
            }
            continue;
        }
        let t1 = (-half[a] - o[a]) / d[a];
        let t2 = (half[a] - o[a]) / d[a];
        let (lo, hi) = if t1 <= t2 { (t1, t2) } else { (t2, t1) };
        if lo > t_near {
            t_near = lo;
            axis = a;
        }
        t_far = t_far.min(hi);
    }
    if t_near > t_far || !t_near.is_finite() {
        return None;
    }
    let mut n = Vector3::zeros();
    n[axis] = -d[axis].signum();
    Some((t_near, n))
}

/// Entry into a capped cylinder along local z: the side (when the entry point is between the caps) or the cap
/// facing the ray (when the entry point is inside the disc).
fn intersect_cylinder(o: &Vector3<f64>, d: &Vector3<f64>, r: f64, hh: f64) -> Option<(f64, Vector3<f64>)> {
    let mut best: Option<(f64, Vector3<f64>)> = None;
    if let Some(t) = entry_root(d.x * d.x + d.y * d.y, 2.0 * (o.x * d.x + o.y * d.y), o.x * o.x + o.y * o.y - r * r) {
        let p = o + d * t;
        if p.z.abs() <= hh {
            best = Some((t, Vector3::new(p.x / r, p.y / r, 0.0)));
        }
    }
    if d.z.abs() > 1e-15 {
        let z = -hh * d.z.signum();
        let t = (z - o.z) / d.z;
        let p = o + d * t;
        if p.x * p.x + p.y * p.y <= r * r && best.is_none_or(|(tb, _)| t < tb) {
            best = Some((t, Vector3::new(0.0, 0.0, z.signum())));
        }
    }
    best
}

/// A rigid group of primitives (one piece of furniture, a wall...) with its bounding box.
#[derive(Clone, Debug)]
pub struct Object {
    /// What it is ("table", "wall"...), for summaries.
    pub kind: &'static str,
    /// Its solids (world frame).
    pub primitives: Vec<Primitive>,
    /// Union of the primitives' bounding boxes.
    pub aabb: Aabb,
}

impl Object {
    /// An object from its world-frame primitives.
    pub fn new(kind: &'static str, primitives: Vec<Primitive>) -> Object {
        let aabb = primitives.iter().fold(Aabb::empty(), |acc, p| acc.union(&p.aabb()));
        Object { kind, primitives, aabb }
    }
}

/// The nearest entry point of the ray `origin + t dir` (unit `dir`) into any object, closer than `t_max`.
pub fn cast_ray(objects: &[Object], origin: &Vector3<f64>, dir: &Vector3<f64>, t_max: f64) -> Option<Hit> {
    cast_ray_object(objects, origin, dir, t_max).map(|(hit, _)| hit)
}

/// As [`cast_ray`], also returning the index of the object that was hit.
pub fn cast_ray_object(
    objects: &[Object],
    origin: &Vector3<f64>,
    dir: &Vector3<f64>,
    t_max: f64,
) -> Option<(Hit, usize)> {
    let inv_dir = dir.map(|c| 1.0 / c);
    let mut best: Option<(Hit, usize)> = None;
    let mut limit = t_max;
    for (k, object) in objects.iter().enumerate() {
        if !object.aabb.hit_by(origin, &inv_dir, limit) {
            continue;
        }
        for p in &object.primitives {
            if let Some(hit) = p.intersect(origin, dir, limit) {
                limit = hit.t;
                best = Some((hit, k));
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f64, y: f64, z: f64) -> Vector3<f64> {
        Vector3::new(x, y, z)
    }

    #[test]
    fn cuboid_entry_point_and_normal() {
        let b = Primitive::cuboid(v(2.0, 0.0, 0.0), v(0.5, 0.5, 0.5), 0.0);
        let hit = b.intersect(&v(0.0, 0.0, 0.0), &v(1.0, 0.0, 0.0), 10.0).unwrap();
        assert!((hit.t - 1.5).abs() < 1e-12);
        assert!((hit.normal - v(-1.0, 0.0, 0.0)).norm() < 1e-12);
        // From inside: no hit (entry only).
        assert!(b.intersect(&v(2.0, 0.0, 0.0), &v(1.0, 0.0, 0.0), 10.0).is_none());
        // Rotated 45 degrees: the corner faces the ray at distance 2 - sqrt(0.5).
        let r = Primitive::cuboid(v(2.0, 0.0, 0.0), v(0.5, 0.5, 0.5), std::f64::consts::FRAC_PI_4);
        let hit = r.intersect(&v(0.0, 0.0, 0.0), &v(1.0, 0.0, 0.0), 10.0).unwrap();
        assert!((hit.t - (2.0 - 0.5f64.sqrt())).abs() < 1e-9);
    }

    #[test]
    fn cylinder_side_and_cap() {
        let c = Primitive::upright_cylinder(v(0.0, 0.0, 0.0), 0.5, 1.0);
        let side = c.intersect(&v(-3.0, 0.0, 0.2), &v(1.0, 0.0, 0.0), 10.0).unwrap();
        assert!((side.t - 2.5).abs() < 1e-12 && (side.normal - v(-1.0, 0.0, 0.0)).norm() < 1e-12);
        let cap = c.intersect(&v(0.1, 0.0, 5.0), &v(0.0, 0.0, -1.0), 10.0).unwrap();
        assert!((cap.t - 4.0).abs() < 1e-12 && (cap.normal - v(0.0, 0.0, 1.0)).norm() < 1e-12);
        // Passes above the top cap.
        assert!(c.intersect(&v(-3.0, 0.0, 1.2), &v(1.0, 0.0, 0.0), 10.0).is_none());
        // A lying cylinder (axis along x) seen from above.
        let lying = Primitive::cylinder(v(0.0, 0.0, 0.0), 0.5, 1.0, rot_y(std::f64::consts::FRAC_PI_2));
        let top = lying.intersect(&v(0.8, 0.0, 3.0), &v(0.0, 0.0, -1.0), 10.0).unwrap();
        assert!((top.t - 2.5).abs() < 1e-9 && (top.normal - v(0.0, 0.0, 1.0)).norm() < 1e-9);
        let bb = lying.aabb();
        assert!((bb.max - v(1.0, 0.5, 0.5)).norm() < 1e-9);
    }

    #[test]
    fn sphere_and_nearest_of_many() {
        let objects = vec![
            Object::new("far", vec![Primitive::sphere(v(5.0, 0.0, 0.0), 1.0)]),
            Object::new("near", vec![Primitive::sphere(v(3.0, 0.0, 0.0), 0.5)]),
        ];
        let hit = cast_ray(&objects, &v(0.0, 0.0, 0.0), &v(1.0, 0.0, 0.0), 100.0).unwrap();
        assert!((hit.t - 2.5).abs() < 1e-12);
        assert!(cast_ray(&objects, &v(0.0, 3.0, 0.0), &v(1.0, 0.0, 0.0), 100.0).is_none());
    }
}
