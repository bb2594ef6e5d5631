//! CPU twin of `shaders/dense.wgsl`: one shared-MLP layer over many rows (points),
//!
//! `out[r, o] = act( (accumulate ? out[r, o] : 0) + sum_k x[r, k] * w_t[k, o] + group_term[r / rows_per_group, o] )`
//!
//! `group_term` carries the bias plus anything constant over a group of rows (a patch): the global max-pool
//! slice of the skip concatenation, or the codeword slice of a folding layer. A concatenated input is
//! computed as one call per slice (`accumulate` on all but the first, `relu` only on the last), so the
//! concatenation is never materialised.

/// Sizes and flags of one dense call.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DenseShape {
    /// Rows (points) in `x` and `out`.
    pub rows: usize,
    /// Input width (row stride of `x`, rows of `w_t`).
    pub in_dim: usize,
    /// Output width (row stride of `out`, columns of `w_t`).
    pub out_dim: usize,
    /// Rows that share one row of `group_term` (points per patch).
    pub rows_per_group: usize,
    /// Add to the existing contents of `out` instead of overwriting.
    pub accumulate: bool,
    /// Apply ReLU to the result.
    pub relu: bool,
}

/// `gamma_n = n u / (1 - n u)` with the f32 unit roundoff `u = 2^-24`: a sum of `n` f32 terms (products
/// included, each rounded) computed in any order with every operation rounded, fused multiply-adds included,
/// is within `gamma_n * sum |terms|` of the exact sum (Higham, *Accuracy and Stability of Numerical
/// Algorithms*, 2nd ed., section 3.1 and eq. 4.4). The GEMM parity tolerances are built from it.
pub fn gamma_f32(n: usize) -> f64 {
    let nu = n as f64 * f64::from(f32::EPSILON) / 2.0;
    nu / (1.0 - nu)
}

const ROW_BLOCK: usize = 4;
const COL_BLOCK: usize = 64;

/// Runs the layer. `w_t` is `in_dim x out_dim` (transposed PyTorch weight); `group_term` is empty or
/// `ceil(rows / rows_per_group) x out_dim`.
pub fn dense(shape: &DenseShape, x: &[f32], w_t: &[f32], group_term: &[f32], out: &mut [f32]) {
    let DenseShape { rows, in_dim, out_dim, rows_per_group, accumulate, relu } = *shape;
    debug_assert_eq!(x.len(), rows * in_dim);
    debug_assert_eq!(w_t.len(), in_dim * out_dim);
    debug_assert_eq!(out.len(), rows * out_dim);
    debug_assert!(group_term.is_empty() || group_term.len() == rows.div_ceil(rows_per_group.max(1)) * out_dim);
    for r0 in (0..rows).step_by(ROW_BLOCK) {
        let rn = ROW_BLOCK.min(rows - r0);
        for c0 in (0..out_dim).step_by(COL_BLOCK) {
            let cn = COL_BLOCK.min(out_dim - c0);
            let mut acc = [[0f32; COL_BLOCK]; ROW_BLOCK];
            for (i, acc_row) in acc.iter_mut().enumerate().take(rn) {
                let r = r0 + i;
                if accumulate {
                    acc_row[..cn].copy_from_slice(&out[r * out_dim + c0..][..cn]);
                }
                if !group_term.is_empty() {
                    let g = &group_term[(r / rows_per_group) * out_dim + c0..][..cn];
                    for (a, b) in acc_row[..cn].iter_mut().zip(g) {
                        *a += b;
                    }
                }
            }
            for k in 0..in_dim {
                let w = &w_t[k * out_dim + c0..][..cn];
                for (i, acc_row) in acc.iter_mut().enumerate().take(rn) {
                    let xv = x[(r0 + i) * in_dim + k];
                    for (a, &wv) in acc_row[..cn].iter_mut().zip(w) {
                        *a += xv * wv;
                    }
                }
            }
            for (i, acc_row) in acc.iter().enumerate().take(rn) {
                let dst = &mut out[(r0 + i) * out_dim + c0..][..cn];
                for (d, &a) in dst.iter_mut().zip(&acc_row[..cn]) {
                    *d = if relu { a.max(0.0) } else { a };
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    /// Plain triple loop in f64: the oracle.
    fn naive(s: &DenseShape, x: &[f32], w_t: &[f32], g: &[f32], init: &[f32]) -> Vec<f32> {
        (0..s.rows * s.out_dim)
            .map(|idx| {
                let (r, o) = (idx / s.out_dim, idx % s.out_dim);
                let mut v = if s.accumulate { init[idx] as f64 } else { 0.0 };
                if !g.is_empty() {
                    v += g[(r / s.rows_per_group) * s.out_dim + o] as f64;
                }
                for k in 0..s.in_dim {
                    v += x[r * s.in_dim + k] as f64 * w_t[k * s.out_dim + o] as f64;
                }
                if s.relu { v.max(0.0) as f32 } else { v as f32 }
            })
            .collect()
    }

    #[test]
    fn matches_naive_on_ragged_sizes() {
        let mut rng = Rng::new(5);
        for &(rows, in_dim, out_dim, rpg, accumulate, relu) in &[
            (7, 3, 5, 7, false, true),
            (13, 70, 130, 4, true, false),
            (64, 33, 64, 16, true, true),
            (1, 1, 1, 1, false, false),
        ] {
            let s = DenseShape { rows, in_dim, out_dim, rows_per_group: rpg, accumulate, relu };
            let mut v = |n: usize| (0..n).map(|_| rng.normal() as f32).collect::<Vec<f32>>();
            let x = v(rows * in_dim);
            let w = v(in_dim * out_dim);
            let g = v(rows.div_ceil(rpg) * out_dim);
            let init = v(rows * out_dim);
            let mut out = init.clone();
            dense(&s, &x, &w, &g, &mut out);
            let want = naive(&s, &x, &w, &g, &init);
            for (a, b) in out.iter().zip(&want) {
                assert!((a - b).abs() <= 1e-4 * (1.0 + b.abs()), "{a} vs {b} for {s:?}");
            }
        }
    }
}
