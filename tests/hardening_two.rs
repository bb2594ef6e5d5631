//! Hostile and clumsy input, round two (issue 36): the commands added since the first round (multiway,
//! eval-trajectory, train's outputs) lose no file, score nothing non-rigid, and every error names its cause
//! before the work is done. Each test names the case of the issue it checks.

mod common;

use common::{room_pair, temp_dir, tiny_dataset};
use dpr_gpu::PointCloud;
use dpr_gpu::io::write_ply;
use dpr_gpu::multiway::Trajectory;
use dpr_gpu::pose::{matrix_from_parts, matrix_from_quaternion};
use nalgebra::{Matrix4, Vector3};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn dpr(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_dpr-gpu")).args(args).output().expect("binary runs")
}

fn text(o: &Output) -> (String, String) {
    (String::from_utf8_lossy(&o.stdout).into_owned(), String::from_utf8_lossy(&o.stderr).into_owned())
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Exit status 1 with one `error:` line that contains every needle and none of `absent`; no panic.
fn assert_failure(o: &Output, needles: &[&str], absent: &[&str]) {
    let (_, err) = text(o);
    assert_eq!(o.status.code(), Some(1), "expected a clean failure (status 1), stderr: {err}");
    assert!(!err.contains("panicked"), "{err}");
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 1, "one line expected: {err}");
    for needle in needles {
        assert!(lines[0].starts_with("error: ") && lines[0].contains(needle), "'{needle}' not in: {err}");
    }
    for word in absent {
        assert!(!lines[0].contains(word), "'{word}' in: {err}");
    }
}

/// Small model (64 points per patch) so CPU runs stay short.
fn small_weights(dir: &Path) -> PathBuf {
    let w = dir.join("w.safetensors");
    let o = dpr(&["init-weights", s(&w), "--seed", "3", "--points", "64", "--grid", "8"]);
    assert!(o.status.success(), "{:?}", text(&o));
    w
}

/// A random rigid pose.
fn pose(rng: &mut dpr_gpu::rng::Rng) -> Matrix4<f64> {
    let t = Vector3::new(rng.uniform(-3.0, 3.0), rng.uniform(-3.0, 3.0), rng.uniform(-1.0, 1.0));
    matrix_from_parts(&matrix_from_quaternion(rng.unit_quaternion()), &t)
}

/// `synth`'s poses.txt text of `t`.
fn poses_text(t: &Trajectory) -> String {
    let mut out = String::new();
    for (k, m) in t.world_from_scan.iter().enumerate() {
        let values: Vec<String> = (0..16).map(|c| format!("{:e}", m[(c / 4, c % 4)])).collect();
        out.push_str(&format!("{k} {}\n", values.join(" ")));
    }
    out
}

// ------------------------------------------------------------------------------ data loss (cases 1-3)

/// Case 1: the scan list is an input: `multiway LIST --out DIR` with LIST in DIR (named like an output) is
/// refused before anything is written, with relative and absolute paths alike.
#[test]
fn multiway_never_rewrites_its_scan_list() {
    let dir = temp_dir("h2-list");
    for (k, name) in ["a.ply", "b.ply"].iter().enumerate() {
        write_ply(&dir.join(name), &room_pair(k as u64, 500).0).unwrap();
    }
    for list in
        ["# my scans\na.ply\nb.ply\n".to_string(), format!("{}\n{}\n", s(&dir.join("a.ply")), s(&dir.join("b.ply")))]
    {
        let path = dir.join("scans.txt");
        std::fs::write(&path, &list).unwrap();
        assert_failure(&dpr(&["multiway", s(&path), "--out", s(&dir)]), &["overwrite", "scans.txt"], &[]);
        assert_eq!(std::fs::read_to_string(&path).unwrap(), list);
        assert!(!dir.join("trajectory.log").exists());
    }
}

