//! The parameters the three GEMM kernels share (`dense`, `dense_fast`, `dense_coop_f16`: same uniform, same
//! bindings), tiled for the portable reference kernel ([`super::dense`]) until [`DenseParams::tiled`] retiles
//! them for the variant that runs.

use crate::cpu::dense::DenseShape;
use crate::error::Result;
use crate::gpu::device::kernel::gpu_params;
use crate::gpu::to_u32;

gpu_params! {
    /// Mirrors `struct DenseParams` in shaders/dense.wgsl.
    pub struct DenseParams {
        /// Rows of `x` and `out`.
        pub rows: u32,
        /// Input width (row stride of `x`).
        pub in_dim: u32,
        /// Output width (row stride of `out` and of the weight).
        pub out_dim: u32,
        /// Rows sharing one row of the group term.
        pub rows_per_group: u32,
        /// First row of the transposed weight used (the slice of a concatenated input).
        pub w_row_offset: u32,
        /// [`FLAG_ACCUMULATE`] | [`FLAG_RELU`] | [`FLAG_HAS_GROUP`].
        pub flags: u32,
        /// Output column tiles (`ceil(out_dim / tile columns)`, for the variant that runs: [`record_with`]
        /// sets it).
        pub col_tiles: u32,
        /// Output tiles in all (for the variant that runs).
        pub tiles: u32,
    }
}

/// Output rows per workgroup tile of the reference kernel.
pub const TILE_M: usize = 64;
/// Output columns per workgroup tile of the reference kernel.
pub const TILE_N: usize = 64;
/// Add to the existing output.
pub const FLAG_ACCUMULATE: u32 = 1;
/// Apply ReLU.
pub const FLAG_RELU: u32 = 2;
/// Add the group term.
pub const FLAG_HAS_GROUP: u32 = 4;

impl DenseParams {
    /// Parameters for `shape`, reading weight rows from `w_row_offset`, with or without a group term (tiled for
    /// the reference kernel; [`super::dense::record_with`] retiles them for the variant it dispatches).
    pub fn new(shape: &DenseShape, w_row_offset: usize, has_group: bool) -> Result<DenseParams> {
        let col_tiles = shape.out_dim.div_ceil(TILE_N);
        let tiles = col_tiles * shape.rows.div_ceil(TILE_M);
        let flag = |on: bool, bit: u32| if on { bit } else { 0 };
        let flags =
            flag(shape.accumulate, FLAG_ACCUMULATE) | flag(shape.relu, FLAG_RELU) | flag(has_group, FLAG_HAS_GROUP);
        Ok(DenseParams {
            rows: to_u32(shape.rows, "dense rows")?,
            in_dim: to_u32(shape.in_dim, "dense input width")?,
            out_dim: to_u32(shape.out_dim, "dense output width")?,
            rows_per_group: to_u32(shape.rows_per_group.max(1), "dense rows per group")?,
            w_row_offset: to_u32(w_row_offset, "dense weight offset")?,
            flags,
            col_tiles: to_u32(col_tiles, "dense column tiles")?,
            tiles: to_u32(tiles, "dense tiles")?,
        })
    }

    /// These parameters with the tile counts of `(tile rows, tile columns)` output tiles.
    pub fn tiled(&self, (tile_m, tile_n): (usize, usize)) -> Result<DenseParams> {
        let col_tiles = (self.out_dim as usize).div_ceil(tile_n);
        let tiles = col_tiles * (self.rows as usize).div_ceil(tile_m);
        Ok(DenseParams {
            col_tiles: to_u32(col_tiles, "dense column tiles")?,
            tiles: to_u32(tiles, "dense tiles")?,
            ..*self
        })
    }
}
