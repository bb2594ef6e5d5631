//! Object-scale scenes: one object, or a small cluster of objects, built from primitives and scaled so its
//! largest extent is a few units (like a turntable scan of a 0.15-0.2 m object, scaled so that a 0.30-unit patch
//! covers the fraction of it a 0.025 m patch covers of the real one), and the viewpoints around it.
//!
//! The object is centred on the world origin; world z is up.

use super::furniture;
use super::geometry::{Aabb, Object, Primitive, rot_x, rot_y, rot_z};
use crate::rng::Rng;
use nalgebra::{Matrix3, Vector3};
use serde::Serialize;
use std::f64::consts::PI;

/// The kind of object scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ObjectFamily {
    /// An organic blob: overlapping spheres along a random walk, with limbs (like an animal figurine).
    Blob,
    /// A mechanical assembly: boxes and cylinders with arbitrary orientations attached to a core.
    Assembly,
    /// A piece of furniture in miniature (chair, table, plant, lamp, sofa, shelf).
    Miniature,
    /// Two to four smaller objects of the other families side by side.
    Cluster,
}

/// A random 3D rotation (uniform).
fn random_rotation(rng: &mut Rng) -> Matrix3<f64> {
    crate::pose::matrix_from_quaternion(crate::pose::random_rotation(rng, 180.0))
}

fn blob(rng: &mut Rng) -> Vec<Primitive> {
    let mut parts = Vec::new();
    let mut p = Vector3::zeros();
    let r0 = rng.uniform(0.25, 0.4);
    let mut dir = Vector3::new(1.0, 0.0, 0.0);
    for _ in 0..6 + rng.below(12) {
        let r = r0 * rng.uniform(0.5, 1.1);
        parts.push(Primitive::sphere(p, r));
        let turn = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.6;
        dir = (dir + turn).normalize();
        p += dir * r * rng.uniform(0.5, 0.9);
    }
    // Limbs: thin cylinders from random spheres, ending in small spheres.
    for _ in 0..rng.below(5) {
        let base = parts[rng.below(parts.len())].center;
        let axis = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
        let len = rng.uniform(0.3, 0.7);
        let radius = r0 * rng.uniform(0.15, 0.35);
        let rotation =
            nalgebra::Rotation3::rotation_between(&Vector3::z(), &axis).map_or(Matrix3::identity(), |r| r.into_inner());
        parts.push(Primitive::cylinder(base + axis * len / 2.0, radius, len / 2.0, rotation));
        parts.push(Primitive::sphere(base + axis * len, radius * rng.uniform(1.0, 1.8)));
    }
    parts
}

fn assembly(rng: &mut Rng) -> Vec<Primitive> {
    let core = Vector3::new(rng.uniform(0.3, 0.6), rng.uniform(0.3, 0.6), rng.uniform(0.2, 0.5));
    let mut parts =
        vec![Primitive { rotation: random_rotation(rng), ..Primitive::cuboid(Vector3::zeros(), core, 0.0) }];
    for _ in 0..3 + rng.below(8) {
        let at =
            Vector3::new(rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0)).component_mul(&core);
        let rotation = random_rotation(rng);
        parts.push(match rng.below(3) {
            0 => Primitive {
                rotation,
                ..Primitive::cuboid(
                    at,
                    Vector3::new(rng.uniform(0.05, 0.35), rng.uniform(0.05, 0.35), rng.uniform(0.05, 0.35)),
                    0.0,
                )
            },
            1 => Primitive::cylinder(at, rng.uniform(0.04, 0.25), rng.uniform(0.1, 0.5), rotation),
            _ => Primitive::sphere(at, rng.uniform(0.08, 0.3)),
        });
    }
    parts
}

fn miniature(rng: &mut Rng) -> Vec<Primitive> {
    let f = match rng.below(6) {
        0 => furniture::chair(rng),
        1 => furniture::round_table(rng),
        2 => furniture::plant(rng),
        3 => furniture::floor_lamp(rng),
        4 => furniture::sofa(rng),
        _ => furniture::cabinet(rng),
    };
    f.parts
}

