//! CPU twin of `shaders/bitonic_sort.wgsl`: sorts [`SortKey`]s ascending by `(hi, lo, index)`.
//!
//! The kernel runs a bitonic network over a power-of-two array padded with [`super::cell_keys::PAD_KEY`];
//! since `(hi, lo, index)` is a total order on distinct indices, the sorted array is unique and equals the
//! twin's, whatever the network's swap order.

use super::cell_keys::{SortKey, pack, unpack};
use rayon::prelude::*;

/// Sorts `keys` ascending by `(hi, lo, index)`, on every core: each key as one 64-bit integer where the cell
/// offsets and indices fit in 64 bits together ([`sort_packed`]; every cloud but the largest grids), else as one
/// 96-bit integer.
pub fn bitonic_sort(keys: &mut [SortKey]) {
    if !sort_packed(keys) {
        keys.par_sort_unstable_by_key(|k| (u128::from(k[0]) << 64) | (u128::from(k[1]) << 32) | u128::from(k[2]));
    }
}

/// The fields of a key in sort order: the cell's x, y and z offsets and the point's index.
fn fields(k: &SortKey) -> [u32; 4] {
    let o = unpack([k[0], k[1]]);
    [o[0], o[1], o[2], k[2]]
}

/// [`bitonic_sort`] with each key packed into a u64 `x | y | z | index`, each field in just the bits the largest
/// value of it needs, which orders the packed keys as the keys; false (and `keys` untouched) when those bits
/// add up to more than 64.
fn sort_packed(keys: &mut [SortKey]) -> bool {
    let widest = keys.par_iter().map(fields).reduce(|| [0; 4], |a, b| [0, 1, 2, 3].map(|i| a[i].max(b[i])));
    let bits = widest.map(|m| u32::BITS - m.leading_zeros());
    if bits.iter().sum::<u32>() > u64::BITS {
        return false;
    }
    let shifts = [bits[1] + bits[2] + bits[3], bits[2] + bits[3], bits[3], 0];
    // A field of 0 bits is 0, so its shift (possibly 64) may wrap.
    let to_u64 = |k: &SortKey| {
        let f = fields(k);
        (0..4).fold(0u64, |v, i| v | u64::from(f[i]).wrapping_shl(shifts[i]))
    };
    let mut packed: Vec<u64> = keys.par_iter().map(to_u64).collect();
    packed.par_sort_unstable();
    let field = |v: u64, i: usize| (v.wrapping_shr(shifts[i]) & ((1u64 << bits[i]) - 1)) as u32;
    keys.par_iter_mut().zip(&packed).for_each(|(k, &v)| {
        let [hi, lo] = pack([field(v, 0), field(v, 1), field(v, 2)]);
        *k = [hi, lo, field(v, 3), 0];
    });
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    /// Keys of random cells within `span` per axis (many points per cell) with distinct indices, shuffled.
    fn keys(rng: &mut Rng, n: usize, span: u32) -> Vec<SortKey> {
        let mut order: Vec<u32> = (0..n as u32).collect();
        for i in (1..n).rev() {
            order.swap(i, rng.below(i + 1));
        }
        let cell = |rng: &mut Rng| [0u32; 3].map(|_| rng.below(span as usize) as u32);
        order
            .into_iter()
            .map(|i| {
                let [hi, lo] = pack(cell(rng));
                [hi, lo, i, 0]
            })
            .collect()
    }

    #[test]
    fn sorts_as_the_96_bit_keys_whether_packed_or_not() {
        let mut rng = Rng::new(3);
        // Small grids pack into 64 bits; 2^21 cells per axis and 2^20 indices (63 + 20 bits) do not.
        for (n, span, packs) in [(1, 1, true), (5000, 7, true), (5000, 300, true), (3000, 1 << 21, false)] {
            let mut ks = keys(&mut rng, n, span);
            let mut want = ks.clone();
            want.sort_by_key(|k| (k[0], k[1], k[2]));
            assert_eq!(sort_packed(&mut ks.clone()), packs, "{n} keys over {span} cells");
            bitonic_sort(&mut ks);
            assert_eq!(ks, want, "{n} keys over {span} cells");
        }
    }
}
