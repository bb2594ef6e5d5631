// SPDX-License-Identifier: MIT OR Apache-2.0
// max_pool: per group (patch), per channel maximum over the group's rows. One invocation per output,
// the workgroup grid linearised over a 2-D dispatch.
// Bindings: 0 params (uniform) | 1 x (read, groups * rows_per_group x channels) | 2 out (groups x channels).
// CPU twin: src/cpu/max_pool.rs

struct MaxPoolParams {
    groups: u32,
    rows_per_group: u32,
    channels: u32,
    _pad: u32,
}

const WG_SIZE: u32 = 64u;

@group(0) @binding(0) var<uniform> params: MaxPoolParams;
@group(0) @binding(1) var<storage, read> x: array<f32>;
@group(0) @binding(2) var<storage, read_write> out: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = (wid.x + wid.y * nwg.x) * WG_SIZE + lid;
    let channels = params.channels;
    if i >= params.groups * channels {
        return;
    }
    let g = i / channels;
    let c = i % channels;
    let first = g * params.rows_per_group;
    // -inf, the twin's starting value: read from a variable, since a constant infinity is invalid WGSL (Tint rejects
    // it; naga let it through).
    var neg_inf_bits = 0xff800000u;
    var m = bitcast<f32>(neg_inf_bits);
    for (var r = 0u; r < params.rows_per_group; r++) {
        m = max(m, x[(first + r) * channels + c]);
    }
    out[i] = m;
}
