// SPDX-License-Identifier: MIT OR Apache-2.0
// unit_rows: each row of `input` (rows x width) scaled to unit length and times `weight`, written into
// columns column..column + width of `out` (rows x out_width): one block of the side-by-side matching rows of
// several codeword sets. The length is the square root of the squares summed in order, at least 1e-12; each
// value is multiplied by weight / length. One invocation per row.
// Bindings: 0 params (uniform) | 1 input (read) | 2 out (read_write; other columns untouched).
// CPU twin: src/cpu/unit_rows.rs

struct UnitRowsParams {
    rows: u32,
    width: u32,
    out_width: u32,
    column: u32,
    weight: f32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

const WG_SIZE: u32 = 64u;

@group(0) @binding(0) var<uniform> params: UnitRowsParams;
@group(0) @binding(1) var<storage, read> input: array<f32>;
@group(0) @binding(2) var<storage, read_write> out: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let row = (wid.x + wid.y * nwg.x) * WG_SIZE + lid;
    if row >= params.rows {
        return;
    }
    let first = row * params.width;
    var sum = 0.0;
    for (var d = 0u; d < params.width; d++) {
        let x = input[first + d];
        sum += x * x;
    }
    let scale = params.weight / max(sqrt(sum), 1e-12);
    let to = row * params.out_width + params.column;
    for (var d = 0u; d < params.width; d++) {
        out[to + d] = input[first + d] * scale;
    }
}
