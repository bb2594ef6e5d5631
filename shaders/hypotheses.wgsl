// SPDX-License-Identifier: MIT OR Apache-2.0
// hypotheses: one rigid pose per correspondence from its rotation R (target_from_source, row-major, from
// rotation_head): R, t = p_target - R p_source. One invocation per correspondence.
// Bindings: 0 params (uniform) | 1 rotations (9 per row), 2 source_points, 3 target_points (xyz per
//           row) (read) | 4 out (12 per row: R row-major, then t; written).
// CPU twin: src/cpu/hypotheses.rs

struct HypothesesParams {
    rows: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

const WG_SIZE: u32 = 64u;

@group(0) @binding(0) var<uniform> params: HypothesesParams;
@group(0) @binding(1) var<storage, read> rotations: array<f32>;
@group(0) @binding(2) var<storage, read> source_points: array<f32>;
@group(0) @binding(3) var<storage, read> target_points: array<f32>;
@group(0) @binding(4) var<storage, read_write> out: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = (wid.x + wid.y * nwg.x) * WG_SIZE + lid;
    if i >= params.rows {
        return;
    }
    var r: array<f32, 9>;
    for (var e = 0u; e < 9u; e++) {
        r[e] = rotations[i * 9u + e];
    }
    let ps = vec3<f32>(source_points[i * 3u], source_points[i * 3u + 1u], source_points[i * 3u + 2u]);
    let pt = vec3<f32>(target_points[i * 3u], target_points[i * 3u + 1u], target_points[i * 3u + 2u]);
    for (var e = 0u; e < 9u; e++) {
        out[i * 12u + e] = r[e];
    }
    for (var a = 0u; a < 3u; a++) {
        let rp = r[a * 3u] * ps.x + r[a * 3u + 1u] * ps.y + r[a * 3u + 2u] * ps.z;
        out[i * 12u + 9u + a] = pt[a] - rp;
    }
}