/// Case 2: every file of a dataset folder is protected from train's outputs (not only gt.log and the clouds),
/// and weights are only written under a .safetensors name.
#[test]
fn train_and_init_weights_never_replace_dataset_or_cloud_files() {
    let dir = temp_dir("h2-train");
    let data = tiny_dataset(&dir);
    let poses = data.join("scene_00/poses.txt");
    let before = std::fs::read(&poses).unwrap();
    let small = ["--points", "8", "--grid", "3", "--batch", "2", "--voxel", "0.03", "--steps", "1"];
    let train = |extra: &[&str]| dpr(&[&["train", "--data", s(&data)], &small[..], extra].concat());
    assert_failure(&train(&["--out", s(&poses)]), &["overwrite", "poses.txt"], &[]);
    let out = dir.join("w.safetensors");
    assert_failure(&train(&["--out", s(&out), "--log", s(&poses)]), &["overwrite", "poses.txt"], &[]);
    assert_eq!(std::fs::read(&poses).unwrap(), before);
    assert!(!out.exists());
    // init-weights onto a cloud: refused by its name, the cloud kept.
    let cloud = dir.join("cloud.ply");
    write_ply(&cloud, &room_pair(1, 100).0).unwrap();
    let cloud_before = std::fs::read(&cloud).unwrap();
    assert_failure(&dpr(&["init-weights", s(&cloud)]), &["cloud.ply", ".safetensors"], &[]);
    assert_eq!(std::fs::read(&cloud).unwrap(), cloud_before);
}

/// Case 3: a write removes the temp files an earlier, killed writer left beside the same destination, and
/// never those of a writer still running or of other destinations.
#[test]
#[cfg(target_os = "linux")]
fn stale_temp_files_of_a_killed_writer_are_removed_by_the_next_write() {
    let dir = temp_dir("h2-temps");
    let mut child = Command::new("true").spawn().unwrap();
    let dead = child.id();
    child.wait().unwrap();
    let live = std::process::id();
    let stale = dir.join(format!(".out.txt.tmp-{dead}-0"));
    let running = dir.join(format!(".out.txt.tmp-{live}-999999"));
    let other = dir.join(format!(".other.txt.tmp-{dead}-0"));
    for p in [&stale, &running, &other] {
        std::fs::write(p, vec![7u8; 4096]).unwrap();
    }
    dpr_gpu::io::write_atomic(&dir.join("out.txt"), b"new").unwrap();
    assert!(!stale.exists(), "the killed writer's temp file is left");
    assert!(running.exists() && other.exists());
    assert_eq!(std::fs::read(dir.join("out.txt")).unwrap(), b"new");
    // Through the CLI too: a killed `register --out` leaves its temp file; the next run removes it.
    let (sp, tp) = (dir.join("s.ply"), dir.join("t.ply"));
    let (source, target, _) = room_pair(3, 2000);
    write_ply(&sp, &source).unwrap();
    write_ply(&tp, &target).unwrap();
    let stale = dir.join(format!(".T.txt.tmp-{dead}-3"));
    std::fs::write(&stale, b"half a matrix").unwrap();
    let weights = small_weights(&dir);
    let o =
        dpr(&["register", s(&sp), s(&tp), "--weights", s(&weights), "--keypoints", "50", "--backend", "cpu", "--out"]
            .iter()
            .copied()
            .chain([s(&dir.join("T.txt"))])
            .collect::<Vec<_>>());
    assert!(matches!(o.status.code(), Some(0 | 3)), "{:?}", text(&o));
    assert!(!stale.exists());
}

// ------------------------------------------------------------------------------ silent wrong answers (5-8)

