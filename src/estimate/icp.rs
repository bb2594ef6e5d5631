//! Point-to-plane ICP: optional refinement of a final pose (the pipeline runs it against a voxel-downsampled
//! copy of the target, see `Registrar::estimate`). The loop ([`iterate`]: solve, update, stopping rules) is
//! shared; the per-point sums run where the backend keeps the clouds ([`crate::backend::Backend::refine_icp`]:
//! [`icp_point_to_plane`] on the host, the `icp_normal_equations` kernel on a GPU).

use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::pose::{matrix_from_parts, transform_point, v3};
use crate::preprocess::{estimate_normals_at, voxel_downsample};
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
/// A source point's query is skipped only when its distance bound exceeds the pairing distance by this
/// factor: far more than the f32 rounding of the moved points and of the tree's squared distances.
const SKIP_MARGIN: f64 = 1.001;

/// Euclidean distance between two points, in f64.
fn distance(a: &[f32; 3], b: &[f32; 3]) -> f64 {
    (v3(*a) - v3(*b)).norm()
}

/// What a point-to-plane ICP refinement of a pair needs besides the clouds and the initial pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IcpProblem {
    /// Pairs further apart than this (cloud units) are ignored; the target is downsampled at half of it.
    pub max_distance: f32,
    /// Iteration limit.
    pub max_iterations: usize,
    /// Neighbours of the PCA normals estimated on the downsampled target (facing the origin).
    pub normal_neighbors: usize,
}

/// The sums of one ICP iteration: `ata = sum J J^T`, `atb = -sum J r` over the `used` pairs within the
/// distance, `J = [m x n, n]` and `r = n . (m - q)` for a moved source point `m`, its nearest target point `q`
/// and that point's normal `n`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NormalEquations {
    /// `sum J J^T`.
    pub ata: Matrix6<f64>,
    /// `-sum J r`.
    pub atb: Vector6<f64>,
    /// Pairs summed.
    pub used: usize,
}

/// The stride of the source points ICP uses: every `stride`-th point, at most [`MAX_ICP_POINTS`] of them.
pub fn source_stride(points: usize) -> usize {
    points.div_ceil(MAX_ICP_POINTS).max(1)
}

