// SPDX-License-Identifier: MIT OR Apache-2.0
// bitonic_sort: one compare-exchange pass (k, j) of a bitonic sorting network over `padded` (a power of two)
// vec4<u32> keys, ascending by (x, y, z) = (key hi, key lo, index). One invocation per pair (i, i + j) with
// bit j of i clear; the pair is ascending when bit k of i is clear. The host runs k = 2, 4, .., padded and,
// for each, j = k / 2, .., 1. The keys are distinct but for identical padding, so the result is unique.
// Bindings: 0 params (uniform) | 1 keys (read_write, padded).
// CPU twin: src/cpu/bitonic_sort.rs

struct BitonicSortParams {
    padded: u32,
    k: u32,
    j: u32,
    _pad: u32,
}

const WG_SIZE: u32 = 256u;

@group(0) @binding(0) var<uniform> params: BitonicSortParams;
@group(0) @binding(1) var<storage, read_write> keys: array<vec4<u32>>;

fn less(a: vec4<u32>, b: vec4<u32>) -> bool {
    if a.x != b.x {
        return a.x < b.x;
    }
    if a.y != b.y {
        return a.y < b.y;
    }
    return a.z < b.z;
}

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let t = (wid.x + wid.y * nwg.x) * WG_SIZE + lid;
    if t >= params.padded / 2u {
        return;
    }
    let j = params.j;
    let i = ((t & ~(j - 1u)) << 1u) | (t & (j - 1u));
    let l = i + j;
    let a = keys[i];
    let b = keys[l];
    let ascending = (i & params.k) == 0u;
    if (ascending && less(b, a)) || (!ascending && less(a, b)) {
        keys[i] = b;
        keys[l] = a;
    }
}
