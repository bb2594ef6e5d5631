// SPDX-License-Identifier: MIT OR Apache-2.0
// dense_weight_grad: the weight (and optionally bias) gradient of one per-row input slice of a dense layer,
// added to what the gradient buffers hold. `dz` is the gradient w.r.t. the layer's pre-activation
// (rows x out_dim, ReLU's mask applied by relu_backward; for a slice shared by a group of rows, the group sums
// of group_row_sums). Invocation (o, c) < (out_dim, width) adds sum_r dz[r, o] * x[r, c] to
// weight_grad[o, offset + c]; with `bias` set, invocation out_dim * width + o adds sum_r dz[r, o] to
// bias_grad[o]. Each element is its starting value plus the terms added one by one in increasing r, the
// twin's order. One invocation per element: no two touch the same one.
// Bindings: 0 params (uniform) | 1 dz (read) | 2 x (read, rows x width)
//           | 3 weight_grad (read_write, out_dim x in_dim) | 4 bias_grad (read_write, out_dim; unused without bias).
// CPU twin: src/cpu/dense_weight_grad.rs

struct DenseWeightGradParams {
    rows: u32,
    out_dim: u32,
    in_dim: u32,
    width: u32,
    offset: u32,
    bias: u32,
    _pad0: u32,
    _pad1: u32,
}

const WG_SIZE: u32 = 64u;

@group(0) @binding(0) var<uniform> params: DenseWeightGradParams;
@group(0) @binding(1) var<storage, read> dz: array<f32>;
@group(0) @binding(2) var<storage, read> x: array<f32>;
@group(0) @binding(3) var<storage, read_write> weight_grad: array<f32>;
@group(0) @binding(4) var<storage, read_write> bias_grad: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = (wid.x + wid.y * nwg.x) * WG_SIZE + lid;
    let out_dim = params.out_dim;
    let width = params.width;
    let weights = out_dim * width;
    if i >= weights {
        let o = i - weights;
        if params.bias == 0u || o >= out_dim {
            return;
        }
        var acc = bias_grad[o];
        for (var r = 0u; r < params.rows; r++) {
            acc = acc + dz[r * out_dim + o];
        }
        bias_grad[o] = acc;
        return;
    }
    let o = i / width;
    let c = i % width;
    let at = o * params.in_dim + params.offset + c;
    var acc = weight_grad[at];
    for (var r = 0u; r < params.rows; r++) {
        acc = acc + dz[r * out_dim + o] * x[r * width + c];
    }
    weight_grad[at] = acc;
}