/// Bounding box of a set of primitives.
fn bounds(parts: &[Primitive]) -> Aabb {
    parts.iter().fold(Aabb::empty(), |acc, p| acc.union(&p.aabb()))
}

/// `parts` rotated by `rotation`, scaled so that the largest bounding-box extent is `size`, and moved so the
/// box centre is at `center`.
fn normalised(parts: &[Primitive], rotation: &Matrix3<f64>, size: f64, center: Vector3<f64>) -> Vec<Primitive> {
    let rotated: Vec<Primitive> = parts.iter().map(|p| p.placed(rotation, &Vector3::zeros())).collect();
    let b = bounds(&rotated);
    let extent = (b.max - b.min).max();
    let s = size / extent.max(1e-9);
    let mid = (b.max + b.min) / 2.0;
    rotated
        .iter()
        .map(|p| p.placed(&Matrix3::identity(), &-mid).scaled(s).placed(&Matrix3::identity(), &center))
        .collect()
}

/// One object of `family` (not a cluster) in a random orientation about z (miniatures stay upright; the
/// others tumble freely).
fn single(rng: &mut Rng, family: ObjectFamily) -> Vec<Primitive> {
    match family {
        ObjectFamily::Blob => {
            let parts = blob(rng);
            let r = random_rotation(rng);
            normalised(&parts, &r, 1.0, Vector3::zeros())
        }
        ObjectFamily::Assembly => {
            let parts = assembly(rng);
            let r = random_rotation(rng);
            normalised(&parts, &r, 1.0, Vector3::zeros())
        }
        _ => {
            let parts = miniature(rng);
            let r = rot_z(rng.uniform(-PI, PI)) * rot_x(rng.uniform(-0.2, 0.2)) * rot_y(rng.uniform(-0.2, 0.2));
            normalised(&parts, &r, 1.0, Vector3::zeros())
        }
    }
}

/// An object scene of `family` whose largest extent is `size` units, centred on the origin.
pub fn generate_object(rng: &mut Rng, family: ObjectFamily, size: f64) -> Vec<Object> {
    let parts = match family {
        ObjectFamily::Cluster => {
            let mut all = Vec::new();
            let n = 2 + rng.below(3);
            for k in 0..n {
                let f = [ObjectFamily::Blob, ObjectFamily::Assembly, ObjectFamily::Miniature][rng.below(3)];
                let piece = single(rng, f);
                let angle = 2.0 * PI * k as f64 / n as f64 + rng.uniform(-0.4, 0.4);
                let d = rng.uniform(0.45, 0.7);
                let scale = rng.uniform(0.6, 1.0);
                let offset = Vector3::new(d * angle.cos(), d * angle.sin(), rng.uniform(-0.2, 0.2));
                all.extend(piece.iter().map(|p| p.scaled(scale).placed(&Matrix3::identity(), &offset)));
            }
            all
        }
        f => single(rng, f),
    };
    let parts = normalised(&parts, &Matrix3::identity(), size, Vector3::zeros());
    parts.into_iter().map(|p| Object::new("object part", vec![p])).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn objects_have_the_requested_size_and_are_centred() {
        for seed in 0..12 {
            for family in [ObjectFamily::Blob, ObjectFamily::Assembly, ObjectFamily::Miniature, ObjectFamily::Cluster] {
                let objects = generate_object(&mut Rng::new(seed), family, 2.0);
                let b = objects.iter().fold(Aabb::empty(), |acc, o| acc.union(&o.aabb));
                assert!(((b.max - b.min).max() - 2.0).abs() < 1e-9, "{family:?} {b:?}");
                assert!(((b.max + b.min) / 2.0).norm() < 1e-9, "{family:?} {b:?}");
            }
        }
    }
}
