//! CPU twin of `shaders/cell_keys.wgsl`: the sort key of every point on a uniform cell grid.
//!
//! WGSL has no 64-bit integers, so a key is a pair of u32: the cell's offsets from the box's minimum corner,
//! 21 bits per axis, packed `x | y | z` from the most significant bit of `hi` down to `lo`. Sorting by
//! `(hi, lo)` therefore orders cells lexicographically by `(x, y, z)`, as sorting the cell coordinates does.
//! A box wider than `2^21` cells on any axis has no key: a clear error, never a wrong order. Each key travels
//! with its point's index as a [`SortKey`] `[hi, lo, index, 0]` (a `vec4<u32>` in WGSL).

use super::cell_bounds::{CellBox, POINTS_PER_TASK, cell_of, out_of_range};
use crate::error::{Error, Result};
use rayon::prelude::*;

/// Bits per axis of a key.
pub const AXIS_BITS: u32 = 21;
/// Most cells a box may span per axis.
pub const MAX_CELLS_PER_AXIS: u64 = 1 << AXIS_BITS;
/// `[key hi, key lo, point index, 0]`.
pub type SortKey = [u32; 4];
/// The key of padding elements (sorts after every real key).
pub const PAD_KEY: SortKey = [u32::MAX, u32::MAX, u32::MAX, 0];

/// Cells per axis of `b`, or an error when an axis spans more than [`MAX_CELLS_PER_AXIS`].
pub fn grid_dims(b: &CellBox) -> Result<[u32; 3]> {
    let mut dims = [0u32; 3];
    for (a, d) in dims.iter_mut().enumerate() {
        let span = i64::from(b.max[a]) - i64::from(b.min[a]) + 1;
        if span <= 0 || span as u64 > MAX_CELLS_PER_AXIS {
            return Err(Error::invalid(format!(
                "cell grid: the cloud spans {span} cells along axis {a}, more than the {MAX_CELLS_PER_AXIS} a \
                 GPU sort key holds (use a larger cell or voxel size, or crop the cloud)"
            )));
        }
        *d = span as u32;
    }
    Ok(dims)
}

/// The key of the cell at offsets `o` (each below `2^21`) from the box's minimum corner.
pub fn pack(o: [u32; 3]) -> [u32; 2] {
    [(o[0] << 10) | (o[1] >> 11), (o[1] << 21) | o[2]]
}

/// The offsets packed in a key ([`pack`]'s inverse).
pub fn unpack(key: [u32; 2]) -> [u32; 3] {
    let mask = (1u32 << AXIS_BITS) - 1;
    [key[0] >> 10, ((key[0] & 0x3ff) << 11) | (key[1] >> 21), key[1] & mask]
}

/// The offsets of cell `c` from `b.min`.
pub fn offsets(c: [i32; 3], b: &CellBox) -> [u32; 3] {
    [0, 1, 2].map(|a| (c[a] as u32).wrapping_sub(b.min[a] as u32))
}

/// The [`SortKey`] of every point, in point order; an error when the box is too wide for a key or a point is
/// outside `b` (or its cell out of range).
pub fn cell_keys(points: &[[f32; 3]], inv_cell: f32, b: &CellBox) -> Result<Vec<SortKey>> {
    let dims = grid_dims(b)?;
    let mut keys = vec![[0u32; 4]; points.len()];
    // Each task fills its keys in point order; the tasks' outcomes in order name the first bad point.
    let outcomes: Vec<Result<()>> = keys
        .par_chunks_mut(POINTS_PER_TASK)
        .zip(points.par_chunks(POINTS_PER_TASK))
        .enumerate()
        .map(|(task, (out, chunk))| {
            for (j, (key, p)) in out.iter_mut().zip(chunk).enumerate() {
                let i = task * POINTS_PER_TASK + j;
                let c = cell_of(p, inv_cell).ok_or_else(|| out_of_range(Some((i, p)), inv_cell))?;
                let o = offsets(c, b);
                if (0..3).any(|a| o[a] >= dims[a]) {
                    return Err(Error::invalid(format!("cell grid: point {i} lies outside the grid's box")));
                }
                let [hi, lo] = pack(o);
                *key = [hi, lo, i as u32, 0];
            }
            Ok(())
        })
        .collect();
    outcomes.into_iter().collect::<Result<()>>()?;
    Ok(keys)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_order_cells_lexicographically_and_unpack() {
        let mut cells =
            [[0, 0, 5], [0, 1, 0], [1, 0, 0], [0, 2047, 3], [0, 2048, 0], [2_097_151, 2_097_151, 2_097_151]];
        cells.sort();
        let keys: Vec<[u32; 2]> = cells.iter().map(|&c| pack(c)).collect();
        assert!(keys.windows(2).all(|w| w[0] < w[1]), "{keys:?}");
        for (c, k) in cells.iter().zip(&keys) {
            assert_eq!(unpack(*k), *c);
        }
        assert!(keys.iter().all(|k| k[0] < PAD_KEY[0]));
    }

    #[test]
    fn keys_across_parallel_tasks_are_each_points_own_and_the_first_bad_point_is_named() {
        let inv_cell = 4.0;
        let mut points: Vec<[f32; 3]> = (0..2 * POINTS_PER_TASK + 9)
            .map(|i| [(i % 97) as f32 * 0.3, -((i % 13) as f32), (i / 1000) as f32])
            .collect();
        let b = super::super::cell_bounds::cell_bounds(&points, inv_cell).unwrap();
        let keys = cell_keys(&points, inv_cell, &b).unwrap();
        for (i, (k, p)) in keys.iter().zip(&points).enumerate() {
            let want = pack(offsets(cell_of(p, inv_cell).unwrap(), &b));
            assert_eq!(*k, [want[0], want[1], i as u32, 0]);
        }
        points[POINTS_PER_TASK + 1] = [1000.0, 0.0, 0.0];
        points[POINTS_PER_TASK + 5] = [f32::NAN, 0.0, 0.0];
        let e = cell_keys(&points, inv_cell, &b).unwrap_err().to_string();
        assert!(e.contains(&format!("point {} lies outside", POINTS_PER_TASK + 1)), "{e}");
    }

    #[test]
    fn too_wide_a_box_is_an_error() {
        let b = CellBox { min: [0, -1_048_576, 0], max: [1, 1_048_576, 0] };
        assert!(grid_dims(&b).unwrap_err().to_string().contains("axis 1"));
        let ok = CellBox { min: [0, -1_048_576, 0], max: [1, 1_048_575, 0] };
        assert_eq!(grid_dims(&ok).unwrap(), [2, 2_097_152, 1]);
    }
}
