//! The rotation sweep of `dpr-gpu eval --rotate`: ground truth scored as results on the rotated data, the
//! frame bookkeeping of scores (original vs rotated frame), and feature-match recall of a real run being
//! invariant to the angle.
//!
//! Datasets are tiny `synth` scenes (64 x 48 rays, 4 frames per fragment), as in tests/synth_eval.rs.

mod common;
use common::temp_dir;
use dpr_gpu::eval::dataset::{SceneData, load_dataset};
use dpr_gpu::eval::gtlog::{LogRecord, format_log};
use dpr_gpu::eval::metrics::information_error;
use dpr_gpu::eval::rotate::{FragmentRotation, RotationSweep, angle_label};
use dpr_gpu::eval::run::{EvalOptions, load_cloud, score_log, score_log_sweep};
use dpr_gpu::pose::rigid_inverse;
use dpr_gpu::pose::rotation_error_deg;
use nalgebra::{Matrix4, Rotation3, Unit, Vector3};
use serde_json::Value;
use std::collections::HashMap;
use std::path::Path;
use std::process::{Command, Output};

const EXE: &str = env!("CARGO_BIN_EXE_dpr-gpu");

fn run(args: &[&str]) -> Output {
    let out = Command::new(EXE).args(args).output().unwrap();
    assert!(
        out.status.success(),
        "dpr-gpu {}\nstdout:\n{}\nstderr:\n{}",
        args.join(" "),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// `synth` into `dir`: small scenes with some non-consecutive gt pairs.
fn synth(dir: &Path, scenes: usize, fragments: usize, seed: u64) {
    let (s, f, seed) = (scenes.to_string(), fragments.to_string(), seed.to_string());
    run(&["synth", dir.to_str().unwrap(), "--scenes", &s, "--fragments", &f, "--frames", "4", "--width", "64"]
        .into_iter()
        .chain(["--seed", seed.as_str()])
        .collect::<Vec<_>>());
}

fn report(dir: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap()
}

/// The report entries of one estimator, by angle.
fn entries<'a>(report: &'a Value, estimator: &str) -> Vec<(f64, &'a Value)> {
    report["estimators"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["estimator"] == estimator)
        .map(|e| (e["rotation_deg"].as_f64().unwrap(), e))
        .collect()
}

/// The sweep rotation of every fragment of `scene` (computed here from the library's definition).
fn rotations(scene: &SceneData, seed: u64) -> HashMap<usize, FragmentRotation> {
    (0..scene.fragment_count())
        .map(|f| {
            let cloud = load_cloud(&scene.files[f], &Default::default()).unwrap();
            (f, FragmentRotation::for_fragment(seed, &scene.name, f, &cloud))
        })
        .collect()
}

fn small_motion(axis: [f64; 3], deg: f64, t: [f64; 3]) -> Matrix4<f64> {
    let r = Rotation3::from_axis_angle(&Unit::new_normalize(Vector3::from(axis)), deg.to_radians());
    dpr_gpu::pose::matrix_from_parts(r.matrix(), &Vector3::from(t))
}

#[test]
fn ground_truth_as_result_log_has_full_recall_at_every_angle_and_unrotated_truth_does_not() {
    let dir = temp_dir("gt");
    let data = dir.join("data");
    synth(&data, 2, 5, 4);
    let degrees = [0.0, 90.0, 180.0];
    let seed = 3;
    // Per angle: the ground truth on the rotated data, T_gt M^-1 (`rotated`), and the unrotated T_gt (`plain`).
    let mut recall_pairs = 0;
    for scene in load_dataset(&data).unwrap() {
        let rot = rotations(&scene, seed);
        for d in degrees {
            let rotated: Vec<LogRecord> = scene
                .gt
                .iter()
                .map(|g| LogRecord {
                    i: g.i,
                    j: g.j,
                    n: scene.fragment_count(),
                    i_from_j: g.i_from_j * rigid_inverse(&rot[&g.j].rotated_from_original(d)),
                })
                .collect();
            let plain: Vec<LogRecord> =
                rotated.iter().zip(&scene.gt).map(|(r, g)| LogRecord { i_from_j: g.i_from_j, ..r.clone() }).collect();
            for (kind, log) in [("rotated", &rotated), ("plain", &plain)] {
                let path = dir.join(kind).join(format!("rot{}", angle_label(d))).join(format!("{}.log", scene.name));
                std::fs::create_dir_all(path.parent().unwrap()).unwrap();
                std::fs::write(&path, format_log(log)).unwrap();
            }
        }
        recall_pairs += scene.gt.iter().filter(|g| scene.counts_for_recall(g.i, g.j)).count();
    }
    assert!(recall_pairs > 0, "the test scenes have no non-consecutive pairs");

    let score = |kind: &str| -> Value {
        let out = dir.join(format!("report_{kind}"));
        let log = format!("{}/{kind}/rot{{rotation}}/{{scene}}.log", dir.display());
        let stdout = run(&[
            "eval",
            data.to_str().unwrap(),
            "--log",
            &log,
            "--rotate",
            "0,90,180",
            "--rotate-seed",
            &seed.to_string(),
            "--out",
            out.to_str().unwrap(),
        ])
        .stdout;
        let table = String::from_utf8_lossy(&stdout).into_owned();
        assert!(table.contains("rotation sweep"), "{table}");
        report(&out)
    };
    let rotated = score("rotated");
    let by_angle = entries(&rotated, "log");
    assert_eq!(by_angle.iter().map(|e| e.0).collect::<Vec<_>>(), degrees);
    for (d, e) in &by_angle {
        for s in e["scenes"].as_array().unwrap() {
            if s["recall_pairs"].as_u64().unwrap() > 0 {
                assert_eq!(s["registration_recall"].as_f64(), Some(1.0), "{d} degrees: {s}");
                assert_eq!(s["precision"].as_f64(), Some(1.0), "{d} degrees: {s}");
            }
            // Errors are reported in the original frames: the ground truth is exact there.
            for p in s["pairs"].as_array().unwrap() {
                assert!(p["rotation_error_deg"].as_f64().unwrap() < 1e-3, "{d}: {p}");
            }
        }
        assert_eq!(e["mean"]["registration_recall"].as_f64(), Some(1.0), "{d}");
    }
    // The report lists the axis and centre used for every source fragment; they are the library's.
    let listed = rotated["rotation"]["fragments"].as_array().unwrap();
    assert!(!listed.is_empty());
    for scene in load_dataset(&data).unwrap() {
        let rot = rotations(&scene, seed);
        for f in listed.iter().filter(|f| f["scene"] == scene.name.as_str()) {
            let expected = &rot[&(f["index"].as_u64().unwrap() as usize)];
            // serde_json parses floats to within an ulp or so, hence the tolerance.
            for (key, values) in [("axis", expected.axis), ("center", expected.center)] {
                for (k, v) in values.iter().enumerate() {
                    assert!((f[key][k].as_f64().unwrap() - v).abs() < 1e-12, "{f}");
                }
            }
        }
    }
    assert_eq!(rotated["rotation"]["degrees"], serde_json::json!([0.0, 90.0, 180.0]));

    // The unrotated ground truth is right only at 0 degrees: the rotation is really applied.
    let plain = score("plain");
    let by_angle = entries(&plain, "log");
    assert_eq!(by_angle[0].1["mean"]["registration_recall"].as_f64(), Some(1.0));
    for (d, e) in &by_angle[1..] {
        assert_eq!(e["mean"]["registration_recall"].as_f64(), Some(0.0), "{d}: {}", e["mean"]);
    }

    // Without {rotation} in the path, --log with --rotate is refused with a one-line reason.
    let out = Command::new(EXE)
        .args(["eval", data.to_str().unwrap(), "--log", dir.join("plain").to_str().unwrap(), "--rotate", "90"])
        .args(["--out", dir.join("refused").to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("{rotation}"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn perturbed_estimates_score_identically_in_the_original_and_the_rotated_frame() {
    let dir = temp_dir("frames");
    synth(&dir, 1, 5, 4);
    let mut scene = load_dataset(&dir).unwrap().remove(0);
    let opts = EvalOptions::default();
    let seed = 11;
    let rot = rotations(&scene, seed);
    // Perturbations from negligible to far off, so that both outcomes occur.
    let perturbed: Vec<LogRecord> = scene
        .gt
        .iter()
        .enumerate()
        .map(|(k, g)| {
            let s = (k % 4) as f64;
            let p = small_motion([0.3, 1.0, -0.2 + s], 2.0 + 6.0 * s, [0.02 * s, -0.05 * s, 0.1 * s]);
            LogRecord { i: g.i, j: g.j, n: scene.fragment_count(), i_from_j: g.i_from_j * p }
        })
        .collect();
    let original = score_log(&mut scene, &perturbed, &opts).unwrap();
    // Oracle: the protocol error computed here, in the original frame.
    for p in &original.pairs {
        let g = scene.lookup(p.i, p.j).unwrap();
        let est = &perturbed.iter().find(|r| (r.i, r.j) == (p.i, p.j)).unwrap().i_from_j;
        let e = information_error(&g.i_from_j, est, g.information.as_ref().unwrap());
        assert!((p.error.unwrap() - e).abs() < 1e-12);
    }
    let outcomes: Vec<bool> = original.pairs.iter().map(|p| p.success.unwrap()).collect();
    assert!(outcomes.contains(&true) && outcomes.contains(&false), "{outcomes:?}");

    let degrees = vec![0.0, 37.5, 90.0, 180.0, -120.0];
    let sweep = RotationSweep::new(degrees.clone(), seed).unwrap();
    // The same estimates as results on the rotated data: T_est' = T_est M^-1.
    let logs: Vec<Vec<LogRecord>> = degrees
        .iter()
        .map(|&d| {
            perturbed
                .iter()
                .map(|r| LogRecord {
                    i_from_j: r.i_from_j * rigid_inverse(&rot[&r.j].rotated_from_original(d)),
                    ..r.clone()
                })
                .collect()
        })
        .collect();
    let (scores, used) = score_log_sweep(&mut scene, &logs, &opts, &sweep).unwrap();
    assert_eq!(used.len(), rot.iter().filter(|(f, _)| scene.gt.iter().any(|g| g.j == **f)).count());
    for (d, score) in degrees.iter().zip(&scores) {
        assert_eq!(score.good, original.good, "{d}");
        for (a, b) in original.pairs.iter().zip(&score.pairs) {
            assert_eq!((a.i, a.j, a.success), (b.i, b.j, b.success));
            let (ea, eb) = (a.error.unwrap(), b.error.unwrap());
            assert!((ea - eb).abs() < 1e-9, "{d} degrees, pair ({}, {}): {ea} vs {eb}", a.i, a.j);
            assert!((a.rotation_error_deg.unwrap() - b.rotation_error_deg.unwrap()).abs() < 1e-9);
            assert!((a.translation_error.unwrap() - b.translation_error.unwrap()).abs() < 1e-9);
        }
    }
    // Control: the 90-degree results taken at face value against the unrotated ground truth are off by the
    // sweep angle, give or take the perturbation (at most 20 degrees).
    let naive = score_log(&mut scene, &logs[2], &opts).unwrap();
    for p in &naive.pairs {
        let (g, r) = (scene.lookup(p.i, p.j).unwrap(), logs[2].iter().find(|r| (r.i, r.j) == (p.i, p.j)).unwrap());
        assert!((rotation_error_deg(&g.i_from_j, &r.i_from_j) - 90.0).abs() <= 20.0 + 1e-9, "{p:?}");
        assert!(p.rotation_error_deg.unwrap() >= 70.0 - 1e-9 && p.success == Some(false), "{p:?}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Feature-match recall may differ between angles by at most this many gt pairs. The sweep describes a moved
/// source with the same random stream as the original, the cloud keeps its point order and no voxel grid is
/// applied here, so the same keypoints and patch samples are drawn at every angle and the PPF codewords are
/// rotation invariant: the only differences left are f32 rounding of the moved coordinates flipping a
/// borderline neighbour or nearest-codeword decision, which can move one pair across tau2 at most in a scene
/// this small.
const FMR_PAIRS_TOLERANCE: f64 = 1.0;
/// The mean inlier ratio may differ between angles by at most this (about one correspondence in 60 per pair).
const INLIER_RATIO_TOLERANCE: f64 = 0.017;

#[test]
fn feature_match_recall_of_a_run_does_not_depend_on_the_angle() {
    let dir = temp_dir("fmr");
    let data = dir.join("data");
    synth(&data, 1, 4, 4);
    let out = dir.join("out");
    // The shipped weights, few keypoints (the fragments are small); both estimators side by side.
    let weights = Path::new(env!("CARGO_MANIFEST_DIR")).join("weights/default.safetensors");
    let stdout = run(&[
        "eval",
        data.to_str().unwrap(),
        "--weights",
        weights.to_str().unwrap(),
        "--keypoints",
        "150",
        "--estimator",
        "both",
        "--rotate",
        "0,90,180",
        "--out",
        out.to_str().unwrap(),
    ])
    .stdout;
    let table = String::from_utf8_lossy(&stdout).into_owned();
    let r = report(&out);
    // Angle-major, estimators side by side at each angle.
    let order: Vec<(String, f64)> = r["estimators"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| (e["estimator"].as_str().unwrap().to_string(), e["rotation_deg"].as_f64().unwrap()))
        .collect();
    let expected: Vec<(String, f64)> =
        [0.0, 90.0, 180.0].iter().flat_map(|&d| [("relativenet".to_string(), d), ("ransac".to_string(), d)]).collect();
    assert_eq!(order, expected);
    let scene = &r["estimators"][0]["scenes"][0];
    let gt_pairs = scene["gt_pairs"].as_u64().unwrap() as f64;
    assert!(gt_pairs >= 3.0, "{scene}");
    let fmr = |e: &Value| e["mean"]["feature_match_recall"].as_f64().unwrap();
    let ratio = |e: &Value| e["mean"]["mean_inlier_ratio"].as_f64().unwrap();
    let base = &r["estimators"][0];
    eprintln!("FMR / inlier ratio at 0 degrees: {} / {}", fmr(base), ratio(base));
    // The run finds real matches at 0 degrees, so counting them with the wrong ground truth would show.
    assert!(fmr(base) > 0.0 && ratio(base) > 0.03, "{table}");
    for e in r["estimators"].as_array().unwrap() {
        let d = e["rotation_deg"].as_f64().unwrap();
        eprintln!("{} at {d}: FMR {} inlier ratio {}", e["estimator"], fmr(e), ratio(e));
        assert!((fmr(e) - fmr(base)).abs() <= FMR_PAIRS_TOLERANCE / gt_pairs + 1e-12, "{d}: {table}");
        assert!((ratio(e) - ratio(base)).abs() <= INLIER_RATIO_TOLERANCE, "{d}: {table}");
        // Both estimators of one angle share the correspondences.
        let twin = r["estimators"]
            .as_array()
            .unwrap()
            .iter()
            .find(|x| x["rotation_deg"] == e["rotation_deg"] && x["estimator"] != e["estimator"])
            .unwrap();
        let fm = |x: &Value| -> Vec<Value> {
            x["scenes"][0]["pairs"].as_array().unwrap().iter().map(|p| p["feature_match"].clone()).collect()
        };
        assert_eq!(fm(e), fm(twin));
    }
    // Targets are described once; each source once more per non-zero angle (0 degrees reuses the original).
    let fragments = r["fragments"].as_array().unwrap();
    let rotated: Vec<(u64, f64)> = fragments
        .iter()
        .filter_map(|f| f["rotation_deg"].as_f64().map(|d| (f["index"].as_u64().unwrap(), d)))
        .collect();
    let sources = r["rotation"]["fragments"].as_array().unwrap().len();
    assert_eq!(rotated.len(), 2 * sources);
    assert!(rotated.iter().all(|&(_, d)| d == 90.0 || d == 180.0));
    assert_eq!(fragments.len() - rotated.len(), scene_fragments(&data));

    // The logs of the run are results on the rotated data; scoring them with the same sweep reproduces the
    // run's registration scores.
    for estimator in ["relativenet", "ransac"] {
        for d in ["0", "90", "180"] {
            assert!(out.join(estimator).join(format!("rot{d}")).join("scene_00.log").is_file());
        }
        let rescored = dir.join(format!("rescored_{estimator}"));
        let log = format!("{}/{estimator}/rot{{rotation}}/{{scene}}.log", out.display());
        run(&[
            "eval",
            data.to_str().unwrap(),
            "--log",
            &log,
            "--rotate",
            "0,90,180",
            "--out",
            rescored.to_str().unwrap(),
        ]);
        let rescored = report(&rescored);
        for ((_, run_entry), (_, log_entry)) in entries(&r, estimator).iter().zip(entries(&rescored, "log")) {
            let (a, b) = (&run_entry["scenes"][0], &log_entry["scenes"][0]);
            assert_eq!(a["good"], b["good"]);
            for (p, q) in a["pairs"].as_array().unwrap().iter().zip(b["pairs"].as_array().unwrap()) {
                assert_eq!((&p["i"], &p["j"], &p["success"]), (&q["i"], &q["j"], &q["success"]));
                if let (Some(x), Some(y)) = (p["error"].as_f64(), q["error"].as_f64()) {
                    // The log format keeps 9 significant digits.
                    assert!((x - y).abs() <= 1e-6 * (1.0 + x.abs()), "{x} vs {y}");
                }
            }
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Number of fragments (cloud_bin_*.ply) in the single scene under `data`.
fn scene_fragments(data: &Path) -> usize {
    load_dataset(data).unwrap()[0].fragment_count()
}
