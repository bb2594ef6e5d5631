//! Furniture built from primitives, each in its own local frame: the footprint is centred on the origin, the
//! floor is z = 0, the back faces +y (it goes against a wall) and the front faces -y. Sizes are random within
//! everyday ranges (metres).

use super::geometry::{Primitive, rot_x, rot_y, rot_z};
use crate::rng::Rng;
use nalgebra::Vector3;
use std::f64::consts::{FRAC_PI_2, PI};

/// One piece of furniture in its local frame.
#[derive(Clone, Debug)]
pub struct Furniture {
    /// What it is.
    pub kind: &'static str,
    /// Its solids (local frame).
    pub parts: Vec<Primitive>,
    /// Half extents of the footprint along local x and y.
    pub half: [f64; 2],
    /// Height of the tallest part.
    pub height: f64,
}

pub(crate) fn v(x: f64, y: f64, z: f64) -> Vector3<f64> {
    Vector3::new(x, y, z)
}

/// A box spanning `[x0, x1] x [y0, y1] x [z0, z1]` (local frame, no rotation).
pub(crate) fn slab(x0: f64, x1: f64, y0: f64, y1: f64, z0: f64, z1: f64) -> Primitive {
    Primitive::cuboid(
        v((x0 + x1) / 2.0, (y0 + y1) / 2.0, (z0 + z1) / 2.0),
        v((x1 - x0) / 2.0, (y1 - y0) / 2.0, (z1 - z0) / 2.0),
        0.0,
    )
}

/// An upright cylinder standing on `z0`.
pub(crate) fn post(x: f64, y: f64, z0: f64, radius: f64, height: f64) -> Primitive {
    Primitive::upright_cylinder(v(x, y, z0 + height / 2.0), radius, height / 2.0)
}

/// Small clutter standing on a surface at height `z` inside `[-hx, hx] x [-hy, hy]`: mugs, books, boxes,
/// bowls (spheres), bottles, a lying can. At most `count` items, skipping ones that would overlap.
pub fn clutter(rng: &mut Rng, hx: f64, hy: f64, z: f64, count: usize, max_height: f64) -> Vec<Primitive> {
    let mut parts = Vec::new();
    let mut taken: Vec<(f64, f64, f64)> = Vec::new();
    for _ in 0..count {
        let size = rng.uniform(0.04, 0.16).min(hx.min(hy) * 0.9);
        if size < 0.03 {
            break;
        }
        let x = rng.uniform(-hx + size, hx - size);
        let y = rng.uniform(-hy + size, hy - size);
        if taken.iter().any(|&(tx, ty, ts)| (tx - x).hypot(ty - y) < ts + size) {
            continue;
        }
        taken.push((x, y, size));
        let h_cap = max_height.max(0.05);
        match rng.below(6) {
            0 => {
                // Mug or can.
                let r = size * 0.5;
                parts.push(post(x, y, z, r, rng.uniform(0.08, 0.16).min(h_cap)));
            }
            1 => {
                // Bottle: body and neck.
                let r = size * 0.35;
                let h = rng.uniform(0.15, 0.3).min(h_cap * 0.75);
                parts.push(post(x, y, z, r, h));
                parts.push(post(x, y, z + h, r * 0.35, h * 0.3));
            }
            2 => {
                // Ball or bowl-ish sphere resting on the surface.
                let r = size * 0.5;
                parts.push(Primitive::sphere(v(x, y, z + r), r));
            }
            3 => {
                // Lying can.
                let r = size * 0.3;
                let rot = rot_z(rng.uniform(0.0, PI)) * rot_y(FRAC_PI_2);
                parts.push(Primitive::cylinder(v(x, y, z + r), r, size * 0.6, rot));
            }
            _ => {
                // Box or stacked books.
                let yaw = rng.uniform(0.0, PI);
                let mut zz = z;
                for _ in 0..1 + rng.below(3) {
                    let h = rng.uniform(0.02, 0.12).min(h_cap / 3.0);
                    let half = v(size * rng.uniform(0.6, 1.0), size * rng.uniform(0.4, 0.8), h / 2.0);
                    parts.push(Primitive::cuboid(v(x, y, zz + h / 2.0), half, yaw + rng.uniform(-0.3, 0.3)));
                    zz += h;
                }
            }
        }
    }
    parts
}

