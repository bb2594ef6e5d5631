// SPDX-License-Identifier: MIT OR Apache-2.0
// pose_feature: a scan's pose features from freshly encoded PC-FoldNet codewords. Slot s holds the PC codeword
// of scan row rows[s]; out[rows[s]] = pc[s] - ppf[rows[s]] (PC-FoldNet codeword minus PPF-FoldNet codeword).
// One invocation per value.
// Bindings: 0 params (uniform) | 1 pc (slots x width), 2 ppf (scan rows x width), 3 rows (scan row of each
//           slot) (read) | 4 out (scan rows x width; the slots' rows written).
// CPU twin: src/cpu/pose_feature.rs

struct PoseFeatureParams {
    slots: u32,
    width: u32,
    _pad0: u32,
    _pad1: u32,
}

const WG_SIZE: u32 = 64u;

@group(0) @binding(0) var<uniform> params: PoseFeatureParams;
@group(0) @binding(1) var<storage, read> pc: array<f32>;
@group(0) @binding(2) var<storage, read> ppf: array<f32>;
@group(0) @binding(3) var<storage, read> rows: array<u32>;
@group(0) @binding(4) var<storage, read_write> out: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = (wid.x + wid.y * nwg.x) * WG_SIZE + lid;
    if i >= params.slots * params.width {
        return;
    }
    let slot = i / params.width;
    let c = i % params.width;
    let at = rows[slot] * params.width + c;
    out[at] = pc[i] - ppf[at];
}
