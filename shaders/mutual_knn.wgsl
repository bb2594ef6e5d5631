// SPDX-License-Identifier: MIT OR Apache-2.0
// mutual_knn: the K <= 4 smallest distances per source row and per target column of a distance matrix
// (ties to the lower index), then the mutual check. Three modes of one entry point, one invocation each:
//   ROWS: per row of a chunk of the matrix (global rows row_offset..+rows), its K nearest targets;
//   COLS: per column, merges the chunk's rows into the column's running K nearest sources (chunks must
//         come in row order; first_chunk starts the lists empty);
//   FLAGS: per source row and slot, 1 when that row is among its target's K nearest sources.
// Lists have 4 slots; unused slots hold index 0xffffffff. The host compacts flagged slots into matches.
// Bindings: 0 params (uniform) | 1 distances (read, rows x cols) | 2 row_dist, 3 row_index, 4 col_dist,
//           5 col_index, 6 flags (read_write, 4 slots per row or column).
// CPU twin: src/cpu/mutual_knn.rs (k_smallest, mutual_knn)

struct MutualKnnParams {
    mode: u32,
    k: u32,
    rows: u32,
    cols: u32,
    row_offset: u32,
    sources: u32,
    first_chunk: u32,
    _pad: u32,
}

const WG_SIZE: u32 = 64u;
const K_MAX: u32 = 4u;
const EMPTY: u32 = 0xffffffffu;
const MODE_ROWS: u32 = 0u;
const MODE_COLS: u32 = 1u;

@group(0) @binding(0) var<uniform> params: MutualKnnParams;
@group(0) @binding(1) var<storage, read> distances: array<f32>;
@group(0) @binding(2) var<storage, read_write> row_dist: array<f32>;
@group(0) @binding(3) var<storage, read_write> row_index: array<u32>;
@group(0) @binding(4) var<storage, read_write> col_dist: array<f32>;
@group(0) @binding(5) var<storage, read_write> col_index: array<u32>;
@group(0) @binding(6) var<storage, read_write> flags: array<u32>;

struct Best {
    count: u32,
    dist: array<f32, 4>,
    index: array<u32, 4>,
}

// Inserts (v, idx) into the ascending list: the twin's k_smallest step (strict <: earlier indices win ties).
fn insert(best: ptr<function, Best>, v: f32, idx: u32, k: u32) {
    let count = (*best).count;
    if count == k && !(v < (*best).dist[k - 1u]) {
        return;
    }
    var pos = count;
    for (var p = 0u; p < count; p++) {
        if v < (*best).dist[p] {
            pos = p;
            break;
        }
    }
    var q = min(count, k - 1u);
    while q > pos {
        (*best).dist[q] = (*best).dist[q - 1u];
        (*best).index[q] = (*best).index[q - 1u];
        q -= 1u;
    }
    (*best).dist[pos] = v;
    (*best).index[pos] = idx;
    (*best).count = min(count + 1u, k);
}

fn empty_best() -> Best {
    return Best(0u, array<f32, 4>(0.0, 0.0, 0.0, 0.0), array<u32, 4>(EMPTY, EMPTY, EMPTY, EMPTY));
}

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = (wid.x + wid.y * nwg.x) * WG_SIZE + lid;
    let k = clamp(params.k, 1u, K_MAX);
    let cols = params.cols;
    if params.mode == MODE_ROWS {
        if i >= params.rows {
            return;
        }
        var best = empty_best();
        for (var j = 0u; j < cols; j++) {
            insert(&best, distances[i * cols + j], j, k);
        }
        let g = params.row_offset + i;
        for (var q = 0u; q < K_MAX; q++) {
            row_dist[g * K_MAX + q] = best.dist[q];
            row_index[g * K_MAX + q] = best.index[q];
        }
    } else if params.mode == MODE_COLS {
        if i >= cols {
            return;
        }
        var best = empty_best();
        if params.first_chunk == 0u {
            for (var q = 0u; q < K_MAX; q++) {
                let idx = col_index[i * K_MAX + q];
                if idx != EMPTY {
                    best.dist[q] = col_dist[i * K_MAX + q];
                    best.index[q] = idx;
                    best.count = q + 1u;
                }
            }
        }
        for (var r = 0u; r < params.rows; r++) {
            insert(&best, distances[r * cols + i], params.row_offset + r, k);
        }
        for (var q = 0u; q < K_MAX; q++) {
            col_dist[i * K_MAX + q] = best.dist[q];
            col_index[i * K_MAX + q] = best.index[q];
        }
    } else {
        if i >= params.sources {
            return;
        }
        for (var q = 0u; q < K_MAX; q++) {
            let j = row_index[i * K_MAX + q];
            var flag = 0u;
            if j != EMPTY {
                for (var p = 0u; p < K_MAX; p++) {
                    if col_index[j * K_MAX + p] == i {
                        flag = 1u;
                    }
                }
            }
            flags[i * K_MAX + q] = flag;
        }
    }
}
