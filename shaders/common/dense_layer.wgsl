// Shared WGSL module `dense_layer`, composed into a kernel at the line `// #include dense_layer` when its source
// is loaded (gpu/device/wgsl.rs): what every GEMM of the dense layer (dense, dense_fast, dense_coop_f16 and its
// generated tiles) declares alike: the parameter struct (mirrored by gpu/kernels/dense_params.rs), the flag
// bits, and the bindings 0 params (uniform) | 1 x, 2 w_t, 3 group (read) | 4 out (read_write). Needs nothing
// from the kernel.

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

const ACCUMULATE: u32 = 1u;
const RELU: u32 = 2u;
const HAS_GROUP: u32 = 4u;

@group(0) @binding(0) var<uniform> params: DenseParams;
@group(0) @binding(1) var<storage, read> x: array<f32>;
@group(0) @binding(2) var<storage, read> w_t: array<f32>;
@group(0) @binding(3) var<storage, read> group_term: array<f32>;
@group(0) @binding(4) var<storage, read_write> out: array<f32>;
