// SPDX-License-Identifier: MIT OR Apache-2.0
// adam_step: one AdamW update of one tensor, element by element, in f32 (the twin computes in f64):
// m = b1 m + (1 - b1) g, v = b2 v + (1 - b2) g^2, x -= lr (m / c1 / (sqrt(v / c2) + eps) + wd x). The
// scalars come from the host, each computed there in f64 (1 - b1 and 1 - b2 too, so they are not rounded twice).
// One invocation per element, the workgroup grid linearised over a 2-D dispatch.
// Bindings: 0 params (uniform) | 1 grad (read) | 2 value (read_write) | 3 m (read_write) | 4 v (read_write).
// CPU twin: src/cpu/adam_step.rs

struct AdamStepParams {
    lr: f32,
    beta1: f32,
    one_minus_beta1: f32,
    beta2: f32,
    one_minus_beta2: f32,
    eps: f32,
    weight_decay: f32,
    c1: f32,
    c2: f32,
    len: u32,
    _pad0: u32,
    _pad1: u32,
}

const WG_SIZE: u32 = 64u;

@group(0) @binding(0) var<uniform> params: AdamStepParams;
@group(0) @binding(1) var<storage, read> grad: array<f32>;
@group(0) @binding(2) var<storage, read_write> value: array<f32>;
@group(0) @binding(3) var<storage, read_write> m: array<f32>;
@group(0) @binding(4) var<storage, read_write> v: array<f32>;

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
    let g = grad[i];
    let m_new = params.beta1 * m[i] + params.one_minus_beta1 * g;
    let v_new = params.beta2 * v[i] + params.one_minus_beta2 * g * g;
    m[i] = m_new;
    v[i] = v_new;
    let x = value[i];
    let update = (m_new / params.c1) / (sqrt(v_new / params.c2) + params.eps) + params.weight_decay * x;
    value[i] = x - params.lr * update;
}
