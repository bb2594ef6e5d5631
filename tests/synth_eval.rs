//! The synthetic data generator and the 3DMatch evaluator, end to end: hand-computed protocol cases, the
//! generator's ground truth re-aligning its fragments, determinism per seed, and `eval --log` on a log equal to
//! the ground truth.
//!
//! Scenes here use a coarse camera (64 x 48 rays, 4 frames per fragment) so the whole file runs in seconds.

mod common;
use common::temp_dir;
use dpr_gpu::eval::dataset::{GtEntry, Protocol, SceneData, load_dataset};
use dpr_gpu::eval::gtlog::{LogRecord, format_log, parse_log, read_log};
use dpr_gpu::eval::metrics::{error_vector, information_error, information_matrix};
use dpr_gpu::eval::run::{EvalOptions, score_log};
use dpr_gpu::eval::score::score_registration;
use dpr_gpu::pose::inverse;
use dpr_gpu::synth::camera::CameraModel;
use dpr_gpu::synth::{SynthSettings, generate_scene, write_dataset};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Matrix4, Rotation3, Unit, Vector3};
use std::path::{Path, PathBuf};
use std::process::Command;

/// A coarse, fast configuration.
fn tiny(fragments: usize) -> SynthSettings {
    SynthSettings {
        fragments,
        frames_per_fragment: 4,
        camera: CameraModel::default().with_size(64, 48),
        ..SynthSettings::default()
    }
}

fn transform(axis: [f64; 3], angle_deg: f64, t: [f64; 3]) -> Matrix4<f64> {
    let r = Rotation3::from_axis_angle(&Unit::new_normalize(Vector3::from(axis)), angle_deg.to_radians());
    let mut m = Matrix4::identity();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(r.matrix());
    m.fixed_view_mut::<3, 1>(0, 3).copy_from(&Vector3::from(t));
    m
}

#[test]
fn information_matrix_of_three_points_matches_the_hand_expanded_sum() {
    // Σ = Σ_q [[I, -[q]x], [[q]x, |q|² I - q qᵀ]] for q = (1,0,0), (0,2,0), (0,0,3).
    let info = information_matrix(&[[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0]]);
    // S = (1, 2, 3); [S]x = [[0,-3,2],[3,0,-1],[-2,1,0]]; bottom-right = diag(4+9, 1+9, 1+4) (the q qᵀ are
    // diagonal here).
    #[rustfmt::skip]
    let expected = nalgebra::Matrix6::new(
        3.0, 0.0, 0.0, 0.0, 3.0, -2.0,
        0.0, 3.0, 0.0, -3.0, 0.0, 1.0,
        0.0, 0.0, 3.0, 2.0, -1.0, 0.0,
        0.0, -3.0, 2.0, 13.0, 0.0, 0.0,
        3.0, 0.0, -1.0, 0.0, 10.0, 0.0,
        -2.0, 1.0, 0.0, 0.0, 0.0, 5.0,
    );
    assert!((info - expected).norm() < 1e-12, "{info}");
}

#[test]
fn near_half_turn_errors_use_the_w_non_negative_quaternion() {
    let gt = transform([0.2, 1.0, 0.1], 30.0, [0.1, 0.2, 0.3]);
    // ΔT = 179.8 degrees about x: w = cos(89.9°) ~ 0.0017 > 0, vector part ~ +x.
    let est = gt * transform([1.0, 0.0, 0.0], 179.8, [0.0; 3]);
    let e = error_vector(&gt, &est);
    assert!((e[3] - 89.9f64.to_radians().sin()).abs() < 1e-9 && e[4].abs() < 1e-9, "{e}");
    // ΔT = -179.8 degrees (= 180.2): the protocol's w >= 0 flips the sign of the vector part to -x.
    let est = gt * transform([1.0, 0.0, 0.0], -179.8, [0.0; 3]);
    let e = error_vector(&gt, &est);
    assert!((e[3] + 89.9f64.to_radians().sin()).abs() < 1e-9, "{e}");
    // Either way the error of a half turn is huge.
    let info = information_matrix(&[[1.0, 2.0, 3.0], [0.0, -1.0, 2.0]]);
    assert!(information_error(&gt, &est, &info) > 1.0);
}

