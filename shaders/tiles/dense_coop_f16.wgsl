// SPDX-License-Identifier: MIT OR Apache-2.0
// tiles/dense_coop_f16: the larger tile shapes of dense_coop_f16 (the dense layer on cooperative matrices,
// tensor cores), f16 inputs, f32 accumulation:
//   out[r, o] = act((accumulate ? out[r, o] : 0) + group[r / rows_per_group, o]
//                   + sum_k f16(x[r, k]) * f16(w_t[w_row_offset + k, o]))
// with the sum of products accumulated in f32 from zero and added to the f32 start value at the end.
// Shape: a workgroup of SG_M x SG_N subgroups of 32 invocations (the host selects this kernel only on adapters
// whose subgroups are exactly 32 wide) computes a TILE_M x TILE_N output tile; subgroup s owns the block at
// rows FM 16 (s / SG_N), columns FN 16 (s % SG_N): FM x FN accumulators of 16 x 16. As written: 2 x 2 subgroups of 2 x 2
// accumulators, a 64 x 64 tile; the host generates the shapes `bench --gemm-sweep` times by replacing SG_M,
// SG_N, FM and FN (gpu/kernels/dense_coop_f16.rs, CoopTile). The default 64 x 64 tile runs
// shaders/dense_coop_f16.wgsl, the kernel whose parity was checked on hardware; a shape from this file runs only
// once a sweep on the device has checked it against the twin and recorded it.
// k advances in tiles of 32, double-buffered in workgroup memory: step t reads k-tile t of x and w_t from
// global memory into registers (four consecutive values under one bounds check; zeros outside the matrices),
// multiplies k-tile t - 1 from one buffer (two 16-deep slices, in increasing k), then stores k-tile t to the
// other buffer as f16; one barrier per step. Every output's products are therefore summed in the same order
// whatever the shape: 16-deep cooperative multiply-adds in increasing k from a zero accumulator.
// The epilogue takes one accumulator of every subgroup at a time through workgroup memory (16 x 16 f32 per
// subgroup) to the f32 epilogue: start value, group term, ReLU, bounds.
// Needs SHADER_F16, SUBGROUP and EXPERIMENTAL_COOPERATIVE_MATRIX with a 16x16x16 f16 -> f32 configuration.
// Bindings: 0 params (uniform) | 1 x, 2 w_t, 3 group (read) | 4 out (read_write).
// CPU twin: src/cpu/dense_coop_f16.rs

enable f16;
enable wgpu_cooperative_matrix;

// #include dense_layer

// The shape (replaced by the host for the other tile shapes).
const SG_M: u32 = 2u;
const SG_N: u32 = 2u;
const FM: u32 = 2u;
const FN: u32 = 2u;

const SUBGROUP: u32 = 32u;
const MAT: u32 = 16u;
const TILE_K: u32 = 32u;
const TILE_M: u32 = SG_M * FM * MAT;
const TILE_N: u32 = SG_N * FN * MAT;
const WG_SIZE: u32 = SG_M * SG_N * SUBGROUP;
// One buffer of each operand tile, in f16 elements.
const A_SIZE: u32 = TILE_M * TILE_K;
const B_SIZE: u32 = TILE_K * TILE_N;
// Four-element groups of each operand tile one invocation loads per k step.
const A_QUADS: u32 = A_SIZE / (4u * WG_SIZE);
const B_QUADS: u32 = B_SIZE / (4u * WG_SIZE);
const_assert A_SIZE % (4u * WG_SIZE) == 0u && B_SIZE % (4u * WG_SIZE) == 0u;

alias MatA = coop_mat16x16<f16, A>;
alias MatB = coop_mat16x16<f16, B>;
alias MatC = coop_mat16x16<f32, C>;

// Two buffers of the x tile, row-major [m][k] (row stride TILE_K), and of the w_t tile, row-major [k][n] (row
// stride TILE_N); one 16 x 16 accumulator per subgroup for the epilogue. 64 x 64: 8 + 8 + 4 KiB.
var<workgroup> a_s: array<f16, 2u * A_SIZE>;
var<workgroup> b_s: array<f16, 2u * B_SIZE>;
var<workgroup> c_s: array<f32, SG_M * SG_N * MAT * MAT>;

// This invocation's share of the next k-tile, as read from global memory (f32).
var<private> xq: array<vec4<f32>, A_QUADS>;
var<private> wq: array<vec4<f32>, B_QUADS>;

// x[r, k..k + 4], zeros outside the matrix.
fn x_quad(r: u32, k: u32) -> vec4<f32> {
    let in_dim = params.in_dim;
    var v = vec4<f32>(0.0);
    if r >= params.rows || k >= in_dim {
        return v;
    }
    let i = r * in_dim + k;
    if k + 4u <= in_dim {
        return vec4<f32>(x[i], x[i + 1u], x[i + 2u], x[i + 3u]);
    }
    for (var j = 0u; k + j < in_dim; j++) {
        v[j] = x[i + j];
    }
    return v;
}

