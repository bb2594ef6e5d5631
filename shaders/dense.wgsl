// SPDX-License-Identifier: MIT OR Apache-2.0
// dense: one shared-MLP layer as a tiled GEMM over many rows,
//   out[r, o] = act((accumulate ? out[r, o] : 0) + group[r / rows_per_group, o]
//                   + sum_k x[r, k] * w_t[w_row_offset + k, o])
// Each workgroup computes a 64 x 64 output tile (16 x 16 invocations, 4 x 4 outputs each) from 64 x 16 and
// 16 x 64 tiles of x and w_t staged in workgroup memory; the tile grid is linearised over a 2-D dispatch.
// Bindings: 0 params (uniform) | 1 x, 2 w_t, 3 group (read) | 4 out (read_write).
// CPU twin: src/cpu/dense.rs

// #include dense_layer

const WG_SIZE: u32 = 256u;
const TILE_M: u32 = 64u;
const TILE_N: u32 = 64u;
const TILE_K: u32 = 16u;

// x tile stored k-major ([k][m]) and w tile [k][n], so the inner loop reads both with unit stride.
var<workgroup> x_tile: array<f32, 1024>;
var<workgroup> w_tile: array<f32, 1024>;

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let tile = wid.x + wid.y * nwg.x;
    if tile >= params.tiles {
        return;
    }
    let r0 = (tile / params.col_tiles) * TILE_M;
    let c0 = (tile % params.col_tiles) * TILE_N;
    let tr = lid / 16u;
    let tc = lid % 16u;
    let rows = params.rows;
    let out_dim = params.out_dim;
    let in_dim = params.in_dim;

    var acc: array<array<f32, 4>, 4>;
    for (var i = 0u; i < 4u; i++) {
        let r = r0 + tr + 16u * i;
        for (var j = 0u; j < 4u; j++) {
            let c = c0 + tc + 16u * j;
            var v = 0.0;
            if r < rows && c < out_dim {
                if (params.flags & ACCUMULATE) != 0u {
                    v = out[r * out_dim + c];
                }
                if (params.flags & HAS_GROUP) != 0u {
                    v += group_term[(r / params.rows_per_group) * out_dim + c];
                }
            }
            acc[i][j] = v;
        }
    }

    for (var k0 = 0u; k0 < in_dim; k0 += TILE_K) {
        for (var q = 0u; q < 4u; q++) {
            let e = lid + WG_SIZE * q;
            let m = e / TILE_K;
            let kx = e % TILE_K;
            var xv = 0.0;
            if r0 + m < rows && k0 + kx < in_dim {
                xv = x[(r0 + m) * in_dim + k0 + kx];
            }
            x_tile[kx * TILE_M + m] = xv;
            let kw = e / TILE_N;
            let n = e % TILE_N;
            var wv = 0.0;
            if c0 + n < out_dim && k0 + kw < in_dim {
                wv = w_t[(params.w_row_offset + k0 + kw) * out_dim + c0 + n];
            }
            w_tile[kw * TILE_N + n] = wv;
        }
        workgroupBarrier();
        let k_end = min(TILE_K, in_dim - k0);
        for (var kk = 0u; kk < k_end; kk++) {
            var xs: array<f32, 4>;
            var ws: array<f32, 4>;
            for (var i = 0u; i < 4u; i++) {
                xs[i] = x_tile[kk * TILE_M + tr + 16u * i];
                ws[i] = w_tile[kk * TILE_N + tc + 16u * i];
            }
            for (var i = 0u; i < 4u; i++) {
                for (var j = 0u; j < 4u; j++) {
                    acc[i][j] += xs[i] * ws[j];
                }
            }
        }
        workgroupBarrier();
    }

    let relu = (params.flags & RELU) != 0u;
    for (var i = 0u; i < 4u; i++) {
        let r = r0 + tr + 16u * i;
        for (var j = 0u; j < 4u; j++) {
            let c = c0 + tc + 16u * j;
            if r < rows && c < out_dim {
                var v = acc[i][j];
                if relu {
                    v = max(v, 0.0);
                }
                out[r * out_dim + c] = v;
            }
        }
    }
}
