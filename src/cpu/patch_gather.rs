//! CPU twin of `shaders/patch_gather.wgsl`: the sampled neighbours of each kept patch, taken from its ranked
//! candidates (slot `s` takes rank `s mod count`, see [`super::patch_sample`]), with their positions and
//! normals in the layout `patch_features` reads; or, in centre mode, each patch's keypoint.

use super::cell_keys::SortKey;
use crate::error::{Error, Result};

/// A kept patch: `[keypoint cloud index, first ranked candidate in the sorted keys, candidates, 0]`.
pub type PatchEntry = [u32; 4];

/// Gathered rows: cloud index, position and normal of each.
pub type Gathered = (Vec<u32>, Vec<[f32; 3]>, Vec<[f32; 3]>);

/// `n` rows per patch of `table` (or one, the keypoint, with `centers`): the cloud index of each row and its
/// point and normal.
pub fn patch_gather(
    points: &[[f32; 3]],
    normals: &[[f32; 3]],
    sorted: &[SortKey],
    table: &[PatchEntry],
    n: usize,
    centers: bool,
) -> Result<Gathered> {
    let rows_per_patch = if centers { 1 } else { n };
    let mut index = Vec::with_capacity(table.len() * rows_per_patch);
    for e in table {
        if centers {
            index.push(e[0]);
            continue;
        }
        let (start, count) = (e[1] as usize, e[2] as usize);
        if count == 0 || start + count > sorted.len() {
            return Err(Error::invalid(format!("patch_gather: patch {e:?} does not fit {} candidates", sorted.len())));
        }
        index.extend((0..n).map(|s| sorted[start + s % count][2]));
    }
    let row = |j: &u32, v: &[[f32; 3]]| {
        v.get(*j as usize).copied().ok_or_else(|| Error::invalid(format!("patch_gather: index {j} out of range")))
    };
    let p = index.iter().map(|j| row(j, points)).collect::<Result<_>>()?;
    let nn = index.iter().map(|j| row(j, normals)).collect::<Result<_>>()?;
    Ok((index, p, nn))
}
