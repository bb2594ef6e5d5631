//! Nearest-neighbour queries over 3-D points (a thin wrapper over kiddo's immutable k-d tree). Results are
//! ordered by (squared distance, index), so ties break deterministically. [`map_nearest`] answers the k nearest
//! of many points of one cloud at once, on cells.

mod knn_cells;

pub use knn_cells::map_nearest;

use crate::error::{Error, Result};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use std::num::NonZero;

/// A static index over a point set; item ids are positions in the slice it was built from.
pub struct PointIndex {
    tree: ImmutableKdTree<f32, 3>,
    len: usize,
}

/// A neighbour: index into the indexed points and squared distance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Neighbor {
    /// Index into the indexed slice.
    pub index: usize,
    /// Squared Euclidean distance to the query.
    pub distance_squared: f32,
}

fn sort(mut v: Vec<Neighbor>) -> Vec<Neighbor> {
    v.sort_by(|a, b| a.distance_squared.total_cmp(&b.distance_squared).then(a.index.cmp(&b.index)));
    v
}

impl PointIndex {
    /// Builds the index. Fails on an empty slice.
    pub fn new(points: &[[f32; 3]]) -> Result<PointIndex> {
        if points.is_empty() {
            return Err(Error::invalid("cannot index an empty point set"));
        }
        let tree = ImmutableKdTree::new_from_slice(points)
            .map_err(|e| Error::invalid(format!("building the k-d tree: {e:?}")))?;
        Ok(PointIndex { tree, len: points.len() })
    }

    /// Number of indexed points.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Always false (an index is never empty).
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The nearest indexed point.
    pub fn nearest_one(&self, query: &[f32; 3]) -> Neighbor {
        let r = self.tree.query(query).nearest_one::<SquaredEuclidean<f32>>().execute();
        Neighbor { index: r.item as usize, distance_squared: r.distance }
    }

    /// The `k` nearest indexed points, nearest first.
    pub fn nearest_n(&self, query: &[f32; 3], k: usize) -> Vec<Neighbor> {
        let Some(k) = NonZero::new(k.min(self.len)) else { return Vec::new() };
        let r = self.tree.query(query).nearest_n::<SquaredEuclidean<f32>>(k).execute();
        sort(r.into_iter().map(|n| Neighbor { index: n.item as usize, distance_squared: n.distance }).collect())
    }

    /// Every indexed point with distance <= `radius`, nearest first.
    pub fn within(&self, query: &[f32; 3], radius: f32) -> Vec<Neighbor> {
        sort(self.within_unsorted(query, radius))
    }

    /// [`PointIndex::within`] in no particular order (for callers whose result does not depend on it).
    pub fn within_unsorted(&self, query: &[f32; 3], radius: f32) -> Vec<Neighbor> {
        self.within_unsorted_iter(query, radius).collect()
    }

    /// [`PointIndex::within_unsorted`] as an iterator, for callers that map or filter the points at once.
    pub fn within_unsorted_iter(&self, query: &[f32; 3], radius: f32) -> impl Iterator<Item = Neighbor> + use<> {
        let r = self.tree.query(query).within::<SquaredEuclidean<f32>>(radius * radius).unsorted().execute();
        r.into_iter().map(|n| Neighbor { index: n.item as usize, distance_squared: n.distance })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn d2(a: &[f32; 3], b: &[f32; 3]) -> f32 {
        (0..3).map(|i| (a[i] - b[i]) * (a[i] - b[i])).sum()
    }

    #[test]
    fn queries_match_brute_force() {
        let mut rng = Rng::new(4);
        let pts: Vec<[f32; 3]> = (0..500).map(|_| [0, 0, 0].map(|_: i32| rng.uniform(-1.0, 1.0) as f32)).collect();
        let index = PointIndex::new(&pts).unwrap();
        for _ in 0..50 {
            let q = [0, 0, 0].map(|_: i32| rng.uniform(-1.2, 1.2) as f32);
            let mut brute: Vec<Neighbor> =
                pts.iter().enumerate().map(|(i, p)| Neighbor { index: i, distance_squared: d2(p, &q) }).collect();
            brute = sort(brute);
            assert_eq!(index.nearest_one(&q).index, brute[0].index);
            let knn: Vec<usize> = index.nearest_n(&q, 7).iter().map(|n| n.index).collect();
            assert_eq!(knn, brute[..7].iter().map(|n| n.index).collect::<Vec<_>>());
            let within: Vec<usize> = index.within(&q, 0.3).iter().map(|n| n.index).collect();
            let want: Vec<usize> = brute.iter().filter(|n| n.distance_squared <= 0.09).map(|n| n.index).collect();
            assert_eq!(within, want);
        }
    }
}
