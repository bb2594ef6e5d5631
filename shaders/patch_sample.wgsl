// SPDX-License-Identifier: MIT OR Apache-2.0
// patch_sample: radius search on a uniform grid's sorted cell table (cells at least `radius` wide), one
// invocation per (keypoint slot, cell of its 4 x 4 x 4 search block). A candidate is a point j != keypoint with
// d2 <= r2, d2 = dx*dx + dy*dy + dz*dz with every product fenced (no FMA contraction) and summed left to
// right, r2 = radius * radius from the host: the CPU twin's f32 operations exactly.
// Stage 0 (count): out[slot * 64 + cell] = the cell's candidates; 0xffffffff in cell 0 when the block spans
//   more than 4 cells on an axis (an error the host reports).
// Stage 1 (write): each candidate as a sort key [slot, hash, j, 0] (4 words) at out[4 * (offsets[slot * 64 +
//   cell] + t)], t counting the cell's candidates; hash = the twin's candidate_hash (lowbias32 mixes).
// Stage 2 (pad): the keys pad_from..pad_to get the padding key [max, max, max, 0] (then bitonic_sort).
// Search block per axis: floor((q -+ (radius + margin)) * inv_cell), margin = radius / 256 + (|q| + radius) *
// 2^-20, products fenced as in the twin.
// Bindings: 0 params (uniform) | 1 points (read, n x 3), 2 keypoints (read, cloud indices), 3 grid (read, i32 x 8:
//           box, invalid, cells), 4 keys (read, sorted), 5 starts (read), 6 run_keys (read), 7 offsets (read,
//           stage 1) | 8 out (read_write).
// CPU twin: src/cpu/patch_sample.rs

struct PatchSampleParams {
    stage: u32,
    keypoints: u32,
    inv_cell: f32,
    radius: f32,
    r2: f32,
    key0: u32,
    key1: u32,
    zero: u32,
    pad_from: u32,
    pad_to: u32,
    _pad0: u32,
    _pad1: u32,
}

const WG_SIZE: u32 = 64u;
const BLOCK: u32 = 4u;
const BLOCK_CELLS: u32 = 64u;
const NONE: u32 = 0xffffffffu;
const MARGIN_REL: f32 = 0.00390625;
const MARGIN_ULP: f32 = 0.00000095367431640625;
const CELL_LIMIT: f32 = 1073741824.0;

@group(0) @binding(0) var<uniform> params: PatchSampleParams;
@group(0) @binding(1) var<storage, read> points: array<f32>;
@group(0) @binding(2) var<storage, read> keypoints: array<u32>;
@group(0) @binding(3) var<storage, read> grid: array<i32>;
@group(0) @binding(4) var<storage, read> keys: array<vec4<u32>>;
@group(0) @binding(5) var<storage, read> starts: array<u32>;
@group(0) @binding(6) var<storage, read> run_keys: array<vec2<u32>>;
@group(0) @binding(7) var<storage, read> offsets: array<u32>;
@group(0) @binding(8) var<storage, read_write> out: array<u32>;

// #include point

// x, rounded on its own: XOR with a runtime zero hides it from FMA contraction.
fn fence(x: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(x) ^ params.zero);
}

// #include distance_squared

fn mix32(v: u32) -> u32 {
    var x = v;
    x ^= x >> 16u;
    x *= 0x7feb352du;
    x ^= x >> 15u;
    x *= 0x846ca68bu;
    x ^= x >> 16u;
    return x;
}

// #include run_keys

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let t = (wid.x + wid.y * nwg.x) * WG_SIZE + lid;
    if params.stage == 2u {
        let e = params.pad_from + t;
        if e < params.pad_to {
            out[e * 4u] = NONE;
            out[e * 4u + 1u] = NONE;
            out[e * 4u + 2u] = NONE;
            out[e * 4u + 3u] = 0u;
        }
        return;
    }
    let slot = t / BLOCK_CELLS;
    let c = t % BLOCK_CELLS;
    if slot >= params.keypoints {
        return;
    }
    let k = keypoints[slot];
    let q = point(k);
    let r = params.radius;
    var lo: vec3<i32>;
    var hi: vec3<i32>;
    var bad = false;
    for (var a = 0u; a < 3u; a++) {
        let margin = fence(r * MARGIN_REL) + fence((abs(q[a]) + r) * MARGIN_ULP);
        let l = floor(fence(((q[a] - r) - margin) * params.inv_cell));
        let h = floor(fence(((q[a] + r) + margin) * params.inv_cell));
        if !(abs(l) < CELL_LIMIT && abs(h) < CELL_LIMIT) || h - l >= f32(BLOCK) {
            bad = true;
        } else {
            lo[a] = i32(l);
            hi[a] = i32(h);
        }
    }
    if bad {
        if params.stage == 0u {
            out[t] = select(0u, NONE, c == 0u);
        }
        return;
    }
    let cell = lo + vec3<i32>(i32(c % BLOCK), i32(c / BLOCK % BLOCK), i32(c / (BLOCK * BLOCK)));
    let glo = vec3<i32>(grid[0], grid[1], grid[2]);
    let ghi = vec3<i32>(grid[3], grid[4], grid[5]);
    var count = 0u;
    if all(cell <= hi) && all(cell >= glo) && all(cell <= ghi) {
        let m = vec3<u32>(cell - glo);
        let s = find(vec2<u32>((m.x << 10u) | (m.y >> 11u), (m.y << 21u) | m.z));
        if s != NONE {
            let stream = mix32(params.key0 ^ mix32(params.key1 ^ k));
            var base = 0u;
            if params.stage == 1u {
                base = offsets[t];
            }
            for (var e = starts[s]; e < starts[s + 1u]; e++) {
                let j = keys[e].z;
                if j != k && distance_squared(point(j), q) <= params.r2 {
                    if params.stage == 1u {
                        let w = (base + count) * 4u;
                        out[w] = slot;
                        out[w + 1u] = mix32(stream ^ mix32(j + 0x9e3779b9u));
                        out[w + 2u] = j;
                        out[w + 3u] = 0u;
                    }
                    count += 1u;
                }
            }
        }
    }
    if params.stage == 0u {
        out[t] = count;
    }
}
