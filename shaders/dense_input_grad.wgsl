// SPDX-License-Identifier: MIT OR Apache-2.0
// dense_input_grad: the gradient w.r.t. one per-row input slice of a dense layer, added to what dx holds. `dz`
// is the gradient w.r.t. the layer's pre-activation (rows x out_dim, ReLU's mask applied by relu_backward; for
// a slice shared by a group of rows, the group sums of group_row_sums) and `weight` the layer's weight
// (out_dim x in_dim, PyTorch layout). Invocation (r, c) < (rows, width) adds sum_o dz[r, o] *
// weight[o, offset + c] to dx[r, c]: its starting value plus the terms added one by one in increasing o, the
// twin's order.
// Bindings: 0 params (uniform) | 1 dz (read) | 2 weight (read) | 3 dx (read_write, rows x width).
// CPU twin: src/cpu/dense_input_grad.rs

struct DenseInputGradParams {
    rows: u32,
    out_dim: u32,
    in_dim: u32,
    width: u32,
    offset: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
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
    if i >= params.rows * width {
        return;
    }
    let r = i / width;
    let column = params.offset + i % width;
    var acc = dx[i];
    for (var o = 0u; o < out_dim; o++) {
        acc = acc + dz[r * out_dim + o] * weight[o * params.in_dim + column];
    }
    dx[i] = acc;
}
