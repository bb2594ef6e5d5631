//! CPU twin of `shaders/cell_bounds.wgsl`: the integer cell of every point on a uniform grid of cubes of side
//! `1 / inv_cell` anchored at the origin, and the bounding box of those cells.
//!
//! A point's cell is `floor(p * inv_cell)` per axis, computed in f32 exactly as the kernel does (one correctly
//! rounded product, then `floor`), so the CPU and the GPU put every point in the same cell bit for bit. Cell
//! coordinates must stay within `+-2^30` (and the point finite); otherwise the cloud is rejected.

use crate::error::{Error, Result};
use rayon::prelude::*;

/// Points per parallel task of the grid's per-point passes (here and in [`super::cell_keys`]).
pub const POINTS_PER_TASK: usize = 16_384;

/// Largest magnitude of a cell coordinate (exclusive): `2^30`, so differences of two coordinates fit an `i32`.
pub const CELL_COORD_LIMIT: f32 = 1_073_741_824.0;

/// The inclusive box of occupied cells.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CellBox {
    /// Smallest cell coordinate per axis.
    pub min: [i32; 3],
    /// Largest cell coordinate per axis.
    pub max: [i32; 3],
}

impl CellBox {
    /// The box of no cell (what [`CellBox::include`] grows from).
    const EMPTY: CellBox = CellBox { min: [i32::MAX; 3], max: [i32::MIN; 3] };

    /// The slack of a nearest-neighbour search's stopping rule on this box's grid, in cells: `1e-3` plus 8 ulp
    /// of the largest cell coordinate, which covers the rounding of the cell assignment (`floor(p * inv_cell)`
    /// in f32) and of the comparison.
    pub fn search_slack(&self) -> f32 {
        let max_abs =
            (0..3).map(|a| (self.min[a].unsigned_abs().max(self.max[a].unsigned_abs() + 1)) as f32).fold(0.0, f32::max);
        1e-3 + 8.0 * f32::EPSILON * max_abs
    }

    /// Grows the box to hold the box `other` (a single cell `c` is `CellBox { min: c, max: c }`).
    fn include(&mut self, other: &CellBox) {
        for a in 0..3 {
            self.min[a] = self.min[a].min(other.min[a]);
            self.max[a] = self.max[a].max(other.max[a]);
        }
    }
}

/// How far `q` is from the nearest face of its cell, in cells (`min(f, 1 - f)` over the axes, `f` the fraction of
/// `q * inv_cell`): what a neighbour search adds to the shells it has visited to bound what lies outside them.
pub fn face_gap(q: &[f32; 3], inv_cell: f32) -> f32 {
    q.iter()
        .map(|&v| {
            let u = v * inv_cell;
            let f = u - u.floor();
            f.min(1.0 - f)
        })
        .fold(f32::INFINITY, f32::min)
}

/// The cell of `p` (`floor(p * inv_cell)` in f32), or `None` when a coordinate is not finite or its cell is out
/// of `+-2^30`.
pub fn cell_of(p: &[f32; 3], inv_cell: f32) -> Option<[i32; 3]> {
    let mut c = [0i32; 3];
    for (a, &v) in p.iter().enumerate() {
        // `floor` without a libm call: below 2^30 in magnitude truncation is exact, and one less than it is the
        // floor of a negative non-integer; a product at 2^30 or beyond is an integer already, so rejecting it
        // rejects exactly the floors out of range.
        let scaled = v * inv_cell;
        if scaled.is_nan() || scaled.abs() >= CELL_COORD_LIMIT {
            return None;
        }
        let t = scaled as i32;
        c[a] = if (t as f32) > scaled { t - 1 } else { t };
    }
    Some(c)
}

