// SPDX-License-Identifier: MIT OR Apache-2.0
// score_hypotheses: inlier count and squared-residual sum of every hypothesis over every correspondence
// (inlier: |p_target - (R p_source + t)|^2 < threshold^2). One workgroup per hypothesis (linearised 2-D
// grid): invocations stride over the correspondences, then a tree reduction in workgroup memory. With
// write_mask set, hypothesis 0 also writes its per-correspondence inlier flags (for refinement).
// Bindings: 0 params (uniform) | 1 hypotheses (12 per row: R row-major, t), 2 source_points,
//           3 target_points (xyz) (read) | 4 inliers (u32), 5 residual_sums (f32), 6 mask (u32 per
//           correspondence) (written).
// CPU twin: src/cpu/score_hypotheses.rs

struct ScoreHypothesesParams {
    hypotheses: u32,
    correspondences: u32,
    threshold_sq: f32,
    write_mask: u32,
}

const WG_SIZE: u32 = 64u;

@group(0) @binding(0) var<uniform> params: ScoreHypothesesParams;
@group(0) @binding(1) var<storage, read> hypotheses: array<f32>;
@group(0) @binding(2) var<storage, read> source_points: array<f32>;
@group(0) @binding(3) var<storage, read> target_points: array<f32>;
@group(0) @binding(4) var<storage, read_write> inliers: array<u32>;
@group(0) @binding(5) var<storage, read_write> residual_sums: array<f32>;
@group(0) @binding(6) var<storage, read_write> mask: array<u32>;

var<workgroup> counts: array<u32, WG_SIZE>;
var<workgroup> sums: array<f32, WG_SIZE>;

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let h = wid.x + wid.y * nwg.x;
    if h >= params.hypotheses {
        return;
    }
    var r: array<f32, 12>;
    for (var e = 0u; e < 12u; e++) {
        r[e] = hypotheses[h * 12u + e];
    }
    let write_mask = params.write_mask != 0u && h == 0u;
    var count = 0u;
    var sum = 0.0;
    for (var c = lid; c < params.correspondences; c += WG_SIZE) {
        let ps = vec3<f32>(source_points[c * 3u], source_points[c * 3u + 1u], source_points[c * 3u + 2u]);
        let pt = vec3<f32>(target_points[c * 3u], target_points[c * 3u + 1u], target_points[c * 3u + 2u]);
        let rp = vec3<f32>(
            r[0] * ps.x + r[1] * ps.y + r[2] * ps.z,
            r[3] * ps.x + r[4] * ps.y + r[5] * ps.z,
            r[6] * ps.x + r[7] * ps.y + r[8] * ps.z,
        );
        let d = vec3<f32>(pt.x - rp.x - r[9], pt.y - rp.y - r[10], pt.z - rp.z - r[11]);
        let r2 = d.x * d.x + d.y * d.y + d.z * d.z;
        let inlier = r2 < params.threshold_sq;
        if inlier {
            count += 1u;
            sum += r2;
        }
        if write_mask {
            mask[c] = select(0u, 1u, inlier);
        }
    }
    counts[lid] = count;
    sums[lid] = sum;
    workgroupBarrier();
    for (var stride = WG_SIZE / 2u; stride > 0u; stride /= 2u) {
        if lid < stride {
            counts[lid] += counts[lid + stride];
            sums[lid] += sums[lid + stride];
        }
        workgroupBarrier();
    }
    if lid == 0u {
        inliers[h] = counts[0];
        residual_sums[h] = sums[0];
    }
}