/// The ICP loop shared by every backend: from `initial`, asks `sums` for the normal equations at the current
/// pose, solves the 6x6 system (Cholesky, f64), applies the small-angle update on the left, and stops after
/// `max_iterations`, when fewer than six pairs are used, when the system is singular, or when the update falls
/// below [`CONVERGED_ROTATION`] and [`CONVERGED_TRANSLATION`]. Async because a device's sums are a readback;
/// the host's are ready at once.
pub async fn iterate(
    initial: Matrix4<f64>,
    max_iterations: usize,
    mut sums: impl AsyncFnMut(&Matrix4<f64>) -> Result<NormalEquations>,
) -> Result<Matrix4<f64>> {
    let mut pose = initial;
    for _ in 0..max_iterations {
        let NormalEquations { ata, atb, used } = sums(&pose).await?;
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
    let stride = source_stride(source.len());
    let max_d2 = max_distance * max_distance;
    let used_points: Vec<[f32; 3]> = source.points.iter().step_by(stride).copied().collect();
    // A lower bound on each point's distance to the target, carried from iteration to iteration: a point whose
    // bound, less how far the new pose moves it, is still beyond the distance cannot pair (triangle
    // inequality), so its query is skipped; the sums are the same, point for point.
    let mut bounds = vec![0.0f64; used_points.len()];
    let mut previous: Option<Matrix4<f64>> = None;
    // The host's sums are computed when asked for, so the loop never waits.
    crate::block_on(iterate(initial, max_iterations, async |pose| {
        let last = previous.replace(*pose);
        // Normal equations summed per fixed chunk in parallel, then the chunks in order: the same sums for
        // any thread count.
        let partial: Vec<(Matrix6<f64>, Vector6<f64>, usize)> = used_points
            .par_chunks(ICP_CHUNK)
            .zip(bounds.par_chunks_mut(ICP_CHUNK))
            .map(|(chunk, bounds)| {
                let (mut ata, mut atb, mut used) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros(), 0);
                for (p, bound) in chunk.iter().zip(bounds) {
                    let moved = transform_point(pose, *p);
                    if let Some(last) = &last {
                        *bound -= distance(&moved, &transform_point(last, *p));
                        if *bound > SKIP_MARGIN * f64::from(max_distance) {
                            continue;
                        }
                    }
                    let nn = target_index.nearest_one(&moved);
                    *bound = f64::from(nn.distance_squared).sqrt();
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
        Ok(NormalEquations { ata, atb, used })
    }))
}

/// Normals of a target's points estimated so far (NaN where not yet), by [`estimate_normals_at`] over
/// `neighbors` neighbours facing `viewpoint` on a k-d tree of the target's own points.
#[derive(Clone, Copy, Debug)]
pub struct KnownNormals<'a> {
    /// One per target point.
    pub normals: &'a [[f32; 3]],
    /// Neighbours of each PCA.
    pub neighbors: usize,
    /// Where they face.
    pub viewpoint: [f32; 3],
}

/// Point-to-plane ICP from `initial` on the host (what a backend runs unless it overrides
/// [`crate::backend::Backend::refine_icp`]): `target` voxel-downsampled at half the distance, PCA normals of
/// the copy facing the origin ([`copy_normals`]: those `known` already gives are reused), then
/// [`icp_point_to_plane`] of every `source` point (strided).
pub fn refine_on_host(
    source: &PointCloud,
    (target, known): (&PointCloud, Option<KnownNormals<'_>>),
    initial: Matrix4<f64>,
    problem: &IcpProblem,
) -> Result<Matrix4<f64>> {
    let voxel = problem.max_distance / 2.0;
    let mut small = voxel_downsample(&PointCloud::from_points(target.points.clone()), voxel)?;
    let index = PointIndex::new(&small.points)?;
    let known = known.filter(|_| small.points == target.points);
    small.normals = Some(copy_normals(&small.points, &index, known, problem.normal_neighbors));
    icp_point_to_plane(source, &small, &index, initial, problem.max_distance, problem.max_iterations)
}

/// The normals of ICP's copy of the target (`points`, indexed by `index`): PCA over `neighbors` neighbours
/// facing the origin. `known`, where given, holds normals of these very points (the copy equals the target
/// when the target is already one point per voxel, as the pipeline's default voxel leaves it): where it was
/// estimated the same way (same neighbours, facing the origin) its normals are taken as they are and only the
/// rest estimated. The same function on the same points and k-d tree, so the same normals bit for bit.
pub fn copy_normals(
    points: &[[f32; 3]],
    index: &PointIndex,
    known: Option<KnownNormals<'_>>,
    neighbors: usize,
) -> Vec<[f32; 3]> {
    const FACING: [f32; 3] = [0.0; 3];
    let reusable =
        known.filter(|k| k.neighbors == neighbors && k.viewpoint == FACING && k.normals.len() == points.len());
    let mut normals = match reusable {
        Some(k) => k.normals.to_vec(),
        None => vec![[f32::NAN; 3]; points.len()],
    };
    let missing: Vec<usize> = (0..points.len()).filter(|&i| normals[i].iter().any(|c| c.is_nan())).collect();
    for (i, n) in missing.iter().zip(estimate_normals_at(points, index, &missing, neighbors, FACING)) {
        normals[*i] = n;
    }
    normals
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pose::{rotation_error_deg, translation_error};

    /// A bumpy sheet with a step, one point per 0.05 cell: enough curvature for distinct PCA normals.
    fn bumpy_sheet() -> Vec<[f32; 3]> {
        let mut pts = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                let (x, y) = (i as f32 * 0.05 + 0.012, j as f32 * 0.05 + 0.013);
                let z = 0.1 * (3.0 * x).sin() * (2.0 * y).cos() + if x > 1.0 { 0.2 } else { 0.0 } + 0.01;
                pts.push([x, y, z]);
            }
        }
        pts
    }

    #[test]
    fn the_copy_reuses_normals_estimated_the_same_way_and_only_those() {
        let pts = bumpy_sheet();
        let index = PointIndex::new(&pts).unwrap();
        let all: Vec<usize> = (0..pts.len()).collect();
        let fresh = estimate_normals_at(&pts, &index, &all, 12, [0.0; 3]);
        // Normals estimated the same way for every third point, NaN elsewhere (a scan's placeholders).
        let partial: Vec<[f32; 3]> =
            fresh.iter().enumerate().map(|(i, &n)| if i % 3 == 0 { n } else { [f32::NAN; 3] }).collect();
        fn known(normals: &[[f32; 3]], neighbors: usize, viewpoint: [f32; 3]) -> Option<KnownNormals<'_>> {
            Some(KnownNormals { normals, neighbors, viewpoint })
        }
        let same =
            |a: &[[f32; 3]], b: &[[f32; 3]]| a.iter().zip(b).all(|(x, y)| x.map(f32::to_bits) == y.map(f32::to_bits));
        assert!(same(&copy_normals(&pts, &index, known(&partial, 12, [0.0; 3]), 12), &fresh));
        // Reused where known: a marker normal comes back where it stands, the rest is estimated.
        let mut marked = partial.clone();
        marked[0] = [0.0, 0.0, 1.0];
        let got = copy_normals(&pts, &index, known(&marked, 12, [0.0; 3]), 12);
        assert_eq!(got[0], [0.0, 0.0, 1.0]);
        assert!(same(&got[1..], &fresh[1..]));
        // Estimated otherwise (other neighbours or another viewpoint): never reused.
        for (k, view) in [(8, [0.0; 3]), (12, [0.0, 0.0, 5.0])] {
            assert!(same(&copy_normals(&pts, &index, known(&marked, k, view), 12), &fresh), "{k} {view:?}");
        }
    }

    #[test]
    fn icp_on_the_host_gives_the_same_pose_with_the_scans_normals() {
        let target = PointCloud::from_points(bumpy_sheet());
        let truth = matrix_from_parts(
            &Rotation3::new(Vector3::new(0.01, -0.02, 0.015)).into_inner(),
            &Vector3::new(0.02, -0.01, 0.01),
        );
        let inv = truth.try_inverse().unwrap();
        let source = PointCloud::from_points(target.points.iter().map(|&p| transform_point(&inv, p)).collect());
        let problem = IcpProblem { max_distance: 0.1, max_iterations: 30, normal_neighbors: 12 };
        // The target already one point per voxel of the copy (0.05), its normals estimated for half its points.
        let index = PointIndex::new(&target.points).unwrap();
        let half: Vec<usize> = (0..target.len()).step_by(2).collect();
        let mut normals = vec![[f32::NAN; 3]; target.len()];
        for (&i, n) in half.iter().zip(estimate_normals_at(&target.points, &index, &half, 12, [0.0; 3])) {
            normals[i] = n;
        }
        let copy = voxel_downsample(&target, problem.max_distance / 2.0).unwrap();
        assert_eq!(copy.points, target.points, "the copy is the target: its normals are reused");
        let known = KnownNormals { normals: &normals, neighbors: 12, viewpoint: [0.0; 3] };
        let without = refine_on_host(&source, (&target, None), Matrix4::identity(), &problem).unwrap();
        let with = refine_on_host(&source, (&target, Some(known)), Matrix4::identity(), &problem).unwrap();
        assert_eq!(with, without, "bit for bit");
        assert!(rotation_error_deg(&with, &truth) < 0.05 && translation_error(&with, &truth) < 1e-3);
    }

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

    /// The ICP sums of every source point, no query skipped: the definition [`icp_point_to_plane`] keeps.
    fn every_point_sums(
        points: &[[f32; 3]],
        target: &PointCloud,
        index: &PointIndex,
        pose: &Matrix4<f64>,
        max_distance: f32,
    ) -> NormalEquations {
        let normals = target.normals.as_ref().unwrap();
        let (mut ata, mut atb, mut used) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros(), 0);
        for chunk in points.chunks(ICP_CHUNK) {
            let (mut a, mut b, mut u) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros(), 0);
            for p in chunk {
                let moved = transform_point(pose, *p);
                let nn = index.nearest_one(&moved);
                if nn.distance_squared > max_distance * max_distance {
                    continue;
                }
                let (q, n, m) = (v3(target.points[nn.index]), v3(normals[nn.index]), v3(moved));
                let c = m.cross(&n);
                let j = Vector6::new(c.x, c.y, c.z, n.x, n.y, n.z);
                a += j * j.transpose();
                b -= j * n.dot(&(m - q));
                u += 1;
            }
            ata += a;
            atb += b;
            used += u;
        }
        NormalEquations { ata, atb, used }
    }

    /// Half the source lies far from the target (a partial overlap), so most of its queries are skipped after
    /// the first iteration; the pose is still bit for bit the one of summing every point at every iteration.
    #[test]
    fn skipping_far_points_gives_the_same_pose_bit_for_bit() {
        let mut pts = Vec::new();
        let mut nrm = Vec::new();
        for i in 0..60 {
            for j in 0..60 {
                let (a, b) = (i as f32 * 0.02, j as f32 * 0.02);
                pts.extend([[a, b, 0.05 * a * a], [a, 0.0, b], [0.0, a, b]]);
                nrm.extend([[-0.1 * a, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]);
            }
        }
        let nrm = nrm.iter().map(|n: &[f32; 3]| v3(*n).normalize()).map(|n| [n.x as f32, n.y as f32, n.z as f32]);
        let target = PointCloud { points: pts.clone(), normals: Some(nrm.collect()) };
        let truth = matrix_from_parts(
            &Rotation3::new(Vector3::new(0.03, -0.02, 0.025)).into_inner(),
            &Vector3::new(0.02, -0.03, 0.015),
        );
        let inv = truth.try_inverse().unwrap();
        // The source: the target's points moved, and as many again: some off the surface within the pairing
        // distance, some just beyond it, most far beyond.
        let mut source_points: Vec<[f32; 3]> = pts.iter().map(|&p| transform_point(&inv, p)).collect();
        source_points.extend(pts.iter().enumerate().map(|(i, p)| match i % 7 {
            // Off the surface but within the pairing distance: they pair at every iteration.
            0 => transform_point(&inv, [p[0] + 0.05, p[1] + 0.05, p[2] + 0.05]),
            // Just beyond it, and far beyond.
            1 => transform_point(&inv, [p[0] + 1.3, p[1] - 0.4, p[2] + 0.12]),
            _ => transform_point(&inv, [p[0] + 1.3, p[1] - 0.4, p[2] + 2.0]),
        }));
        let source = PointCloud::from_points(source_points);
        let index = PointIndex::new(&target.points).unwrap();
        let (max_distance, iterations) = (0.1, 40);
        let got = icp_point_to_plane(&source, &target, &index, Matrix4::identity(), max_distance, iterations).unwrap();
        let used: Vec<[f32; 3]> = source.points.iter().step_by(source_stride(source.len())).copied().collect();
        let want = crate::block_on(iterate(Matrix4::identity(), iterations, async |pose| {
            Ok(every_point_sums(&used, &target, &index, pose, max_distance))
        }))
        .unwrap();
        assert_eq!(got, want, "bit for bit");
        // The off-surface points pull it a little; it still lands far nearer the truth than it started (2.5 deg).
        assert!(rotation_error_deg(&got, &truth) < 0.5, "{}", rotation_error_deg(&got, &truth));
    }
}
