// SPDX-License-Identifier: MIT OR Apache-2.0
// chamfer_grad: the second half of the reconstruction loss. Per patch pair (x: patches * n x dim, the input points;
// y: patches * m x dim, the reconstruction; nearest, distance: chamfer_nearest's) the paper's Chamfer distance
// max(a, b), a = mean over x of the distance to its nearest y, b = mean over y of the distance to its nearest x
// (each summed in row order), and scale times its gradient w.r.t. y: when a >= b each y row gathers
// (y - x) / |y - x| / n over the x rows whose nearest it is, in row order; else each y row gets (y - x) / |y - x| / m
// for its own nearest x. |y - x| is guarded at NORM_EPS. grad (patches * m x dim) and loss (patches) are
// overwritten. One invocation per (patch, y row); the patch's first row also writes its loss.
// Bindings: 0 params (uniform) | 1 x (read) | 2 y (read) | 3 nearest (read, u32) | 4 distance (read)
//           | 5 grad (read_write) | 6 loss (read_write).
// CPU twin: src/cpu/chamfer_grad.rs (in f64, as the trainer's loss)

struct ChamferGradParams {
    patches: u32,
    n: u32,
    m: u32,
    dim: u32,
    scale: f32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

const WG_SIZE: u32 = 64u;
// Widest row (the host refuses wider): PPF rows are 4 wide, point rows 3.
const MAX_DIM: u32 = 8u;
const NORM_EPS: f32 = 1e-12;

@group(0) @binding(0) var<uniform> params: ChamferGradParams;
@group(0) @binding(1) var<storage, read> x: array<f32>;
@group(0) @binding(2) var<storage, read> y: array<f32>;
@group(0) @binding(3) var<storage, read> nearest: array<u32>;
@group(0) @binding(4) var<storage, read> distance: array<f32>;
@group(0) @binding(5) var<storage, read_write> grad: array<f32>;
@group(0) @binding(6) var<storage, read_write> loss: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = (wid.x + wid.y * nwg.x) * WG_SIZE + lid;
    let n = params.n;
    let m = params.m;
    let dim = params.dim;
    if i >= params.patches * m {
        return;
    }
    let p = i / m;
    let j = i % m;
    let base = p * (n + m);
    var a = 0.0;
    for (var k = 0u; k < n; k++) {
        a = a + distance[base + k];
    }
    a = a / f32(n);
    var b = 0.0;
    for (var k = 0u; k < m; k++) {
        b = b + distance[base + n + k];
    }
    b = b / f32(m);
    let y_row = (p * m + j) * dim;
    var acc: array<f32, MAX_DIM>;
    for (var c = 0u; c < MAX_DIM; c++) {
        acc[c] = 0.0;
    }
    // The x rows this y row's gradient comes from: those whose nearest it is (a >= b), or its own nearest.
    var first = 0u;
    var last = n;
    var weight = 1.0 / f32(n);
    if a < b {
        first = nearest[base + n + j];
        last = first + 1u;
        weight = 1.0 / f32(m);
    }
    for (var k = first; k < last; k++) {
        if a >= b && nearest[base + k] != j {
            continue;
        }
        let x_row = (p * n + k) * dim;
        var len2 = 0.0;
        for (var c = 0u; c < dim; c++) {
            let t = y[y_row + c] - x[x_row + c];
            len2 = len2 + t * t;
        }
        let len = max(sqrt(len2), NORM_EPS);
        for (var c = 0u; c < dim; c++) {
            acc[c] = acc[c] + weight * (y[y_row + c] - x[x_row + c]) / len;
        }
    }
    for (var c = 0u; c < dim; c++) {
        grad[y_row + c] = params.scale * acc[c];
    }
    if j == 0u {
        loss[p] = max(a, b);
    }
}
