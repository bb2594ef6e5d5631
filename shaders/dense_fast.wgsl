// SPDX-License-Identifier: MIT OR Apache-2.0
// dense_fast: the dense layer of dense.wgsl (same function, same summation order: the start value, then the
// products in increasing k), tiled for throughput:
//   out[r, o] = act((accumulate ? out[r, o] : 0) + group[r / rows_per_group, o]
//                   + sum_k x[r, k] * w_t[w_row_offset + k, o])
// Each workgroup computes a 128 x 128 output tile: 16 x 16 invocations with 8 x 8 outputs each (rows
// 4 tr + {0..3} and 64 + 4 tr + {0..3}, columns likewise with tc), so every k step reads two vec4 of x and two
// vec4 of w_t from workgroup memory for 64 multiply-adds. k advances in tiles of 8, double-buffered: while the
// tile in one buffer is multiplied, the next is read from global memory into registers and then stored into
// the other buffer, one barrier per k-tile. 2 x (8 x 128) floats of each operand: 16 KiB of workgroup memory.
// That is the default tile (BM = BN = 2); `dpr-gpu bench --gemm-sweep` also compiles 64 x 64, 64 x 128 and
// 128 x 64 tiles (BM, BN in {1, 2}), which compute every output in the same order, so give the same bits.
// Bindings: 0 params (uniform) | 1 x, 2 w_t, 3 group (read) | 4 out (read_write).
// CPU twin: src/cpu/dense_fast.rs

// #include dense_layer

const WG_SIZE: u32 = 256u;
// The tile shape: BM (BN) blocks of 4 rows (columns) per invocation, 64 apart, so a tile is 64 BM x 64 BN
// outputs and an invocation computes 4 BM x 4 BN of them. The host compiles other shapes by replacing these two
// lines (gpu::kernels::dense_fast::FastTile); as written, the default 128 x 128 tile.
const BM: u32 = 2u;
const BN: u32 = 2u;
const TILE_M: u32 = 64u * BM;
const TILE_N: u32 = 64u * BN;
const TILE_K: u32 = 8u;
// vec4 per k row of a staged tile, and per buffer, for each operand.
const X_ROW: u32 = 16u * BM;
const W_ROW: u32 = 16u * BN;
const X_BUF: u32 = TILE_K * X_ROW;
const W_BUF: u32 = TILE_K * W_ROW;

// Two buffers of [k][m / 4] (x, k-major) and [k][n / 4] (w_t).
var<workgroup> x_s: array<vec4<f32>, 2u * X_BUF>;
var<workgroup> w_s: array<vec4<f32>, 2u * W_BUF>;

// Row (or column) offset in the tile of register row i (0..4 BM, or 0..4 BN) of the invocation at position t
// (0..16): block i / 4, 64 rows apart.
fn tile_offset(t: u32, i: u32) -> u32 {
    return 64u * (i / 4u) + 4u * t + i % 4u;
}

// The 4 rows 4 m4 .. 4 m4 + 3 of x at input column k (0 outside the matrix).
fn load_x(r0: u32, m4: u32, k: u32) -> vec4<f32> {
    var v = vec4<f32>(0.0);
    if k < params.in_dim {
        for (var j = 0u; j < 4u; j++) {
            let r = r0 + 4u * m4 + j;
            if r < params.rows {
                v[j] = x[r * params.in_dim + k];
            }
        }
    }
    return v;
}

