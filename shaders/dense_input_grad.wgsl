// SPDX-License-Identifier: MIT OR Apache-2.0
// dense_input_grad: the gradient w.r.t. one input slice of a dense layer, added to what dx holds. `dz` is the
// gradient w.r.t. the layer's pre-activation (rows x out_dim, ReLU's mask applied) and `weight` the layer's
// weight (out_dim x in_dim, PyTorch layout); the slice has one row per group of rows_per_group consecutive
// output rows (1 for a per-row input). Invocation (g, c) < (rows / rows_per_group, width) adds
// sum_o dz_g[g, o] * weight[o, offset + c] to dx[g, c], where dz_g sums dz over the group's rows from zero in
// row order: its starting value plus the terms added one by one in increasing o, the twin's order. The
// per-group path recomputes the group sums in every invocation (correct; slow for large groups).
// Bindings: 0 params (uniform) | 1 dz (read) | 2 weight (read) | 3 dx (read_write, groups x width).
// CPU twin: src/cpu/dense_input_grad.rs

struct DenseInputGradParams {
    rows: u32,
    rows_per_group: u32,
    out_dim: u32,
    in_dim: u32,
    width: u32,
    offset: u32,
    _pad0: u32,
    _pad1: u32,
}

const WG_SIZE: u32 = 64u;

@group(0) @binding(0) var<uniform> params: DenseInputGradParams;
@group(0) @binding(1) var<storage, read> dz: array<f32>;
@group(0) @binding(2) var<storage, read> weight: array<f32>;
@group(0) @binding(3) var<storage, read_write> dx: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = (wid.x + wid.y * nwg.x) * WG_SIZE + lid;
    let out_dim = params.out_dim;
    let width = params.width;
    let rpg = max(params.rows_per_group, 1u);
    if i >= (params.rows / rpg) * width {
        return;
    }
    let g = i / width;
    let c = i % width;
    let column = params.offset + c;
    var acc = dx[i];
    for (var o = 0u; o < out_dim; o++) {
        var term = 0.0;
        if rpg == 1u {
            term = dz[g * out_dim + o];
        } else {
            for (var r = g * rpg; r < (g + 1u) * rpg; r++) {
                term = term + dz[r * out_dim + o];
            }
        }
        acc = acc + term * weight[o * params.in_dim + column];
    }
    dx[i] = acc;
}
