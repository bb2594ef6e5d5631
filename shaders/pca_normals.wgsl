// SPDX-License-Identifier: MIT OR Apache-2.0
// pca_normals: per query point p (queries[i], or point i when all_points is 1), the unit eigenvector of the
// smallest eigenvalue of the covariance of its neighbours (k slots of knn_index, unused ones 0xffffffff),
// flipped so that n . (viewpoint - p) >= 0. The covariance is accumulated relative to p; the eigenvectors
// come from 8 cyclic Jacobi sweeps of rotations (0,1), (0,2), (1,2), exactly as the twin. Fewer than 3
// neighbours or a zero covariance give the direction to the viewpoint (+z on it).
// Bindings: 0 params (uniform) | 1 points (read, n x 3), 2 queries (read), 3 knn_index (read, queries x k) |
//           4 normals (read_write, queries x 3).
// CPU twin: src/cpu/pca_normals.rs

struct PcaNormalsParams {
    queries: u32,
    k: u32,
    all_points: u32,
    _pad0: u32,
    viewpoint: vec3<f32>,
    _pad1: u32,
}

const WG_SIZE: u32 = 64u;
const NONE: u32 = 0xffffffffu;
const SWEEPS: u32 = 8u;

@group(0) @binding(0) var<uniform> params: PcaNormalsParams;
@group(0) @binding(1) var<storage, read> points: array<f32>;
@group(0) @binding(2) var<storage, read> queries: array<u32>;
@group(0) @binding(3) var<storage, read> knn_index: array<u32>;
@group(0) @binding(4) var<storage, read_write> normals: array<f32>;

// #include point

fn fallback(to_view: vec3<f32>) -> vec3<f32> {
    let len = sqrt(to_view.x * to_view.x + to_view.y * to_view.y + to_view.z * to_view.z);
    if len > 0.0 {
        return to_view / len;
    }
    return vec3<f32>(0.0, 0.0, 1.0);
}

fn normal_of(p: vec3<f32>, base: u32, k: u32) -> vec3<f32> {
    let to_view = params.viewpoint - p;
    var used = k;
    for (var s = 0u; s < k; s++) {
        if knn_index[base + s] == NONE {
            used = s;
            break;
        }
    }
    if used < 3u {
        return fallback(to_view);
    }
    var mean = vec3<f32>(0.0);
    for (var s = 0u; s < used; s++) {
        mean += point(knn_index[base + s]) - p;
    }
    mean = mean / f32(used);
    var a: array<array<f32, 3>, 3>;
    for (var r = 0u; r < 3u; r++) {
        for (var c = 0u; c < 3u; c++) {
            a[r][c] = 0.0;
        }
    }
    for (var s = 0u; s < used; s++) {
        let d = (point(knn_index[base + s]) - p) - mean;
        for (var r = 0u; r < 3u; r++) {
            for (var c = 0u; c < 3u; c++) {
                a[r][c] += d[r] * d[c];
            }
        }
    }
    var nonzero = false;
    for (var r = 0u; r < 3u; r++) {
        for (var c = 0u; c < 3u; c++) {
            nonzero = nonzero || a[r][c] != 0.0;
        }
    }
    if !nonzero {
        return fallback(to_view);
    }
    var v: array<array<f32, 3>, 3>;
    for (var r = 0u; r < 3u; r++) {
        for (var c = 0u; c < 3u; c++) {
            v[r][c] = select(0.0, 1.0, r == c);
        }
    }
    for (var sweep = 0u; sweep < SWEEPS; sweep++) {
        for (var pair = 0u; pair < 3u; pair++) {
            let p_ = select(0u, 1u, pair == 2u);
            let q_ = select(1u, 2u, pair > 0u);
            let apq = a[p_][q_];
            if apq == 0.0 {
                continue;
            }
            let theta = (a[q_][q_] - a[p_][p_]) / (2.0 * apq);
            var t: f32;
            if abs(theta) > 1e15 {
                t = 0.5 / theta;
            } else {
                t = 1.0 / (abs(theta) + sqrt(theta * theta + 1.0));
                if theta < 0.0 {
                    t = -t;
                }
            }
            let c = 1.0 / sqrt(t * t + 1.0);
            let s = t * c;
            for (var r = 0u; r < 3u; r++) {
                let arp = a[r][p_];
                let arq = a[r][q_];
                a[r][p_] = c * arp - s * arq;
                a[r][q_] = s * arp + c * arq;
            }
            for (var r = 0u; r < 3u; r++) {
                let apr = a[p_][r];
                let aqr = a[q_][r];
                a[p_][r] = c * apr - s * aqr;
                a[q_][r] = s * apr + c * aqr;
            }
            for (var r = 0u; r < 3u; r++) {
                let vp = v[r][p_];
                let vq = v[r][q_];
                v[r][p_] = c * vp - s * vq;
                v[r][q_] = s * vp + c * vq;
            }
        }
    }
    var imin = 0u;
    for (var i = 1u; i < 3u; i++) {
        if a[i][i] < a[imin][imin] {
            imin = i;
        }
    }
    let n = vec3<f32>(v[0][imin], v[1][imin], v[2][imin]);
    let len = sqrt(n.x * n.x + n.y * n.y + n.z * n.z);
    // Not (len > 0 and finite): the twin's fallback.
    // 0x7f7fffff is the largest finite f32 (the literal 3.4028235e38 lies above it, which Tint rejects).
    if !(len > 0.0 && len <= bitcast<f32>(0x7f7fffffu)) {
        return fallback(to_view);
    }
    let u = n / len;
    if u.x * to_view.x + u.y * to_view.y + u.z * to_view.z < 0.0 {
        return -u;
    }
    return u;
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
    var qi = i;
    if params.all_points == 0u {
        qi = queries[i];
    }
    let n = normal_of(point(qi), i * params.k, params.k);
    normals[i * 3u] = n.x;
    normals[i * 3u + 1u] = n.y;
    normals[i * 3u + 2u] = n.z;
}