/// Case 5: matrices that are not rigid motions are refused by every pose reader (trajectory .log, poses.txt,
/// gt.log, pairs files), naming the file and the line, and eval-trajectory never prints a NaN ATE.
#[test]
fn non_rigid_poses_are_refused_by_every_reader() {
    let dir = temp_dir("h2-rigid");
    let mut rng = dpr_gpu::rng::Rng::new(5);
    let truth = Trajectory { world_from_scan: (0..3).map(|_| pose(&mut rng)).collect() };
    std::fs::write(dir.join("poses.txt"), poses_text(&truth)).unwrap();
    let mut doubled = truth.world_from_scan[1];
    doubled.fixed_view_mut::<3, 3>(0, 0).scale_mut(2.0);
    let mut sheared = Matrix4::identity();
    sheared[(0, 1)] = 0.3;
    let mut far = truth.world_from_scan[1];
    far[(0, 3)] = 1e300;
    let mirrored = Matrix4::from_diagonal(&nalgebra::Vector4::new(-1.0, 1.0, 1.0, 1.0));
    for (name, bad) in
        [("x2", doubled), ("shear", sheared), ("zero", Matrix4::zeros()), ("mirror", mirrored), ("1e300", far)]
    {
        let mut t = truth.clone();
        t.world_from_scan[1] = bad;
        let log = dir.join(format!("{name}.log"));
        std::fs::write(&log, t.to_log_text()).unwrap();
        // Record 1's header is on line 6.
        assert_failure(
            &dpr(&["eval-trajectory", s(&log), s(&dir.join("poses.txt"))]),
            &[&format!("{name}.log"), "line 6"],
            &["NaN"],
        );
        let gt = dir.join(format!("{name}-poses.txt"));
        std::fs::write(&gt, poses_text(&t)).unwrap();
        let good = dir.join("good.log");
        std::fs::write(&good, truth.to_log_text()).unwrap();
        assert_failure(&dpr(&["eval-trajectory", s(&good), s(&gt)]), &[&format!("{name}-poses.txt"), "line 2"], &[]);
    }
    // eval: a non-rigid gt.log.
    let scene = dir.join("scene");
    std::fs::create_dir(&scene).unwrap();
    std::fs::write(scene.join("gt.log"), "0 2 3\n2 0 0 0\n0 2 0 0\n0 0 2 0\n0 0 0 1\n").unwrap();
    assert_failure(&dpr(&["eval", s(&scene), "--out", s(&dir.join("e"))]), &["gt.log", "line 1", "rotation"], &[]);
}

/// Case 6: eval-trajectory takes fragment ids from scans.txt only when every name is cloud_bin_K; a list with
/// some other name is refused (the scans' order would pair them with the wrong poses).
#[test]
fn eval_trajectory_refuses_scan_lists_it_cannot_map_to_fragments() {
    let dir = temp_dir("h2-ids");
    let mut rng = dpr_gpu::rng::Rng::new(6);
    let truth = Trajectory { world_from_scan: (0..4).map(|_| pose(&mut rng)).collect() };
    std::fs::write(dir.join("poses.txt"), poses_text(&truth)).unwrap();
    // The trajectory holds fragments 3, 1, 2 in that order.
    let order = [3usize, 1, 2];
    let estimate = Trajectory { world_from_scan: order.iter().map(|&k| truth.world_from_scan[k]).collect() };
    let out = dir.join("out");
    std::fs::create_dir(&out).unwrap();
    std::fs::write(out.join("trajectory.log"), estimate.to_log_text()).unwrap();
    let run = || dpr(&["eval-trajectory", s(&out.join("trajectory.log")), s(&dir.join("poses.txt")), "--json"]);
    std::fs::write(out.join("scans.txt"), "/d/cloud_bin_3.ply\n/d/cloud_bin_1.ply\n/d/cloud_bin_2.ply\n").unwrap();
    let o = run();
    assert!(o.status.success(), "{:?}", text(&o));
    let report: serde_json::Value = serde_json::from_str(text(&o).0.trim()).unwrap();
    assert!(report["trajectory"]["ate_rmse"].as_f64().unwrap() < 1e-6, "{report}");
    std::fs::write(out.join("scans.txt"), "/d/cloud_bin_3.ply\n/d/scan_b.ply\n/d/cloud_bin_2.ply\n").unwrap();
    assert_failure(&run(), &["scans.txt", "line 2", "scan_b.ply", "--ids"], &[]);
    std::fs::write(out.join("scans.txt"), "/d/cloud_bin_3.ply\n/d/cloud_bin_1.ply\n").unwrap();
    assert_failure(&run(), &["scans.txt", "2 scans", "--ids"], &[]);
}

