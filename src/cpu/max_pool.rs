//! CPU twin of `shaders/max_pool.wgsl`: per-group, per-channel maximum over the rows of each group
//! (the points of each patch).

/// `x` is `groups * rows_per_group x channels`; returns `groups x channels`.
pub fn max_pool(x: &[f32], groups: usize, rows_per_group: usize, channels: usize) -> Vec<f32> {
    debug_assert_eq!(x.len(), groups * rows_per_group * channels);
    let mut out = vec![f32::NEG_INFINITY; groups * channels];
    for g in 0..groups {
        let dst = &mut out[g * channels..][..channels];
        for r in 0..rows_per_group {
            let row = &x[(g * rows_per_group + r) * channels..][..channels];
            // `v > d ? v : d` rather than `f32::max`: the same maximum (a NaN row value is skipped either way,
            // and `d` starts at -inf), but it is x86's `maxps`, one instruction per 16 channels.
            for (d, &v) in dst.iter_mut().zip(row) {
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
