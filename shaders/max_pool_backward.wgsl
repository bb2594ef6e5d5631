// SPDX-License-Identifier: MIT OR Apache-2.0
// max_pool_backward: the gradient of max_pool. Per group (patch) and channel, the output's gradient goes to
// the row that attains the maximum (strictly greater replaces, so the lowest such row keeps a tie), added to
// what dx holds. One invocation per (group, channel); each writes one element of its own channel and group, so
// no two invocations touch the same element. The workgroup grid is linearised over a 2-D dispatch.
// Bindings: 0 params (uniform) | 1 x (read, groups * rows_per_group x channels: the pooled layer's input)
//           | 2 d_out (read, groups x channels) | 3 dx (read_write, groups * rows_per_group x channels).
// CPU twin: src/cpu/max_pool_backward.rs

struct MaxPoolBackwardParams {
    groups: u32,
    rows_per_group: u32,
    channels: u32,
    _pad: u32,
}

const WG_SIZE: u32 = 64u;

@group(0) @binding(0) var<uniform> params: MaxPoolBackwardParams;
@group(0) @binding(1) var<storage, read> x: array<f32>;
@group(0) @binding(2) var<storage, read> d_out: array<f32>;
@group(0) @binding(3) var<storage, read_write> dx: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = (wid.x + wid.y * nwg.x) * WG_SIZE + lid;
    let channels = params.channels;
    if i >= params.groups * channels || params.rows_per_group == 0u {
        return;
    }
    let g = i / channels;
    let c = i % channels;
    let first = g * params.rows_per_group;
    var best_row = 0u;
    var best = x[first * channels + c];
    for (var r = 1u; r < params.rows_per_group; r++) {
        let v = x[(first + r) * channels + c];
        if v > best {
            best = v;
            best_row = r;
        }
    }
    let at = (first + best_row) * channels + c;
    dx[at] = dx[at] + d_out[i];
}