/// Case 7: --min-overlap is a fraction: NaN, negative or above 1 is refused before the dataset is read.
#[test]
fn eval_min_overlap_must_be_a_fraction() {
    let dir = temp_dir("h2-overlap");
    for bad in ["nan", "2", "-1"] {
        let flag = format!("--min-overlap={bad}");
        let o = dpr(&["eval", s(&dir.join("missing")), "--all-pairs", &flag, "--out", s(&dir.join("e"))]);
        assert_failure(&o, &["--min-overlap"], &["missing"]);
    }
}

/// Writes a list of `names` in `dir` (one scan per line).
fn write_list(dir: &Path, names: &[&str]) -> PathBuf {
    let list = dir.join("list.txt");
    std::fs::write(&list, names.iter().map(|n| format!("{n}\n")).collect::<String>()).unwrap();
    list
}

/// Case 8: multiway's resume key holds the scans' contents: swapping two equal-size scans while keeping their
/// modification times registers the pair again. Scans left unconnected give exit status 3, and --max-pairs 0
/// is refused.
#[test]
fn multiway_resume_sees_changed_contents_and_unplaced_scans_are_not_a_success() {
    let dir = temp_dir("h2-resume");
    let (a, b, _) = room_pair(2, 3000);
    let c = room_pair(4, 3000).0;
    for (name, cloud) in [("a.ply", &a), ("b.ply", &b), ("c.ply", &c)] {
        write_ply(&dir.join(name), cloud).unwrap();
    }
    let list = write_list(&dir, &["a.ply", "b.ply", "c.ply"]);
    let weights = small_weights(&dir);
    let out = dir.join("out");
    let quick =
        ["--pairs", "all", "--keypoints", "300", "--voxel", "0.03", "--estimator", "ransac", "--backend", "cpu"];
    let run = |extra: &[&str]| {
        dpr(&[&["multiway", s(&list), "--out", s(&out), "--weights", s(&weights)][..], &quick, extra].concat())
    };
    assert_failure(&run(&["--max-pairs", "0"]), &["--max-pairs"], &[]);
    // One pair for three scans: scan 2 is not placed, which is not a success.
    let first = run(&["--max-pairs", "1"]);
    let (stdout, stderr) = text(&first);
    assert_eq!(first.status.code(), Some(3), "{stdout}{stderr}");
    assert!(stdout.contains(" 0 pairs reused") && stderr.contains("[2]"), "{stdout}{stderr}");
    let again = run(&["--max-pairs", "1"]);
    assert!(text(&again).0.contains(" 1 pairs reused"), "{:?}", text(&again));
    // Swap the contents of a and b (equal sizes), keeping each file's modification time.
    let (pa, pb) = (dir.join("a.ply"), dir.join("b.ply"));
    let times = [&pa, &pb].map(|p| std::fs::metadata(p).unwrap().modified().unwrap());
    let (bytes_a, bytes_b) = (std::fs::read(&pa).unwrap(), std::fs::read(&pb).unwrap());
    assert_eq!(bytes_a.len(), bytes_b.len());
    std::fs::write(&pa, &bytes_b).unwrap();
    std::fs::write(&pb, &bytes_a).unwrap();
    for (p, t) in [&pa, &pb].iter().zip(times) {
        std::fs::File::options().write(true).open(p).unwrap().set_modified(t).unwrap();
    }
    let swapped = run(&["--max-pairs", "1"]);
    assert!(text(&swapped).0.contains(" 0 pairs reused"), "{:?}", text(&swapped));
}

// ------------------------------------------------------------------------------ unclear errors (9-14)

