//! Occlusion cuts: the part of a training patch that a second sensor would see too.
//!
//! Two scans of one surface seen from directions far apart share only part of each keypoint's patch: the rest
//! is hidden from one of the sensors by the surface itself or by what stands in front of it, or lies outside
//! its image. A cut keeps the
//! points of a fragment's patch that a virtual second sensor also sees, so the feature-consistency loss asks the
//! codeword of that shared part to equal the codeword of the other fragment's whole patch.
//!
//! The second sensor looks at the keypoint from the fragment's own sensor direction turned by a drawn angle about
//! a random axis, at the same distance, and must see the keypoint's surface from its front. Visibility is a point
//! z-buffer: every point near the keypoint is projected through the second sensor onto square cells whose side
//! is `cell` (world units) at the keypoint's depth; a point is visible when it lies within the second sensor's
//! image (the keypoint drawn at a random place in it), faces the sensor and lies little enough behind its cell's
//! nearest point (`visible_from`).

use crate::pose::v3;
use crate::rng::Rng;
use nalgebra::{Rotation3, Unit, Vector3};
use std::collections::HashMap;

/// Smallest cosine between the second sensor's direction and the keypoint's normal (it must see the surface's
/// front, at most 75 degrees from head-on).
const MIN_FACING_COS: f64 = 0.26;

/// Axis draws before giving up on a second sensor that faces the keypoint's surface.
const SENSOR_DRAWS: usize = 16;

/// Largest depth spread of a surface over one cell, in cells (an incidence of 76 degrees).
const MAX_SPREAD_CELLS: f64 = 4.0;

/// A virtual second sensor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SecondSensor {
    /// Where it is.
    pub position: Vector3<f64>,
    /// Where the keypoint lies in its image, as tangents of the angles off the optical axis (within
    /// `HALF_FIELD_TAN`): patch points beyond the image's edges are not seen.
    pub keypoint_in_image: [f64; 2],
}

/// Tangents of a depth camera's half fields of view (58 x 45 degrees, a Kinect's).
pub const HALF_FIELD_TAN: [f64; 2] = [0.555, 0.414];

/// A second sensor: `sensor`'s direction seen from `keypoint` turned by an angle drawn uniformly from
/// `angle_deg` (degrees) about a random axis, at the same distance, facing the surface of unit `normal` from its
/// front, with the keypoint at a uniformly drawn place in its image. `None` when no draw faces the surface (or
/// the keypoint sits on the sensor).
pub fn second_sensor(
    keypoint: [f32; 3],
    normal: [f32; 3],
    sensor: Vector3<f64>,
    angle_deg: [f64; 2],
    rng: &mut Rng,
) -> Option<SecondSensor> {
    let k = v3(keypoint);
    let to_sensor = sensor - k;
    let distance = to_sensor.norm();
    if distance <= f64::EPSILON {
        return None;
    }
    let toward = to_sensor / distance;
    let n = v3(normal);
    for _ in 0..SENSOR_DRAWS {
        let angle = rng.uniform(angle_deg[0], angle_deg[1]).to_radians();
        let r = Vector3::new(rng.normal(), rng.normal(), rng.normal());
        let Some(axis) = Unit::try_new(r - toward * toward.dot(&r), 1e-9) else {
            continue;
        };
        let turned = Rotation3::from_axis_angle(&axis, angle) * toward;
        if turned.dot(&n) >= MIN_FACING_COS {
            let keypoint_in_image = HALF_FIELD_TAN.map(|t| rng.uniform(-t, t));
            return Some(SecondSensor { position: k + turned * distance, keypoint_in_image });
        }
    }
    None
}