// w_t[w_row_offset + k, c..c + 4], zeros outside the used rows and the columns.
fn w_quad(k: u32, c: u32) -> vec4<f32> {
    let out_dim = params.out_dim;
    var v = vec4<f32>(0.0);
    if k >= params.in_dim || c >= out_dim {
        return v;
    }
    let i = (params.w_row_offset + k) * out_dim + c;
    if c + 4u <= out_dim {
        return vec4<f32>(w_t[i], w_t[i + 1u], w_t[i + 2u], w_t[i + 3u]);
    }
    for (var j = 0u; c + j < out_dim; j++) {
        v[j] = w_t[i + j];
    }
    return v;
}

// Loads this invocation's share of k-tile k0 of the workgroup's x rows r0.. and w_t columns c0.. into xq, wq:
// consecutive invocations read consecutive groups of four along a row.
fn fetch(r0: u32, c0: u32, k0: u32, lid: u32) {
    for (var i = 0u; i < A_QUADS; i++) {
        let e = 4u * (lid + WG_SIZE * i);
        xq[i] = x_quad(r0 + e / TILE_K, k0 + e % TILE_K);
    }
    for (var i = 0u; i < B_QUADS; i++) {
        let e = 4u * (lid + WG_SIZE * i);
        wq[i] = w_quad(k0 + e / TILE_N, c0 + e % TILE_N);
    }
}

// Stores xq, wq as f16 into buffer `buf` of a_s, b_s (the layout fetch read them in).
fn stage(buf: u32, lid: u32) {
    for (var i = 0u; i < A_QUADS; i++) {
        let e = buf * A_SIZE + 4u * (lid + WG_SIZE * i);
        let h = vec4<f16>(xq[i]);
        a_s[e] = h.x;
        a_s[e + 1u] = h.y;
        a_s[e + 2u] = h.z;
        a_s[e + 3u] = h.w;
    }
    for (var i = 0u; i < B_QUADS; i++) {
        let e = buf * B_SIZE + 4u * (lid + WG_SIZE * i);
        let h = vec4<f16>(wq[i]);
        b_s[e] = h.x;
        b_s[e + 1u] = h.y;
        b_s[e + 2u] = h.z;
        b_s[e + 3u] = h.w;
    }
}

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
    let sr = (sg / SG_N) * (FM * MAT);
    let sc = (sg % SG_N) * (FN * MAT);
    let k_tiles = (params.in_dim + TILE_K - 1u) / TILE_K;

    var acc: array<MatC, FM * FN>;
    for (var f = 0u; f < FM * FN; f++) {
        acc[f] = MatC();
    }
    // k-tile 0 into buffer 0; step t multiplies k-tile t from buffer t % 2 between loading k-tile t + 1 into
    // registers and storing it to the other buffer (the coop operations stay outside any branch: naga requires
    // them in uniform control flow and takes a local variable's value as non-uniform).
    fetch(r0, c0, 0u, lid);
    stage(0u, lid);
    workgroupBarrier();
    for (var t = 0u; t < k_tiles; t++) {
        let more = t + 1u < k_tiles;
        if more {
            fetch(r0, c0, (t + 1u) * TILE_K, lid);
        }
        let a0 = (t % 2u) * A_SIZE;
        let b0 = (t % 2u) * B_SIZE;
        for (var kk = 0u; kk < TILE_K; kk += MAT) {
            var a: array<MatA, FM>;
            for (var i = 0u; i < FM; i++) {
                a[i] = coopLoadT<MatA>(&a_s[a0 + (sr + i * MAT) * TILE_K + kk], TILE_K);
            }
            for (var j = 0u; j < FN; j++) {
                let b = coopLoadT<MatB>(&b_s[b0 + kk * TILE_N + sc + j * MAT], TILE_N);
                for (var i = 0u; i < FM; i++) {
                    acc[i * FN + j] = coopMultiplyAdd(a[i], b, acc[i * FN + j]);
                }
            }
        }
        if more {
            stage((t + 1u) % 2u, lid);
        }
        workgroupBarrier();
    }

    // Accumulator f of every subgroup at once: subgroup s's 16 x 16 block at c_s[256 s..], then the epilogue.
    let relu = (params.flags & RELU) != 0u;
    for (var f = 0u; f < FM * FN; f++) {
        coopStoreT(acc[f], &c_s[sg * MAT * MAT], MAT);
        workgroupBarrier();
        for (var q = 0u; q < MAT * MAT / SUBGROUP; q++) {
            let e = lid + WG_SIZE * q;
            let s = e / (MAT * MAT);
            let i = e % (MAT * MAT);
            let r = r0 + (s / SG_N) * (FM * MAT) + (f / FN) * MAT + i / MAT;
            let c = c0 + (s % SG_N) * (FN * MAT) + (f % FN) * MAT + i % MAT;
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
        workgroupBarrier();
    }
}
