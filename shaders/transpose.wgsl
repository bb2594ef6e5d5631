// SPDX-License-Identifier: MIT OR Apache-2.0
// transpose: out (cols x rows) = x (rows x cols) transposed, out[c * rows + r] = x[r * cols + c]. The trainer keeps
// each weight as the optimiser updates it (out x in, PyTorch layout) and refreshes the forward pass's transposed
// copy (in x out) after every step. One invocation per output value; consecutive invocations write consecutive
// values.
// Bindings: 0 params (uniform) | 1 x (read) | 2 out (read_write).
// CPU twin: src/cpu/transpose.rs

struct TransposeParams {
    rows: u32,
    cols: u32,
    _pad0: u32,
    _pad1: u32,
}

const WG_SIZE: u32 = 64u;

@group(0) @binding(0) var<uniform> params: TransposeParams;
@group(0) @binding(1) var<storage, read> x: array<f32>;
@group(0) @binding(2) var<storage, read_write> out: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = (wid.x + wid.y * nwg.x) * WG_SIZE + lid;
    if i >= params.rows * params.cols {
        return;
    }
    let c = i / params.rows;
    let r = i % params.rows;
    out[i] = x[r * params.cols + c];
}
