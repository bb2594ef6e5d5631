//! CPU twin of `shaders/bitonic_sort.wgsl`: sorts [`SortKey`]s ascending by `(hi, lo, index)`.
//!
//! The kernel runs a bitonic network over a power-of-two array padded with [`super::cell_keys::PAD_KEY`];
//! since `(hi, lo, index)` is a total order on distinct indices, the sorted array is unique and equals the
//! twin's, whatever the network's swap order.

use super::cell_keys::SortKey;

/// Sorts `keys` ascending by `(hi, lo, index)`.
pub fn bitonic_sort(keys: &mut [SortKey]) {
    keys.sort_unstable_by_key(|k| (k[0], k[1], k[2]));
}
