// SPDX-License-Identifier: MIT OR Apache-2.0
// rotation_head: RelativeNet's raw outputs to rotations target_from_source in the fragments' frames. Per row,
// the raw output (mode 0, width 4: a quaternion [w, x, y, z], normalised; mode 1, width 6: two columns made
// orthonormal by Gram-Schmidt, the third their cross product; mode 2, width = bins: angle logits about +z, of
// which the `candidates` best bins (ties to the lower bin), each refined by the parabola through its wrapped
// neighbours (clamped to half a bin), give one rotation each) is the rotation between the two patches as
// PC-FoldNet saw them;
// with normal-aligned patches (frame = 1) the fragment-frame rotation is F(n_t)^T R F(n_s), F(n) the normal frame
// of a keypoint normal (rows t1, t2, n; Duff et al. 2017). A degenerate output (norm not above min_norm, or NaN;
// for 6-D also a second column whose part orthogonal to the first is not above min_orthogonal_share of its
// length) gives the identity; a zero normal gives the identity frame. One invocation per row, the workgroup grid
// linearised.
// Bindings: 0 params (uniform) | 1 raw (width per row) | 2 source_normals, 3 target_normals (xyz per row)
//           (read) | 4 out (candidates x 9 per row, row-major, written).
// CPU twin: src/cpu/rotation_head.rs

struct RotationHeadParams {
    rows: u32,
    width: u32,
    frame: u32,
    mode: u32,
    candidates: u32,
    min_norm: f32,
    min_orthogonal_share: f32,
    _pad1: u32,
}

const TAU: f32 = 6.28318530717958647692528676655900577;
const PI: f32 = 3.14159265358979323846264338327950288;

const WG_SIZE: u32 = 64u;

@group(0) @binding(0) var<uniform> params: RotationHeadParams;
@group(0) @binding(1) var<storage, read> raw: array<f32>;
@group(0) @binding(2) var<storage, read> source_normals: array<f32>;
@group(0) @binding(3) var<storage, read> target_normals: array<f32>;
@group(0) @binding(4) var<storage, read_write> out: array<f32>;

fn identity() -> array<f32, 9> {
    return array<f32, 9>(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0);
}

// NaN-safe "is this norm usable": false for NaN (every comparison with NaN is false).
fn usable(n: f32) -> bool {
    return n > params.min_norm;
}

fn normal_frame(v: vec3<f32>) -> array<f32, 9> {
    let len = sqrt(v.x * v.x + v.y * v.y + v.z * v.z);
    if !usable(len) {
        return identity();
    }
    let x = v.x / len;
    let y = v.y / len;
    let z = v.z / len;
    let sign = select(-1.0, 1.0, z >= 0.0);
    let a = -1.0 / (sign + z);
    let b = x * y * a;
    return array<f32, 9>(1.0 + sign * x * x * a, sign * b, -sign * x, b, sign + y * y * a, -y, x, y, z);
}

fn quaternion_rotation(base: u32) -> array<f32, 9> {
    let r = vec4<f32>(raw[base], raw[base + 1u], raw[base + 2u], raw[base + 3u]);
    let n = sqrt(r.x * r.x + r.y * r.y + r.z * r.z + r.w * r.w);
    if !usable(n) {
        return identity();
    }
    let w = r.x / n;
    let x = r.y / n;
    let y = r.z / n;
    let z = r.w / n;
    return array<f32, 9>(
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y - w * z),
        2.0 * (x * z + w * y),
        2.0 * (x * y + w * z),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z - w * x),
        2.0 * (x * z - w * y),
        2.0 * (y * z + w * x),
        1.0 - 2.0 * (x * x + y * y),
    );
}

fn dot3(a: vec3<f32>, b: vec3<f32>) -> f32 {
    return a.x * b.x + a.y * b.y + a.z * b.z;
}

