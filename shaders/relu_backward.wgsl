// SPDX-License-Identifier: MIT OR Apache-2.0
// relu_backward: a gradient masked by ReLU's derivative, dz[i] = out[i] > 0 ? d_out[i] : 0 (0 at exactly zero,
// where the output is clamped). One invocation per element, the workgroup grid linearised over a 2-D dispatch.
// Bindings: 0 params (uniform) | 1 out (read: the layer's post-ReLU output) | 2 d_out (read) | 3 dz (read_write).
// CPU twin: src/cpu/relu_backward.rs

struct ReluBackwardParams {
    len: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

const WG_SIZE: u32 = 64u;

@group(0) @binding(0) var<uniform> params: ReluBackwardParams;
@group(0) @binding(1) var<storage, read> out: array<f32>;
@group(0) @binding(2) var<storage, read> d_out: array<f32>;
@group(0) @binding(3) var<storage, read_write> dz: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = (wid.x + wid.y * nwg.x) * WG_SIZE + lid;
    if i >= params.len {
        return;
    }
    dz[i] = select(0.0, d_out[i], out[i] > 0.0);
}
