//! The batch contrastive loss on PPF-FoldNet codewords: each pair's two codewords must lie closer to each other
//! than either lies to the other pairs' codewords of the opposite side, by a margin.
//!
//! The feature-consistency loss only pulls corresponding codewords together; nothing in the reconstruction or
//! pose losses pushes codewords of different surfaces apart, and matching is a nearest-neighbour search. With
//! `B` pairs of codewords (source `s_i`, target `t_i`) and `d_ij = |s_i - t_j|`:
//!
//! `L = 1/B sum_i 1/2 [relu(m + d_ii - min_{j != i} d_ij) + relu(m + d_ii - min_{j != i} d_ji)]`
//!
//! the hardest negative of each pair in both directions (a triplet loss with in-batch hardest negatives). The
//! codewords are not normalised, so the margin is relative to the batch's scale: `m = ratio * mean_{i != j}
//! d_ij`, held constant for the gradient (it only sets the hinge's position). Scaling every codeword by `c`
//! scales the loss by `c`: nothing is gained by shrinking the codeword space.

/// Value and gradient of the contrastive loss over `B = source.len() / dim` pairs (`source` and `target` are
/// `B x dim`, row i of each from the same pair): `(L, dL/dsource, dL/dtarget)`. Zero with a zero gradient
/// when `B < 2` (no negatives). Deterministic: sums run in index order, ties pick the lowest index.
pub fn hardest_negative_loss(
    source: &[f32],
    target: &[f32],
    dim: usize,
    margin_ratio: f64,
) -> (f64, Vec<f32>, Vec<f32>) {
    let b = source.len().checked_div(dim).unwrap_or(0);
    let mut d_source = vec![0.0f32; source.len()];
    let mut d_target = vec![0.0f32; target.len()];
    if b < 2 || target.len() != source.len() {
        return (0.0, d_source, d_target);
    }
    let row = |x: &[f32], i: usize| -> Vec<f64> { x[i * dim..][..dim].iter().map(|&v| v as f64).collect() };
    let (s, t): (Vec<Vec<f64>>, Vec<Vec<f64>>) = (0..b).map(|i| (row(source, i), row(target, i))).unzip();
    let dist = |a: &[f64], c: &[f64]| a.iter().zip(c).map(|(x, y)| (x - y) * (x - y)).sum::<f64>().sqrt();
    let d: Vec<Vec<f64>> = (0..b).map(|i| (0..b).map(|j| dist(&s[i], &t[j])).collect()).collect();
    let off_diagonal: f64 =
        (0..b).flat_map(|i| (0..b).filter(move |&j| j != i).map(move |j| (i, j))).map(|(i, j)| d[i][j]).sum();
    let margin = margin_ratio * off_diagonal / (b * (b - 1)) as f64;

    // d|s_i - t_j| / ds_i = (s_i - t_j) / d_ij, and the negation for t_j.
    let mut add = |i: usize, j: usize, weight: f64| {
        let g = weight / d[i][j].max(NORM_EPS);
        for k in 0..dim {
            let v = (g * (s[i][k] - t[j][k])) as f32;
            d_source[i * dim + k] += v;
            d_target[j * dim + k] -= v;
        }
    };
    let weight = 0.5 / b as f64;
    let mut value = 0.0;
    for (i, row) in d.iter().enumerate() {
        // `min_by` keeps the first of equal minima: ties pick the lowest index.
        let nearest =
            |key: &dyn Fn(usize) -> f64| (0..b).filter(|&j| j != i).min_by(|&j, &k| key(j).total_cmp(&key(k)));
        // Source anchor against the other targets, then target anchor against the other sources.
        let row_negative = nearest(&|j| row[j]).expect("b >= 2");
        let column_negative = nearest(&|j| d[j][i]).expect("b >= 2");
        let negatives = [(row[row_negative], (i, row_negative)), (d[column_negative][i], (column_negative, i))];
        for (negative, (ni, nj)) in negatives {
            let hinge = margin + row[i] - negative;
            if hinge > 0.0 {
                value += weight * hinge;
                add(i, i, weight);
                add(ni, nj, -weight);
            }
        }
    }
    (value, d_source, d_target)
}

/// Below this distance the gradient of a distance is taken as zero (coincident codewords).
const NORM_EPS: f64 = 1e-12;
