//! The verdict's free-space check (`VerdictSettings::free_space_check`): a pose that every correspondence
//! supports is still untrusted when it moves a scan's walls into space the other scan saw empty, as a slide along
//! repeated structure does; the true pose of the same scans stays trusted.

mod common;

use dpr_gpu::cloud::PointCloud;
use dpr_gpu::model::Weights;
use dpr_gpu::pose::{matrix_from_parts, transform_point};
use dpr_gpu::settings::BackendKind;
use dpr_gpu::synth::geometry::box_room_grid;
use dpr_gpu::verdict::VerdictSettings;
use dpr_gpu::{Correspondence, PoseEstimate, Registrar, RegistrationSettings};
use nalgebra::{Matrix3, Matrix4, Rotation3, Vector3};

/// Correspondences between keypoints of the source and their images under `target_from_source` (every one an
/// inlier of that pose).
fn agreeing(source_keypoints: &[[f32; 3]], target_from_source: &Matrix4<f64>) -> Vec<Correspondence> {
    source_keypoints
        .iter()
        .enumerate()
        .map(|(k, &p)| Correspondence {
            source_index: k as u32,
            target_index: k as u32,
            source_point: p,
            target_point: transform_point(target_from_source, p),
            feature_distance: 0.0,
        })
        .collect()
}

#[test]
fn a_pose_that_moves_a_wall_into_seen_empty_space_is_not_trusted() {
    // One room seen from inside by two sensors, each scan in its sensor's frame (the viewpoint at the origin).
    let world = box_room_grid([3.0, 2.0, 1.5], 0.05);
    let source_from_world = matrix_from_parts(&Matrix3::identity(), &Vector3::new(0.4, -0.2, 0.1));
    let truth =
        matrix_from_parts(&Rotation3::from_euler_angles(0.05, -0.1, 0.9).into_inner(), &Vector3::new(0.3, 0.5, -0.1));
    let scan = |from_world: &Matrix4<f64>| {
        PointCloud::from_points(world.iter().map(|&p| transform_point(from_world, p)).collect())
    };
    let (source, target) = (scan(&source_from_world), scan(&(truth * source_from_world)));
    // The verdict's count, ratio and spread rules trust both poses below; the box is mirror-symmetric, so the
    // handedness check is left out to test this check alone.
    let verdict = VerdictSettings { max_reflection_draws: 0, ..VerdictSettings::default() };
    let settings = RegistrationSettings {
        radius: Some(0.6),
        keypoints: 200,
        first_keypoints: None,
        verdict,
        context_radii: Vec::new(),
        backend: BackendKind::Cpu,
        ..Default::default()
    };
    let weights = Weights::init(&common::tiny_config(), 3).unwrap();
    let registrar = Registrar::with_weights(&settings, &weights).unwrap();
    let (s, t) = (registrar.describe(&source, 0).unwrap(), registrar.describe(&target, 1).unwrap());
    let judge = |target_from_source: Matrix4<f64>| {
        let correspondences = agreeing(&s.keypoints, &target_from_source);
        let n = correspondences.len();
        let estimate =
            PoseEstimate { target_from_source, inliers: n, inlier_rmse: 0.0, fitness: 1.0, hypotheses_scored: 1 };
        registrar.judge((&s, &t), &estimate, &correspondences)
    };

    let right = judge(truth);
    assert!(right.success, "the true pose: {:?}", right.reason);
    // Sliding the source 0.8 m along the target's x puts a whole wall inside the room the target saw empty.
    let slid = matrix_from_parts(&Matrix3::identity(), &Vector3::new(0.8, 0.0, 0.0)) * truth;
    let wrong = judge(slid);
    assert!(!wrong.success, "the slid pose is trusted");
    assert!(wrong.reason.as_deref().unwrap_or("").contains("saw empty"), "{:?}", wrong.reason);
    // Off, the same pose passes: nothing else in the verdict tells the two apart.
    let off = RegistrationSettings { verdict: VerdictSettings { free_space_check: false, ..verdict }, ..settings };
    let lenient = Registrar::with_weights(&off, &weights).unwrap();
    let correspondences = agreeing(&s.keypoints, &slid);
    let n = correspondences.len();
    let estimate =
        PoseEstimate { target_from_source: slid, inliers: n, inlier_rmse: 0.0, fitness: 1.0, hypotheses_scored: 1 };
    assert!(lenient.judge((&s, &t), &estimate, &correspondences).success);
}
