// SPDX-License-Identifier: MIT OR Apache-2.0
// prefix_scan: exclusive prefix sum of n u32 values (wrapping), in three passes of one entry point:
//   BLOCKS (0): per workgroup of 256 values, an in-workgroup scan (Hillis-Steele in shared memory); writes
//               each value's exclusive sum within its block and the block's total to block_sums[block];
//   SUMS (1):   one invocation scans the `blocks` block totals in place (exclusive) and writes the grand
//               total to block_sums[blocks];
//   ADD (2):    adds its block's offset to each value's sum.
// Integer adds are exact, so the result does not depend on scheduling.
// Bindings: 0 params (uniform) | 1 values (read, n) | 2 sums (read_write, n), 3 block_sums (blocks + 1).
// CPU twin: src/cpu/prefix_scan.rs

struct PrefixScanParams {
    n: u32,
    mode: u32,
    blocks: u32,
    _pad: u32,
}

const WG_SIZE: u32 = 256u;
const MODE_BLOCKS: u32 = 0u;
const MODE_SUMS: u32 = 1u;

@group(0) @binding(0) var<uniform> params: PrefixScanParams;
@group(0) @binding(1) var<storage, read> values: array<u32>;
@group(0) @binding(2) var<storage, read_write> sums: array<u32>;
@group(0) @binding(3) var<storage, read_write> block_sums: array<u32>;

var<workgroup> tmp: array<u32, 256>;

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let block = wid.x + wid.y * nwg.x;
    let i = block * WG_SIZE + lid;
    if params.mode == MODE_BLOCKS {
        var v = 0u;
        if i < params.n {
            v = values[i];
        }
        tmp[lid] = v;
        workgroupBarrier();
        for (var offset = 1u; offset < WG_SIZE; offset <<= 1u) {
            var add = 0u;
            if lid >= offset {
                add = tmp[lid - offset];
            }
            workgroupBarrier();
            tmp[lid] += add;
            workgroupBarrier();
        }
        if i < params.n {
            sums[i] = tmp[lid] - v;
        }
        if lid == WG_SIZE - 1u {
            block_sums[block] = tmp[lid];
        }
    } else if params.mode == MODE_SUMS {
        if i == 0u {
            var total = 0u;
            for (var b = 0u; b < params.blocks; b++) {
                let s = block_sums[b];
                block_sums[b] = total;
                total += s;
            }
            block_sums[params.blocks] = total;
        }
    } else {
        if i < params.n {
            sums[i] += block_sums[block];
        }
    }
}
