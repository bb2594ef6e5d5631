// SPDX-License-Identifier: MIT OR Apache-2.0
// codeword_distance: squared L2 distances between a chunk of source codewords (rows row_offset..+rows)
// and all target codewords, summed over the dimensions in order. Each workgroup computes a 16 x 16 output
// tile from 16 x 32 slices of both sets staged in workgroup memory; the tile grid is linearised.
// Bindings: 0 params (uniform) | 1 source_codewords, 2 target_codewords (read, rows of `dim`) |
//           3 out (rows x cols, written).
// CPU twin: src/cpu/mutual_knn.rs (codeword_distance)

struct CodewordDistanceParams {
    rows: u32,
    cols: u32,
    dim: u32,
    row_offset: u32,
    col_tiles: u32,
    tiles: u32,
    _pad0: u32,
    _pad1: u32,
}

const WG_SIZE: u32 = 256u;
const TILE: u32 = 16u;
const TILE_D: u32 = 32u;

@group(0) @binding(0) var<uniform> params: CodewordDistanceParams;
@group(0) @binding(1) var<storage, read> source_codewords: array<f32>;
@group(0) @binding(2) var<storage, read> target_codewords: array<f32>;
@group(0) @binding(3) var<storage, read_write> out: array<f32>;

// [d][row] and [d][col]: the inner loop reads both with unit stride across invocations.
var<workgroup> s_tile: array<f32, 512>;
var<workgroup> t_tile: array<f32, 512>;

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
    let r0 = (tile / params.col_tiles) * TILE;
    let c0 = (tile % params.col_tiles) * TILE;
    let ty = lid / TILE;
    let tx = lid % TILE;
    let dim = params.dim;
    var acc = 0.0;
    for (var d0 = 0u; d0 < dim; d0 += TILE_D) {
        for (var q = 0u; q < 2u; q++) {
            let e = lid + WG_SIZE * q;
            let r = e / TILE_D;
            let d = e % TILE_D;
            var sv = 0.0;
            var tv = 0.0;
            if d0 + d < dim {
                if r0 + r < params.rows {
                    sv = source_codewords[(params.row_offset + r0 + r) * dim + d0 + d];
                }
                if c0 + r < params.cols {
                    tv = target_codewords[(c0 + r) * dim + d0 + d];
                }
            }
            s_tile[d * TILE + r] = sv;
            t_tile[d * TILE + r] = tv;
        }
        workgroupBarrier();
        let d_end = min(TILE_D, dim - d0);
        for (var d = 0u; d < d_end; d++) {
            let diff = s_tile[d * TILE + ty] - t_tile[d * TILE + tx];
            acc += diff * diff;
        }
        workgroupBarrier();
    }
    let r = r0 + ty;
    let c = c0 + tx;
    if r < params.rows && c < params.cols {
        out[r * params.cols + c] = acc;
    }
}
