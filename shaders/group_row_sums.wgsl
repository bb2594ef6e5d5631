// SPDX-License-Identifier: MIT OR Apache-2.0
// group_row_sums: the rows of x (rows x width) summed over each group of rows_per_group consecutive rows, each
// sum from zero in row order (the twin's order): sums is groups x width, overwritten. The backward pass of an
// input shared by a group of rows sums the group's output gradients first. One invocation per (group, column);
// consecutive invocations read consecutive columns of a row.
// Bindings: 0 params (uniform) | 1 x (read) | 2 sums (read_write, groups x width).
// CPU twin: src/cpu/group_row_sums.rs

struct GroupRowSumsParams {
    groups: u32,
    rows_per_group: u32,
    width: u32,
    _pad: u32,
}

const WG_SIZE: u32 = 64u;

@group(0) @binding(0) var<uniform> params: GroupRowSumsParams;
@group(0) @binding(1) var<storage, read> x: array<f32>;
@group(0) @binding(2) var<storage, read_write> sums: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = (wid.x + wid.y * nwg.x) * WG_SIZE + lid;
    let width = params.width;
    if i >= params.groups * width {
        return;
    }
    let g = i / width;
    let c = i % width;
    let first = g * params.rows_per_group;
    var acc = 0.0;
    for (var r = first; r < first + params.rows_per_group; r++) {
        acc = acc + x[r * width + c];
    }
    sums[i] = acc;
}
