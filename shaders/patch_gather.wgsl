// SPDX-License-Identifier: MIT OR Apache-2.0
// patch_gather: the rows of each kept patch in patch_features' layout. Row s of patch p takes the candidate of
// rank s mod count in the patch's run of the sorted candidate keys (table[p] = [keypoint, start, count, 0],
// count > 0); in centre mode (centers = 1) row p is the keypoint itself. Each row's cloud index, point and
// normal are written.
// Bindings: 0 params (uniform) | 1 points, 2 normals (read, n x 3), 3 sorted (read, candidate keys), 4 table
//           (read, per patch) | 5 out_index (rows), 6 out_points, 7 out_normals (rows x 3), written.
// CPU twin: src/cpu/patch_gather.rs

struct PatchGatherParams {
    rows: u32,
    points_per_patch: u32,
    centers: u32,
    _pad: u32,
}

const WG_SIZE: u32 = 64u;

@group(0) @binding(0) var<uniform> params: PatchGatherParams;
@group(0) @binding(1) var<storage, read> points: array<f32>;
@group(0) @binding(2) var<storage, read> normals: array<f32>;
@group(0) @binding(3) var<storage, read> sorted: array<vec4<u32>>;
@group(0) @binding(4) var<storage, read> table: array<vec4<u32>>;
@group(0) @binding(5) var<storage, read_write> out_index: array<u32>;
@group(0) @binding(6) var<storage, read_write> out_points: array<f32>;
@group(0) @binding(7) var<storage, read_write> out_normals: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let t = (wid.x + wid.y * nwg.x) * WG_SIZE + lid;
    if t >= params.rows {
        return;
    }
    var j: u32;
    if params.centers == 1u {
        j = table[t].x;
    } else {
        let n = params.points_per_patch;
        let e = table[t / n];
        j = sorted[e.y + (t % n) % max(e.z, 1u)].z;
    }
    out_index[t] = j;
    for (var a = 0u; a < 3u; a++) {
        out_points[t * 3u + a] = points[j * 3u + a];
        out_normals[t * 3u + a] = normals[j * 3u + a];
    }
}
