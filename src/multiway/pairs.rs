//! Which pairs of scans to register: all pairs, or consecutive pairs plus retrieval, where every scan adds the
//! K scans whose pooled codewords are most similar to its own.
//!
//! A scan's pooled codeword is the mean of its keypoints' unit-length PPF-FoldNet codewords, scaled to unit
//! length. The codewords are rotation-invariant descriptions of local geometry, so two scans of the same place
//! pool to similar vectors whatever their poses; the cosine similarity of two pooled codewords ranks candidate
//! loop closures at the cost of one dot product per pair, instead of a registration per pair.

use serde::{Deserialize, Serialize};

/// How candidate pairs are chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum PairSelection {
    /// Every pair i < j.
    All,
    /// Consecutive pairs (k, k + 1), plus for every scan the `k` most similar other scans by pooled codewords.
    ConsecutiveAndRetrieval {
        /// Retrieved scans per scan.
        k: usize,
    },
}

/// Mean of the unit-length rows of `codewords` (`rows x dim`, row-major), scaled to unit length (zero rows are
/// skipped; all zeros gives a zero vector).
pub fn pooled_codeword(codewords: &[f32], dim: usize) -> Vec<f32> {
    let mut sum = vec![0f64; dim];
    if dim == 0 {
        return Vec::new();
    }
    for row in codewords.chunks_exact(dim) {
        let norm = row.iter().map(|&v| f64::from(v) * f64::from(v)).sum::<f64>().sqrt();
        if norm > 0.0 {
            for (s, &v) in sum.iter_mut().zip(row) {
                *s += f64::from(v) / norm;
            }
        }
    }
    let norm = sum.iter().map(|v| v * v).sum::<f64>().sqrt();
    sum.iter().map(|&v| if norm > 0.0 { (v / norm) as f32 } else { 0.0 }).collect()
}

/// Cosine similarity of two unit vectors (their dot product).
fn similarity(a: &[f32], b: &[f32]) -> f64 {
    a.iter().zip(b).map(|(&x, &y)| f64::from(x) * f64::from(y)).sum()
}

/// The pairs `(i, j)`, i < j, to register among `n` scans, in registration order: consecutive pairs first (they
/// hold the trajectory together), then the other candidates by decreasing similarity (for `All`: by increasing
/// j - i), cut to `max_pairs` when given. `pooled` (one pooled codeword per scan) is needed for retrieval only.
pub fn select_pairs(
    n: usize,
    selection: PairSelection,
    pooled: Option<&[Vec<f32>]>,
    max_pairs: Option<usize>,
) -> Vec<(usize, usize)> {
    let consecutive: Vec<(usize, usize)> = (1..n).map(|k| (k - 1, k)).collect();
    let mut others: Vec<((usize, usize), f64)> = match selection {
        PairSelection::All => (0..n).flat_map(|i| (i + 2..n).map(move |j| ((i, j), -((j - i) as f64)))).collect(),
        PairSelection::ConsecutiveAndRetrieval { k } => {
            let mut chosen: Vec<((usize, usize), f64)> = Vec::new();
            if let Some(pooled) = pooled {
                for i in 0..n.min(pooled.len()) {
                    let mut ranked: Vec<(usize, f64)> = (0..n.min(pooled.len()))
                        .filter(|&j| j != i)
                        .map(|j| (j, similarity(&pooled[i], &pooled[j])))
                        .collect();
                    // Most similar first; ties to the nearer index, so the order is total and deterministic.
                    ranked.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
                    for &(j, s) in ranked.iter().take(k) {
                        let pair = (i.min(j), i.max(j));
                        if pair.1 > pair.0 + 1 && !chosen.iter().any(|(p, _)| *p == pair) {
                            chosen.push((pair, s));
                        }
                    }
                }
            }
            chosen
        }
    };
    others.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
    let mut pairs = consecutive;
    pairs.extend(others.into_iter().map(|(p, _)| p));
    if let Some(m) = max_pairs {
        pairs.truncate(m);
    }
    pairs
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn all_pairs_lists_consecutive_first_then_by_gap() {
        let pairs = select_pairs(4, PairSelection::All, None, None);
        assert_eq!(pairs, [(0, 1), (1, 2), (2, 3), (0, 2), (1, 3), (0, 3)]);
        assert_eq!(select_pairs(4, PairSelection::All, None, Some(4)).len(), 4);
        assert!(select_pairs(1, PairSelection::All, None, None).is_empty());
    }

    #[test]
    fn retrieval_adds_the_most_similar_non_consecutive_scans() {
        // Scans 0 and 4 look alike, as do 1 and 3; 2 is unlike everything (its best match, at similarity 0, is the
        // lowest index: scan 0).
        let pooled: Vec<Vec<f32>> =
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.1, 0.99, 0.0], [0.99, 0.1, 0.0]]
                .iter()
                .map(|v| pooled_codeword(v, 3))
                .collect();
        let pairs = select_pairs(5, PairSelection::ConsecutiveAndRetrieval { k: 1 }, Some(&pooled), None);
        assert_eq!(pairs, [(0, 1), (1, 2), (2, 3), (3, 4), (0, 4), (1, 3), (0, 2)]);
        let capped = select_pairs(5, PairSelection::ConsecutiveAndRetrieval { k: 1 }, Some(&pooled), Some(5));
        assert_eq!(capped, [(0, 1), (1, 2), (2, 3), (3, 4), (0, 4)]);
    }

    #[test]
    fn pooling_normalises_rows_and_the_result() {
        let p = pooled_codeword(&[3.0, 0.0, 0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 0.0], 3);
        let s = std::f32::consts::FRAC_1_SQRT_2;
        assert!((p[0] - s).abs() < 1e-6 && (p[1] - s).abs() < 1e-6 && p[2] == 0.0, "{p:?}");
    }
}
