//! CPU twin of `shaders/mutual_knn.wgsl`: mutual K-nearest-neighbour (or "closest") correspondences from the
//! squared distances of two codeword sets (computed by [`super::codeword_distance`]).
//!
//! Ties break towards the lower index, so the result is deterministic. A pair (a, b) is mutual-K when b is
//! among the K nearest targets of a and a is among the K nearest sources of b.

use crate::settings::MatchMode;

/// A codeword match between source row `source` and target row `target`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Match {
    /// Source keypoint (row of the source codewords).
    pub source: u32,
    /// Target keypoint (row of the target codewords).
    pub target: u32,
    /// Euclidean distance between the codewords.
    pub distance: f32,
}

/// The `k` smallest entries of `values` (index order breaks ties), ascending.
pub fn k_smallest(values: impl Iterator<Item = f32>, k: usize) -> Vec<(f32, u32)> {
    let mut best: Vec<(f32, u32)> = Vec::with_capacity(k + 1);
    for (i, v) in values.enumerate() {
        if best.len() == k && v.partial_cmp(&best[k - 1].0) != Some(std::cmp::Ordering::Less) {
            continue;
        }
        let pos = best.iter().position(|&(bv, _)| v < bv).unwrap_or(best.len());
        best.insert(pos, (v, i as u32));
        best.truncate(k);
    }
    best
}

/// Matches from a distance matrix (the `mutual_knn` kernel's job), sorted by (source, target).
pub fn mutual_knn(distances: &[f32], ns: usize, nt: usize, mode: MatchMode) -> Vec<Match> {
    if ns == 0 || nt == 0 {
        return Vec::new();
    }
    let row = |i: usize| distances[i * nt..][..nt].iter().copied();
    match mode {
        MatchMode::Closest => (0..ns)
            .map(|i| {
                let (d, j) = k_smallest(row(i), 1)[0];
                Match { source: i as u32, target: j, distance: d.max(0.0).sqrt() }
            })
            .collect(),
        MatchMode::Mutual(k) => {
            let k = k.max(1);
            let col_best: Vec<Vec<(f32, u32)>> =
                (0..nt).map(|j| k_smallest((0..ns).map(|i| distances[i * nt + j]), k)).collect();
            let mut out = Vec::new();
            for i in 0..ns {
                for (d, j) in k_smallest(row(i), k) {
                    if col_best[j as usize].iter().any(|&(_, s)| s == i as u32) {
                        out.push(Match { source: i as u32, target: j, distance: d.max(0.0).sqrt() });
                    }
                }
            }
            out.sort_by_key(|m| (m.source, m.target));
            out
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn k_smallest_breaks_ties_by_index() {
        assert_eq!(k_smallest([3.0, 1.0, 1.0, 0.5].into_iter(), 2), vec![(0.5, 3), (1.0, 1)]);
        assert_eq!(k_smallest([2.0, 2.0].into_iter(), 4), vec![(2.0, 0), (2.0, 1)]);
    }
}
