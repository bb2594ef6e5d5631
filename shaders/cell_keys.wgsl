// SPDX-License-Identifier: MIT OR Apache-2.0
// cell_keys: per point, the sort key of its cell floor(p * inv_cell) on the grid whose box is grid[0..6]
// (from cell_bounds): offsets from the box's minimum corner, 21 bits per axis, packed x | y | z into
// (hi, lo), then the point index: vec4(hi, lo, index, 0). Elements n..padded get the padding key
// (0xffffffff, 0xffffffff, 0xffffffff, 0), which sorts last. status (atomic max): 2 when the box spans more
// than 2^21 cells on an axis, 1 when a point's cell is invalid or outside the box.
// Bindings: 0 params (uniform) | 1 points (read, n x 3), 2 grid (read, i32 x 8) | 3 keys (padded),
//           4 status (read_write).
// CPU twin: src/cpu/cell_keys.rs

struct CellKeysParams {
    n: u32,
    padded: u32,
    inv_cell: f32,
    _pad: u32,
}

const WG_SIZE: u32 = 256u;
const LIMIT: f32 = 1073741824.0;
const MAX_CELLS: u32 = 2097152u;
const PAD: u32 = 0xffffffffu;

@group(0) @binding(0) var<uniform> params: CellKeysParams;
@group(0) @binding(1) var<storage, read> points: array<f32>;
@group(0) @binding(2) var<storage, read> grid: array<i32>;
@group(0) @binding(3) var<storage, read_write> keys: array<vec4<u32>>;
@group(0) @binding(4) var<storage, read_write> status: array<atomic<u32>>;

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = (wid.x + wid.y * nwg.x) * WG_SIZE + lid;
    if i >= params.padded {
        return;
    }
    if i >= params.n {
        keys[i] = vec4<u32>(PAD, PAD, PAD, 0u);
        return;
    }
    let lo = bitcast<vec3<u32>>(vec3<i32>(grid[0], grid[1], grid[2]));
    let hi = bitcast<vec3<u32>>(vec3<i32>(grid[3], grid[4], grid[5]));
    let span = hi - lo;
    if any(span >= vec3<u32>(MAX_CELLS)) {
        atomicMax(&status[0], 2u);
    }
    var c = vec3<u32>(0u);
    for (var a = 0u; a < 3u; a++) {
        let v = floor(points[i * 3u + a] * params.inv_cell);
        if !(abs(v) < LIMIT) {
            atomicMax(&status[0], 1u);
        } else {
            c[a] = bitcast<u32>(i32(v));
        }
    }
    let o = c - lo;
    if any(o > span) {
        atomicMax(&status[0], 1u);
    }
    let m = o & vec3<u32>(MAX_CELLS - 1u);
    keys[i] = vec4<u32>((m.x << 10u) | (m.y >> 11u), (m.y << 21u) | m.z, i, 0u);
}
