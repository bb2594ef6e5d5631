//! The progressive keypoint schedule (`RegistrationSettings::first_keypoints`) against direct runs: a round
//! that describes k keypoints per scan must give exactly what describing k keypoints at once gives, so the
//! schedule changes the time a pair takes and never the pose it ends with.

mod common;

use dpr_gpu::model::Weights;
use dpr_gpu::settings::Estimator;
use dpr_gpu::verdict::VerdictSettings;
use dpr_gpu::{PointCloud, Registrar, RegistrationSettings};

fn tiny_weights() -> Weights {
    Weights::init(&common::tiny_config(), 3).unwrap()
}

fn registrar(settings: &RegistrationSettings, weights: &Weights) -> Registrar {
    Registrar::with_weights(settings, weights).unwrap()
}

/// 120 keypoints, the main radius alone and a verdict nothing passes: every round runs.
fn never_trusted(estimator: Estimator) -> RegistrationSettings {
    let never = VerdictSettings { min_inliers: usize::MAX, ..VerdictSettings::default() };
    RegistrationSettings { keypoints: 120, estimator, verdict: never, context_radii: Vec::new(), ..Default::default() }
}

#[test]
fn a_pair_that_needs_every_round_ends_with_the_direct_result() {
    let (source, target, _) = common::room_pair(4, 4000);
    let weights = tiny_weights();
    for estimator in [Estimator::RelativeNet, Estimator::Ransac] {
        let base = never_trusted(estimator);
        let staged = RegistrationSettings { first_keypoints: Some(25), ..base.clone() };
        let direct = RegistrationSettings { first_keypoints: None, ..base };
        let a = registrar(&staged, &weights).register_detailed(&source, &target).unwrap();
        let b = registrar(&direct, &weights).register_detailed(&source, &target).unwrap();
        assert_eq!(a.result.keypoints, 120);
        assert_eq!(a.result.estimate.target_from_source, b.result.estimate.target_from_source, "{estimator:?}");
        assert_eq!(a.correspondences, b.correspondences);
        assert_eq!(a.source.read_codewords().unwrap(), b.source.read_codewords().unwrap());
        assert_eq!(a.target.keypoints, b.target.keypoints);
        // Four rounds (25, 50, 100, 120): matching is timed once per round.
        assert_eq!(a.result.timings.iter().filter(|t| t.stage == "matching").count(), 4);
        assert_eq!(b.result.timings.iter().filter(|t| t.stage == "matching").count(), 1);
    }
}

/// A pair and settings on which the schedule stops at an early round with the tiny random weights: a verdict
/// that trusts any pose with a handful of inliers, every point kept (the round was found on the full cloud), the
/// main radius alone.
fn early_stopping_pair() -> (PointCloud, PointCloud, RegistrationSettings) {
    let (source, target, _) = common::room_pair(8, 4000);
    let lenient = VerdictSettings {
        min_inliers: 3,
        min_inlier_ratio: 0.0,
        min_spread_over_threshold: 0.0,
        min_spread_over_scan: 0.0,
        max_reflection_draws: 0,
        free_space_check: false,
    };
    let settings = RegistrationSettings {
        keypoints: 320,
        first_keypoints: Some(40),
        voxel: Some(0.0),
        estimator: Estimator::Ransac,
        verdict: lenient,
        context_radii: Vec::new(),
        ..Default::default()
    };
    (source, target, settings)
}

#[test]
fn a_trusted_early_round_is_the_direct_result_at_its_keypoints() {
    // A verdict that trusts any pose with a handful of inliers: the schedule stops at an early round (on this
    // pair, with these tiny random weights, after the third of four rounds).
    let (source, target, base) = early_stopping_pair();
    let weights = tiny_weights();
    let staged = registrar(&base, &weights).register_detailed(&source, &target).unwrap();
    assert!(staged.result.success, "{:?}", staged.result.reason);
    let k = staged.result.keypoints;
    assert!(k < 320, "the schedule should stop before the last round, stopped at {k}");
    // Describing k keypoints at once gives the same pose.
    let direct = RegistrationSettings { keypoints: k, first_keypoints: None, ..base.clone() };
    let d = registrar(&direct, &weights).register(&source, &target).unwrap();
    assert_eq!(d.estimate.target_from_source, staged.result.estimate.target_from_source);
    // And the same schedule over scans described in full (what `eval` does) stops at the same round.
    // At the radius `register` chose from the two clouds, as `eval` describes a scene's scans.
    let full = registrar(&base, &weights).at_scale_of(&[(&source, "source"), (&target, "target")]).unwrap();
    let (s, t) = (full.describe(&source, 0).unwrap(), full.describe(&target, 1).unwrap());
    let round = full.register_described(&s, &t, Estimator::Ransac).unwrap();
    assert_eq!(round.keypoints, k);
    assert_eq!(round.estimate.target_from_source, staged.result.estimate.target_from_source);
}

