//! Point-to-plane ICP: optional refinement of a final pose (the pipeline runs it against a voxel-downsampled
//! copy of the target, see `Registrar::estimate`).

use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::pose::{matrix_from_parts, transform_point, v3};
use crate::spatial::PointIndex;
use nalgebra::{Matrix4, Matrix6, Rotation3, Vector3, Vector6};
use rayon::prelude::*;

/// Source points used per iteration at most (an even stride over the cloud).
pub const MAX_ICP_POINTS: usize = 20_000;
/// Source points per parallel task of an iteration (fixed, so the sums do not depend on the thread count).
const ICP_CHUNK: usize = 2048;
/// Stop when the update's rotation (rad) and translation (cloud units) both fall below these.
pub const CONVERGED_ROTATION: f64 = 1e-6;
/// See [`CONVERGED_ROTATION`].
pub const CONVERGED_TRANSLATION: f64 = 1e-6;

/// Refines `target_from_source` by minimising point-to-plane distances to the target's normals, ignoring
/// pairs further apart than `max_distance` (cloud units), for at most `max_iterations` iterations.
pub fn icp_point_to_plane(
    source: &PointCloud,
    target: &PointCloud,
    target_index: &PointIndex,
    initial: Matrix4<f64>,
    max_distance: f32,
    max_iterations: usize,
) -> Result<Matrix4<f64>> {
    let normals = target.normals.as_ref().ok_or_else(|| Error::invalid("point-to-plane ICP needs target normals"))?;
    let stride = source.len().div_ceil(MAX_ICP_POINTS).max(1);
    let max_d2 = max_distance * max_distance;
    let used_points: Vec<[f32; 3]> = source.points.iter().step_by(stride).copied().collect();
    let mut pose = initial;
    for _ in 0..max_iterations {
        // Normal equations summed per fixed chunk in parallel, then the chunks in order: the same sums for
        // any thread count.
        let partial: Vec<(Matrix6<f64>, Vector6<f64>, usize)> = used_points
            .par_chunks(ICP_CHUNK)
            .map(|chunk| {
                let (mut ata, mut atb, mut used) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros(), 0);
                for p in chunk {
                    let moved = transform_point(&pose, *p);
                    let nn = target_index.nearest_one(&moved);
                    if nn.distance_squared > max_d2 {
                        continue;
                    }
                    let (q, n) = (v3(target.points[nn.index]), v3(normals[nn.index]));
                    let m = v3(moved);
                    let r = n.dot(&(m - q));
                    let c = m.cross(&n);
                    let j = Vector6::new(c.x, c.y, c.z, n.x, n.y, n.z);
                    ata += j * j.transpose();
                    atb -= j * r;
                    used += 1;
                }
                (ata, atb, used)
            })
            .collect();
        let (mut ata, mut atb, mut used) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros(), 0);
        for (a, b, u) in partial {
            ata += a;
            atb += b;
            used += u;
        }
        if used < 6 {
            break;
        }
        let Some(x) = ata.cholesky().map(|ch| ch.solve(&atb)) else { break };
        let omega = Vector3::new(x[0], x[1], x[2]);
        let delta = matrix_from_parts(&Rotation3::new(omega).into_inner(), &Vector3::new(x[3], x[4], x[5]));
        pose = delta * pose;
        if omega.norm() < CONVERGED_ROTATION && Vector3::new(x[3], x[4], x[5]).norm() < CONVERGED_TRANSLATION {
            break;
        }
    }
    Ok(pose)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pose::{rotation_error_deg, translation_error};

    #[test]
    fn converges_from_a_small_offset_on_three_planes() {
        // A corner of three perpendicular planes constrains all six degrees of freedom.
        let mut pts = Vec::new();
        let mut nrm = Vec::new();
        for i in 0..30 {
            for j in 0..30 {
                let (a, b) = (i as f32 * 0.02, j as f32 * 0.02);
                pts.extend([[a, b, 0.0], [a, 0.0, b], [0.0, a, b]]);
                nrm.extend([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]);
            }
        }
        let target = PointCloud { points: pts.clone(), normals: Some(nrm) };
        let truth = matrix_from_parts(
            &Rotation3::new(Vector3::new(0.02, -0.01, 0.015)).into_inner(),
            &Vector3::new(0.01, -0.02, 0.015),
        );
        let inv = truth.try_inverse().unwrap();
        let source = PointCloud::from_points(pts.iter().map(|&p| transform_point(&inv, p)).collect());
        let index = PointIndex::new(&target.points).unwrap();
        let est = icp_point_to_plane(&source, &target, &index, Matrix4::identity(), 0.1, 50).unwrap();
        assert!(rotation_error_deg(&est, &truth) < 0.05, "{}", rotation_error_deg(&est, &truth));
        assert!(translation_error(&est, &truth) < 1e-3);
    }
}
