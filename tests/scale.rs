//! Scale from the data: with no radius given, a pair registers the same whatever its units. The oracle is the
//! example pair's ground truth (examples/pair/pairs.txt) and the pair itself in metres: the same pair in
//! millimetres and in kilometres must give the same verdict, the same support and the same pose (within the rounding of scaling f32 coordinates; translation
//! scaled), at a radius scaled by the same factor.

use dpr_gpu::backend::CpuBackend;
use dpr_gpu::model::{Model, Weights};
use dpr_gpu::pose::{rotation_error_deg, translation_error};
use dpr_gpu::{PointCloud, Registrar, RegistrationSettings};
use nalgebra::Matrix4;
use std::path::Path;

fn example_pair() -> (PointCloud, PointCloud, Matrix4<f64>) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/pair");
    let load = |name: &str| dpr_gpu::io::read_cloud(&dir.join(name), &Default::default()).unwrap().0;
    let pairs = std::fs::read_to_string(dir.join("pairs.txt")).unwrap();
    let line = pairs.lines().find(|l| !l.starts_with('#')).unwrap();
    let values: Vec<f64> = line.split_whitespace().skip(2).map(|x| x.parse().unwrap()).collect();
    (load("cloud_bin_1.ply"), load("cloud_bin_0.ply"), Matrix4::from_row_slice(&values))
}

fn scaled(cloud: &PointCloud, k: f32) -> PointCloud {
    PointCloud::from_points(cloud.points.iter().map(|p| p.map(|c| c * k)).collect())
}

/// The f32 CPU path (bf16 would round differently at each scale only through the same products, but f32
/// keeps the comparison about the scale alone).
fn registrar(settings: &RegistrationSettings) -> Registrar {
    let model = Model::from_weights(&Weights::built_in().unwrap()).unwrap();
    Registrar::with_backend(settings, Box::new(CpuBackend::new(model))).unwrap()
}

#[test]
fn a_pair_in_millimetres_or_kilometres_registers_as_in_metres() {
    let (source, target, truth) = example_pair();
    let settings = RegistrationSettings { keypoints: 250, first_keypoints: None, ..Default::default() };
    let reg = registrar(&settings);
    let metres = reg.register(&source, &target).unwrap();
    assert!(metres.success, "{:?}", metres.reason);
    assert!(metres.scale.rule.starts_with("auto"), "{}", metres.scale.rule);
    let t = &metres.estimate.target_from_source;
    assert!(rotation_error_deg(t, &truth) < 3.0, "rotation error {}", rotation_error_deg(t, &truth));
    assert!(translation_error(t, &truth) < 0.1, "translation error {}", translation_error(t, &truth));
    for k in [1000.0f32, 0.001] {
        let other = reg.register(&scaled(&source, k), &scaled(&target, k)).unwrap();
        let ratio = f64::from(other.scale.radius) / f64::from(metres.scale.radius);
        assert!(
            (ratio / f64::from(k) - 1.0).abs() < 1e-4,
            "radius {} vs {} at x{k}",
            other.scale.radius,
            metres.scale.radius
        );
        assert_eq!(other.success, metres.success, "x{k}: {:?}", other.reason);
        // Scaling by 1000 is not exact in f32, so a point or two may fall into another voxel and the keypoints
        // differ slightly; the correspondences stay nearly the same and the pose the same within ICP's noise.
        let (a, b) = (other.correspondences as f64, metres.correspondences as f64);
        assert!((a - b).abs() <= 0.1 * b, "x{k}: {a} correspondences vs {b}");
        // The pose in metres: the translation divided by k.
        let mut back = other.estimate.target_from_source;
        for r in 0..3 {
            back[(r, 3)] /= f64::from(k);
        }
        eprintln!("x{k}: {} deg, {} m from the metres pose", rotation_error_deg(&back, t), translation_error(&back, t));
        assert!(
            rotation_error_deg(&back, t) < 0.5,
            "x{k}: rotation {} deg from the metres pose",
            rotation_error_deg(&back, t)
        );
        assert!(
            translation_error(&back, t) < 0.01,
            "x{k}: translation {} m from the metres pose",
            translation_error(&back, t)
        );
    }
}

#[test]
fn a_given_radius_is_kept_and_the_distances_follow_it() {
    let (source, target, _) = example_pair();
    let settings =
        RegistrationSettings { radius: Some(0.6), keypoints: 100, first_keypoints: None, ..Default::default() };
    let result = registrar(&settings).register(&source, &target).unwrap();
    assert_eq!(result.scale.rule, "given");
    assert_eq!(result.scale.radius, 0.6);
    assert!((result.scale.inlier_threshold - 0.1).abs() < 1e-6);
    assert!(result.scale.voxel.is_some_and(|v| (v - 0.6 / 24.0).abs() < 1e-6));
}

#[test]
fn the_auto_radius_is_the_rule_applied_to_both_clouds() {
    // Brute force: the median distance from the centre (the coordinate-wise median) of each cloud, sorted in
    // full, then the median of the two (their mean) times 0.6.
    let (source, target, _) = example_pair();
    let size = |c: &PointCloud| {
        let med = |mut v: Vec<f64>| {
            v.sort_by(f64::total_cmp);
            let h = v.len() / 2;
            if v.len() % 2 == 1 { v[h] } else { 0.5 * (v[h - 1] + v[h]) }
        };
        let m = [0, 1, 2].map(|i| med(c.points.iter().map(|p| f64::from(p[i])).collect()));
        let d: Vec<f64> = c
            .points
            .iter()
            .map(|p| [0, 1, 2].map(|i| (f64::from(p[i]) - m[i]).powi(2)).iter().sum::<f64>().sqrt())
            .collect();
        med(d)
    };
    let expected = 0.6 * 0.5 * (size(&source) + size(&target));
    let reg = registrar(&RegistrationSettings::default());
    let chosen = reg.at_scale_of(&[(&source, "source"), (&target, "target")]).unwrap();
    assert!((f64::from(chosen.radius()) / expected - 1.0).abs() < 1e-5, "{} vs {expected}", chosen.radius());
    assert!((f64::from(chosen.inlier_threshold()) - expected / 6.0).abs() < 1e-5);
    // A scan too small to measure is refused by name.
    let e = reg.at_scale_of(&[(&source, "source"), (&PointCloud::from_points(vec![[0.0; 3]; 2]), "target")]);
    assert!(e.is_err_and(|e| e.to_string().contains("target")));
}