// The 4 columns 4 n4 .. 4 n4 + 3 of w_t at input row k (0 outside the matrix).
fn load_w(c0: u32, n4: u32, k: u32) -> vec4<f32> {
    var v = vec4<f32>(0.0);
    if k < params.in_dim {
        let row = (params.w_row_offset + k) * params.out_dim;
        for (var j = 0u; j < 4u; j++) {
            let c = c0 + 4u * n4 + j;
            if c < params.out_dim {
                v[j] = w_t[row + c];
            }
        }
    }
    return v;
}

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

    // acc[BN i + h][j]: register row i, column h * 64 + 4 tc + j.
    var acc: array<vec4<f32>, 4u * BM * BN>;
    for (var i = 0u; i < 4u * BM; i++) {
        let r = r0 + tile_offset(tr, i);
        for (var h = 0u; h < BN; h++) {
            for (var j = 0u; j < 4u; j++) {
                let c = c0 + 64u * h + 4u * tc + j;
                var v = 0.0;
                if r < rows && c < out_dim {
                    if (params.flags & ACCUMULATE) != 0u {
                        v = out[r * out_dim + c];
                    }
                    if (params.flags & HAS_GROUP) != 0u {
                        v += group_term[(r / params.rows_per_group) * out_dim + c];
                    }
                }
                acc[BN * i + h][j] = v;
            }
        }
    }

    // Staging: invocation lid < X_BUF loads rows 4 (lid / 8) .. + 3 of x at k = lid % 8, and lid < W_BUF
    // columns 4 (lid % W_ROW) .. + 3 of w_t at k = lid / W_ROW: one vec4 store each per k-tile (every
    // invocation of the default 128 x 128 tile).
    let xk = lid % TILE_K;
    let xm4 = lid / TILE_K;
    let wk = lid / W_ROW;
    let wn4 = lid % W_ROW;
    let x_loads = lid < X_BUF;
    let w_loads = lid < W_BUF;
    let k_tiles = (params.in_dim + TILE_K - 1u) / TILE_K;
    if k_tiles > 0u {
        if x_loads {
            x_s[xk * X_ROW + xm4] = load_x(r0, xm4, xk);
        }
        if w_loads {
            w_s[wk * W_ROW + wn4] = load_w(c0, wn4, wk);
        }
    }
    workgroupBarrier();
    for (var t = 0u; t < k_tiles; t++) {
        let x_cur = (t & 1u) * X_BUF;
        let w_cur = (t & 1u) * W_BUF;
        let has_next = t + 1u < k_tiles;
        var x_next = vec4<f32>(0.0);
        var w_next = vec4<f32>(0.0);
        if has_next {
            let k0 = (t + 1u) * TILE_K;
            if x_loads {
                x_next = load_x(r0, xm4, k0 + xk);
            }
            if w_loads {
                w_next = load_w(c0, wn4, k0 + wk);
            }
        }
        for (var kk = 0u; kk < TILE_K; kk++) {
            var a: array<vec4<f32>, BM>;
            var b: array<vec4<f32>, BN>;
            for (var m = 0u; m < BM; m++) {
                a[m] = x_s[x_cur + kk * X_ROW + 16u * m + tr];
            }
            for (var n = 0u; n < BN; n++) {
                b[n] = w_s[w_cur + kk * W_ROW + 16u * n + tc];
            }
            for (var m = 0u; m < BM; m++) {
                for (var i = 0u; i < 4u; i++) {
                    for (var n = 0u; n < BN; n++) {
                        acc[BN * (4u * m + i) + n] += a[m][i] * b[n];
                    }
                }
            }
        }
        if has_next {
            if x_loads {
                x_s[X_BUF - x_cur + xk * X_ROW + xm4] = x_next;
            }
            if w_loads {
                w_s[W_BUF - w_cur + wk * W_ROW + wn4] = w_next;
            }
        }
        workgroupBarrier();
    }

    let relu = (params.flags & RELU) != 0u;
    for (var i = 0u; i < 4u * BM; i++) {
        let r = r0 + tile_offset(tr, i);
        for (var h = 0u; h < BN; h++) {
            for (var j = 0u; j < 4u; j++) {
                let c = c0 + 64u * h + 4u * tc + j;
                if r < rows && c < out_dim {
                    var v = acc[BN * i + h][j];
                    if relu {
                        v = max(v, 0.0);
                    }
                    out[r * out_dim + c] = v;
                }
            }
        }
    }
}