/// A rectangular table (four legs, optional apron, clutter on top).
pub fn table(rng: &mut Rng) -> Furniture {
    let (w, d, h) = (rng.uniform(0.7, 1.8), rng.uniform(0.6, 1.0), rng.uniform(0.70, 0.78));
    let th = rng.uniform(0.025, 0.05);
    let (hx, hy) = (w / 2.0, d / 2.0);
    let mut parts = vec![slab(-hx, hx, -hy, hy, h - th, h)];
    let inset = rng.uniform(0.03, 0.1);
    let round_legs = rng.below(2) == 0;
    let leg = rng.uniform(0.025, 0.045);
    for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
        let (x, y) = (sx * (hx - inset - leg), sy * (hy - inset - leg));
        parts.push(if round_legs {
            post(x, y, 0.0, leg, h - th)
        } else {
            slab(x - leg, x + leg, y - leg, y + leg, 0.0, h - th)
        });
    }
    if rng.below(2) == 0 {
        let a = h - th - 0.08;
        let (ax, ay) = (hx - inset - leg, hy - inset - leg);
        parts.push(slab(-ax, ax, -ay, -ay + 0.02, a, h - th));
        parts.push(slab(-ax, ax, ay - 0.02, ay, a, h - th));
    }
    let n = rng.below(5);
    parts.extend(clutter(rng, hx * 0.9, hy * 0.9, h, n, 0.35));
    Furniture { kind: "table", parts, half: [hx, hy], height: h + 0.35 }
}

/// A round table on a pedestal.
pub fn round_table(rng: &mut Rng) -> Furniture {
    let r = rng.uniform(0.35, 0.6);
    let h = rng.uniform(0.55, 0.76);
    let th = rng.uniform(0.025, 0.045);
    let mut parts = vec![
        post(0.0, 0.0, h - th, r, th),
        post(0.0, 0.0, 0.0, rng.uniform(0.03, 0.06), h - th),
        post(0.0, 0.0, 0.0, r * rng.uniform(0.4, 0.7), 0.03),
    ];
    let n = rng.below(4);
    parts.extend(clutter(rng, r * 0.6, r * 0.6, h, n, 0.3));
    Furniture { kind: "round table", parts, half: [r, r], height: h + 0.3 }
}

/// A chair with four legs and a backrest at +y.
pub fn chair(rng: &mut Rng) -> Furniture {
    let (w, d) = (rng.uniform(0.4, 0.5), rng.uniform(0.4, 0.5));
    let seat = rng.uniform(0.42, 0.48);
    let back = seat + rng.uniform(0.35, 0.5);
    let (hx, hy) = (w / 2.0, d / 2.0);
    let leg = rng.uniform(0.015, 0.025);
    let mut parts = vec![slab(-hx, hx, -hy, hy, seat - 0.04, seat)];
    for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
        let (x, y) = (sx * (hx - leg), sy * (hy - leg));
        parts.push(slab(x - leg, x + leg, y - leg, y + leg, 0.0, seat - 0.04));
    }
    if rng.below(2) == 0 {
        parts.push(slab(-hx, hx, hy - 0.03, hy, seat + 0.12, back));
        parts.push(slab(-hx, -hx + 0.03, hy - 0.03, hy, seat, back));
        parts.push(slab(hx - 0.03, hx, hy - 0.03, hy, seat, back));
    } else {
        parts.push(slab(-hx, hx, hy - 0.03, hy, seat, back));
    }
    Furniture { kind: "chair", parts, half: [hx, hy], height: back }
}

