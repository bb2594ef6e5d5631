//! CPU twin of `shaders/segments.wgsl`: the runs of equal cell keys in a sorted [`SortKey`] array.
//!
//! The kernel flags each run's first element, takes the exclusive prefix sum of the flags (the
//! [`super::prefix_scan`] kernel) to number the runs, and scatters each run's start and key. Runs come out in
//! key order, so the table is the grid's cell table: cell `s` holds the sorted elements `starts[s]..starts[s + 1]`.

use super::cell_keys::SortKey;

/// The runs of equal `(hi, lo)` in sorted keys.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Segments {
    /// Start of each run in the sorted array, then the array's length (`runs + 1` entries).
    pub starts: Vec<u32>,
    /// Each run's key `(hi, lo)`.
    pub keys: Vec<[u32; 2]>,
}

impl Segments {
    /// Number of runs.
    pub fn len(&self) -> usize {
        self.keys.len()
    }

    /// Whether there is no run.
    pub fn is_empty(&self) -> bool {
        self.keys.is_empty()
    }

    /// The run with key `key`, by binary search (as the kernels look cells up).
    pub fn find(&self, key: [u32; 2]) -> Option<usize> {
        self.keys.binary_search(&key).ok()
    }
}

/// Whether sorted element `i` starts a run.
pub fn is_head(sorted: &[SortKey], i: usize) -> bool {
    i == 0 || sorted[i][0] != sorted[i - 1][0] || sorted[i][1] != sorted[i - 1][1]
}

/// The runs of `sorted` (sorted by [`super::bitonic_sort`]).
pub fn segments(sorted: &[SortKey]) -> Segments {
    let mut s = Segments::default();
    for (i, k) in sorted.iter().enumerate() {
        if is_head(sorted, i) {
            s.starts.push(i as u32);
            s.keys.push([k[0], k[1]]);
        }
    }
    s.starts.push(sorted.len() as u32);
    s
}