/// A one-pair-per-record 3DMatch scene with information matrices built from `points`.
fn scene_with(pairs: &[(usize, usize, Matrix4<f64>)], points: &[[f64; 3]]) -> SceneData {
    let info = information_matrix(points);
    let gt = pairs.iter().map(|&(i, j, t)| GtEntry { i, j, i_from_j: t, information: Some(info) }).collect();
    SceneData::new("hand".into(), PathBuf::new(), vec![PathBuf::new(); 8], gt, Protocol::ThreeDMatch)
}

fn info_error(g: &GtEntry, t: &Matrix4<f64>) -> dpr_gpu::Result<f64> {
    Ok(information_error(&g.i_from_j, t, g.information.as_ref().unwrap()))
}

#[test]
fn transform_direction_consecutive_pairs_missing_pairs_and_false_positives() {
    let t02 = transform([0.0, 0.0, 1.0], 35.0, [0.8, -0.3, 0.2]);
    let t13 = transform([1.0, 0.5, 0.0], -20.0, [-0.4, 0.1, 0.6]);
    let t01 = transform([0.0, 1.0, 0.0], 10.0, [0.3, 0.0, 0.0]);
    let t35 = transform([0.0, 1.0, 1.0], 15.0, [0.0, 0.5, 0.0]);
    let points: Vec<[f64; 3]> =
        (0..40).map(|k| [(k % 5) as f64 * 0.4, (k / 5) as f64 * 0.3, 1.5 + (k % 3) as f64]).collect();
    let scene = scene_with(&[(0, 1, t01), (0, 2, t02), (1, 3, t13), (3, 5, t35)], &points);
    // The estimate equal to the ground truth succeeds; its inverse (the wrong direction) fails.
    let results = [
        LogRecord { i: 0, j: 2, n: 8, i_from_j: t02 },
        LogRecord { i: 1, j: 3, n: 8, i_from_j: inverse(&t13) },
        // Consecutive and wrong: listed, but neither recall nor precision counts it.
        LogRecord { i: 0, j: 1, n: 8, i_from_j: Matrix4::identity() },
        // Not in gt.log: a false positive against precision.
        LogRecord { i: 2, j: 6, n: 8, i_from_j: Matrix4::identity() },
    ];
    let s = score_registration(&scene, &results, &info_error, 0.04).unwrap();
    // Recall set: (0,2), (1,3), (3,5); (3,5) is missing.
    assert_eq!((s.recall_pairs, s.good, s.reported), (3, 1, 3));
    assert_eq!(s.registration_recall, Some(1.0 / 3.0));
    assert_eq!(s.precision, Some(1.0 / 3.0));
    let wrong_way = s.pairs.iter().find(|p| (p.i, p.j) == (1, 3)).unwrap();
    assert_eq!(wrong_way.success, Some(false));
    assert!(wrong_way.error.unwrap() > 0.04);
    let consecutive = s.pairs.iter().find(|p| (p.i, p.j) == (0, 1)).unwrap();
    assert!(!consecutive.counts_for_recall && consecutive.reported);
}

