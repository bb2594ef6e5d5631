// SPDX-License-Identifier: MIT OR Apache-2.0
// grid_knn: per query point (queries[i], or point i when all_points is 1), its k <= 64 nearest points
// (itself included) ordered by (squared distance, index), from the sorted cell table of a uniform grid
// (cell_bounds, cell_keys, bitonic_sort, segments).
// Shells of cells at Chebyshev distance r = 0, 1, .. around the query's cell, clipped to the grid, are visited
// (each cell found by
// binary search in the run keys) until the k-th neighbour is nearer than r + min(f, 1 - f) cells less
// a slack (f: the query's position within its cell; slack = 1e-3 + 8 ulp of the largest cell coordinate), which nothing outside the visited block can beat.
// Squared distances dx*dx + dy*dy + dz*dz. Unused slots: index 0xffffffff, distance +inf.
// Bindings: 0 params (uniform) | 1 points (read, n x 3), 2 queries (read, point indices), 3 grid (read, i32 x 8:
//           box, invalid, cells), 4 keys (read, sorted), 5 starts (read, cells + 1), 6 run_keys (read, cells)
//           | 7 out_index, 8 out_d2 (read_write, queries x k).
// CPU twin: src/cpu/grid_knn.rs

struct GridKnnParams {
    queries: u32,
    k: u32,
    inv_cell: f32,
    all_points: u32,
}

const WG_SIZE: u32 = 64u;
const K_MAX: u32 = 64u;
const NONE: u32 = 0xffffffffu;
const INF_BITS: u32 = 0x7f800000u;

@group(0) @binding(0) var<uniform> params: GridKnnParams;
@group(0) @binding(1) var<storage, read> points: array<f32>;
@group(0) @binding(2) var<storage, read> queries: array<u32>;
@group(0) @binding(3) var<storage, read> grid: array<i32>;
@group(0) @binding(4) var<storage, read> keys: array<vec4<u32>>;
@group(0) @binding(5) var<storage, read> starts: array<u32>;
@group(0) @binding(6) var<storage, read> run_keys: array<vec2<u32>>;
@group(0) @binding(7) var<storage, read_write> out_index: array<u32>;
@group(0) @binding(8) var<storage, read_write> out_d2: array<f32>;

var<private> best_d: array<f32, 64>;
var<private> best_i: array<u32, 64>;
var<private> count: u32;

// #include point

fn before(d: f32, i: u32, e: f32, j: u32) -> bool {
    return d < e || (d == e && i < j);
}

// #include run_keys

fn visit(o: vec3<i32>, dims: vec3<i32>, q: vec3<f32>, k: u32) {
    if any(o < vec3<i32>(0)) || any(o >= dims) {
        return;
    }
    let m = vec3<u32>(o);
    let s = find(vec2<u32>((m.x << 10u) | (m.y >> 11u), (m.y << 21u) | m.z));
    if s == NONE {
        return;
    }
    for (var e = starts[s]; e < starts[s + 1u]; e++) {
        let j = keys[e].z;
        let d = point(j) - q;
        let d2 = d.x * d.x + d.y * d.y + d.z * d.z;
        if count == k && !before(d2, j, best_d[k - 1u], best_i[k - 1u]) {
            continue;
        }
        var pos = count;
        for (var p = 0u; p < count; p++) {
            if before(d2, j, best_d[p], best_i[p]) {
                pos = p;
                break;
            }
        }
        var t = min(count, k - 1u);
        while t > pos {
            best_d[t] = best_d[t - 1u];
            best_i[t] = best_i[t - 1u];
            t -= 1u;
        }
        best_d[pos] = d2;
        best_i[pos] = j;
        count = min(count + 1u, k);
    }
}

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = (wid.x + wid.y * nwg.x) * WG_SIZE + lid;
    if i >= params.queries {
        return;
    }
    let k = clamp(params.k, 1u, K_MAX);
    var qi = i;
    if params.all_points == 0u {
        qi = queries[i];
    }
    let q = point(qi);
    let lo = vec3<i32>(grid[0], grid[1], grid[2]);
    let dims = vec3<i32>(grid[3], grid[4], grid[5]) - lo + vec3<i32>(1);
    let u = q * params.inv_cell;
    let fl = floor(u);
    let oq = vec3<i32>(fl) - lo;
    let f = u - fl;
    let g = min(f, vec3<f32>(1.0) - f);
    let frac_gap = min(g.x, min(g.y, g.z));
    let hi = vec3<i32>(grid[3], grid[4], grid[5]);
    let extent = vec3<f32>(max(abs(lo), abs(hi) + vec3<i32>(1)));
    let slack = 1e-3 + 8.0 * 1.1920929e-7 * max(extent.x, max(extent.y, extent.z));
    let reach = max(oq, dims - vec3<i32>(1) - oq);
    let rmax = max(reach.x, max(reach.y, max(reach.z, 0)));
    count = 0u;
    for (var r = 0; r <= rmax; r++) {
        // The shell, clipped to the grid: full rows where |dy| or |dz| is r, else its two ends.
        let lo_d = max(vec3<i32>(-r), -oq);
        let hi_d = min(vec3<i32>(r), dims - vec3<i32>(1) - oq);
        for (var dz = lo_d.z; dz <= hi_d.z; dz++) {
            for (var dy = lo_d.y; dy <= hi_d.y; dy++) {
                if r == 0 || abs(dy) == r || abs(dz) == r {
                    for (var dx = lo_d.x; dx <= hi_d.x; dx++) {
                        visit(oq + vec3<i32>(dx, dy, dz), dims, q, k);
                    }
                } else {
                    if -r >= lo_d.x {
                        visit(oq + vec3<i32>(-r, dy, dz), dims, q, k);
                    }
                    if r <= hi_d.x {
                        visit(oq + vec3<i32>(r, dy, dz), dims, q, k);
                    }
                }
            }
        }
        if count == k && sqrt(best_d[k - 1u]) * params.inv_cell < f32(r) + frac_gap - slack {
            break;
        }
    }
    // A runtime value: a constant expression may not evaluate to infinity.
    var inf_bits = INF_BITS;
    for (var s = 0u; s < k; s++) {
        var idx = NONE;
        var d2 = bitcast<f32>(inf_bits);
        if s < count {
            idx = best_i[s];
            d2 = best_d[s];
        }
        out_index[i * k + s] = idx;
        out_d2[i * k + s] = d2;
    }
}