/// A shelf unit: sides, top, bottom, back panel and boards holding books, cans and balls.
pub fn shelf(rng: &mut Rng) -> Furniture {
    let (w, d, h) = (rng.uniform(0.6, 1.4), rng.uniform(0.25, 0.4), rng.uniform(1.0, 2.0));
    let t = rng.uniform(0.015, 0.025);
    let (hx, hy) = (w / 2.0, d / 2.0);
    let mut parts = vec![
        slab(-hx, -hx + t, -hy, hy, 0.0, h),
        slab(hx - t, hx, -hy, hy, 0.0, h),
        slab(-hx, hx, -hy, hy, h - t, h),
        slab(-hx + t, hx - t, -hy, hy, 0.0, 0.06),
        slab(-hx + t, hx - t, hy - 0.01, hy, 0.06, h - t),
    ];
    let boards = 2 + (h / 0.45) as usize;
    let gap = (h - 0.06 - t) / (boards - 1) as f64;
    for b in 0..boards - 1 {
        let z = 0.06 + b as f64 * gap;
        if b > 0 {
            parts.push(slab(-hx + t, hx - t, -hy, hy - 0.01, z - t, z));
        }
        // Books: a row of boxes of varying size, sometimes a gap or a leaning one; else clutter.
        if rng.below(3) > 0 {
            let mut x = -hx + t + rng.uniform(0.0, 0.1);
            while x < hx - t - 0.05 {
                let bw = rng.uniform(0.015, 0.05);
                if x + bw > hx - t {
                    break;
                }
                let bh = rng.uniform(0.15, (gap - 0.03).clamp(0.16, 0.32));
                let bd = rng.uniform(0.12, (d - 0.03).max(0.13));
                let lean = if rng.below(12) == 0 { rng.uniform(-0.3, 0.3) } else { 0.0 };
                let mut book = Primitive::cuboid(
                    v(x + bw / 2.0, hy - 0.01 - bd / 2.0, z + bh / 2.0),
                    v(bw / 2.0, bd / 2.0, bh / 2.0),
                    0.0,
                );
                book.rotation = rot_y(lean);
                parts.push(book);
                x += bw + if rng.below(8) == 0 { rng.uniform(0.05, 0.2) } else { 0.002 };
            }
        } else {
            let n = 1 + rng.below(4);
            parts.extend(clutter(rng, hx - t, hy - 0.02, z, n, gap - 0.05));
        }
    }
    Furniture { kind: "shelf", parts, half: [hx, hy], height: h }
}

/// A sofa: base, back, arms, seat cushions, sometimes a bolster.
pub fn sofa(rng: &mut Rng) -> Furniture {
    let (w, d) = (rng.uniform(1.4, 2.4), rng.uniform(0.8, 1.0));
    let (hx, hy) = (w / 2.0, d / 2.0);
    let seat = rng.uniform(0.38, 0.45);
    let back_h = rng.uniform(0.75, 0.95);
    let arm_w = rng.uniform(0.12, 0.25);
    let arm_h = rng.uniform(0.55, 0.7);
    let back_d = rng.uniform(0.18, 0.28);
    let mut parts = vec![
        slab(-hx + arm_w, hx - arm_w, -hy, hy, 0.08, seat - 0.12),
        slab(-hx, hx, hy - back_d, hy, 0.08, back_h),
        slab(-hx, -hx + arm_w, -hy, hy, 0.08, arm_h),
        slab(hx - arm_w, hx, -hy, hy, 0.08, arm_h),
    ];
    for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
        parts.push(post(sx * (hx - 0.06), sy * (hy - 0.06), 0.0, 0.025, 0.08));
    }
    let n = 2 + rng.below(2);
    let cw = (w - 2.0 * arm_w) / n as f64;
    for k in 0..n {
        let x0 = -hx + arm_w + k as f64 * cw;
        parts.push(slab(x0 + 0.01, x0 + cw - 0.01, -hy + 0.02, hy - back_d, seat - 0.12, seat));
    }
    if rng.below(2) == 0 {
        let r = rng.uniform(0.08, 0.12);
        let x = hx - arm_w - r * 1.8 - 0.01;
        parts.push(Primitive::cylinder(v(x, hy - back_d - r, seat + r), r, r * 1.8, rot_y(FRAC_PI_2)));
    }
    Furniture { kind: "sofa", parts, half: [hx, hy], height: back_h }
}