/// The `candidates` (indices into `points`, whose unit normals are `normals`) that `sensor` sees past the
/// `occluders` (indices into `points`, the candidates among them), looking at point `keypoint` through cells of
/// side `cell` at the keypoint's depth. A point is seen when it lies within the sensor's image, its normal faces
/// the sensor (the fragment holds only the surfaces its own sensor saw, so a back face would be seen through a
/// missing front) and it lies behind its cell's nearest point by at most one cell plus its own surface's depth
/// spread over a cell (the tangent of its incidence angle, at most four), in cells at its depth. `None` when the
/// keypoint itself is not seen.
pub fn visible_from(
    points: &[[f32; 3]],
    normals: &[[f32; 3]],
    candidates: &[u32],
    occluders: &[u32],
    keypoint: usize,
    second: &SecondSensor,
    cell: f64,
) -> Option<Vec<u32>> {
    let sensor = second.position;
    let axis = v3(points[keypoint]) - sensor;
    let depth = axis.norm();
    if depth <= f64::EPSILON || cell <= 0.0 {
        return None;
    }
    let axis = axis / depth;
    let side = if axis.x.abs() < 0.9 { Vector3::x() } else { Vector3::y() };
    let u = axis.cross(&side).normalize();
    let w = axis.cross(&u);
    let pixel = cell / depth;
    let project = |j: usize| {
        let d = v3(points[j]) - sensor;
        let z = d.dot(&axis);
        let image = [d.dot(&u) / z, d.dot(&w) / z];
        (z > cell * 1e-3).then(|| (image, ((image[0] / pixel).floor() as i64, (image[1] / pixel).floor() as i64), d, z))
    };
    // The keypoint's ray is the projection's axis; the image's edges are where the drawn offset puts them.
    let in_image =
        |image: [f64; 2]| (0..2).all(|a| (image[a] + second.keypoint_in_image[a]).abs() <= HALF_FIELD_TAN[a]);
    let mut nearest: HashMap<(i64, i64), f64> = HashMap::with_capacity(occluders.len());
    for &j in occluders {
        if let Some((_, key, _, z)) = project(j as usize) {
            let slot = nearest.entry(key).or_insert(z);
            *slot = slot.min(z);
        }
    }
    let seen = |j: usize| {
        project(j).is_some_and(|(image, key, d, z)| {
            let facing = -v3(normals[j]).dot(&d) / d.norm();
            let spread = (1.0 - facing * facing).max(0.0).sqrt() / facing.max(1e-9);
            let tolerance = (1.0 + spread.min(MAX_SPREAD_CELLS)) * cell * z / depth;
            facing > 0.0 && in_image(image) && z <= nearest.get(&key).copied().unwrap_or(z) + tolerance
        })
    };
    if !seen(keypoint) {
        return None;
    }
    Some(candidates.iter().copied().filter(|&j| seen(j as usize)).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sensor at the origin with the keypoint at the centre of its image.
    const AT_ORIGIN: SecondSensor = SecondSensor { position: Vector3::new(0.0, 0.0, 0.0), keypoint_in_image: [0.0; 2] };

    /// A 4 x 4 m wall at z = 3 and a 0.5 x 0.5 m plate at z = 2 in front of it, 2 cm apart points.
    fn wall_and_plate() -> (Vec<[f32; 3]>, Vec<[f32; 3]>, usize) {
        let mut points = Vec::new();
        for i in -100..=100 {
            for j in -100..=100 {
                points.push([i as f32 * 0.02, j as f32 * 0.02, 3.0]);
            }
        }
        let plate_start = points.len();
        for i in -12..=12 {
            for j in -12..=12 {
                points.push([0.3 + i as f32 * 0.02, j as f32 * 0.02, 2.0]);
            }
        }
        let normals = vec![[0.0, 0.0, -1.0]; points.len()];
        (points, normals, plate_start)
    }

    /// The index of the point nearest to `q`.
    fn at(points: &[[f32; 3]], q: [f32; 3]) -> usize {
        let d = |p: &[f32; 3]| (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f32>();
        (0..points.len()).min_by(|&a, &b| d(&points[a]).total_cmp(&d(&points[b]))).unwrap()
    }

    /// Whether the segment from the sensor at the origin to `p` on the wall passes through the plate.
    fn behind_plate(p: [f32; 3]) -> bool {
        let s = 2.0 / p[2] as f64;
        let (x, y) = (p[0] as f64 * s, p[1] as f64 * s);
        (x - 0.3).abs() <= 0.24 && y.abs() <= 0.24
    }

    #[test]
    fn the_wall_behind_a_plate_is_hidden_and_the_rest_is_seen() {
        let (points, normals, plate_start) = wall_and_plate();
        let all: Vec<u32> = (0..points.len() as u32).collect();
        let keypoint = at(&points, [0.45, -0.5, 3.0]);
        let seen = visible_from(&points, &normals, &all, &all, keypoint, &AT_ORIGIN, 0.05).unwrap();
        let seen: std::collections::HashSet<u32> = seen.into_iter().collect();
        let (mut checked, mut wrong) = (0, 0);
        for (j, &p) in points.iter().enumerate() {
            let expected = j >= plate_start || !behind_plate(p);
            // Points within a cell of the shadow's edge may go either way.
            let margin = |q: [f32; 3]| {
                [0.0f32, 0.08, -0.08].iter().all(|&dx| {
                    [0.0f32, 0.08, -0.08]
                        .iter()
                        .all(|&dy| behind_plate([q[0] + dx, q[1] + dy, q[2]]) == behind_plate(q))
                })
            };
            // Away from the image's edges (the keypoint at its centre: 1.28 m either side in x, 1.72 m in y).
            let inside = (-0.6..=1.5).contains(&p[0]) && (-1.9..=1.0).contains(&p[1]);
            if j < plate_start && !(margin(p) && inside) {
                continue;
            }
            checked += 1;
            wrong += usize::from(seen.contains(&(j as u32)) != expected);
        }
        assert!(checked > 12_000, "{checked}");
        assert_eq!(wrong, 0, "{wrong} of {checked} points misjudged");
        // The shadow is there: a quarter-metre square of wall, about 1,300 points at 2 cm.
        let in_view = |p: [f32; 3]| (0.0..1.2).contains(&p[0]) && p[1].abs() < 1.0;
        let shadow = (0..plate_start).filter(|&j| in_view(points[j]) && !seen.contains(&(j as u32))).count();
        assert!((900..1_700).contains(&shadow), "{shadow}");
        // Beyond the image's edge nothing is seen.
        let beyond = (0..plate_start).filter(|&j| points[j][0] < -1.1);
        assert!(beyond.clone().count() > 4_000 && beyond.clone().all(|j| !seen.contains(&(j as u32))));
        // The keypoint elsewhere in the image moves the edges: placed near one edge or the other (across x), one
        // of the two views takes in the wall beyond the centred view's edge.
        let views = [0.4, -0.4].map(|w| {
            let shifted = SecondSensor { keypoint_in_image: [0.0, w], ..AT_ORIGIN };
            let seen = visible_from(&points, &normals, &all, &all, keypoint, &shifted, 0.05).unwrap();
            seen.into_iter().collect::<std::collections::HashSet<u32>>()
        });
        let far_left: Vec<u32> = (0..plate_start as u32)
            .filter(|&j| (-1.5..-1.1).contains(&points[j as usize][0]) && (points[j as usize][1] + 0.5).abs() < 0.6)
            .collect();
        assert!(far_left.len() > 1_000);
        assert!(far_left.iter().all(|j| views[0].contains(j) != views[1].contains(j)));
    }

    #[test]
    fn a_hidden_keypoint_gives_no_patch() {
        let (points, mut normals, _) = wall_and_plate();
        let all: Vec<u32> = (0..points.len() as u32).collect();
        let behind = at(&points, [0.44, 0.0, 3.0]);
        assert!(visible_from(&points, &normals, &all, &all, behind, &AT_ORIGIN, 0.05).is_none());
        // A back face is not seen: the wall turned away from the sensor.
        let open = at(&points, [-1.0, 0.0, 3.0]);
        assert!(visible_from(&points, &normals, &all, &all, open, &AT_ORIGIN, 0.05).is_some());
        normals.iter_mut().for_each(|n| *n = [0.0, 0.0, 1.0]);
        assert!(visible_from(&points, &normals, &all, &all, open, &AT_ORIGIN, 0.05).is_none());
    }

    #[test]
    fn the_second_sensor_is_turned_by_the_drawn_angle_and_faces_the_surface() {
        let mut rng = Rng::new(5);
        let keypoint = [0.5, -0.2, 2.0];
        let normal = [0.0, 0.0, -1.0];
        let k = v3(keypoint);
        let (mut some, mut none) = (0, 0);
        for _ in 0..200 {
            match second_sensor(keypoint, normal, Vector3::zeros(), [40.0, 70.0], &mut rng) {
                Some(SecondSensor { position: s, keypoint_in_image }) => {
                    some += 1;
                    assert!((0..2).all(|a| keypoint_in_image[a].abs() <= HALF_FIELD_TAN[a]));
                    let angle = (s - k).angle(&(-k)).to_degrees();
                    assert!((40.0 - 1e-6..=70.0 + 1e-6).contains(&angle), "{angle}");
                    assert!(((s - k).norm() - k.norm()).abs() < 1e-9);
                    assert!((s - k).normalize().dot(&v3(normal)) >= MIN_FACING_COS - 1e-12);
                }
                None => none += 1,
            }
        }
        assert!(some > 190, "{some} of 200 found ({none} not)");
        // Facing away from every direction near the sensor's: nothing to see.
        let away = second_sensor(keypoint, [0.0, 0.0, 1.0], Vector3::zeros(), [1.0, 5.0], &mut rng);
        assert!(away.is_none());
    }
}
