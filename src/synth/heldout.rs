//! Scenes of the `heldout` style: open-plan workshops, kitchens and offices with families that no other style
//! builds (column grids, ceiling beams and pipes, kitchen counter runs with upper cabinets, cubicle partitions,
//! staircases, pallets with crates, workbenches with vices). Never train or tune on them: they are the
//! generalisation check.
//!
//! World frame as in [`super::room`]: z up, floor z = 0, rectangular floor plan.

use super::furniture::{Furniture, slab, v};
use super::geometry::{Object, Primitive, rot_y};
use super::room::{Footprint, Room};
use crate::rng::Rng;
use serde::Serialize;
use std::f64::consts::{FRAC_PI_2, PI};

/// What was drawn for a held-out hall (written to style.json).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct HallRecord {
    /// Extent along x (metres).
    pub width: f64,
    /// Extent along y (metres).
    pub depth: f64,
    /// Floor-to-ceiling height (metres).
    pub height: f64,
    /// Columns in the grid.
    pub columns: usize,
    /// Pieces of furniture placed, by kind.
    pub pieces: Vec<&'static str>,
}

/// A kitchen counter run: base cabinets with plinth and doors, a worktop with a sink block and a tap, and
/// upper cabinets; the back is at +y.
fn counter(rng: &mut Rng) -> Furniture {
    let w = rng.uniform(1.5, 3.2);
    let hx = w / 2.0;
    let hy = 0.31;
    let top = rng.uniform(0.86, 0.93);
    let mut parts = vec![slab(-hx, hx, -hy + 0.05, hy, 0.1, top - 0.04), slab(-hx, hx, -hy, hy, top - 0.04, top)];
    parts.push(slab(-hx, hx, -hy + 0.1, hy, 0.0, 0.1));
    let doors = (w / 0.6).round().max(1.0) as usize;
    let dw = w / doors as f64;
    for k in 0..doors {
        let x0 = -hx + k as f64 * dw;
        parts.push(slab(x0 + 0.004, x0 + dw - 0.004, -hy + 0.03, -hy + 0.05, 0.12, top - 0.06));
        parts.push(slab(x0 + dw / 2.0 - 0.06, x0 + dw / 2.0 + 0.06, -hy + 0.01, -hy + 0.03, top - 0.12, top - 0.1));
    }
    let sx = rng.uniform(-hx + 0.4, hx - 0.4);
    parts.push(slab(sx - 0.25, sx + 0.25, -0.15, 0.15, top, top + 0.015));
    parts.push(Primitive::upright_cylinder(v(sx, 0.2, top + 0.15), 0.015, 0.15));
    parts.push(Primitive::cylinder(
        v(sx, 0.12, top + 0.3),
        0.012,
        0.08,
        rot_y(FRAC_PI_2) * super::geometry::rot_x(0.0),
    ));
    let upper = rng.below(3) > 0;
    let mut height = top + 0.3;
    if upper {
        let (z0, z1) = (top + rng.uniform(0.5, 0.65), top + rng.uniform(1.2, 1.4));
        parts.push(slab(-hx, hx, hy - 0.35, hy, z0, z1));
        height = z1;
    }
    Furniture { kind: "kitchen counter", parts, half: [hx, hy], height }
}

/// A cubicle: three thin partition panels in a U around a plain desk slab on panel legs, with a monitor box.
fn cubicle(rng: &mut Rng) -> Furniture {
    let (w, d) = (rng.uniform(1.4, 1.8), rng.uniform(1.3, 1.7));
    let (hx, hy) = (w / 2.0, d / 2.0);
    let ph = rng.uniform(1.1, 1.6);
    let t = 0.03;
    let mut parts = vec![
        slab(-hx, hx, hy - t, hy, 0.0, ph),
        slab(-hx, -hx + t, -hy, hy, 0.0, ph),
        slab(hx - t, hx, -hy, hy, 0.0, ph),
    ];
    let top = rng.uniform(0.72, 0.76);
    parts.push(slab(-hx + t, hx - t, hy - 0.7, hy - t, top - 0.03, top));
    parts.push(slab(-0.3, 0.3, hy - 0.25, hy - 0.2, top + 0.1, top + 0.45));
    parts.push(slab(-0.05, 0.05, hy - 0.22, hy - 0.12, top, top + 0.1));
    Furniture { kind: "cubicle", parts, half: [hx, hy], height: ph }
}