/// Case 9: an output that cannot be written is refused before any input is read: a name ending in a separator
/// (a folder), a folder where no file can be created.
#[test]
fn unwritable_outputs_are_refused_before_the_work() {
    let dir = temp_dir("h2-unwritable");
    // The inputs do not exist: an error about them would mean the outputs were checked too late.
    let (sp, tp) = (dir.join("missing-source.ply"), dir.join("missing-target.ply"));
    let register = |flag: &str, out: &str| dpr(&["register", s(&sp), s(&tp), flag, out]);
    let newdir = format!("{}/", s(&dir.join("newdir")));
    assert_failure(&register("--out", &newdir), &["--out", "newdir/", "separator"], &["missing-source"]);
    #[cfg(target_os = "linux")]
    {
        // /proc takes no new files, whoever runs the test (root included).
        assert_failure(
            &register("--out", "/proc/T.txt"),
            &["--out", "/proc/T.txt", "cannot create"],
            &["missing-source"],
        );
        let o = dpr(&["train", "--data", s(&dir.join("missing-data")), "--out", "/proc/w.safetensors"]);
        assert_failure(&o, &["/proc/w.safetensors"], &["missing-data"]);
    }
}

/// Case 10: an empty, all-NaN or far-away scan is refused naming its file and the cause, without advice about
/// the radius or voxel size.
#[test]
fn empty_nan_and_far_scans_are_named_with_the_cause() {
    let dir = temp_dir("h2-empty");
    let weights = small_weights(&dir);
    let (source, _, _) = room_pair(1, 2000);
    let good = dir.join("good.xyz");
    let xyz = |c: &PointCloud, shift: f32| {
        c.points.iter().map(|p| format!("{} {} {}\n", p[0] + shift, p[1], p[2])).collect::<String>()
    };
    std::fs::write(&good, xyz(&source, 0.0)).unwrap();
    let empty = dir.join("empty.xyz");
    std::fs::write(&empty, "").unwrap();
    let nan = dir.join("nan.xyz");
    std::fs::write(&nan, "nan nan nan\n".repeat(50)).unwrap();
    let far = dir.join("far.xyz");
    std::fs::write(&far, xyz(&source, 1e7)).unwrap();
    let advice = ["radius", "voxel", "correspondences"];
    let register = |a: &Path, b: &Path, extra: &[&str]| {
        dpr(&[&["register", s(a), s(b), "--weights", s(&weights), "--backend", "cpu"][..], extra].concat())
    };
    assert_failure(&register(&empty, &good, &[]), &["empty.xyz", "0 usable points"], &advice);
    assert_failure(&register(&good, &empty, &["--radius", "0.3"]), &["empty.xyz", "0 usable points"], &advice);
    assert_failure(
        &register(&good, &nan, &[]),
        &["nan.xyz", "0 usable points", "50 points with a non-finite"],
        &advice,
    );
    assert_failure(&register(&good, &far, &[]), &["far.xyz", "local frame"], &advice);
    let list = write_list(&dir, &["good.xyz", "nan.xyz"]);
    let o = dpr(&["multiway", s(&list), "--out", s(&dir.join("m")), "--weights", s(&weights), "--backend", "cpu"]);
    assert_failure(&o, &["nan.xyz", "0 usable points"], &advice);
}

/// Case 11: a cloud where a scan list or pairs file is expected is named as such, not as invalid UTF-8.
#[test]
fn a_cloud_given_as_a_list_is_named_as_a_cloud() {
    let dir = temp_dir("h2-cloud-list");
    let cloud = dir.join("cloud.ply");
    write_ply(&cloud, &room_pair(1, 200).0).unwrap();
    let o = dpr(&["multiway", s(&cloud), "--out", s(&dir.join("m"))]);
    assert_failure(&o, &["cloud.ply", "PLY point cloud", "scan list"], &["UTF-8"]);
    let o = dpr(&["train", "--data", s(&cloud), "--out", s(&dir.join("w.safetensors"))]);
    assert_failure(&o, &["cloud.ply", "PLY point cloud", "pairs file"], &["UTF-8"]);
    let binary = dir.join("list.txt");
    std::fs::write(&binary, b"a.ply\n\xff\xfe\x00\x01").unwrap();
    let o = dpr(&["multiway", s(&binary), "--out", s(&dir.join("m"))]);
    assert_failure(&o, &["list.txt", "byte 6", "binary"], &["UTF-8"]);
}

