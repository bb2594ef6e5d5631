// SPDX-License-Identifier: MIT OR Apache-2.0
// patch_features: per gathered patch point, the 4-D point pair feature (PPF) against the patch centre and
// the centred, radius-scaled coordinate (PC). One invocation per point, the workgroup grid linearised.
// Bindings: 0 params (uniform) | 1 centers, 2 center_normals (xyz per patch) | 3 points, 4 normals
//           (xyz per point) | 5 ppf (4 per point), 6 pc (3 per point), written.
// CPU twin: src/cpu/patch_features.rs

struct PatchFeaturesParams {
    rows: u32,
    points_per_patch: u32,
    radius: f32,
    _pad: u32,
}

const WG_SIZE: u32 = 64u;
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
    pc[i * 3u] = -d.x / r;
    pc[i * 3u + 1u] = -d.y / r;
    pc[i * 3u + 2u] = -d.z / r;
}
