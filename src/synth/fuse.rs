//! Fusing depth frames into a fragment by voxel averaging, and grid-average downsampling.

use crate::cloud::PointCloud;

/// The integer voxel index of `p` for voxel size `voxel`.
fn voxel_key(p: &[f64; 3], voxel: f64) -> [i64; 3] {
    [(p[0] / voxel).floor() as i64, (p[1] / voxel).floor() as i64, (p[2] / voxel).floor() as i64]
}

/// Averages (point, normal) samples per voxel of size `voxel`: one output point per occupied voxel at the mean
/// of its samples, with the normalised sum of their normals. Output order is by voxel index (x, then y, then
/// z), and each voxel's samples are summed in input order, so the result is fully deterministic.
pub fn fuse_voxels(samples: &[([f64; 3], [f64; 3])], voxel: f64) -> PointCloud {
    let mut order: Vec<(usize, [i64; 3])> =
        samples.iter().enumerate().map(|(i, (p, _))| (i, voxel_key(p, voxel))).collect();
    order.sort_by_key(|&(i, key)| (key, i));
    let mut points = Vec::new();
    let mut normals = Vec::new();
    let mut start = 0;
    while start < order.len() {
        let key = order[start].1;
        let mut end = start;
        let (mut sp, mut sn) = ([0.0f64; 3], [0.0f64; 3]);
        while end < order.len() && order[end].1 == key {
            let (p, n) = &samples[order[end].0];
            for a in 0..3 {
                sp[a] += p[a];
                sn[a] += n[a];
            }
            end += 1;
        }
        let count = (end - start) as f64;
        let norm = (sn[0] * sn[0] + sn[1] * sn[1] + sn[2] * sn[2]).sqrt();
        let n = if norm > 1e-9 { sn.map(|c| c / norm) } else { samples[order[start].0].1 };
        points.push(sp.map(|c| (c / count) as f32));
        normals.push(n.map(|c| c as f32));
        start = end;
    }
    PointCloud { points, normals: Some(normals) }
}

/// Grid-average downsampling (as MATLAB's `pcdownsample(..., 'gridAverage', g)`): the mean of the points in
/// each occupied cell of size `grid`, in f64, ordered by cell index.
pub fn grid_average(points: &[[f32; 3]], grid: f64) -> Vec<[f64; 3]> {
    let samples: Vec<([f64; 3], [f64; 3])> =
        points.iter().map(|p| ([p[0] as f64, p[1] as f64, p[2] as f64], [0.0; 3])).collect();
    let mut order: Vec<(usize, [i64; 3])> =
        samples.iter().enumerate().map(|(i, (p, _))| (i, voxel_key(p, grid))).collect();
    order.sort_by_key(|&(i, key)| (key, i));
    let mut out = Vec::new();
    let mut start = 0;
    while start < order.len() {
        let key = order[start].1;
        let mut sum = [0.0f64; 3];
        let mut end = start;
        while end < order.len() && order[end].1 == key {
            let p = &samples[order[end].0].0;
            for a in 0..3 {
                sum[a] += p[a];
            }
            end += 1;
        }
        out.push(sum.map(|c| c / (end - start) as f64));
        start = end;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_in_one_voxel_average_and_normals_renormalise() {
        let s = vec![
            ([0.001, 0.001, 0.001], [0.0, 0.0, 1.0]),
            ([0.003, 0.001, 0.001], [0.0, 1.0, 0.0]),
            ([0.010, 0.0, 0.0], [1.0, 0.0, 0.0]),
        ];
        let c = fuse_voxels(&s, 0.006);
        assert_eq!(c.len(), 2);
        assert!((c.points[0][0] - 0.002).abs() < 1e-7);
        let n = c.normals.as_ref().unwrap()[0];
        assert!((n[1] - std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-6 && (n[2] - n[1]).abs() < 1e-6);
        assert_eq!(c.points[1], [0.010, 0.0, 0.0]);
    }

    #[test]
    fn grid_average_is_order_independent_per_cell() {
        let pts = [[0.001f32, 0.0, 0.0], [-0.001, 0.0, 0.0], [0.004, 0.0, 0.0], [0.012, 0.0, 0.0]];
        let g = grid_average(&pts, 0.01);
        assert_eq!(g.len(), 3);
        assert!((g[1][0] - 0.0025).abs() < 1e-9);
    }
}