/// A straight staircase against a wall (rising along +x), with a handrail on posts.
fn stairs(rng: &mut Rng, room_height: f64) -> Furniture {
    let steps = 6 + rng.below(6);
    let rise = (room_height * 0.7 / steps as f64).min(0.19);
    let run = rng.uniform(0.25, 0.3);
    let hw = rng.uniform(0.45, 0.6);
    let len = steps as f64 * run;
    let hx = len / 2.0;
    let mut parts = Vec::new();
    for k in 0..steps {
        let x0 = -hx + k as f64 * run;
        parts.push(slab(x0, x0 + run, -hw, hw, 0.0, (k + 1) as f64 * rise));
    }
    for k in (0..steps).step_by(3) {
        let x = -hx + (k as f64 + 0.5) * run;
        parts.push(Primitive::upright_cylinder(v(x, -hw + 0.04, (k + 1) as f64 * rise + 0.45), 0.015, 0.45));
    }
    let slope = (rise / run).atan();
    let rail_len = (len * len + (steps as f64 * rise).powi(2)).sqrt();
    parts.push(Primitive::cylinder(
        v(0.0, -hw + 0.04, steps as f64 * rise / 2.0 + 0.9),
        0.025,
        rail_len / 2.0,
        rot_y(FRAC_PI_2 - slope),
    ));
    Furniture { kind: "stairs", parts, half: [hx, hw], height: steps as f64 * rise + 1.0 }
}

/// A pallet (slats on blocks) with crates stacked on it.
fn pallet(rng: &mut Rng) -> Furniture {
    let (hx, hy) = (0.6, 0.4);
    let mut parts = Vec::new();
    for x in [-0.55, 0.0, 0.55] {
        parts.push(slab(x - 0.05, x + 0.05, -hy, hy, 0.0, 0.1));
    }
    for k in 0..7 {
        let y = -hy + 0.05 + k as f64 * (2.0 * hy - 0.1) / 6.0;
        parts.push(slab(-hx, hx, y - 0.05, y + 0.05, 0.1, 0.125));
    }
    let mut z = 0.125;
    for _ in 0..1 + rng.below(3) {
        let h = rng.uniform(0.25, 0.5);
        let cols = 1 + rng.below(2);
        let cw = 2.0 * hx / cols as f64;
        for c in 0..cols {
            let x0 = -hx + c as f64 * cw;
            parts.push(slab(x0 + 0.01, x0 + cw - 0.01, -hy + 0.01, hy - 0.01, z, z + h));
        }
        z += h;
    }
    Furniture { kind: "pallet", parts, half: [hx, hy], height: z }
}

/// A workbench: thick top on square-tube legs with a lower shelf, a vice and a toolbox.
fn workbench(rng: &mut Rng) -> Furniture {
    let (w, d) = (rng.uniform(1.2, 2.2), rng.uniform(0.6, 0.8));
    let (hx, hy) = (w / 2.0, d / 2.0);
    let top = rng.uniform(0.85, 0.95);
    let mut parts =
        vec![slab(-hx, hx, -hy, hy, top - 0.06, top), slab(-hx + 0.05, hx - 0.05, -hy + 0.05, hy - 0.05, 0.15, 0.18)];
    for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
        let (x, y) = (sx * (hx - 0.05), sy * (hy - 0.05));
        parts.push(slab(x - 0.025, x + 0.025, y - 0.025, y + 0.025, 0.0, top - 0.06));
    }
    let vx = hx - 0.2;
    parts.push(slab(vx - 0.08, vx + 0.08, -hy - 0.02, -hy + 0.12, top, top + 0.1));
    parts.push(Primitive::cylinder(v(vx, -hy - 0.06, top + 0.05), 0.012, 0.08, super::geometry::rot_x(FRAC_PI_2)));
    let tx = rng.uniform(-hx + 0.3, 0.0);
    parts.push(slab(tx - 0.25, tx + 0.25, -0.1, 0.12, top, top + 0.2));
    Furniture { kind: "workbench", parts, half: [hx, hy], height: top + 0.2 }
}

