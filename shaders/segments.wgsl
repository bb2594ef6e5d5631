// SPDX-License-Identifier: MIT OR Apache-2.0
// segments: the runs of equal cell keys (x, y) in sorted keys, in two passes of one entry point:
//   HEADS (0):   heads[i] = 1 when element i starts a run (i == 0 or its key differs from element i - 1);
//   SCATTER (1): with offsets = exclusive prefix sum of heads (prefix_scan), each head i writes
//                starts[offsets[i]] = i and run_keys[offsets[i]] = key; the last element writes
//                starts[runs] = n.
// Bindings: 0 params (uniform) | 1 keys (read, sorted), 2 offsets (read) | 3 heads, 4 starts (runs + 1),
//           5 run_keys (read_write).
// CPU twin: src/cpu/segments.rs

struct SegmentsParams {
    n: u32,
    mode: u32,
    _pad0: u32,
    _pad1: u32,
}

const WG_SIZE: u32 = 256u;
const MODE_HEADS: u32 = 0u;

@group(0) @binding(0) var<uniform> params: SegmentsParams;
@group(0) @binding(1) var<storage, read> keys: array<vec4<u32>>;
@group(0) @binding(2) var<storage, read> offsets: array<u32>;
@group(0) @binding(3) var<storage, read_write> heads: array<u32>;
@group(0) @binding(4) var<storage, read_write> starts: array<u32>;
@group(0) @binding(5) var<storage, read_write> run_keys: array<vec2<u32>>;

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = (wid.x + wid.y * nwg.x) * WG_SIZE + lid;
    let n = params.n;
    if i >= n {
        return;
    }
    if params.mode == MODE_HEADS {
        var head = 1u;
        if i > 0u && all(keys[i].xy == keys[i - 1u].xy) {
            head = 0u;
        }
        heads[i] = head;
    } else {
        let h = heads[i];
        let s = offsets[i];
        if h == 1u {
            starts[s] = i;
            run_keys[s] = keys[i].xy;
        }
        if i == n - 1u {
            starts[s + h] = n;
        }
    }
}
