//! Voxel-grid downsampling: one averaged point (and normal) per occupied voxel.
//!
//! The definition lives in [`crate::cpu::voxel_average`], the CPU twin of the GPU kernels, so the CPU and
//! GPU paths assign every point to the same voxel bit for bit.

pub use crate::cpu::voxel_average::voxel_downsample;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cloud::PointCloud;

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