/// A cabinet or chest of drawers with door panels, handles and things on top.
pub fn cabinet(rng: &mut Rng) -> Furniture {
    let (w, d, h) = (rng.uniform(0.4, 1.4), rng.uniform(0.35, 0.6), rng.uniform(0.5, 1.1));
    let (hx, hy) = (w / 2.0, d / 2.0);
    let mut parts = vec![slab(-hx, hx, -hy + 0.02, hy, 0.0, h), slab(-hx + 0.02, hx - 0.02, -hy + 0.03, hy, 0.0, 0.06)];
    let drawers = rng.below(2) == 0;
    let rows = if drawers { 2 + rng.below(3) } else { 1 };
    let cols = if drawers { 1 } else { 1 + (w > 0.7) as usize };
    let (pw, ph) = ((w - 0.03) / cols as f64, (h - 0.09) / rows as f64);
    for r in 0..rows {
        for c in 0..cols {
            let x0 = -hx + 0.015 + c as f64 * pw;
            let z0 = 0.07 + r as f64 * ph;
            parts.push(slab(x0 + 0.005, x0 + pw - 0.005, -hy, -hy + 0.02, z0 + 0.005, z0 + ph - 0.005));
            let (hx_, hz) = if drawers { (x0 + pw / 2.0, z0 + ph * 0.6) } else { (x0 + pw * 0.85, z0 + ph * 0.5) };
            let handle = if drawers {
                Primitive::cylinder(v(hx_, -hy - 0.015, hz), 0.008, 0.06, rot_y(FRAC_PI_2))
            } else {
                Primitive::cylinder(v(hx_, -hy - 0.015, hz), 0.008, 0.05, nalgebra::Matrix3::identity())
            };
            parts.push(handle);
        }
    }
    let n = rng.below(4);
    parts.extend(clutter(rng, hx * 0.9, hy * 0.9, h, n, 0.4));
    Furniture { kind: "cabinet", parts, half: [hx, hy], height: h + 0.4 }
}

/// A desk with a monitor on a stand and a keyboard.
pub fn desk(rng: &mut Rng) -> Furniture {
    let mut f = table(rng);
    let top = f.parts[0].center.z
        + match f.parts[0].shape {
            super::geometry::Shape::Cuboid { half } => half.z,
            _ => 0.0,
        };
    let [hx, hy] = f.half;
    // Remove clutter that could collide with the monitor: keep the structure only, then add the screen.
    f.parts.retain(|p| p.center.z < top - 1e-9);
    let mw = rng.uniform(0.45, 0.7).min(hx * 1.6);
    let mh = mw * rng.uniform(0.55, 0.65);
    let my = hy * 0.5;
    f.parts.push(slab(-0.1, 0.1, my - 0.08, my + 0.08, top, top + 0.015));
    f.parts.push(slab(-0.025, 0.025, my - 0.01, my + 0.03, top, top + 0.12));
    f.parts.push(slab(-mw / 2.0, mw / 2.0, my - 0.03, my, top + 0.1, top + 0.1 + mh));
    f.parts.push(slab(-0.22, 0.22, -hy * 0.4 - 0.07, -hy * 0.4 + 0.07, top, top + 0.02));
    let n = rng.below(3);
    for mut p in clutter(rng, hx * 0.9, hy * 0.25, top, n, 0.25) {
        p.center.x = p.center.x.clamp(-hx * 0.9, hx * 0.9);
        if p.center.x.abs() > mw / 2.0 + 0.1 {
            f.parts.push(p);
        }
    }
    Furniture { kind: "desk", height: top + 0.1 + mh, ..f }
}

