// SPDX-License-Identifier: MIT OR Apache-2.0
// farthest_point: one step of greedy farthest-point sampling, in two stages.
// Stage 0 (update): per point i, nearest[i] = min(nearest[i], d2(point i, chosen[step])) (nearest taken as
//   +inf at step 0), d2 = dx*dx + dy*dy + dz*dz with fenced products (no FMA contraction), summed left to right;
//   each workgroup's farthest point (largest nearest, lowest index on ties) into partials[workgroup].
// Stage 1 (pick): one workgroup reduces the `partials` entries; chosen[step + 1] = the farthest point.
// Distances are non-negative, so their bit patterns order as the floats do.
// Bindings: 0 params (uniform) | 1 points (read, n x 3) | 2 nearest (n), 3 partials (vec2: bits, index),
//           4 chosen (count), read_write.
// CPU twin: src/cpu/farthest_point.rs

struct FarthestPointParams {
    stage: u32,
    n: u32,
    partials: u32,
    step: u32,
    zero: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

const WG_SIZE: u32 = 256u;
const NONE: u32 = 0xffffffffu;
const INF_BITS: u32 = 0x7f800000u;

@group(0) @binding(0) var<uniform> params: FarthestPointParams;
@group(0) @binding(1) var<storage, read> points: array<f32>;
@group(0) @binding(2) var<storage, read_write> nearest: array<f32>;
@group(0) @binding(3) var<storage, read_write> partials: array<vec2<u32>>;
@group(0) @binding(4) var<storage, read_write> chosen: array<u32>;

var<workgroup> best_bits: array<u32, 256>;
var<workgroup> best_index: array<u32, 256>;

// #include point

fn fence(x: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(x) ^ params.zero);
}

// Whether (bits a, index i) is farther than (bits b, index j): larger distance, then lower index.
fn farther(a: u32, i: u32, b: u32, j: u32) -> bool {
    return a > b || (a == b && i < j);
}

fn reduce(lid: u32) {
    for (var s = WG_SIZE / 2u; s > 0u; s >>= 1u) {
        if lid < s && farther(best_bits[lid + s], best_index[lid + s], best_bits[lid], best_index[lid]) {
            best_bits[lid] = best_bits[lid + s];
            best_index[lid] = best_index[lid + s];
        }
        workgroupBarrier();
    }
}

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let w = wid.x + wid.y * nwg.x;
    var bits = 0u;
    var index = NONE;
    if params.stage == 0u {
        let i = w * WG_SIZE + lid;
        if i < params.n {
            let d = point(i) - point(chosen[params.step]);
            let d2 = (fence(d.x * d.x) + fence(d.y * d.y)) + fence(d.z * d.z);
            var previous = nearest[i];
            if params.step == 0u {
                previous = bitcast<f32>(INF_BITS + params.zero);
            }
            let m = min(previous, d2);
            nearest[i] = m;
            bits = bitcast<u32>(m);
            index = i;
        }
    } else {
        for (var t = lid; t < params.partials; t += WG_SIZE) {
            let p = partials[t];
            if farther(p.x, p.y, bits, index) {
                bits = p.x;
                index = p.y;
            }
        }
    }
    best_bits[lid] = bits;
    best_index[lid] = index;
    workgroupBarrier();
    reduce(lid);
    if lid == 0u {
        if params.stage == 0u {
            partials[w] = vec2<u32>(best_bits[0], best_index[0]);
        } else {
            chosen[params.step + 1u] = best_index[0];
        }
    }
}
