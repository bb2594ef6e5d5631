//! The `dpr-gpu` binary end to end: a generated pair registers; bad input exits non-zero with one line and
//! never panics; outputs are atomic and never replace an input.

mod common;

use common::{room_pair, temp_dir};
use dpr_gpu::io::{LoadOptions, read_cloud, write_ply};
use dpr_gpu::pose::{rotation_error_deg, translation_error};
use nalgebra::Matrix4;
use std::path::Path;
use std::process::{Command, Output};

fn dpr(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_dpr-gpu")).args(args).output().expect("binary runs")
}

fn text(o: &Output) -> (String, String) {
    (String::from_utf8_lossy(&o.stdout).into_owned(), String::from_utf8_lossy(&o.stderr).into_owned())
}

fn assert_clean_failure(o: &Output, needle: &str) {
    let (_, err) = text(o);
    assert!(!o.status.success(), "expected failure, stderr: {err}");
    assert!(!err.contains("panicked"), "panic: {err}");
    let lines: Vec<&str> = err.lines().filter(|l| !l.contains("XDG_RUNTIME_DIR")).collect();
    assert_eq!(lines.len(), 1, "one line expected: {err}");
    assert!(lines[0].starts_with("error: ") && lines[0].contains(needle), "'{needle}' not in: {err}");
}

/// Small model (64 points per patch) so the CPU run stays short in tests.
fn small_weights(dir: &Path) -> String {
    let w = dir.join("w.safetensors");
    let o = dpr(&["init-weights", w.to_str().unwrap(), "--seed", "3", "--points", "64", "--grid", "8"]);
    assert!(o.status.success(), "{:?}", text(&o));
    w.to_str().unwrap().to_string()
}

#[test]
fn registers_a_generated_pair_with_ransac_on_random_weights() {
    // PPF-FoldNet codewords are rotation invariant even with random weights, so mutual matches of the same
    // surfaces are mostly right and RANSAC recovers the known pose to within the keypoint spacing; ICP on the
    // full clouds then makes it exact up to the sampling noise.
    let dir = temp_dir("cli-register");
    let (source, target, truth) = room_pair(1, 20_000);
    let (s, t) = (dir.join("source.ply"), dir.join("target.ply"));
    write_ply(&s, &source).unwrap();
    write_ply(&t, &target).unwrap();
    let weights = small_weights(&dir);
    let (out, aligned) = (dir.join("T.txt"), dir.join("aligned.ply"));
    let (s, t) = (s.to_str().unwrap(), t.to_str().unwrap());
    let ransac_json: &[&str] = &[
        "register",
        s,
        t,
        "--weights",
        &weights,
        "--keypoints",
        "600",
        "--estimator",
        "ransac",
        "--voxel",
        "0.02",
        "--icp",
        "--json",
    ];
    let o = dpr(&[ransac_json, &["--out", out.to_str().unwrap(), "--aligned", aligned.to_str().unwrap()]].concat());
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stderr}");
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).expect("one JSON object");
    let rows = v["target_from_source"].as_array().unwrap();
    let m = Matrix4::from_fn(|r, c| rows[r][c].as_f64().unwrap());
    assert!(rotation_error_deg(&m, &truth) < 0.5, "rotation error {}", rotation_error_deg(&m, &truth));
    assert!(translation_error(&m, &truth) < 0.01, "translation error {}", translation_error(&m, &truth));
    assert!(v["inliers"].as_u64().unwrap() >= 10);
    assert!(v["hypotheses_scored"].as_u64().unwrap() >= 1);
    assert!(v["timings"].as_array().unwrap().iter().any(|t| t["stage"] == "source.ppf_encoder"));
    // --out holds the same matrix; --aligned holds the moved source.
    let written: Vec<f64> =
        std::fs::read_to_string(&out).unwrap().split_whitespace().map(|x| x.parse().unwrap()).collect();
    assert_eq!(written.len(), 16);
    assert!((Matrix4::from_row_slice(&written) - m).abs().max() < 1e-6);
    let (moved, _) = read_cloud(&aligned, &LoadOptions::default()).unwrap();
    assert_eq!(moved.len(), source.len());
    // Same inputs and seed, same result.
    let again = dpr(ransac_json);
    let w: serde_json::Value = serde_json::from_str(text(&again).0.trim()).unwrap();
    assert_eq!(w["target_from_source"], v["target_from_source"]);
    // Text output names the matrix and the stages.
    let plain = dpr(&["register", s, t, "--weights", &weights, "--keypoints", "100", "--voxel", "0.02"]);
    let (stdout, _) = text(&plain);
    // 100 keypoints on random weights: a pose, but too little support to trust (status 3, said in the text).
    assert!(matches!(plain.status.code(), Some(0 | 3)), "{:?}", text(&plain));
    assert_eq!(plain.status.code() == Some(3), stdout.contains("verdict: NOT TRUSTED"), "{stdout}");
    assert!(
        stdout.contains("target_from_source") && stdout.contains("inliers:") && stdout.contains("hypotheses scored")
    );
}