/// A bed: frame, mattress, pillows, headboard at +y.
pub fn bed(rng: &mut Rng) -> Furniture {
    let (w, l) = (rng.uniform(0.9, 1.8), rng.uniform(1.9, 2.1));
    let (hx, hy) = (w / 2.0, l / 2.0);
    let frame = rng.uniform(0.2, 0.35);
    let mattress = frame + rng.uniform(0.15, 0.25);
    let mut parts = vec![
        slab(-hx, hx, -hy, hy - 0.05, 0.05, frame),
        slab(-hx + 0.02, hx - 0.02, -hy + 0.02, hy - 0.07, frame, mattress),
        slab(-hx, hx, hy - 0.05, hy, 0.0, mattress + rng.uniform(0.3, 0.6)),
    ];
    for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0)] {
        parts.push(post(sx * (hx - 0.05), sy * (hy - 0.05), 0.0, 0.03, 0.05));
    }
    let pillows = if w > 1.3 { 2 } else { 1 };
    let pw = (w - 0.2) / pillows as f64;
    for k in 0..pillows {
        let x0 = -hx + 0.1 + k as f64 * pw;
        let mut p = slab(x0 + 0.03, x0 + pw - 0.03, hy - 0.45, hy - 0.1, mattress, mattress + 0.12);
        p.rotation = rot_x(rng.uniform(-0.15, 0.0));
        parts.push(p);
    }
    Furniture { kind: "bed", parts, half: [hx, hy], height: mattress + 0.6 }
}

/// Cardboard boxes stacked with random offsets.
pub fn box_stack(rng: &mut Rng) -> Furniture {
    let mut parts = Vec::new();
    let mut z = 0.0;
    let (mut hx, mut hy) = (rng.uniform(0.15, 0.35), rng.uniform(0.12, 0.3));
    let mut reach: f64 = 0.0;
    for _ in 0..1 + rng.below(3) {
        let h = rng.uniform(0.15, 0.4);
        let yaw = rng.uniform(-0.3, 0.3);
        parts.push(Primitive::cuboid(v(0.0, 0.0, z + h / 2.0), v(hx, hy, h / 2.0), yaw));
        reach = reach.max(hx.hypot(hy));
        z += h;
        hx *= rng.uniform(0.6, 1.0);
        hy *= rng.uniform(0.6, 1.0);
    }
    Furniture { kind: "boxes", parts, half: [reach, reach], height: z }
}

/// A waste bin, a drum or a stool: an upright cylinder, sometimes with a rim.
pub fn bin(rng: &mut Rng) -> Furniture {
    let r = rng.uniform(0.12, 0.3);
    let h = rng.uniform(0.3, 0.7);
    let mut parts = vec![post(0.0, 0.0, 0.0, r, h)];
    if rng.below(2) == 0 {
        parts.push(post(0.0, 0.0, h - 0.03, r + 0.015, 0.03));
    }
    Furniture { kind: "cylinder", parts, half: [r + 0.02, r + 0.02], height: h }
}

/// A ball (or two) on the floor.
pub fn ball(rng: &mut Rng) -> Furniture {
    let r = rng.uniform(0.1, 0.3);
    let mut parts = vec![Primitive::sphere(v(0.0, 0.0, r), r)];
    if rng.below(3) == 0 {
        let r2 = r * rng.uniform(0.4, 0.8);
        parts.push(Primitive::sphere(v(r + r2 + 0.02, 0.0, r2), r2));
        return Furniture { kind: "ball", parts, half: [r + r2 + 0.02 + r2, r], height: 2.0 * r };
    }
    Furniture { kind: "ball", parts, half: [r, r], height: 2.0 * r }
}

/// A floor lamp: base disc, pole and shade.
pub fn floor_lamp(rng: &mut Rng) -> Furniture {
    let h = rng.uniform(1.3, 1.8);
    let base = rng.uniform(0.12, 0.2);
    let shade = rng.uniform(0.12, 0.22);
    let parts = vec![
        post(0.0, 0.0, 0.0, base, 0.03),
        post(0.0, 0.0, 0.03, 0.012, h - 0.25),
        post(0.0, 0.0, h - 0.3, shade, 0.3),
    ];
    Furniture { kind: "lamp", parts, half: [base.max(shade), base.max(shade)], height: h }
}

