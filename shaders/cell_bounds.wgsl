// SPDX-License-Identifier: MIT OR Apache-2.0
// cell_bounds: the box of the integer cells floor(p * inv_cell) of all points (one f32 product, then floor,
// exactly as the CPU twin), by i32 atomic min / max: first per workgroup in shared memory, then one global
// atomic per workgroup and bound. Integer min / max commute, so the result does not depend on scheduling.
// A coordinate whose cell is not finite or lies beyond +-2^30 sets the invalid flag (grid[6]).
// The host initialises grid to [i32::MAX x3, i32::MIN x3, 0, 0]; grid[7] is left for the cell count.
// Bindings: 0 params (uniform) | 1 points (read, n x 3) | 2 grid (read_write atomic i32 x 8).
// CPU twin: src/cpu/cell_bounds.rs

struct CellBoundsParams {
    n: u32,
    inv_cell: f32,
    _pad0: u32,
    _pad1: u32,
}

const WG_SIZE: u32 = 256u;
const LIMIT: f32 = 1073741824.0;

@group(0) @binding(0) var<uniform> params: CellBoundsParams;
@group(0) @binding(1) var<storage, read> points: array<f32>;
@group(0) @binding(2) var<storage, read_write> grid: array<atomic<i32>>;

var<workgroup> local_meta: array<atomic<i32>, 7>;

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    if lid < 3u {
        atomicStore(&local_meta[lid], 2147483647);
    } else if lid < 6u {
        atomicStore(&local_meta[lid], -2147483647 - 1);
    } else if lid == 6u {
        atomicStore(&local_meta[lid], 0);
    }
    workgroupBarrier();
    let i = (wid.x + wid.y * nwg.x) * WG_SIZE + lid;
    if i < params.n {
        for (var a = 0u; a < 3u; a++) {
            let v = floor(points[i * 3u + a] * params.inv_cell);
            if !(abs(v) < LIMIT) {
                atomicMax(&local_meta[6], 1);
            } else {
                let c = i32(v);
                atomicMin(&local_meta[a], c);
                atomicMax(&local_meta[a + 3u], c);
            }
        }
    }
    workgroupBarrier();
    if lid < 3u {
        atomicMin(&grid[lid], atomicLoad(&local_meta[lid]));
    } else if lid < 7u {
        atomicMax(&grid[lid], atomicLoad(&local_meta[lid]));
    }
}
