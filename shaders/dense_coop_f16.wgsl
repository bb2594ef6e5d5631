// SPDX-License-Identifier: MIT OR Apache-2.0
// dense_coop_f16: the dense layer on cooperative matrices (tensor cores), f16 inputs, f32 accumulation:
//   out[r, o] = act((accumulate ? out[r, o] : 0) + group[r / rows_per_group, o]
//                   + sum_k f16(x[r, k]) * f16(w_t[w_row_offset + k, o]))
// with the sum of products accumulated in f32 from zero and added to the f32 start value at the end.
// Each workgroup computes a 64 x 64 output tile with four subgroups of 32 invocations (the host selects this
// kernel only on adapters whose subgroups are exactly 32 wide); subgroup s owns the 32 x 32 quarter at rows
// 32 (s / 2), columns 32 (s % 2): 2 x 2 accumulators of 16 x 16. k advances in tiles of 32: the workgroup
// converts a 64 x 32 tile of x and a 32 x 64 tile of w_t to f16 in workgroup memory (zeros outside the
// matrices), then each subgroup multiplies two 16-deep slices. The accumulators go through workgroup memory
// to the f32 epilogue (start value, group term, ReLU, bounds).
// Needs SHADER_F16, SUBGROUP and EXPERIMENTAL_COOPERATIVE_MATRIX with a 16x16x16 f16 -> f32 configuration.
// Bindings: 0 params (uniform) | 1 x, 2 w_t, 3 group (read) | 4 out (read_write).
// CPU twin: src/cpu/dense_coop_f16.rs

enable f16;
enable wgpu_cooperative_matrix;

// #include dense_layer

const WG_SIZE: u32 = 128u;
const TILE_M: u32 = 64u;
const TILE_N: u32 = 64u;
const TILE_K: u32 = 32u;
const MAT: u32 = 16u;

// x tile row-major [m][k] (row stride TILE_K), w_t tile row-major [k][n] (row stride TILE_N), product tile
// row-major [m][n]: 4 + 4 + 16 KiB.
var<workgroup> a_s: array<f16, 2048>;
var<workgroup> b_s: array<f16, 2048>;
var<workgroup> c_s: array<f32, 4096>;

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
    @builtin(subgroup_id) sg: u32,
) {
    let tile = wid.x + wid.y * nwg.x;
    if tile >= params.tiles {
        return;
    }
    let r0 = (tile / params.col_tiles) * TILE_M;
    let c0 = (tile % params.col_tiles) * TILE_N;
    let rows = params.rows;
    let out_dim = params.out_dim;
    let in_dim = params.in_dim;
    let sr = (sg / 2u) * 32u;
    let sc = (sg % 2u) * 32u;

    var c00 = coop_mat16x16<f32, C>();
    var c01 = coop_mat16x16<f32, C>();
    var c10 = coop_mat16x16<f32, C>();
    var c11 = coop_mat16x16<f32, C>();
    for (var k0 = 0u; k0 < in_dim; k0 += TILE_K) {
        for (var q = 0u; q < 16u; q++) {
            let e = lid + WG_SIZE * q;
            let m = e / TILE_K;
            let kx = e % TILE_K;
            var xv = 0.0;
            if r0 + m < rows && k0 + kx < in_dim {
                xv = x[(r0 + m) * in_dim + k0 + kx];
            }
            a_s[e] = f16(xv);
            let kw = e / TILE_N;
            let n = e % TILE_N;
            var wv = 0.0;
            if c0 + n < out_dim && k0 + kw < in_dim {
                wv = w_t[(params.w_row_offset + k0 + kw) * out_dim + c0 + n];
            }
            b_s[e] = f16(wv);
        }
        workgroupBarrier();
        for (var kk = 0u; kk < TILE_K; kk += MAT) {
            let a0 = coopLoadT<coop_mat16x16<f16, A>>(&a_s[sr * TILE_K + kk], TILE_K);
            let a1 = coopLoadT<coop_mat16x16<f16, A>>(&a_s[(sr + MAT) * TILE_K + kk], TILE_K);
            let b0 = coopLoadT<coop_mat16x16<f16, B>>(&b_s[kk * TILE_N + sc], TILE_N);
            let b1 = coopLoadT<coop_mat16x16<f16, B>>(&b_s[kk * TILE_N + sc + MAT], TILE_N);
            c00 = coopMultiplyAdd(a0, b0, c00);
            c01 = coopMultiplyAdd(a0, b1, c01);
            c10 = coopMultiplyAdd(a1, b0, c10);
            c11 = coopMultiplyAdd(a1, b1, c11);
        }
        workgroupBarrier();
    }
    coopStoreT(c00, &c_s[sr * TILE_N + sc], TILE_N);
    coopStoreT(c01, &c_s[sr * TILE_N + sc + MAT], TILE_N);
    coopStoreT(c10, &c_s[(sr + MAT) * TILE_N + sc], TILE_N);
    coopStoreT(c11, &c_s[(sr + MAT) * TILE_N + sc + MAT], TILE_N);
    workgroupBarrier();

    let relu = (params.flags & RELU) != 0u;
    for (var q = 0u; q < 32u; q++) {
        let e = lid + WG_SIZE * q;
        let r = r0 + e / TILE_N;
        let c = c0 + e % TILE_N;
        if r < rows && c < out_dim {
            var v = 0.0;
            if (params.flags & ACCUMULATE) != 0u {
                v = out[r * out_dim + c];
            }
            if (params.flags & HAS_GROUP) != 0u {
                v += group_term[(r / params.rows_per_group) * out_dim + c];
            }
            v += c_s[e];
            if relu {
                v = max(v, 0.0);
            }
            out[r * out_dim + c] = v;
        }
    }
}