/// A potted plant: pot cylinder and a few foliage spheres.
pub fn plant(rng: &mut Rng) -> Furniture {
    let r = rng.uniform(0.1, 0.22);
    let h = rng.uniform(0.2, 0.45);
    let mut parts = vec![post(0.0, 0.0, 0.0, r, h), post(0.0, 0.0, h - 0.02, r + 0.015, 0.03)];
    let mut top = h;
    for _ in 0..2 + rng.below(3) {
        let fr = r * rng.uniform(0.8, 1.6);
        let c = v(rng.uniform(-r, r), rng.uniform(-r, r), h + fr * rng.uniform(0.6, 1.6));
        top = top.max(c.z + fr);
        parts.push(Primitive::sphere(c, fr));
    }
    Furniture { kind: "plant", parts, half: [r * 2.6, r * 2.6], height: top }
}

/// Furniture families that only the `randomized` style uses (the `kinect` style keeps its original set).
pub const EXTRA_FAMILIES: [fn(&mut Rng) -> Furniture; 5] = [bench, stool, coat_rack, tv_unit, drum_cluster];

/// A bench: a long seat board on two slab or post legs, sometimes with a backrest.
pub fn bench(rng: &mut Rng) -> Furniture {
    let (w, d, h) = (rng.uniform(0.9, 2.0), rng.uniform(0.3, 0.45), rng.uniform(0.4, 0.48));
    let (hx, hy) = (w / 2.0, d / 2.0);
    let th = rng.uniform(0.03, 0.06);
    let mut parts = vec![slab(-hx, hx, -hy, hy, h - th, h)];
    let inset = rng.uniform(0.05, 0.2);
    if rng.below(2) == 0 {
        for sx in [-1.0, 1.0] {
            let x = sx * (hx - inset);
            parts.push(slab(x - 0.025, x + 0.025, -hy + 0.02, hy - 0.02, 0.0, h - th));
        }
    } else {
        for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
            parts.push(post(sx * (hx - inset), sy * (hy - 0.04), 0.0, 0.02, h - th));
        }
    }
    let mut height = h;
    if rng.below(2) == 0 {
        height = h + rng.uniform(0.3, 0.45);
        parts.push(slab(-hx, hx, hy - 0.03, hy, h + 0.08, height));
    }
    Furniture { kind: "bench", parts, half: [hx, hy], height }
}

/// A bar stool: round seat on a central post with a foot ring and a disc base.
pub fn stool(rng: &mut Rng) -> Furniture {
    let r = rng.uniform(0.16, 0.22);
    let h = rng.uniform(0.45, 0.8);
    let mut parts = vec![
        post(0.0, 0.0, h - 0.05, r, 0.05),
        post(0.0, 0.0, 0.0, rng.uniform(0.02, 0.035), h - 0.05),
        post(0.0, 0.0, 0.0, r * rng.uniform(0.8, 1.1), 0.025),
    ];
    if rng.below(2) == 0 {
        parts.push(post(0.0, 0.0, h * 0.35, r * 0.8, 0.02));
    }
    Furniture { kind: "stool", parts, half: [r * 1.1, r * 1.1], height: h }
}

/// A coat rack: a pole on crossed feet with hooks and hanging coats (boxes) or hats (spheres).
pub fn coat_rack(rng: &mut Rng) -> Furniture {
    let h = rng.uniform(1.6, 1.9);
    let foot = rng.uniform(0.2, 0.3);
    let mut parts = vec![
        post(0.0, 0.0, 0.0, 0.02, h),
        slab(-foot, foot, -0.02, 0.02, 0.0, 0.03),
        slab(-0.02, 0.02, -foot, foot, 0.0, 0.03),
    ];
    for k in 0..4 {
        let a = k as f64 * FRAC_PI_2 + rng.uniform(-0.2, 0.2);
        let (c, s) = (a.cos(), a.sin());
        parts.push(Primitive::cylinder(v(0.07 * c, 0.07 * s, h - 0.1), 0.008, 0.07, rot_z(a) * rot_y(FRAC_PI_2)));
        match rng.below(3) {
            0 => parts.push(Primitive::sphere(v(0.13 * c, 0.13 * s, h - 0.05), rng.uniform(0.06, 0.1))),
            1 => {
                let len = rng.uniform(0.5, 0.9);
                let half = v(0.04, rng.uniform(0.12, 0.2), len / 2.0);
                parts.push(Primitive {
                    rotation: rot_z(a),
                    ..Primitive::cuboid(v(0.12 * c, 0.12 * s, h - 0.1 - len / 2.0), half, 0.0)
                });
            }
            _ => {}
        }
    }
    Furniture { kind: "coat rack", parts, half: [foot.max(0.35), foot.max(0.35)], height: h }
}