#[test]
fn bad_input_fails_with_one_line_and_never_overwrites_inputs() {
    let dir = temp_dir("cli-bad");
    let weights = small_weights(&dir);
    let (source, target, _) = room_pair(2, 2_000);
    let (s, t) = (dir.join("s.ply"), dir.join("t.ply"));
    write_ply(&s, &source).unwrap();
    write_ply(&t, &target).unwrap();
    let (s, t) = (s.to_str().unwrap(), t.to_str().unwrap());

    assert_clean_failure(&dpr(&["register", "/nonexistent/a.ply", t, "--weights", &weights]), "/nonexistent/a.ply");
    let truncated = dir.join("truncated.ply");
    let bytes = std::fs::read(s).unwrap();
    std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();
    assert_clean_failure(&dpr(&["register", truncated.to_str().unwrap(), t, "--weights", &weights]), "truncated.ply");
    let empty = dir.join("empty.xyz");
    std::fs::write(&empty, "# nothing\n").unwrap();
    assert_clean_failure(&dpr(&["register", empty.to_str().unwrap(), t, "--weights", &weights]), "points");
    assert_clean_failure(&dpr(&["register", s, t, "--weights", "/nonexistent/w.safetensors"]), "w.safetensors");
    assert_clean_failure(&dpr(&["register", s, t, "--weights", s]), "weights");
    assert_clean_failure(&dpr(&["register", s, t, "--weights", &weights, "--radius=-1"]), "radius");
    assert_clean_failure(&dpr(&["register", s, t, "--weights", &weights, "--mutual", "7"]), "mutual");
    assert_clean_failure(&dpr(&["register", s, t, "--weights", &weights, "--estimator", "magic"]), "magic");
    assert_clean_failure(&dpr(&["register", s, t, "--weights", &weights, "--context-radius", "2"]), "FACTOR:WEIGHT");
    assert_clean_failure(&dpr(&["register", s, t, "--weights", &weights, "--context-radius", "0.5:1"]), "factor");
    let when = ["register", s, t, "--weights", &weights, "--context-radius", "2:1", "--context-when", "sometimes"];
    assert_clean_failure(&dpr(&when), "sometimes");
    // A radius far too small for the cloud's units: no patch has neighbours.
    assert_clean_failure(&dpr(&["register", s, t, "--weights", &weights, "--radius", "0.00001"]), "radius");

    let before = std::fs::read(s).unwrap();
    assert_clean_failure(&dpr(&["register", s, t, "--weights", &weights, "--aligned", s]), "overwrite");
    assert_clean_failure(&dpr(&["register", s, t, "--weights", &weights, "--out", t]), "overwrite");
    assert_eq!(std::fs::read(s).unwrap(), before);
}

#[test]
fn init_weights_and_info_describe_the_model() {
    let dir = temp_dir("cli-info");
    let w = dir.join("paper.safetensors");
    assert!(dpr(&["init-weights", w.to_str().unwrap(), "--config", "paper", "--seed", "1"]).status.success());
    let o = dpr(&["info", w.to_str().unwrap()]);
    let (stdout, _) = text(&o);
    assert!(o.status.success());
    assert!(stdout.contains("\"points_per_patch\": 2048") && stdout.contains("\"grid\""), "{stdout}");
    assert!(stdout.contains("parameters total"));
    assert_clean_failure(&dpr(&["init-weights", dir.join("x").to_str().unwrap(), "--config", "huge"]), "huge");
}

#[test]
fn a_copied_binary_registers_the_example_pair_with_its_built_in_weights() {
    // The weights travel inside the binary: a copy in an empty directory, run from there with no weights file
    // named anywhere, registers the example pair to its exact ground truth (examples/pair/pairs.txt).
    let dir = temp_dir("cli-copied-binary");
    let binary = dir.join("dpr-gpu");
    std::fs::copy(env!("CARGO_BIN_EXE_dpr-gpu"), &binary).unwrap();
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/pair");
    for name in ["cloud_bin_0.ply", "cloud_bin_1.ply"] {
        std::fs::copy(example.join(name), dir.join(name)).unwrap();
    }
    let o = Command::new(&binary)
        .current_dir(&dir)
        .env_remove("DPR_GPU_WEIGHTS")
        .args(["register", "cloud_bin_1.ply", "cloud_bin_0.ply", "--backend", "cpu", "--json"])
        .output()
        .unwrap();
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stderr}");
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).expect("one JSON object");
    let rows = v["target_from_source"].as_array().unwrap();
    let estimate = Matrix4::from_fn(|r, c| rows[r][c].as_f64().unwrap());
    let pairs = std::fs::read_to_string(example.join("pairs.txt")).unwrap();
    let line = pairs.lines().find(|l| !l.starts_with('#')).unwrap();
    let values: Vec<f64> = line.split_whitespace().skip(2).map(|x| x.parse().unwrap()).collect();
    let truth = Matrix4::from_row_slice(&values);
    assert!(rotation_error_deg(&estimate, &truth) < 5.0, "rotation error {}", rotation_error_deg(&estimate, &truth));
    assert!(translation_error(&estimate, &truth) < 0.1, "translation error {}", translation_error(&estimate, &truth));
    assert_eq!(v["success"], true);
    // No radius given: it was chosen from the two clouds, and the distances follow it.
    let scale = &v["scale"];
    assert!(scale["rule"].as_str().unwrap().starts_with("auto: 0.6 x median distance"), "{scale}");
    let radius = scale["radius"].as_f64().unwrap();
    assert!((scale["inlier_threshold"].as_f64().unwrap() - radius / 6.0).abs() < 1e-6, "{scale}");
}