#[test]
fn pose_features_computed_on_demand_do_not_depend_on_which_rows_came_first() {
    let (source, _, _) = common::room_pair(2, 3000);
    let weights = tiny_weights();
    let settings = RegistrationSettings { keypoints: 60, ..Default::default() };
    let r = registrar(&settings, &weights);
    let a = r.describe(&source, 0).unwrap();
    let b = a.clone();
    let rows = a.keypoints.len() as u32;
    let all: Vec<u32> = (0..rows).collect();
    let everything_at_once = r.pose_features(&a, &all).unwrap();
    // `b` computes a few rows first, then all of them in reverse order.
    let some: Vec<u32> = (0..rows).step_by(7).collect();
    let first = r.pose_features(&b, &some).unwrap();
    let reversed: Vec<u32> = all.iter().rev().copied().collect();
    let later = r.pose_features(&b, &reversed).unwrap();
    let dim = everything_at_once.len() / rows as usize;
    for (slot, &row) in some.iter().enumerate() {
        assert_eq!(&first[slot * dim..][..dim], &everything_at_once[row as usize * dim..][..dim]);
    }
    for (slot, &row) in reversed.iter().enumerate() {
        assert_eq!(&later[slot * dim..][..dim], &everything_at_once[row as usize * dim..][..dim]);
    }
    assert!(everything_at_once.iter().all(|v| v.is_finite()));
    assert!(r.pose_features(&a, &[rows]).is_err());
}

/// `ContextWhen::Untrusted`: rounds on the main radius's codewords alone, then, only while untrusted, one round
/// on every radius over all keypoints, which must be exactly what matching on every radius from the start
/// (`ContextWhen::Always`, keypoints described at once) gives; a pair trusted early never describes the context
/// patches and gets exactly the result without context radii.
#[test]
fn context_radii_only_when_untrusted_add_one_round_on_every_radius() {
    use dpr_gpu::settings::{ContextRadius, ContextWhen};
    let (source, target, _) = common::room_pair(4, 4000);
    let weights = tiny_weights();
    let context = vec![ContextRadius { factor: 2.0, weight: 1.0 }];
    for estimator in [Estimator::RelativeNet, Estimator::Ransac] {
        let base = never_trusted(estimator);
        let lazy = RegistrationSettings {
            first_keypoints: Some(40),
            context_radii: context.clone(),
            context_when: ContextWhen::Untrusted,
            ..base.clone()
        };
        let always = RegistrationSettings {
            first_keypoints: None,
            context_radii: context.clone(),
            context_when: ContextWhen::Always,
            ..base.clone()
        };
        let main_only = RegistrationSettings { first_keypoints: None, ..base.clone() };
        let a = registrar(&lazy, &weights).register_detailed(&source, &target).unwrap();
        let b = registrar(&always, &weights).register_detailed(&source, &target).unwrap();
        let c = registrar(&main_only, &weights).register_detailed(&source, &target).unwrap();
        assert_eq!(a.result.estimate.target_from_source, b.result.estimate.target_from_source, "{estimator:?}");
        assert_eq!(a.correspondences, b.correspondences);
        assert_ne!(a.correspondences, c.correspondences, "the last round matched on the context radius too");
        assert_eq!(
            dpr_gpu::block_on(a.source.context[0].rows.read_codewords()).unwrap(),
            dpr_gpu::block_on(b.source.context[0].rows.read_codewords()).unwrap()
        );
        // Rounds at 40, 80 and 120 keypoints, then the context round: four matchings, one context description
        // per scan.
        assert_eq!(a.result.timings.iter().filter(|t| t.stage == "matching").count(), 4);
        assert_eq!(a.result.timings.iter().filter(|t| t.stage.ends_with("context_encoder")).count(), 2);
        // Scans described in full (`eval`) give the same rounds.
        let r = registrar(&lazy, &weights).at_scale_of(&[(&source, "source"), (&target, "target")]).unwrap();
        let (s, t) = (r.describe(&source, 0).unwrap(), r.describe(&target, 1).unwrap());
        let round = r.register_described(&s, &t, estimator).unwrap();
        assert_eq!(round.estimate.target_from_source, a.result.estimate.target_from_source);
        let once = r.register_described_at_once(&s, &t, estimator).unwrap();
        assert_eq!(once.correspondences, a.correspondences);
    }

    // Trusted in an early round (the pair of `a_trusted_early_round_is_the_direct_result_at_its_keypoints`):
    // no context round and no context description; the result of the main radius alone.
    let (source, target, base) = early_stopping_pair();
    let lazy = RegistrationSettings { context_radii: context, context_when: ContextWhen::Untrusted, ..base.clone() };
    let a = registrar(&lazy, &weights).register_detailed(&source, &target).unwrap();
    let c = registrar(&base, &weights).register_detailed(&source, &target).unwrap();
    assert!(a.result.success, "{:?}", a.result.reason);
    assert_eq!(a.result.estimate.target_from_source, c.result.estimate.target_from_source);
    assert_eq!(a.correspondences, c.correspondences);
    assert!(a.result.timings.iter().all(|t| !t.stage.ends_with("context_encoder")));
    assert_eq!(a.source.context[0].rows.rows(), 0);
}