/// A low TV unit with a flat screen on a foot and a speaker bar.
pub fn tv_unit(rng: &mut Rng) -> Furniture {
    let (w, d, h) = (rng.uniform(1.0, 2.0), rng.uniform(0.35, 0.5), rng.uniform(0.35, 0.55));
    let (hx, hy) = (w / 2.0, d / 2.0);
    let mut parts = vec![slab(-hx, hx, -hy, hy, 0.05, h)];
    for sx in [-1.0, 1.0] {
        parts.push(post(sx * (hx - 0.06), 0.0, 0.0, 0.025, 0.05));
    }
    let sw = rng.uniform(0.8, 1.4).min(w);
    let sh = sw * 9.0 / 16.0;
    parts.push(slab(-0.15, 0.15, -0.1, 0.1, h, h + 0.02));
    parts.push(slab(-0.03, 0.03, 0.0, 0.04, h, h + 0.1));
    parts.push(slab(-sw / 2.0, sw / 2.0, 0.0, rng.uniform(0.02, 0.06), h + 0.08, h + 0.08 + sh));
    if rng.below(2) == 0 {
        parts.push(Primitive::cylinder(v(0.0, -hy + 0.08, h + 0.04), 0.04, sw * 0.35, rot_y(FRAC_PI_2)));
    }
    Furniture { kind: "tv unit", parts, half: [hx, hy], height: h + 0.08 + sh }
}

/// A cluster of drums or tubes of different radii and heights, some with lids.
pub fn drum_cluster(rng: &mut Rng) -> Furniture {
    let mut parts = Vec::new();
    let mut reach: f64 = 0.0;
    let mut height: f64 = 0.0;
    let mut placed: Vec<(f64, f64, f64)> = Vec::new();
    for _ in 0..2 + rng.below(4) {
        let r = rng.uniform(0.08, 0.3);
        let h = rng.uniform(0.2, 1.0);
        let (x, y) = (rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.4));
        if placed.iter().any(|&(px, py, pr)| (px - x).hypot(py - y) < pr + r + 0.01) {
            continue;
        }
        placed.push((x, y, r));
        parts.push(post(x, y, 0.0, r, h));
        if rng.below(2) == 0 {
            parts.push(post(x, y, h, r * 1.05, 0.02));
        }
        reach = reach.max(x.abs() + r * 1.05).max(y.abs() + r * 1.05);
        height = height.max(h + 0.02);
    }
    Furniture { kind: "drums", parts, half: [reach, reach], height }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_builder_stays_inside_its_footprint_and_above_the_floor() {
        let builders: [fn(&mut Rng) -> Furniture; 13] =
            [table, round_table, chair, shelf, sofa, cabinet, desk, bed, box_stack, bin, ball, floor_lamp, plant];
        for seed in 0..20 {
            let mut rng = Rng::new(seed);
            for b in builders.into_iter().chain(EXTRA_FAMILIES) {
                let f = b(&mut rng);
                for p in &f.parts {
                    let bb = p.aabb();
                    assert!(bb.min.z > -1e-9, "{} below the floor: {:?}", f.kind, bb);
                    // Handles protrude a few centimetres from the front.
                    assert!(bb.min.x > -f.half[0] - 0.05 && bb.max.x < f.half[0] + 0.05, "{}: {:?}", f.kind, bb);
                    assert!(bb.min.y > -f.half[1] - 0.05 && bb.max.y < f.half[1] + 0.05, "{}: {:?}", f.kind, bb);
                }
            }
        }
    }
}
