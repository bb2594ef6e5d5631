// SPDX-License-Identifier: MIT OR Apache-2.0
// icp_normal_equations: one point-to-plane ICP iteration's normal equations, reduced in a fixed order.
// Stage 0, one invocation per used source point i (point source[i * stride]): m = R p + t (params rows
//   [R | t]), the nearest target point q within max_d2 by (d2, index) in the 3 x 3 x 3 cells around m's cell of
//   the target's sorted cell table (cells >= the distance wide), and the pair's 28 terms (J J^T upper triangle
//   row by row, -J r, count 1) with n the target normal, J = [m x n, n], r = n . (m - q); zeros without a pair.
//   Each workgroup sums its 64 lanes in a tree (lane l < s adds lane l + s; s = 32 .. 1) into partial w at
//   sums[28 * (1 + w)].
// Stage 1, one workgroup: lane l sums partials l, l + 64, .. in order from zero, the same tree, total at
//   sums[0..28].
// Every product is fenced (no FMA contraction), sums run in the order written: the CPU twin's f32 operations
// exactly. d2 = dx*dx + dy*dy + dz*dz left to right.
// Bindings: 0 params (uniform) | 1 source (read, n x 3), 2 points (read, target m x 3), 3 normals (read, m x
//           3), 4 grid (read, i32 x 8: box, invalid, cells), 5 keys (read, sorted), 6 starts (read),
//           7 run_keys (read) | 8 sums (read_write, 28 x (1 + partials)).
// CPU twin: src/cpu/icp_normal_equations.rs

struct IcpNormalEquationsParams {
    row0: vec4<f32>,
    row1: vec4<f32>,
    row2: vec4<f32>,
    stage: u32,
    used: u32,
    stride: u32,
    partials: u32,
    inv_cell: f32,
    max_d2: f32,
    zero: u32,
    _pad0: u32,
}

const WG_SIZE: u32 = 64u;
const TERMS: u32 = 28u;
const NONE: u32 = 0xffffffffu;
const CELL_LIMIT: f32 = 1073741824.0;
const INF_BITS: u32 = 0x7f800000u;

@group(0) @binding(0) var<uniform> params: IcpNormalEquationsParams;
@group(0) @binding(1) var<storage, read> source: array<f32>;
@group(0) @binding(2) var<storage, read> points: array<f32>;
@group(0) @binding(3) var<storage, read> normals: array<f32>;
@group(0) @binding(4) var<storage, read> grid: array<i32>;
@group(0) @binding(5) var<storage, read> keys: array<vec4<u32>>;
@group(0) @binding(6) var<storage, read> starts: array<u32>;
@group(0) @binding(7) var<storage, read> run_keys: array<vec2<u32>>;
@group(0) @binding(8) var<storage, read_write> sums: array<f32>;

var<workgroup> lanes: array<f32, 1792>;
var<private> terms: array<f32, 28>;

// x, rounded on its own: XOR with a runtime zero hides it from FMA contraction.
fn fence(x: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(x) ^ params.zero);
}

fn target_point(i: u32) -> vec3<f32> {
    return vec3<f32>(points[i * 3u], points[i * 3u + 1u], points[i * 3u + 2u]);
}

fn target_normal(i: u32) -> vec3<f32> {
    return vec3<f32>(normals[i * 3u], normals[i * 3u + 1u], normals[i * 3u + 2u]);
}

fn moved(r: vec4<f32>, p: vec3<f32>) -> f32 {
    return ((fence(r.x * p.x) + fence(r.y * p.y)) + fence(r.z * p.z)) + r.w;
}

// #include distance_squared

// #include run_keys

