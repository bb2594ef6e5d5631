//! CPU twin of `shaders/max_pool.wgsl`: per-group, per-channel maximum over the rows of each group
//! (the points of each patch).

/// Channels pooled at once: their running maxima stay in registers over a group's rows (eight 128-bit
/// registers on the baseline x86-64 target), not in memory.
const CHANNEL_BLOCK: usize = 32;

/// `x` is `groups * rows_per_group x channels`; returns `groups x channels`.
pub fn max_pool(x: &[f32], groups: usize, rows_per_group: usize, channels: usize) -> Vec<f32> {
    debug_assert_eq!(x.len(), groups * rows_per_group * channels);
    let mut out = vec![f32::NEG_INFINITY; groups * channels];
    if channels == 0 {
        return out;
    }
    for g in 0..groups {
        let rows = &x[g * rows_per_group * channels..][..rows_per_group * channels];
        let dst = &mut out[g * channels..][..channels];
        let mut c0 = 0;
        while c0 + CHANNEL_BLOCK <= channels {
            let mut best = [f32::NEG_INFINITY; CHANNEL_BLOCK];
            for row in rows.chunks_exact(channels) {
                let row: &[f32; CHANNEL_BLOCK] = row[c0..c0 + CHANNEL_BLOCK].try_into().expect("a block");
                // `v > d ? v : d` rather than `f32::max`: the same maximum (a NaN row value is skipped either
                // way, and `d` starts at -inf), but it is x86's `maxps`.
                for (d, &v) in best.iter_mut().zip(row) {
                    *d = if v > *d { v } else { *d };
                }
            }
            dst[c0..c0 + CHANNEL_BLOCK].copy_from_slice(&best);
            c0 += CHANNEL_BLOCK;
        }
        for row in rows.chunks_exact(channels) {
            for (d, &v) in dst[c0..].iter_mut().zip(&row[c0..]) {
                *d = if v > *d { v } else { *d };
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn equals_the_brute_force_maximum_at_every_width() {
        let mut rng = Rng::new(3);
        for (groups, rows, ch) in [(2, 9, 1), (3, 5, 32), (2, 7, 70), (1, 4, 240), (2, 3, 0)] {
            let x: Vec<f32> = (0..groups * rows * ch).map(|_| rng.normal() as f32).collect();
            let brute: Vec<f32> = (0..groups * ch)
                .map(|i| {
                    let (g, c) = (i / ch, i % ch);
                    (0..rows).map(|r| x[(g * rows + r) * ch + c]).fold(f32::NEG_INFINITY, f32::max)
                })
                .collect();
            assert_eq!(max_pool(&x, groups, rows, ch), brute, "{groups} x {rows} x {ch}");
        }
    }

    #[test]
    fn invariant_under_row_permutation_within_a_group() {
        let (groups, rows, ch) = (3, 17, 5);
        let mut rng = Rng::new(9);
        let x: Vec<f32> = (0..groups * rows * ch).map(|_| rng.normal() as f32).collect();
        let pooled = max_pool(&x, groups, rows, ch);
        let mut permuted = x.clone();
        for g in 0..groups {
            let order = rng.sample_without_replacement(rows, rows);
            for (dst, &src) in order.iter().enumerate() {
                permuted[(g * rows + dst) * ch..][..ch].copy_from_slice(&x[(g * rows + src) * ch..][..ch]);
            }
        }
        assert_eq!(pooled, max_pool(&permuted, groups, rows, ch));
        // Each output is attained by some row of its group.
        for g in 0..groups {
            for c in 0..ch {
                assert!((0..rows).any(|r| x[(g * rows + r) * ch + c] == pooled[g * ch + c]));
            }
        }
    }
}
