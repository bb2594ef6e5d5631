//! Voxel-grid downsampling: one averaged point (and normal) per occupied voxel.

use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use std::collections::HashMap;

/// Averages the points (and normals, renormalised) in each `voxel`-sized cube. Output order is sorted by voxel
/// coordinate, so the result does not depend on input order.
pub fn voxel_downsample(cloud: &PointCloud, voxel: f32) -> Result<PointCloud> {
    if !(voxel.is_finite() && voxel > 0.0) {
        return Err(Error::invalid(format!("voxel size must be positive, got {voxel}")));
    }
    let mut cells: HashMap<[i64; 3], ([f64; 3], [f64; 3], usize)> = HashMap::new();
    for (i, p) in cloud.points.iter().enumerate() {
        let key = p.map(|c| (c as f64 / voxel as f64).floor() as i64);
        let cell = cells.entry(key).or_insert(([0.0; 3], [0.0; 3], 0));
        for (sum, &c) in cell.0.iter_mut().zip(p) {
            *sum += c as f64;
        }
        if let Some(n) = cloud.normals.as_ref().map(|ns| ns[i]) {
            for (sum, &c) in cell.1.iter_mut().zip(&n) {
                *sum += c as f64;
            }
        }
        cell.2 += 1;
    }
    let mut cells: Vec<_> = cells.into_iter().collect();
    cells.sort_unstable_by_key(|(k, _)| *k);
    let points = cells.iter().map(|(_, (s, _, n))| s.map(|v| (v / *n as f64) as f32)).collect();
    let normals = cloud.normals.as_ref().map(|_| {
        cells
            .iter()
            .map(|(_, (_, s, _))| {
                let len = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt();
                if len > 0.0 { s.map(|v| (v / len) as f32) } else { [0.0; 3] }
            })
            .collect()
    });
    Ok(PointCloud { points, normals })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn averages_within_cells_and_is_order_independent() {
        let pts = vec![[0.01, 0.01, 0.01], [0.03, 0.03, 0.03], [0.11, 0.0, 0.0], [-0.01, 0.0, 0.0]];
        let out = voxel_downsample(&PointCloud::from_points(pts.clone()), 0.1).unwrap();
        assert_eq!(out.len(), 3);
        let mut rev = pts;
        rev.reverse();
        assert_eq!(out, voxel_downsample(&PointCloud::from_points(rev), 0.1).unwrap());
        assert!(out.points.iter().any(|p| (p[0] - 0.02).abs() < 1e-6 && (p[2] - 0.02).abs() < 1e-6));
        assert!(voxel_downsample(&out, 0.0).is_err());
    }
}
