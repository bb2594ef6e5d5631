//! CPU twin of `shaders/cell_bounds.wgsl`: the integer cell of every point on a uniform grid of cubes of side
//! `1 / inv_cell` anchored at the origin, and the bounding box of those cells.
//!
//! A point's cell is `floor(p * inv_cell)` per axis, computed in f32 exactly as the kernel does (one correctly
//! rounded product, then `floor`), so the CPU and the GPU put every point in the same cell bit for bit. Cell
//! coordinates must stay within `+-2^30` (and the point finite); otherwise the cloud is rejected.

use crate::error::{Error, Result};

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

/// The cell of `p` (`floor(p * inv_cell)` in f32), or `None` when a coordinate is not finite or its cell is out
/// of `+-2^30`.
pub fn cell_of(p: &[f32; 3], inv_cell: f32) -> Option<[i32; 3]> {
    let mut c = [0i32; 3];
    for (a, &v) in p.iter().enumerate() {
        let f = (v * inv_cell).floor();
        if f.is_nan() || f.abs() >= CELL_COORD_LIMIT {
            return None;
        }
        c[a] = f as i32;
    }
    Some(c)
}

/// The box of the cells of `points`; an error for an empty slice or a point whose cell is out of range.
pub fn cell_bounds(points: &[[f32; 3]], inv_cell: f32) -> Result<CellBox> {
    check_inv_cell(inv_cell)?;
    let mut b = CellBox { min: [i32::MAX; 3], max: [i32::MIN; 3] };
    for (i, p) in points.iter().enumerate() {
        let c = cell_of(p, inv_cell).ok_or_else(|| out_of_range(Some((i, p)), inv_cell))?;
        for (a, &ca) in c.iter().enumerate() {
            b.min[a] = b.min[a].min(ca);
            b.max[a] = b.max[a].max(ca);
        }
    }
    if points.is_empty() {
        return Err(Error::invalid("cell grid: no points"));
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
        let b = cell_bounds(&[[0.25, -0.25, 1.0], [-3.0, 2.0, 0.0]], 2.0).unwrap();
        assert_eq!(b, CellBox { min: [-6, -1, 0], max: [0, 4, 2] });
        assert!(cell_bounds(&[], 2.0).is_err());
        assert!(cell_bounds(&[[0.0; 3]], 0.0).is_err());
        assert!(cell_bounds(&[[1e30, 0.0, 0.0]], 1.0).unwrap_err().to_string().contains("point 0"));
    }
}
