// SPDX-License-Identifier: MIT OR Apache-2.0
// voxel_average: per run s of equal voxel keys (segments), the averaged point p0 + (sum of (p - p0)) / count
// over the run's points in sorted order (p0 its first point), and, when has_normals, the renormalised sum of
// their normals (zero when the sum is zero). One invocation per run, sequential sums: deterministic.
// grid[7] holds the number of runs (copied from prefix_scan's total).
// Bindings: 0 params (uniform) | 1 points (read, n x 3), 2 normals (read, n x 3 or a placeholder),
//           3 keys (read, sorted), 4 starts (read, runs + 1), 5 grid (read, u32 x 8) |
//           6 out_points (runs x 3), 7 out_normals (runs x 3 or a placeholder).
// CPU twin: src/cpu/voxel_average.rs

struct VoxelAverageParams {
    n: u32,
    has_normals: u32,
    _pad0: u32,
    _pad1: u32,
}

const WG_SIZE: u32 = 64u;

@group(0) @binding(0) var<uniform> params: VoxelAverageParams;
@group(0) @binding(1) var<storage, read> points: array<f32>;
@group(0) @binding(2) var<storage, read> normals: array<f32>;
@group(0) @binding(3) var<storage, read> keys: array<vec4<u32>>;
@group(0) @binding(4) var<storage, read> starts: array<u32>;
@group(0) @binding(5) var<storage, read> grid: array<u32>;
@group(0) @binding(6) var<storage, read_write> out_points: array<f32>;
@group(0) @binding(7) var<storage, read_write> out_normals: array<f32>;

// #include point

fn normal(i: u32) -> vec3<f32> {
    return vec3<f32>(normals[i * 3u], normals[i * 3u + 1u], normals[i * 3u + 2u]);
}

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let s = (wid.x + wid.y * nwg.x) * WG_SIZE + lid;
    if s >= grid[7] {
        return;
    }
    let start = starts[s];
    let end = starts[s + 1u];
    let p0 = point(keys[start].z);
    var sum = vec3<f32>(0.0);
    for (var e = start + 1u; e < end; e++) {
        sum += point(keys[e].z) - p0;
    }
    let mean = p0 + sum / f32(end - start);
    out_points[s * 3u] = mean.x;
    out_points[s * 3u + 1u] = mean.y;
    out_points[s * 3u + 2u] = mean.z;
    if params.has_normals == 1u {
        var ns = vec3<f32>(0.0);
        for (var e = start; e < end; e++) {
            ns += normal(keys[e].z);
        }
        let len = sqrt(ns.x * ns.x + ns.y * ns.y + ns.z * ns.z);
        var unit = vec3<f32>(0.0);
        if len > 0.0 {
            unit = ns / len;
        }
        out_normals[s * 3u] = unit.x;
        out_normals[s * 3u + 1u] = unit.y;
        out_normals[s * 3u + 2u] = unit.z;
    }
}