/// A held-out hall: rectangle with a column grid, ceiling beams and pipes, and held-out furniture families.
pub fn generate_hall(rng: &mut Rng) -> (Room, HallRecord) {
    let (w, d) = (rng.uniform(6.0, 11.0), rng.uniform(5.0, 9.0));
    let height = rng.uniform(2.8, 4.0);
    let polygon = vec![[0.0, 0.0], [w, 0.0], [w, d], [0.0, d]];
    let mut room =
        Room { polygon, height, kernel_center: [w / 2.0, d / 2.0], objects: Vec::new(), footprints: Vec::new() };
    let t = 0.2;
    room.objects.push(Object::new("floor", vec![slab(-t, w + t, -t, d + t, -t, 0.0)]));
    room.objects.push(Object::new("ceiling", vec![slab(-t, w + t, -t, d + t, height, height + t)]));
    for p in [
        slab(-t, 0.0, -t, d + t, 0.0, height),
        slab(w, w + t, -t, d + t, 0.0, height),
        slab(-t, w + t, -t, 0.0, 0.0, height),
        slab(-t, w + t, d, d + t, 0.0, height),
    ] {
        room.objects.push(Object::new("wall", vec![p]));
    }
    // Beams across the ceiling along y, every 1.5-2.5 m, and a pipe run along one long wall.
    let spacing = rng.uniform(1.5, 2.5);
    let bh = rng.uniform(0.2, 0.4);
    let mut x = spacing;
    while x < w - 0.5 {
        room.objects.push(Object::new("beam", vec![slab(x - 0.1, x + 0.1, 0.0, d, height - bh, height)]));
        x += spacing;
    }
    let pipes = 1 + rng.below(3);
    for k in 0..pipes {
        let r = rng.uniform(0.03, 0.1);
        let y = 0.2 + k as f64 * 0.25;
        let z = height - bh - 0.2 - k as f64 * 0.05;
        room.objects
            .push(Object::new("pipe", vec![Primitive::cylinder(v(w / 2.0, y, z), r, w / 2.0, rot_y(FRAC_PI_2))]));
    }
    // A grid of columns (square or round), kept away from the centre where the scanner stands.
    let round = rng.below(2) == 0;
    let (nx, ny) = (1 + rng.below(3), 1 + rng.below(2));
    let cs = rng.uniform(0.15, 0.25);
    let mut columns = 0;
    for i in 0..nx {
        for j in 0..ny {
            let c = [w * (i as f64 + 1.0) / (nx as f64 + 1.0), d * (j as f64 + 1.0) / (ny as f64 + 1.0)];
            if (c[0] - w / 2.0).hypot(c[1] - d / 2.0) < 1.0 {
                continue;
            }
            let p = if round {
                Primitive::upright_cylinder(v(c[0], c[1], height / 2.0), cs, height / 2.0)
            } else {
                slab(c[0] - cs, c[0] + cs, c[1] - cs, c[1] + cs, 0.0, height)
            };
            room.objects.push(Object::new("column", vec![p]));
            room.footprints.push(Footprint { center: c, half: [cs, cs], yaw: 0.0, height });
            columns += 1;
        }
    }
    let mut pieces = Vec::new();
    let perimeter = 2.0 * (w + d);
    for _ in 0..(perimeter / 2.5) as usize {
        let f = match rng.below(4) {
            0 | 1 => counter(rng),
            2 => workbench(rng),
            _ => stairs(rng, height),
        };
        if room.place_against_wall(rng, &f).is_some() {
            pieces.push(f.kind);
        }
    }
    for _ in 0..(w * d / 8.0) as usize {
        let f = match rng.below(3) {
            0 => cubicle(rng),
            1 => pallet(rng),
            _ => workbench(rng),
        };
        let placed = if rng.below(2) == 0 {
            room.place_free(rng, &f, 0.8)
        } else {
            let (x, y) = (rng.uniform(1.0, w - 1.0), rng.uniform(1.0, d - 1.0));
            let yaw = (rng.below(4) as f64) * FRAC_PI_2
                + rng.uniform(-0.1, 0.1)
                + if rng.below(5) == 0 { PI / 4.0 } else { 0.0 };
            room.place(&f, x, y, yaw, 0.3, None)
        };
        if placed.is_some() {
            pieces.push(f.kind);
        }
    }
    (room, HallRecord { width: w, depth: d, height, columns, pieces })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn halls_are_furnished_inside_their_walls() {
        for seed in 0..8 {
            let (room, record) = generate_hall(&mut Rng::new(seed));
            assert!(!record.pieces.is_empty(), "seed {seed}");
            for f in &room.footprints {
                assert!(room.contains(f.center), "seed {seed}: {f:?}");
            }
            for o in &room.objects {
                assert!(o.aabb.min.z > -0.21 && o.aabb.max.z < room.height + 0.21, "{}: {:?}", o.kind, o.aabb);
            }
        }
    }
}
