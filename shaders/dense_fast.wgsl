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
// Bindings: 0 params (uniform) | 1 x, 2 w_t, 3 group (read) | 4 out (read_write).
// CPU twin: src/cpu/dense_fast.rs

struct DenseParams {
    rows: u32,
    in_dim: u32,
    out_dim: u32,
    rows_per_group: u32,
    w_row_offset: u32,
    flags: u32,
    col_tiles: u32,
    tiles: u32,
}

const WG_SIZE: u32 = 256u;
const TILE_M: u32 = 128u;
const TILE_N: u32 = 128u;
const TILE_K: u32 = 8u;
// vec4 per k row of a staged tile, and per buffer.
const VEC_ROW: u32 = 32u;
const VEC_BUF: u32 = 256u;
const ACCUMULATE: u32 = 1u;
const RELU: u32 = 2u;
const HAS_GROUP: u32 = 4u;

@group(0) @binding(0) var<uniform> params: DenseParams;
@group(0) @binding(1) var<storage, read> x: array<f32>;
@group(0) @binding(2) var<storage, read> w_t: array<f32>;
@group(0) @binding(3) var<storage, read> group_term: array<f32>;
@group(0) @binding(4) var<storage, read_write> out: array<f32>;

// Two buffers of [k][m / 4] (x, k-major) and [k][n / 4] (w_t).
var<workgroup> x_s: array<vec4<f32>, 512>;
var<workgroup> w_s: array<vec4<f32>, 512>;

// Row (or column) offset in the tile of register row i (0..8) of the invocation at position t (0..16).
fn tile_offset(t: u32, i: u32) -> u32 {
    return select(4u * t + i, 64u + 4u * t + i - 4u, i >= 4u);
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

    // acc[2 i + h][j]: register row i, column h * 64 + 4 tc + j.
    var acc: array<vec4<f32>, 16>;
    for (var i = 0u; i < 8u; i++) {
        let r = r0 + tile_offset(tr, i);
        for (var h = 0u; h < 2u; h++) {
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
                acc[2u * i + h][j] = v;
            }
        }
    }

    // Staging: invocation lid loads rows 4 (lid / 8) .. + 3 of x at k = lid % 8, and columns
    // 4 (lid % 32) .. + 3 of w_t at k = lid / 32: one vec4 store each per k-tile.
    let xk = lid % TILE_K;
    let xm4 = lid / TILE_K;
    let wk = lid / VEC_ROW;
    let wn4 = lid % VEC_ROW;
    let k_tiles = (params.in_dim + TILE_K - 1u) / TILE_K;
    if k_tiles > 0u {
        x_s[xk * VEC_ROW + xm4] = load_x(r0, xm4, xk);
        w_s[wk * VEC_ROW + wn4] = load_w(c0, wn4, wk);
    }
    workgroupBarrier();
    for (var t = 0u; t < k_tiles; t++) {
        let cur = (t & 1u) * VEC_BUF;
        let nxt = VEC_BUF - cur;
        let has_next = t + 1u < k_tiles;
        var x_next = vec4<f32>(0.0);
        var w_next = vec4<f32>(0.0);
        if has_next {
            let k0 = (t + 1u) * TILE_K;
            x_next = load_x(r0, xm4, k0 + xk);
            w_next = load_w(c0, wn4, k0 + wk);
        }
        for (var kk = 0u; kk < TILE_K; kk++) {
            let base = cur + kk * VEC_ROW;
            let a0 = x_s[base + tr];
            let a1 = x_s[base + 16u + tr];
            let b0 = w_s[base + tc];
            let b1 = w_s[base + 16u + tc];
            for (var i = 0u; i < 4u; i++) {
                acc[2u * i] += a0[i] * b0;
                acc[2u * i + 1u] += a0[i] * b1;
                acc[8u + 2u * i] += a1[i] * b0;
                acc[9u + 2u * i] += a1[i] * b1;
            }
        }
        if has_next {
            x_s[nxt + xk * VEC_ROW + xm4] = x_next;
            w_s[nxt + wk * VEC_ROW + wn4] = w_next;
        }
        workgroupBarrier();
    }

    let relu = (params.flags & RELU) != 0u;
    for (var i = 0u; i < 8u; i++) {
        let r = r0 + tile_offset(tr, i);
        for (var h = 0u; h < 2u; h++) {
            for (var j = 0u; j < 4u; j++) {
                let c = c0 + 64u * h + 4u * tc + j;
                if r < rows && c < out_dim {
                    var v = acc[2u * i + h][j];
                    if relu {
                        v = max(v, 0.0);
                    }
                    out[r * out_dim + c] = v;
                }
            }
        }
    }
}