#[test]
fn gt_log_round_trip_keeps_unsorted_records_and_keys_them_by_pair() {
    let records = vec![
        LogRecord { i: 3, j: 7, n: 9, i_from_j: transform([1.0, 2.0, 3.0], 50.0, [0.5, -1.25, 2.0]) },
        LogRecord { i: 0, j: 1, n: 9, i_from_j: transform([0.0, 0.0, 1.0], -5.0, [1e-5, 0.0, 3.0]) },
        LogRecord { i: 1, j: 8, n: 9, i_from_j: Matrix4::identity() },
    ];
    let text = format_log(&records);
    let back = parse_log(&text, Path::new("mem.log")).unwrap();
    assert_eq!(back.len(), 3);
    for (a, b) in records.iter().zip(&back) {
        assert_eq!((a.i, a.j, a.n), (b.i, b.j, b.n));
        // %15.8e keeps 9 significant digits.
        assert!((a.i_from_j - b.i_from_j).abs().max() < 1e-8, "{}", a.i_from_j - b.i_from_j);
    }
    let dir = temp_dir("roundtrip");
    std::fs::write(dir.join("gt.log"), &text).unwrap();
    let scene = load_dataset(&dir).unwrap().remove(0);
    assert!(scene.lookup(3, 7).is_some() && scene.lookup(0, 1).is_some() && scene.lookup(7, 3).is_none());
    assert_eq!(read_log(&dir.join("gt.log")).unwrap(), back);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Median of a slice (sorted copy).
fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

#[test]
fn generated_ground_truth_realigns_fragments_at_noise_level() {
    // The default camera (160 x 120): with coarser sampling the nearest-neighbour distance measures the sample
    // spacing rather than the alignment.
    let settings = SynthSettings { fragments: 3, frames_per_fragment: 6, ..SynthSettings::default() };
    let scene = generate_scene(21, &settings).unwrap();
    let gt = scene.ground_truth(&settings.ground_truth, 0);
    assert!(!gt.is_empty(), "no overlapping pairs");
    for p in &gt {
        let target: Vec<[f64; 3]> = scene.fragments[p.i].points.iter().map(|q| q.map(f64::from)).collect();
        let tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(&target).unwrap();
        let nn = |t: &Matrix4<f64>| -> Vec<f64> {
            scene.fragments[p.j]
                .transformed(t)
                .points
                .iter()
                .map(|q| tree.query(&q.map(f64::from)).nearest_one::<SquaredEuclidean<f64>>().execute().distance.sqrt())
                .collect()
        };
        let mut good: Vec<f64> = nn(&p.i_from_j).into_iter().filter(|&d| d < 0.03).collect();
        let mut wrong: Vec<f64> = nn(&inverse(&p.i_from_j)).into_iter().filter(|&d| d < 0.03).collect();
        let n = scene.fragments[p.j].len() as f64;
        let (overlap_good, overlap_wrong) = (good.len() as f64 / n, wrong.len() as f64 / n);
        let med = median(&mut good);
        eprintln!("pair ({}, {}): overlap {overlap_good:.3} (inverse {overlap_wrong:.3}), median {med:.4}", p.i, p.j);
        assert!(med < 0.01, "pair ({}, {}): median NN distance in the overlap {med}", p.i, p.j);
        assert!(overlap_good > 0.3, "pair ({}, {}): overlap {overlap_good}", p.i, p.j);
        // The inverse transform aligns far less of fragment j, and what it aligns is farther away.
        let med_wrong = if wrong.is_empty() { f64::INFINITY } else { median(&mut wrong) };
        assert!(overlap_wrong < overlap_good / 2.0 || med_wrong > 2.0 * med, "pair ({}, {})", p.i, p.j);
    }
}

fn files_of(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    for scene in std::fs::read_dir(dir).unwrap() {
        let scene = scene.unwrap().path();
        for f in std::fs::read_dir(&scene).unwrap() {
            let f = f.unwrap().path();
            let name = f.strip_prefix(dir).unwrap().display().to_string();
            out.push((name, std::fs::read(&f).unwrap()));
        }
    }
    out.sort();
    out
}

#[test]
fn same_seed_gives_identical_bytes_and_another_seed_differs() {
    let (a, b, c) = (temp_dir("det_a"), temp_dir("det_b"), temp_dir("det_c"));
    let settings = tiny(3);
    write_dataset(&a, 9, 2, &settings, false, |_| {}).unwrap();
    write_dataset(&b, 9, 2, &settings, false, |_| {}).unwrap();
    write_dataset(&c, 10, 2, &settings, false, |_| {}).unwrap();
    let (fa, fb, fc) = (files_of(&a), files_of(&b), files_of(&c));
    assert!(fa.iter().any(|(n, _)| n.ends_with("cloud_bin_2.ply")) && fa.iter().any(|(n, _)| n.ends_with("gt.info")));
    assert_eq!(fa, fb);
    assert_ne!(fa, fc);
    // Writing again without force is refused and leaves the files alone.
    let err = write_dataset(&a, 9, 2, &settings, false, |_| {}).unwrap_err().to_string();
    assert!(err.contains("--force"), "{err}");
    assert_eq!(files_of(&a), fb);
    for d in [a, b, c] {
        std::fs::remove_dir_all(d).unwrap();
    }
}

#[test]
fn eval_log_equal_to_ground_truth_has_full_recall_and_a_perturbed_one_less() {
    let dir = temp_dir("cli");
    let data = dir.join("data");
    let exe = env!("CARGO_BIN_EXE_dpr-gpu");
    let synth = |extra: &[&str]| {
        Command::new(exe)
            .args(["synth", data.to_str().unwrap(), "--scenes", "2", "--fragments", "5", "--frames", "4"])
            .args(["--width", "64", "--seed", "4"])
            .args(extra)
            .output()
            .unwrap()
    };
    let out = synth(&[]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    // A second run without --force fails with one line; with --force it succeeds.
    let again = synth(&[]);
    assert!(!again.status.success() && String::from_utf8_lossy(&again.stderr).contains("--force"));
    assert!(synth(&["--force"]).status.success());

    let report_dir = dir.join("report");
    let log = format!("{}/{{scene}}/gt.log", data.display());
    let out = Command::new(exe)
        .args(["eval", data.to_str().unwrap(), "--log", &log, "--out", report_dir.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(report_dir.join("report.json")).unwrap()).unwrap();
    let scenes = report["estimators"][0]["scenes"].as_array().unwrap();
    assert_eq!(scenes.len(), 2);
    let mut recall_pairs = 0;
    for s in scenes {
        let n = s["recall_pairs"].as_u64().unwrap();
        recall_pairs += n;
        if n > 0 {
            assert_eq!(s["registration_recall"].as_f64(), Some(1.0), "{s}");
            assert_eq!(s["precision"].as_f64(), Some(1.0), "{s}");
        }
    }
    assert!(recall_pairs > 0, "the test scenes have no non-consecutive pairs");

    // Every estimate slid by 0.3 m: e^T Sigma e / Sigma_11 = 0.09 m^2 fails the protocol's 0.04 m^2 (and the
    // about 0.055 m^2 of the radius chosen from the data), passes the 0.16 m^2 of distances scaled by 2, which
    // --radius 1.2 implies and --protocol-scale sets either way.
    let slid_dir = dir.join("slid");
    for scene in load_dataset(&data).unwrap() {
        let slid: Vec<LogRecord> = read_log(&scene.dir.join("gt.log"))
            .unwrap()
            .iter()
            .map(|r| LogRecord {
                i_from_j: Matrix4::new_translation(&Vector3::new(0.3, 0.0, 0.0)) * r.i_from_j,
                ..r.clone()
            })
            .collect();
        std::fs::create_dir_all(&slid_dir).unwrap();
        std::fs::write(slid_dir.join(format!("{}.log", scene.name)), format_log(&slid)).unwrap();
    }
    let slid_recall = |extra: &[&str]| {
        let out = Command::new(exe)
            .args(["eval", data.to_str().unwrap(), "--log", slid_dir.to_str().unwrap(), "--out"])
            .arg(&report_dir)
            .args(extra)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let report: serde_json::Value =
            serde_json::from_slice(&std::fs::read(report_dir.join("report.json")).unwrap()).unwrap();
        let scenes = report["estimators"][0]["scenes"].as_array().unwrap().clone();
        let good: u64 = scenes.iter().map(|s| s["good"].as_u64().unwrap()).sum();
        (good, report["thresholds"]["tau1"].as_f64().unwrap(), report["scales"].clone())
    };
    // No flags: the distances follow the radius chosen from the first scene's clouds (0.6 x their median
    // distance from the centre, about 0.7 m for these rooms), and the slide still fails.
    let (g, t, scales) = slid_recall(&[]);
    let auto_radius = scales[0]["radius"].as_f64().unwrap();
    assert!((0.4..1.0).contains(&auto_radius), "{scales}");
    assert!(scales[0]["rule"].as_str().unwrap().starts_with("auto"), "{scales}");
    assert!(g == 0 && (t - 0.10 * auto_radius / 0.6).abs() < 1e-6, "no flags: {g} good, tau1 {t}, {scales}");
    for (extra, good, tau1) in [
        (&["--radius", "1.2"][..], recall_pairs, 0.20),
        (&["--radius", "1.2", "--protocol-scale", "1"][..], 0, 0.10),
        (&["--protocol-scale", "2"][..], recall_pairs, 0.20),
    ] {
        let (g, t, _) = slid_recall(extra);
        assert!(g == good && (t - tau1).abs() < 1e-6, "{extra:?}: {g} good, tau1 {t}");
    }
    let bad = Command::new(exe).args(["eval", data.to_str().unwrap(), "--protocol-scale", "0"]).output().unwrap();
    assert!(!bad.status.success() && String::from_utf8_lossy(&bad.stderr).contains("--protocol-scale"));

    // The same scenes scored from the library with every estimate rotated by 20 degrees about the source
    // origin: recall drops, precision equals recall (every result is a gt pair).
    for mut scene in load_dataset(&data).unwrap() {
        let log = read_log(&scene.dir.join("gt.log")).unwrap();
        let perturbed: Vec<LogRecord> = log
            .iter()
            .map(|r| LogRecord { i_from_j: r.i_from_j * transform([0.3, 1.0, 0.2], 20.0, [0.0; 3]), ..r.clone() })
            .collect();
        let exact = score_log(&mut scene, &log, &EvalOptions::default()).unwrap();
        let off = score_log(&mut scene, &perturbed, &EvalOptions::default()).unwrap();
        if exact.recall_pairs > 0 {
            assert_eq!(exact.registration_recall, Some(1.0));
            assert!(off.registration_recall.unwrap() < 1.0, "{:?}", off.registration_recall);
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn pipeline_run_registers_every_gt_pair_in_the_gt_direction_and_reports_both_estimators() {
    use dpr_gpu::eval::run::run_scene;
    use dpr_gpu::model::{ModelConfig, Weights};
    use dpr_gpu::settings::{Estimator, RegistrationSettings};
    // A tiny random model: the scores are meaningless, the bookkeeping is what is checked.
    let config = ModelConfig {
        points_per_patch: 16,
        encoder_widths: vec![8, 8, 16],
        head_widths: vec![16, 12],
        fold_widths: vec![8, 8],
        grid: [3, 3],
        relative_widths: vec![16, 8],
        ..ModelConfig::default()
    };
    let weights = Weights::init(&config, 1).unwrap();
    let settings = RegistrationSettings { keypoints: 60, voxel: Some(0.03), ..RegistrationSettings::default() };
    let registrar = dpr_gpu::Registrar::with_weights(&settings, &weights).unwrap();
    let dir = temp_dir("pipeline");
    write_dataset(&dir, 4, 1, &tiny(4), false, |_| {}).unwrap();
    let mut scene = load_dataset(&dir).unwrap().remove(0);
    let gt_pairs: Vec<(usize, usize)> = scene.gt.iter().map(|g| (g.i, g.j)).collect();
    assert!(!gt_pairs.is_empty());
    let mut ticks = 0;
    let run = run_scene(
        &mut scene,
        &registrar,
        &[Estimator::RelativeNet, Estimator::Ransac],
        &EvalOptions::default(),
        &mut || ticks += 1,
    )
    .unwrap();
    assert_eq!(ticks, gt_pairs.len());
    assert_eq!(run.estimators.len(), 2);
    // Each fragment described once (stream = its index).
    let mut described: Vec<usize> = run.fragments.iter().map(|f| f.index).collect();
    described.sort_unstable();
    described.dedup();
    assert_eq!(described.len(), run.fragments.len());
    for (_, score, log) in &run.estimators {
        // One result per gt pair, under "i j" with i < j: source = fragment j, target = fragment i.
        let mut logged: Vec<(usize, usize)> = log.iter().map(|r| (r.i, r.j)).collect();
        logged.sort_unstable();
        let mut expected = gt_pairs.clone();
        expected.sort_unstable();
        assert_eq!(logged, expected);
        assert!(log.iter().all(|r| r.n == scene.fragment_count()));
        let fmr = score.feature_match_recall.unwrap();
        assert!((0.0..=1.0).contains(&fmr));
        for p in &score.pairs {
            let run = p.run.as_ref().unwrap();
            let fm = p.feature_match.unwrap();
            assert_eq!(fm.correspondences, run.correspondences);
            assert!(fm.inliers <= fm.correspondences && p.rotation_error_deg.is_some());
        }
    }
    // Both estimators saw the same correspondences.
    let (a, b) = (&run.estimators[0].1.pairs, &run.estimators[1].1.pairs);
    assert!(a.iter().zip(b).all(|(x, y)| x.feature_match == y.feature_match));
    std::fs::remove_dir_all(&dir).unwrap();
}
