// SPDX-License-Identifier: MIT OR Apache-2.0
// patch_features: per gathered patch point, the 4-D point pair feature (PPF) against the patch centre and
// the centred, radius-scaled coordinate (PC), rotated into the centre normal's frame F(n_r) (rows t1, t2, n;
// Duff et al. 2017) when normal_frame = 1. One invocation per point, the workgroup grid linearised.
// Bindings: 0 params (uniform) | 1 centers, 2 center_normals (xyz per patch) | 3 points, 4 normals
//           (xyz per point) | 5 ppf (4 per point), 6 pc (3 per point), written.
// CPU twin: src/cpu/patch_features.rs

struct PatchFeaturesParams {
    rows: u32,
    points_per_patch: u32,
    radius: f32,
    normal_frame: u32,
}

const WG_SIZE: u32 = 64u;
const MIN_NORM: f32 = 1e-12;
const INV_PI: f32 = 0.318309886183790671537767526745028724;

@group(0) @binding(0) var<uniform> params: PatchFeaturesParams;
@group(0) @binding(1) var<storage, read> centers: array<f32>;
@group(0) @binding(2) var<storage, read> center_normals: array<f32>;
@group(0) @binding(3) var<storage, read> points: array<f32>;
@group(0) @binding(4) var<storage, read> normals: array<f32>;
@group(0) @binding(5) var<storage, read_write> ppf: array<f32>;
@group(0) @binding(6) var<storage, read_write> pc: array<f32>;

// Angle between a and b in [0, pi]; exactly 0 when either is zero (atan2(0, 0) is undefined in WGSL).
fn angle(a: vec3<f32>, b: vec3<f32>) -> f32 {
    let c = vec3<f32>(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
    let s = sqrt(c.x * c.x + c.y * c.y + c.z * c.z);
    let d = a.x * b.x + a.y * b.y + a.z * b.z;
    if s == 0.0 && d == 0.0 {
        return 0.0;
    }
    return atan2(s, d);
}

// Rotation taking the unit normal v to +z (rows t1, t2, n); identity for a zero or NaN normal. Same formula
// and branch as rotation_head.wgsl and the CPU twin (src/cpu/rotation_head.rs: normal_frame).
fn normal_frame(v: vec3<f32>) -> array<f32, 9> {
    let len = sqrt(v.x * v.x + v.y * v.y + v.z * v.z);
    if !(len > MIN_NORM) {
        return array<f32, 9>(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0);
    }
    let x = v.x / len;
    let y = v.y / len;
    let z = v.z / len;
    let sign = select(-1.0, 1.0, z >= 0.0);
    let a = -1.0 / (sign + z);
    let b = x * y * a;
    return array<f32, 9>(1.0 + sign * x * x * a, sign * b, -sign * x, b, sign + y * y * a, -y, x, y, z);
}

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = (wid.x + wid.y * nwg.x) * WG_SIZE + lid;
    if i >= params.rows {
        return;
    }
    let p = i / params.points_per_patch;
    let p_r = vec3<f32>(centers[p * 3u], centers[p * 3u + 1u], centers[p * 3u + 2u]);
    let n_r = vec3<f32>(center_normals[p * 3u], center_normals[p * 3u + 1u], center_normals[p * 3u + 2u]);
    let p_i = vec3<f32>(points[i * 3u], points[i * 3u + 1u], points[i * 3u + 2u]);
    let n_i = vec3<f32>(normals[i * 3u], normals[i * 3u + 1u], normals[i * 3u + 2u]);
    let d = p_r - p_i;
    let dist = sqrt(d.x * d.x + d.y * d.y + d.z * d.z);
    let r = params.radius;
    ppf[i * 4u] = angle(n_r, d) * INV_PI;
    ppf[i * 4u + 1u] = angle(n_i, d) * INV_PI;
    ppf[i * 4u + 2u] = angle(n_r, n_i) * INV_PI;
    ppf[i * 4u + 3u] = dist / r;
    let c = vec3<f32>(-d.x / r, -d.y / r, -d.z / r);
    if params.normal_frame == 1u {
        let f = normal_frame(n_r);
        pc[i * 3u] = f[0] * c.x + f[1] * c.y + f[2] * c.z;
        pc[i * 3u + 1u] = f[3] * c.x + f[4] * c.y + f[5] * c.z;
        pc[i * 3u + 2u] = f[6] * c.x + f[7] * c.y + f[8] * c.z;
    } else {
        pc[i * 3u] = c.x;
        pc[i * 3u + 1u] = c.y;
        pc[i * 3u + 2u] = c.z;
    }
}
