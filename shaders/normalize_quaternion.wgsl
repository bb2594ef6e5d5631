// SPDX-License-Identifier: MIT OR Apache-2.0
// normalize_quaternion: RelativeNet's raw 4-wide outputs [w, x, y, z] to unit quaternions; a norm not above
// MIN_NORM (or NaN) gives the identity. One invocation per row, the workgroup grid linearised.
// Bindings: 0 params (uniform) | 1 raw (read, 4 per row) | 2 out (4 per row, written).
// CPU twin: src/model/relativenet.rs (normalize_quaternion)

struct NormalizeQuaternionParams {
    rows: u32,
    min_norm: f32,
    _pad0: u32,
    _pad1: u32,
}

const WG_SIZE: u32 = 64u;

@group(0) @binding(0) var<uniform> params: NormalizeQuaternionParams;
@group(0) @binding(1) var<storage, read> raw: array<f32>;
@group(0) @binding(2) var<storage, read_write> out: array<f32>;

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
    let q = vec4<f32>(raw[i * 4u], raw[i * 4u + 1u], raw[i * 4u + 2u], raw[i * 4u + 3u]);
    let n = sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w);
    var u = vec4<f32>(1.0, 0.0, 0.0, 0.0);
    if n > params.min_norm {
        u = q / n;
    }
    out[i * 4u] = u.x;
    out[i * 4u + 1u] = u.y;
    out[i * 4u + 2u] = u.z;
    out[i * 4u + 3u] = u.w;
}
