// SPDX-License-Identifier: MIT OR Apache-2.0
// chamfer_nearest: the first half of the reconstruction loss. For each of `patches` patch pairs, x (patches * n x
// dim, the input points) and y (patches * m x dim, the reconstruction): the nearest y of every x row, then the
// nearest x of every y row, by brute force over squared distances (ties to the lowest index). nearest and distance
// are patches * (n + m), in that order per patch: indices local to the patch, and Euclidean distances. One
// invocation per (patch, row of x or y); consecutive invocations take consecutive rows.
// Bindings: 0 params (uniform) | 1 x (read) | 2 y (read) | 3 nearest (read_write, u32) | 4 distance (read_write).
// CPU twin: src/cpu/chamfer_nearest.rs (in f64, as the trainer's loss)

struct ChamferNearestParams {
    patches: u32,
    n: u32,
    m: u32,
    dim: u32,
}

const WG_SIZE: u32 = 64u;

@group(0) @binding(0) var<uniform> params: ChamferNearestParams;
@group(0) @binding(1) var<storage, read> x: array<f32>;
@group(0) @binding(2) var<storage, read> y: array<f32>;
@group(0) @binding(3) var<storage, read_write> nearest: array<u32>;
@group(0) @binding(4) var<storage, read_write> distance: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = (wid.x + wid.y * nwg.x) * WG_SIZE + lid;
    let per_patch = params.n + params.m;
    if i >= params.patches * per_patch {
        return;
    }
    let p = i / per_patch;
    let r = i % per_patch;
    let dim = params.dim;
    // The row searched for, and the set searched: the patch's y rows for an x row, its x rows for a y row.
    var row_start: u32;
    var set_start: u32;
    var set_len: u32;
    var from_x = r < params.n;
    if from_x {
        row_start = (p * params.n + r) * dim;
        set_start = p * params.m * dim;
        set_len = params.m;
    } else {
        row_start = (p * params.m + r - params.n) * dim;
        set_start = p * params.n * dim;
        set_len = params.n;
    }
    var best = 0.0;
    var best_k = 0u;
    for (var k = 0u; k < set_len; k++) {
        var d = 0.0;
        for (var c = 0u; c < dim; c++) {
            var t: f32;
            if from_x {
                t = x[row_start + c] - y[set_start + k * dim + c];
            } else {
                t = x[set_start + k * dim + c] - y[row_start + c];
            }
            d = d + t * t;
        }
        if k == 0u || d < best {
            best = d;
            best_k = k;
        }
    }
    nearest[i] = best_k;
    distance[i] = sqrt(best);
}
