//! CPU twin of `shaders/bitonic_sort.wgsl`: sorts [`SortKey`]s ascending by `(hi, lo, index)`.
//!
//! The kernel runs a bitonic network over a power-of-two array padded with [`super::cell_keys::PAD_KEY`];
//! since `(hi, lo, index)` is a total order on distinct indices, the sorted array is unique and equals the
//! twin's, whatever the network's swap order.

use super::cell_keys::SortKey;
use rayon::slice::ParallelSliceMut;

/// Sorts `keys` ascending by `(hi, lo, index)`: on every core, each key compared as one 96-bit integer.
pub fn bitonic_sort(keys: &mut [SortKey]) {
    keys.par_sort_unstable_by_key(|k| (u128::from(k[0]) << 64) | (u128::from(k[1]) << 32) | u128::from(k[2]));
}
