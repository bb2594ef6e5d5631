//! `RegistrationSettings::pose_candidates` in the pipeline: a result the verdict trusts is exactly the
//! estimator's choice (what one candidate gives), so the free-space check can only change results that would
//! come back untrusted.

mod common;

use dpr_gpu::model::Weights;
use dpr_gpu::settings::Estimator;
use dpr_gpu::verdict::VerdictSettings;
use dpr_gpu::{Registrar, RegistrationSettings};

#[test]
fn a_trusted_result_is_the_estimators_choice_whatever_the_candidates() {
    let (source, target, _) = common::room_pair(8, 4000);
    let weights = Weights::init(&common::tiny_config(), 3).unwrap();
    // A verdict that trusts any pose (the tiny random weights' RelativeNet poses have hardly an inlier).
    let lenient = VerdictSettings {
        min_inliers: 0,
        min_inlier_ratio: 0.0,
        min_spread_over_threshold: 0.0,
        min_spread_over_scan: 0.0,
        max_reflection_draws: 0,
        free_space_check: false,
    };
    for estimator in [Estimator::RelativeNet, Estimator::Ransac] {
        let base = RegistrationSettings {
            keypoints: 160,
            first_keypoints: None,
            estimator,
            verdict: lenient,
            context_radii: Vec::new(),
            ..Default::default()
        };
        let run = |candidates: usize| {
            let settings = RegistrationSettings { pose_candidates: candidates, ..base.clone() };
            Registrar::with_weights(&settings, &weights).unwrap().register(&source, &target).unwrap()
        };
        let (one, many) = (run(1), run(16));
        assert!(one.success, "{estimator:?}: the lenient verdict trusts the pose: {:?}", one.reason);
        assert_eq!(one.estimate.target_from_source, many.estimate.target_from_source, "{estimator:?}");
        assert_eq!(one.estimate.inliers, many.estimate.inliers);
    }
}