/// A scan with sensor no-returns (points written at exactly (0,0,0)) registers with no flags exactly as the same
/// scan without them: the points are dropped by default and `register` says how many; a scan with none says
/// nothing about them.
#[test]
fn no_return_points_are_dropped_by_default_and_counted() {
    let dir = temp_dir("cli-no-returns");
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/pair");
    let (mut with_zeros, _) = read_cloud(&example.join("cloud_bin_1.ply"), &LoadOptions::default()).unwrap();
    // Interleaved, as a spinning sensor writes them: every 7th point is followed by a no-return.
    let mut points = Vec::new();
    let mut normals = Vec::new();
    let given_normals = with_zeros.normals.clone().unwrap();
    for (i, (p, n)) in with_zeros.points.iter().zip(&given_normals).enumerate() {
        points.push(*p);
        normals.push(*n);
        if i % 7 == 0 {
            points.push([0.0; 3]);
            normals.push([0.0, 0.0, 1.0]);
        }
    }
    let zeros = points.len() - with_zeros.len();
    with_zeros.points = points;
    with_zeros.normals = Some(normals);
    let sweep = dir.join("with_no_returns.ply");
    write_ply(&sweep, &with_zeros).unwrap();
    let target = example.join("cloud_bin_0.ply");
    let run = |source: &Path| {
        let o = dpr(&["register", source.to_str().unwrap(), target.to_str().unwrap(), "--backend", "cpu"]);
        let (stdout, stderr) = text(&o);
        assert!(o.status.success(), "{stderr}");
        stdout
    };
    let plain = run(&example.join("cloud_bin_1.ply"));
    let swept = run(&sweep);
    assert!(!plain.contains("no-return"), "{plain}");
    let said = format!("{zeros} no-return points at (0,0,0) dropped, --keep-zero keeps them");
    assert!(swept.lines().next().unwrap().contains(&said), "'{said}' not in: {swept}");
    let matrix = |out: &str| -> Vec<String> {
        out.lines().skip_while(|l| !l.starts_with("target_from_source")).skip(1).take(4).map(String::from).collect()
    };
    assert_eq!(matrix(&plain), matrix(&swept), "the same pose with and without the no-returns");
}

#[test]
fn bench_without_a_gpu_times_the_cpu_and_says_what_it_did_not_measure() {
    // WGPU_BACKEND=dx12 on a machine without DX12 leaves no adapter: the default `--backend both` still times
    // every stage on the CPU, and says the GPU was not measured; `--backend gpu` fails with one line.
    let bench = |backend: &str| {
        Command::new(env!("CARGO_BIN_EXE_dpr-gpu"))
            .env("WGPU_BACKEND", "dx12")
            .args(["bench", "--keypoints", "16", "--points", "16", "--repeat", "1", "--backend", backend])
            .output()
            .unwrap()
    };
    let o = bench("both");
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stderr}");
    assert!(stdout.contains("gpu: not measured"), "{stdout}");
    for stage in ["encode ppf", "predict_rotations", "hypotheses", "score_hypotheses"] {
        let row = stdout
            .lines()
            .find(|l| l.starts_with(&format!("{stage} ")))
            .unwrap_or_else(|| panic!("no {stage}: {stdout}"));
        let cpu_ms: f64 = row[stage.len()..].split_whitespace().next().unwrap().parse().expect("a CPU time");
        assert!(cpu_ms >= 0.0 && row.split_whitespace().any(|c| c == "-"), "{row}");
    }
    // The GEMM the CPU backend runs is timed, and marked.
    let gemm = stdout.lines().find(|l| l.starts_with("gemm cpu_gemm_") && l.ends_with("[backend]"));
    let gemm = gemm.unwrap_or_else(|| panic!("no CPU GEMM row: {stdout}"));
    let gflops: f64 = gemm.split_whitespace().rev().nth(2).unwrap().parse().expect("GFLOP/s");
    assert!(gflops > 0.0, "{gemm}");
    assert_clean_failure(&bench("gpu"), "GPU");
}