/// The box of the cells of `points`; an error for an empty slice or a point whose cell is out of range.
pub fn cell_bounds(points: &[[f32; 3]], inv_cell: f32) -> Result<CellBox> {
    check_inv_cell(inv_cell)?;
    if points.is_empty() {
        return Err(Error::invalid("cell grid: no points"));
    }
    // Each task's box in point order, then the boxes merged in order: the first bad point is the one reported.
    let boxes: Vec<Result<CellBox>> = points
        .par_chunks(POINTS_PER_TASK)
        .enumerate()
        .map(|(task, chunk)| {
            let mut b = CellBox::EMPTY;
            for (j, p) in chunk.iter().enumerate() {
                let i = task * POINTS_PER_TASK + j;
                let c = cell_of(p, inv_cell).ok_or_else(|| out_of_range(Some((i, p)), inv_cell))?;
                b.include(&CellBox { min: c, max: c });
            }
            Ok(b)
        })
        .collect();
    let mut b = CellBox::EMPTY;
    for part in boxes {
        b.include(&part?);
    }
    Ok(b)
}

/// An error unless `inv_cell` is finite and positive.
pub fn check_inv_cell(inv_cell: f32) -> Result<()> {
    if inv_cell.is_finite() && inv_cell > 0.0 {
        Ok(())
    } else {
        Err(Error::invalid(format!("cell grid: the cell size must be positive and finite (1 / cell = {inv_cell})")))
    }
}

/// The error for a point whose cell is out of range (`point` when known).
pub fn out_of_range(point: Option<(usize, &[f32; 3])>, inv_cell: f32) -> Error {
    let which = point.map(|(i, p)| format!("point {i} {p:?}")).unwrap_or_else(|| "a point".into());
    Error::invalid(format!(
        "cell grid: {which} is not finite or lies more than 2^30 cells (of size {}) from the origin",
        1.0 / inv_cell
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_floor_the_scaled_coordinates() {
        assert_eq!(cell_of(&[0.25, -0.25, 1.0], 2.0), Some([0, -1, 2]));
        assert_eq!(cell_of(&[f32::NAN, 0.0, 0.0], 2.0), None);
        assert_eq!(cell_of(&[1e30, 0.0, 0.0], 2.0), None);
        // The floor without libm against `f32::floor`, around zero, integers and the range limit.
        let limit = CELL_COORD_LIMIT;
        for v in [
            0.0f32,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            -1e-30,
            2.9999998,
            -2.9999998,
            8388607.5,
            -8388607.5,
            limit - 64.0,
            -(limit - 64.0),
            limit,
            -limit,
            f32::INFINITY,
        ] {
            let want = v.floor();
            let want = (want.abs() < limit).then_some(want as i32);
            assert_eq!(cell_of(&[v, 0.0, 0.0], 1.0).map(|c| c[0]), want, "{v}");
        }
        let b = cell_bounds(&[[0.25, -0.25, 1.0], [-3.0, 2.0, 0.0]], 2.0).unwrap();
        assert_eq!(b, CellBox { min: [-6, -1, 0], max: [0, 4, 2] });
        assert!(cell_bounds(&[], 2.0).is_err());
        assert!(cell_bounds(&[[0.0; 3]], 0.0).is_err());
        assert!(cell_bounds(&[[1e30, 0.0, 0.0]], 1.0).unwrap_err().to_string().contains("point 0"));
        // Across parallel tasks: the box of every point, and the first bad point named.
        let mut many: Vec<[f32; 3]> =
            (0..3 * POINTS_PER_TASK + 5).map(|i| [i as f32 * 0.01, -(i as f32), 0.5]).collect();
        let b = cell_bounds(&many, 1.0).unwrap();
        let n = many.len() as i32;
        assert_eq!(b, CellBox { min: [0, -(n - 1), 0], max: [((n - 1) as f32 * 0.01).floor() as i32, 0, 0] });
        many[2 * POINTS_PER_TASK + 3][1] = f32::NAN;
        many[POINTS_PER_TASK + 7][2] = 1e30;
        let e = cell_bounds(&many, 1.0).unwrap_err().to_string();
        assert!(e.contains(&format!("point {}", POINTS_PER_TASK + 7)), "{e}");
    }
}