// The nearest target point to m within max_d2 (ties to the lower index), or NONE.
fn nearest(m: vec3<f32>) -> u32 {
    let fl = floor(m * params.inv_cell);
    if !(abs(fl.x) < CELL_LIMIT && abs(fl.y) < CELL_LIMIT && abs(fl.z) < CELL_LIMIT) {
        return NONE;
    }
    let lo = vec3<i32>(grid[0], grid[1], grid[2]);
    let dims = vec3<i32>(grid[3], grid[4], grid[5]) - lo + vec3<i32>(1);
    let oq = vec3<i32>(fl) - lo;
    var inf_bits = INF_BITS;
    var best_d = bitcast<f32>(inf_bits);
    var best_i = NONE;
    for (var dz = -1; dz <= 1; dz++) {
        for (var dy = -1; dy <= 1; dy++) {
            for (var dx = -1; dx <= 1; dx++) {
                let o = oq + vec3<i32>(dx, dy, dz);
                if any(o < vec3<i32>(0)) || any(o >= dims) {
                    continue;
                }
                let c = vec3<u32>(o);
                let s = find(vec2<u32>((c.x << 10u) | (c.y >> 11u), (c.y << 21u) | c.z));
                if s == NONE {
                    continue;
                }
                for (var e = starts[s]; e < starts[s + 1u]; e++) {
                    let j = keys[e].z;
                    let d2 = distance_squared(target_point(j), m);
                    if d2 <= params.max_d2 && (d2 < best_d || (d2 == best_d && j < best_i)) {
                        best_d = d2;
                        best_i = j;
                    }
                }
            }
        }
    }
    return best_i;
}

// This lane's pair terms for used source point i (zeros without a pair).
fn pair_terms(i: u32) {
    for (var t = 0u; t < TERMS; t++) {
        terms[t] = 0.0;
    }
    if i >= params.used {
        return;
    }
    let at = i * params.stride * 3u;
    let p = vec3<f32>(source[at], source[at + 1u], source[at + 2u]);
    let m = vec3<f32>(moved(params.row0, p), moved(params.row1, p), moved(params.row2, p));
    let j = nearest(m);
    if j == NONE {
        return;
    }
    let q = target_point(j);
    let n = target_normal(j);
    let d = m - q;
    let r = (fence(n.x * d.x) + fence(n.y * d.y)) + fence(n.z * d.z);
    var jac = array<f32, 6>(
        fence(m.y * n.z) - fence(m.z * n.y),
        fence(m.z * n.x) - fence(m.x * n.z),
        fence(m.x * n.y) - fence(m.y * n.x),
        n.x,
        n.y,
        n.z,
    );
    var k = 0u;
    for (var a = 0u; a < 6u; a++) {
        for (var b = a; b < 6u; b++) {
            terms[k] = fence(jac[a] * jac[b]);
            k++;
        }
    }
    for (var a = 0u; a < 6u; a++) {
        terms[21u + a] = -fence(jac[a] * r);
    }
    terms[27] = 1.0;
}

// Sums the lanes' terms in the fixed tree and writes lane 0's at sums[base..base + 28].
fn reduce(lid: u32, base: u32, write: bool) {
    for (var t = 0u; t < TERMS; t++) {
        lanes[t * WG_SIZE + lid] = terms[t];
    }
    workgroupBarrier();
    for (var s = WG_SIZE / 2u; s > 0u; s >>= 1u) {
        if lid < s {
            for (var t = 0u; t < TERMS; t++) {
                lanes[t * WG_SIZE + lid] = lanes[t * WG_SIZE + lid] + lanes[t * WG_SIZE + lid + s];
            }
        }
        workgroupBarrier();
    }
    if write && lid < TERMS {
        sums[base + lid] = lanes[lid * WG_SIZE];
    }
}

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let w = wid.x + wid.y * nwg.x;
    if params.stage == 0u {
        pair_terms(w * WG_SIZE + lid);
        reduce(lid, TERMS * (1u + w), w < params.partials);
    } else {
        for (var t = 0u; t < TERMS; t++) {
            terms[t] = 0.0;
        }
        for (var p = lid; p < params.partials; p += WG_SIZE) {
            for (var t = 0u; t < TERMS; t++) {
                terms[t] = terms[t] + sums[TERMS * (1u + p) + t];
            }
        }
        reduce(lid, 0u, w == 0u);
    }
}
