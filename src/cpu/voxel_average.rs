//! CPU twin of `shaders/voxel_average.wgsl`, and [`voxel_downsample`], the one definition of voxel-grid
//! downsampling that `preprocess::voxel_downsample` and the GPU share.
//!
//! A voxel is a cell of the grid of [`super::cell_bounds`] with `inv_cell = 1 / voxel` (f32). Its points are
//! the run of equal keys in the sorted keys ([`super::segments`]), in point-index order (the sort breaks ties
//! by index). The average is taken in f32 relative to the run's first point `p0`, in that order:
//! `p0 + (sum of (p - p0)) / count`, which keeps the sum's rounding relative to the voxel's size rather than to
//! the coordinates' magnitude. Normals are summed the same way (no offset) and renormalised; a zero sum gives a
//! zero normal. Output order is the key order: voxels sorted by cell `(x, y, z)`.

use super::cell_keys::SortKey;
use super::segments::Segments;
use crate::cloud::PointCloud;
use crate::error::{Error, Result};

/// Averaged points and, when normals were given, averaged normals, one per run.
pub type Averages = (Vec<[f32; 3]>, Option<Vec<[f32; 3]>>);

/// The averaged point of run `s` (see the module docs).
pub fn average_point(points: &[[f32; 3]], sorted: &[SortKey], seg: &Segments, s: usize) -> [f32; 3] {
    let (start, end) = (seg.starts[s] as usize, seg.starts[s + 1] as usize);
    let p0 = points[sorted[start][2] as usize];
    let mut sum = [0.0f32; 3];
    for k in &sorted[start + 1..end] {
        let p = points[k[2] as usize];
        for ((s, v), o) in sum.iter_mut().zip(p).zip(p0) {
            *s += v - o;
        }
    }
    let count = (end - start) as f32;
    [0, 1, 2].map(|a| p0[a] + sum[a] / count)
}

/// The renormalised sum of the normals of run `s` (zero when the sum is zero).
pub fn average_normal(normals: &[[f32; 3]], sorted: &[SortKey], seg: &Segments, s: usize) -> [f32; 3] {
    let (start, end) = (seg.starts[s] as usize, seg.starts[s + 1] as usize);
    let mut sum = [0.0f32; 3];
    for k in &sorted[start..end] {
        let n = normals[k[2] as usize];
        for (s, v) in sum.iter_mut().zip(n) {
            *s += v;
        }
    }
    let len = (sum[0] * sum[0] + sum[1] * sum[1] + sum[2] * sum[2]).sqrt();
    if len > 0.0 { sum.map(|v| v / len) } else { [0.0; 3] }
}

/// One averaged point (and normal, when `normals` is given) per run of `seg`, in run order.
pub fn voxel_average(
    points: &[[f32; 3]],
    normals: Option<&[[f32; 3]]>,
    sorted: &[SortKey],
    seg: &Segments,
) -> Averages {
    let pts = (0..seg.len()).map(|s| average_point(points, sorted, seg, s)).collect();
    let nrm = normals.map(|ns| (0..seg.len()).map(|s| average_normal(ns, sorted, seg, s)).collect());
    (pts, nrm)
}

/// The sorted keys and cell table of `points` on the grid of cell size `1 / inv_cell`: the CPU form of the
/// GPU's bounds, keys, sort, scan and scatter passes.
pub fn sorted_cells(
    points: &[[f32; 3]],
    inv_cell: f32,
) -> Result<(super::cell_bounds::CellBox, Vec<SortKey>, Segments)> {
    let bounds = super::cell_bounds::cell_bounds(points, inv_cell)?;
    let mut keys = super::cell_keys::cell_keys(points, inv_cell, &bounds)?;
    super::bitonic_sort::bitonic_sort(&mut keys);
    let seg = super::segments::segments(&keys);
    Ok((bounds, keys, seg))
}

/// Checks the inputs of voxel downsampling (here and on the GPU): a positive finite voxel, as many normals as
/// points. `Some(empty cloud)` is the whole answer for an empty cloud.
pub fn check_downsample(cloud: &PointCloud, voxel: f32) -> Result<Option<PointCloud>> {
    if !(voxel.is_finite() && voxel > 0.0) {
        return Err(Error::invalid(format!("voxel size must be positive, got {voxel}")));
    }
    if cloud.normals.as_ref().is_some_and(|n| n.len() != cloud.len()) {
        return Err(Error::invalid("voxel downsampling: the normals and points differ in number"));
    }
    Ok(cloud.is_empty().then(|| PointCloud { points: Vec::new(), normals: cloud.normals.as_ref().map(|_| Vec::new()) }))
}

/// Voxel-grid downsampling (see the module docs): one averaged point (and normal) per occupied `voxel`-sized
/// cube, sorted by voxel. An error for a voxel size that is not positive and finite, or a cloud too wide for
/// the grid's keys.
pub fn voxel_downsample(cloud: &PointCloud, voxel: f32) -> Result<PointCloud> {
    if let Some(empty) = check_downsample(cloud, voxel)? {
        return Ok(empty);
    }
    let (_, sorted, seg) = sorted_cells(&cloud.points, 1.0 / voxel)?;
    let (points, normals) = voxel_average(&cloud.points, cloud.normals.as_deref(), &sorted, &seg);
    Ok(PointCloud { points, normals })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use std::collections::BTreeMap;

    /// The f64 definition this module replaced (cells `floor(p / voxel)` in f64, means in f64), as an oracle.
    fn f64_reference(points: &[[f32; 3]], voxel: f32) -> Vec<([i64; 3], [f64; 3])> {
        let mut cells: BTreeMap<[i64; 3], ([f64; 3], usize)> = BTreeMap::new();
        for p in points {
            let key = p.map(|c| (c as f64 / voxel as f64).floor() as i64);
            let cell = cells.entry(key).or_insert(([0.0; 3], 0));
            for (s, &c) in cell.0.iter_mut().zip(p) {
                *s += c as f64;
            }
            cell.1 += 1;
        }
        cells.into_iter().map(|(k, (s, n))| (k, s.map(|v| v / n as f64))).collect()
    }

    #[test]
    fn matches_the_f64_definition_away_from_voxel_boundaries() {
        let mut rng = Rng::new(3);
        let voxel = 0.1f32;
        // Points at least 1e-2 voxels from any boundary, where f32 and f64 cells agree.
        let pts: Vec<[f32; 3]> = (0..5000)
            .map(|_| {
                [0; 3].map(|_: i32| ((rng.below(200) as f64 - 100.0 + rng.uniform(0.01, 0.99)) * 0.1 + 37.0) as f32)
            })
            .collect();
        let want = f64_reference(&pts, voxel);
        let got = voxel_downsample(&PointCloud::from_points(pts), voxel).unwrap();
        assert_eq!(got.len(), want.len());
        for (g, (_, w)) in got.points.iter().zip(&want) {
            for a in 0..3 {
                assert!((g[a] as f64 - w[a]).abs() < 1e-5, "{g:?} vs {w:?}");
            }
        }
    }

    #[test]
    fn too_wide_a_cloud_and_mismatched_normals_are_errors() {
        let wide = PointCloud::from_points(vec![[0.0; 3], [1e6, 0.0, 0.0]]);
        assert!(voxel_downsample(&wide, 0.1).unwrap_err().to_string().contains("2097152"));
        let bad = PointCloud { points: vec![[0.0; 3]; 2], normals: Some(vec![[0.0; 3]]) };
        assert!(voxel_downsample(&bad, 0.1).is_err());
        assert!(voxel_downsample(&PointCloud::default(), 0.1).unwrap().is_empty());
    }
}