/// Case 12: numeric flags are checked before the work: --rotate beyond a full turn, --fused too small for the
/// scans' extent (nothing written), and multiway's other numbers.
#[test]
fn numeric_flags_are_checked_before_the_work() {
    let dir = temp_dir("h2-flags");
    let o = dpr(&["eval", s(&dir.join("missing")), "--rotate", "1e308", "--out", s(&dir.join("e"))]);
    assert_failure(&o, &["--rotate", "1e308"], &["missing"]);
    let weights = small_weights(&dir);
    for (k, name) in ["a.ply", "b.ply"].iter().enumerate() {
        write_ply(&dir.join(name), &room_pair(k as u64, 2000).0).unwrap();
    }
    let list = write_list(&dir, &["a.ply", "b.ply"]);
    let out = dir.join("m");
    let multiway = |extra: &[&str]| {
        dpr(&[&["multiway", s(&list), "--out", s(&out), "--weights", s(&weights), "--backend", "cpu"][..], extra]
            .concat())
    };
    assert_failure(&multiway(&["--fused", "1e-9"]), &["--fused", "2^30"], &[]);
    assert!(!out.join("trajectory.log").exists(), "the trajectory was written before --fused was refused");
    for (flag, value) in [("--retrieval-k", "0"), ("--information-distance", "nan"), ("--loop-preference", "-1")] {
        assert_failure(&multiway(&[&format!("{flag}={value}")]), &[flag], &[]);
    }
}

/// Case 13: too few correspondences to estimate a pose names the weights as a likely cause.
#[test]
fn too_few_correspondences_point_at_the_weights() {
    let dir = temp_dir("h2-useless");
    let mut weights = dpr_gpu::model::Weights::init(&common::tiny_config(), 1).unwrap();
    for values in weights.tensors.values_mut() {
        values.iter_mut().for_each(|v| *v = 0.0);
    }
    let path = dir.join("zero.safetensors");
    weights.save(&path).unwrap();
    let (source, target, _) = room_pair(1, 3000);
    let (sp, tp) = (dir.join("s.ply"), dir.join("t.ply"));
    write_ply(&sp, &source).unwrap();
    write_ply(&tp, &target).unwrap();
    let o = dpr(&["register", s(&sp), s(&tp), "--weights", s(&path), "--backend", "cpu", "--keypoints", "200"]);
    assert_failure(&o, &["correspondences", "zero.safetensors", "may not describe"], &[]);
}

/// Case 14: without a desktop session (no XDG_RUNTIME_DIR), probing for an adapter prints no error: a run
/// that succeeds prints nothing with "error" in it.
#[test]
fn adapter_probing_without_a_session_prints_no_error() {
    let dir = temp_dir("h2-xdg");
    let weights = small_weights(&dir);
    let (source, target, _) = room_pair(2, 2000);
    let (sp, tp) = (dir.join("s.ply"), dir.join("t.ply"));
    write_ply(&sp, &source).unwrap();
    write_ply(&tp, &target).unwrap();
    for backend in ["auto", "cpu"] {
        let o = Command::new(env!("CARGO_BIN_EXE_dpr-gpu"))
            .args(["register", s(&sp), s(&tp), "--weights", s(&weights), "--keypoints", "100", "--backend", backend])
            .env_remove("XDG_RUNTIME_DIR")
            .env_remove("NODEVICE_SELECT")
            .output()
            .unwrap();
        let (_, err) = text(&o);
        assert!(matches!(o.status.code(), Some(0 | 3)), "{err}");
        assert!(!err.to_lowercase().contains("error"), "--backend {backend}: {err}");
    }
}