fn six_d_rotation(base: u32) -> array<f32, 9> {
    let a1 = vec3<f32>(raw[base], raw[base + 1u], raw[base + 2u]);
    let a2 = vec3<f32>(raw[base + 3u], raw[base + 4u], raw[base + 5u]);
    let n1 = sqrt(dot3(a1, a1));
    if !usable(n1) {
        return identity();
    }
    let b1 = a1 / n1;
    let d = dot3(b1, a2);
    let u2 = vec3<f32>(a2.x - d * b1.x, a2.y - d * b1.y, a2.z - d * b1.z);
    let n2 = sqrt(dot3(u2, u2));
    if !usable(n2) || !(n2 > params.min_orthogonal_share * sqrt(dot3(a2, a2))) {
        return identity();
    }
    let b2 = u2 / n2;
    let b3 = vec3<f32>(b1.y * b2.z - b1.z * b2.y, b1.z * b2.x - b1.x * b2.z, b1.x * b2.y - b1.y * b2.x);
    return array<f32, 9>(b1.x, b2.x, b3.x, b1.y, b2.y, b3.y, b1.z, b2.z, b3.z);
}

// The angle (radians, in [-pi, pi)) of bin `best` of the row at `base`, refined by the parabola through its
// logit and its two wrapped neighbours' (clamped to half a bin; no shift unless the parabola opens downwards).
fn bin_angle(base: u32, best: u32) -> f32 {
    let k_bins = params.width;
    let l0 = raw[base + (best + k_bins - 1u) % k_bins];
    let l1 = raw[base + best];
    let l2 = raw[base + (best + 1u) % k_bins];
    let den = l0 - 2.0 * l1 + l2;
    var offset = 0.0;
    if den < 0.0 {
        offset = clamp(0.5 * (l0 - l2) / den, -0.5, 0.5);
    }
    var angle = TAU * (f32(best) + offset) / f32(k_bins);
    if angle >= PI {
        angle -= TAU;
    }
    return angle;
}

// `r` (network frames) to the fragments' frames of row i, then written as candidate `slot` of row i.
fn emit(i: u32, slot: u32, net: array<f32, 9>) {
    var r = net;
    if params.frame == 1u {
        let fs = normal_frame(vec3<f32>(source_normals[i * 3u], source_normals[i * 3u + 1u], source_normals[i * 3u + 2u]));
        let ft = normal_frame(vec3<f32>(target_normals[i * 3u], target_normals[i * 3u + 1u], target_normals[i * 3u + 2u]));
        // m = ft^T r, then r = m fs (the CPU twin's order).
        var m: array<f32, 9>;
        for (var a = 0u; a < 3u; a++) {
            for (var c = 0u; c < 3u; c++) {
                m[a * 3u + c] = ft[a] * r[c] + ft[3u + a] * r[3u + c] + ft[6u + a] * r[6u + c];
            }
        }
        for (var a = 0u; a < 3u; a++) {
            for (var c = 0u; c < 3u; c++) {
                r[a * 3u + c] = m[a * 3u] * fs[c] + m[a * 3u + 1u] * fs[3u + c] + m[a * 3u + 2u] * fs[6u + c];
            }
        }
    }
    let o = (i * params.candidates + slot) * 9u;
    for (var e = 0u; e < 9u; e++) {
        out[o + e] = r[e];
    }
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
    if params.mode == 0u {
        emit(i, 0u, quaternion_rotation(i * 4u));
        return;
    }
    if params.mode == 1u {
        emit(i, 0u, six_d_rotation(i * 6u));
        return;
    }
    // Angle bins: candidate j is the best bin ranked after candidate j - 1 (by logit, then lower bin first).
    let base = i * params.width;
    var prev_v = 0.0;
    var prev_k = 0u;
    for (var j = 0u; j < params.candidates; j++) {
        var best = params.width;
        var best_v = 0.0;
        for (var k = 0u; k < params.width; k++) {
            let v = raw[base + k];
            if j > 0u && !(v < prev_v || (v == prev_v && k > prev_k)) {
                continue;
            }
            if best == params.width || v > best_v {
                best = k;
                best_v = v;
            }
        }
        let angle = bin_angle(base, best);
        let s = sin(angle);
        let c = cos(angle);
        emit(i, j, array<f32, 9>(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0));
        prev_v = best_v;
        prev_k = best;
    }
}
