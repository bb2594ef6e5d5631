//! Hostile and clumsy input (issue 10): no panic or abort from any size, bounded reading of endless inputs,
//! outputs that never destroy a file that is not ours, correct answers on awkward input, a verdict on every
//! result, errors that name the problem, and a thread pool capped whatever `RAYON_NUM_THREADS` says.

mod common;

use common::{room_corner, room_pair, temp_dir, tiny_dataset};
use dpr_gpu::io::{LoadOptions, read_cloud, write_ply};
use dpr_gpu::model::Weights;
use dpr_gpu::pose::rotation_error_deg;
use dpr_gpu::{PointCloud, RegistrationSettings};
use nalgebra::{Matrix4, Vector3};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

fn dpr(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_dpr-gpu")).args(args).output().expect("binary runs")
}

fn text(o: &Output) -> (String, String) {
    (String::from_utf8_lossy(&o.stdout).into_owned(), String::from_utf8_lossy(&o.stderr).into_owned())
}

/// Output into a pipe whose reader is gone (`dpr-gpu info w | head -1`) ends the process by SIGPIPE, as it ends
/// other Unix tools: never a panic in `println!`.
#[cfg(unix)]
#[test]
fn output_into_a_closed_pipe_ends_quietly() {
    use std::os::unix::process::ExitStatusExt;
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let o = Command::new(env!("CARGO_BIN_EXE_dpr-gpu"))
        .args(["info", "weights/default.safetensors"])
        .stdout(writer)
        .output()
        .expect("binary runs");
    let (_, err) = text(&o);
    assert!(!err.contains("panicked"), "{err}");
    // SIGPIPE is 13 on Linux and macOS.
    assert_eq!(o.status.signal(), Some(13), "status {:?}, stderr: {err}", o.status);
}

/// Exit status 1 with one `error:` line that contains every needle; no panic, no abort (a signal).
fn assert_clean_failure(o: &Output, needles: &[&str]) {
    let (_, err) = text(o);
    assert_eq!(o.status.code(), Some(1), "expected a clean failure (status 1), stderr: {err}");
    assert!(!err.contains("panicked") && !err.contains("memory allocation"), "{err}");
    let lines: Vec<&str> = err.lines().filter(|l| !l.contains("XDG_RUNTIME_DIR")).collect();
    assert_eq!(lines.len(), 1, "one line expected: {err}");
    for needle in needles {
        assert!(lines[0].starts_with("error: ") && lines[0].contains(needle), "'{needle}' not in: {err}");
    }
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Small model (64 points per patch) so CPU runs stay short.
fn small_weights(dir: &Path) -> PathBuf {
    let w = dir.join("w.safetensors");
    let o = dpr(&["init-weights", s(&w), "--seed", "3", "--points", "64", "--grid", "8"]);
    assert!(o.status.success(), "{:?}", text(&o));
    w
}

/// A generated pair written as PLY files in `dir`.
fn pair_files(dir: &Path, seed: u64, n: usize) -> (PathBuf, PathBuf, Matrix4<f64>) {
    let (source, target, truth) = room_pair(seed, n);
    let (sp, tp) = (dir.join("source.ply"), dir.join("target.ply"));
    write_ply(&sp, &source).unwrap();
    write_ply(&tp, &target).unwrap();
    (sp, tp, truth)
}

/// Register options that give a correct pose quickly on `room_pair` with random weights (RANSAC + ICP).
const QUICK: &[&str] = &["--keypoints", "600", "--estimator", "ransac", "--voxel", "0.02", "--icp"];

// ------------------------------------------------------------------------------ 1. sizes are bounded

#[test]
fn every_size_from_the_command_line_is_bounded() {
    let dir = temp_dir("hard-sizes");
    let synth_dir = dir.join("synth");
    let out = s(&synth_dir);
    assert_clean_failure(&dpr(&["synth", out, "--width", "1000000000"]), &["--width", "4096"]);
    assert_clean_failure(&dpr(&["synth", out, "--scenes", "1000000000000"]), &["--scenes"]);
    assert_clean_failure(&dpr(&["synth", out, "--fragments", "1000000000000"]), &["--fragments"]);
    assert_clean_failure(&dpr(&["synth", out, "--frames", "1000000000000"]), &["--frames"]);
    assert_clean_failure(&dpr(&["synth", out, "--width", "4096", "--frames", "1000"]), &["rays per fragment"]);
    assert_clean_failure(&dpr(&["bench", "--backend", "cpu", "--keypoints", "1000000000000"]), &["--keypoints"]);
    assert_clean_failure(&dpr(&["bench", "--backend", "cpu", "--points", "1000000000000"]), &["--points"]);
    assert_clean_failure(
        &dpr(&["train", "--data", out, "--out", s(&dir.join("w.safetensors")), "--points", "1099511627776"]),
        &["points_per_patch", "65536"],
    );
    assert_clean_failure(&dpr(&["init-weights", s(&dir.join("g.safetensors")), "--grid", "1000000"]), &["grid"]);
    let weights = small_weights(&dir);
    let (sp, tp, _) = pair_files(&dir, 1, 500);
    let register = |extra: &[&str]| dpr(&[&["register", s(&sp), s(&tp), "--weights", s(&weights)], extra].concat());
    assert_clean_failure(&register(&["--keypoints", "1000000000000"]), &["keypoints", "1000000"]);
    assert_clean_failure(&register(&["--normal-k", "1000000000000"]), &["normal neighbours"]);
    assert_clean_failure(&register(&["--ransac-iterations", "1000000000000"]), &["RANSAC iterations"]);
    assert_clean_failure(&register(&["--voxel", "nan"]), &["voxel"]);
    assert_clean_failure(&register(&["--min-inlier-ratio", "2"]), &["inlier ratio"]);
}

/// Rewrites the model config stored in a weights file's metadata.
fn with_config(weights: &Path, edit: impl Fn(&mut serde_json::Value)) -> Vec<u8> {
    let bytes = std::fs::read(weights).unwrap();
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let mut header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    let meta = header["__metadata__"].as_object_mut().unwrap();
    let key = meta.keys().find(|k| k.contains("config")).unwrap().clone();
    let mut config: serde_json::Value = serde_json::from_str(meta[&key].as_str().unwrap()).unwrap();
    edit(&mut config);
    meta.insert(key, config.to_string().into());
    let mut text = header.to_string().into_bytes();
    while !text.len().is_multiple_of(8) {
        text.push(b' ');
    }
    let mut out = (text.len() as u64).to_le_bytes().to_vec();
    out.extend(text);
    out.extend(&bytes[8 + n..]);
    out
}

#[test]
fn weights_whose_config_declares_huge_sizes_are_refused() {
    let dir = temp_dir("hard-weights-config");
    let weights = small_weights(&dir);
    let (sp, tp, _) = pair_files(&dir, 2, 500);
    for (name, edit, needle) in [
        (
            "grid.safetensors",
            Box::new(|c: &mut serde_json::Value| c["grid"] = serde_json::json!([1_000_000, 1_000_000]))
                as Box<dyn Fn(&mut serde_json::Value)>,
            "grid",
        ),
        (
            "points.safetensors",
            Box::new(|c: &mut serde_json::Value| c["points_per_patch"] = (1u64 << 31).into()),
            "points_per_patch",
        ),
    ] {
        let path = dir.join(name);
        std::fs::write(&path, with_config(&weights, edit)).unwrap();
        assert_clean_failure(&dpr(&["info", s(&path)]), &[needle, name]);
        assert_clean_failure(&dpr(&["register", s(&sp), s(&tp), "--weights", s(&path)]), &[needle]);
    }
}

// ------------------------------------------------------------------------------ 2. bounded reading

/// Runs the binary with its address space limited to 2 GiB (and two worker threads, whose stacks and malloc
/// arenas take address space too), so unbounded reading aborts instead of passing.
fn dpr_limited(args: &[&str]) -> Output {
    let mut command = String::from("ulimit -v 2097152; RAYON_NUM_THREADS=2 exec \"$0\"");
    for i in 0..args.len() {
        command.push_str(&format!(" \"${}\"", i + 1));
    }
    Command::new("sh").arg("-c").arg(command).arg(env!("CARGO_BIN_EXE_dpr-gpu")).args(args).output().unwrap()
}

#[test]
#[cfg(unix)]
fn endless_inputs_and_huge_lines_fail_in_bounded_memory() {
    let dir = temp_dir("hard-endless");
    let weights = small_weights(&dir);
    let (_, tp, _) = pair_files(&dir, 3, 500);
    for device in ["/dev/zero", "/dev/urandom"] {
        for ext in ["xyz", "ply", "pcd", "txt"] {
            let link = dir.join(format!("{}.{ext}", &device[5..]));
            std::os::unix::fs::symlink(device, &link).unwrap();
            let started = Instant::now();
            let o = dpr_limited(&["register", s(&link), s(&tp), "--weights", s(&weights)]);
            assert_clean_failure(&o, &[s(&link)]);
            assert!(started.elapsed() < Duration::from_secs(20), "{device} as .{ext}");
        }
    }
    let huge = dir.join("huge.xyz");
    let mut line = vec![b'1'; 3 << 20];
    line.push(b'\n');
    std::fs::write(&huge, line).unwrap();
    assert_clean_failure(
        &dpr_limited(&["register", s(&huge), s(&tp), "--weights", s(&weights)]),
        &["line length limit"],
    );
    let long_header = dir.join("long.ply");
    std::fs::write(&long_header, format!("ply\ncomment {}\n", "c".repeat(2 << 20))).unwrap();
    let o = dpr_limited(&["register", s(&long_header), s(&tp), "--weights", s(&weights)]);
    assert_clean_failure(&o, &["long.ply", "limit"]);
}

// ------------------------------------------------------------------------------ 3. outputs

#[test]
#[cfg(unix)]
fn outputs_never_destroy_inputs_or_special_files() {
    use std::os::unix::fs::FileTypeExt;
    let dir = temp_dir("hard-outputs");
    let weights = small_weights(&dir);
    let (sp, tp, _) = pair_files(&dir, 4, 3000);
    let w_before = std::fs::read(&weights).unwrap();
    let base = ["register", s(&sp), s(&tp), "--weights", s(&weights), "--keypoints", "50"];
    let run = |extra: &[&str]| dpr(&[&base[..], extra].concat());
    // The weights are an input too.
    assert_clean_failure(&run(&["--out", s(&weights)]), &["overwrite", "w.safetensors"]);
    assert_eq!(std::fs::read(&weights).unwrap(), w_before);
    // A hard link to an input is the input.
    let link = dir.join("link.txt");
    std::fs::hard_link(&sp, &link).unwrap();
    assert_clean_failure(&run(&["--out", s(&link)]), &["overwrite"]);
    // A symlink to an input too.
    let sym = dir.join("sym.ply");
    std::os::unix::fs::symlink(&tp, &sym).unwrap();
    assert_clean_failure(&run(&["--aligned", s(&sym)]), &["overwrite"]);
    // Two outputs on one path.
    let both = dir.join("both.ply");
    assert_clean_failure(&run(&["--out", s(&both), "--aligned", s(&both)]), &["same file"]);
    // Output folders are checked before the pipeline runs; unknown extensions are refused, not written as PLY.
    let started = Instant::now();
    assert_clean_failure(&run(&["--out", s(&dir.join("missing/T.txt"))]), &["does not exist"]);
    assert_clean_failure(&run(&["--aligned", s(&dir.join("a.obj"))]), &["a.obj", ".xyz"]);
    assert!(started.elapsed() < Duration::from_secs(5));
    // A symlink output is written through and stays a symlink.
    let real = dir.join("real.txt");
    std::fs::write(&real, "old").unwrap();
    let out_link = dir.join("out-link.txt");
    std::os::unix::fs::symlink(&real, &out_link).unwrap();
    // /dev/null stays a device (and may take two outputs).
    let o = run(&["--out", s(&out_link), "--aligned", "/dev/null", "--json"]);
    assert!(matches!(o.status.code(), Some(0 | 3)), "{:?}", text(&o));
    assert!(std::fs::symlink_metadata(&out_link).unwrap().file_type().is_symlink());
    assert_eq!(std::fs::read_to_string(&real).unwrap().split_whitespace().count(), 16);
    assert!(std::fs::metadata("/dev/null").unwrap().file_type().is_char_device());
    // A FIFO output is written into, never replaced.
    let fifo = dir.join("fifo.txt");
    assert!(Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    let reader = {
        let fifo = fifo.clone();
        std::thread::spawn(move || std::fs::read_to_string(fifo).unwrap())
    };
    let o = run(&["--out", s(&fifo)]);
    assert!(matches!(o.status.code(), Some(0 | 3)), "{:?}", text(&o));
    assert_eq!(reader.join().unwrap().split_whitespace().count(), 16);
    assert!(std::fs::symlink_metadata(&fifo).unwrap().file_type().is_fifo());
}

#[test]
fn aligned_output_is_written_in_the_format_its_extension_names() {
    let dir = temp_dir("hard-aligned");
    let weights = small_weights(&dir);
    let (sp, tp, _) = pair_files(&dir, 5, 3000);
    let (source, _) = read_cloud(&sp, &LoadOptions::default()).unwrap();
    for ext in ["xyz", "pcd", "txt", "ply"] {
        let aligned = dir.join(format!("aligned.{ext}"));
        let o =
            dpr(&["register", s(&sp), s(&tp), "--weights", s(&weights), "--keypoints", "50", "--aligned", s(&aligned)]);
        assert!(matches!(o.status.code(), Some(0 | 3)), "{:?}", text(&o));
        let bytes = std::fs::read(&aligned).unwrap();
        match ext {
            "pcd" => assert!(bytes.starts_with(b"# .PCD")),
            "ply" => assert!(bytes.starts_with(b"ply\n")),
            _ => assert!(bytes.starts_with(b"# x y z")),
        }
        let (cloud, _) = read_cloud(&aligned, &LoadOptions::default()).unwrap();
        assert_eq!(cloud.len(), source.len(), "{ext}");
    }
}

#[test]
fn train_outputs_never_replace_dataset_files_and_the_log_appends() {
    let dir = temp_dir("hard-train");
    let data = tiny_dataset(&dir);
    let scene = data.join("scene_00");
    let fragment = std::fs::read_dir(&scene)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .find(|p| p.extension().is_some_and(|e| e == "ply"))
        .unwrap();
    let gt = scene.join("gt.log");
    let gt_before = std::fs::read(&gt).unwrap();
    let frag_before = std::fs::read(&fragment).unwrap();
    let out = dir.join("w.safetensors");
    let small = ["--points", "8", "--grid", "3", "--batch", "2", "--voxel", "0.03", "--steps", "1"];
    let train = |extra: &[&str]| dpr(&[&["train", "--data", s(&data)], &small[..], extra].concat());
    assert_clean_failure(&train(&["--out", s(&fragment)]), &["overwrite"]);
    assert_clean_failure(&train(&["--out", s(&out), "--log", s(&gt)]), &["overwrite", "gt.log"]);
    assert_clean_failure(&train(&["--out", s(&out), "--checkpoint", s(&gt)]), &["overwrite"]);
    assert_clean_failure(&train(&["--out", s(&out), "--log", s(&out)]), &["same file"]);
    assert_eq!(std::fs::read(&gt).unwrap(), gt_before);
    assert_eq!(std::fs::read(&fragment).unwrap(), frag_before);
    // --log appends, as its help says.
    let log = dir.join("losses.csv");
    std::fs::write(&log, "step,total,rec,pose,feat,lr,seconds\n0,earlier run\n").unwrap();
    let o = train(&["--out", s(&out), "--log", s(&log)]);
    assert!(o.status.success(), "{:?}", text(&o));
    let lines: Vec<String> = std::fs::read_to_string(&log).unwrap().lines().map(String::from).collect();
    assert_eq!(lines[..2], ["step,total,rec,pose,feat,lr,seconds", "0,earlier run"]);
    assert!(lines.len() == 3 && lines[2].starts_with("1,"), "{lines:?}");
}

#[test]
fn train_max_seconds_stops_early_saves_everything_and_the_run_resumes() {
    let dir = temp_dir("hard-train-time");
    let data = tiny_dataset(&dir);
    let (out, log) = (dir.join("w.safetensors"), dir.join("losses.csv"));
    let small = ["--points", "8", "--grid", "3", "--batch", "2", "--voxel", "0.03", "--checkpoint-every", "0"];
    let args = [&["train", "--data", s(&data), "--out", s(&out), "--log", s(&log)], &small[..]].concat();
    // Far more steps than a second allows: the limit ends the run, which still writes its outputs.
    let o = dpr(&[&args[..], &["--steps", "100000000", "--max-seconds", "1"]].concat());
    assert!(o.status.success(), "{:?}", text(&o));
    let steps: u64 = Weights::load(&out).unwrap().notes["dpr_gpu.train.steps"].parse().unwrap();
    assert!((1..100_000_000).contains(&steps), "{steps} steps");
    let rows = std::fs::read_to_string(&log).unwrap().lines().count();
    assert_eq!(rows as u64, steps + 1, "one log row per step, and the header");
    // The checkpoint holds the last step: resuming runs exactly the steps left.
    let ckpt = dir.join("w.ckpt.safetensors");
    let more = (steps + 2).to_string();
    let o = dpr(&["train", "--resume", s(&ckpt), "--out", s(&out), "--log", s(&log), "--steps", &more]);
    assert!(o.status.success(), "{:?}", text(&o));
    assert_eq!(Weights::load(&out).unwrap().notes["dpr_gpu.train.steps"], more);
    assert_eq!(std::fs::read_to_string(&log).unwrap().lines().count() as u64, steps + 3);
}

#[test]
fn train_on_the_gpu_backend_fails_cleanly_without_a_device_or_with_a_cpu_only_option() {
    let dir = temp_dir("hard-train-gpu");
    let data = tiny_dataset(&dir);
    let out = dir.join("w.safetensors");
    let args = ["train", "--data", s(&data), "--out", s(&out), "--points", "8", "--grid", "3", "--steps", "1"];
    let gpu = |extra: &[&str]| {
        // No Metal adapter exists on Linux or Windows.
        let all = [&args[..], &["--backend", "gpu"], extra].concat();
        Command::new(env!("CARGO_BIN_EXE_dpr-gpu")).args(all).env("DPR_GPU_BACKEND", "metal").output().unwrap()
    };
    if !cfg!(target_os = "macos") {
        assert_clean_failure(&gpu(&[]), &["--backend gpu", "adapter"]);
    }
    assert_clean_failure(&gpu(&["--pose-trains-ppf"]), &["--pose-trains-ppf", "CPU trainer only"]);
    assert!(!out.exists(), "a failed run wrote its output");
}

#[test]
fn train_precision_is_saved_with_the_run_and_cannot_change_on_resume() {
    let dir = temp_dir("hard-train-precision");
    let data = tiny_dataset(&dir);
    let out = dir.join("w.safetensors");
    let small = ["--points", "8", "--grid", "3", "--batch", "2", "--voxel", "0.03", "--steps", "1"];
    let args = [&["train", "--data", s(&data), "--out", s(&out)], &small[..]].concat();
    let train = |extra: &[&str]| dpr(&[&args[..], extra].concat());
    assert_clean_failure(&train(&["--precision", "bf16", "--backend", "gpu"]), &["--precision bf16", "--backend gpu"]);
    assert!(!out.exists(), "a failed run wrote its output");
    let saved_precision = || {
        let notes = Weights::load(&out).unwrap().notes;
        let settings: serde_json::Value = serde_json::from_str(&notes["dpr_gpu.train.settings"]).unwrap();
        settings["precision"].as_str().unwrap().to_string()
    };
    let o = train(&["--precision", "f32"]);
    assert!(o.status.success(), "{:?}", text(&o));
    assert_eq!(saved_precision(), "f32");
    // A resumed run keeps the checkpoint's precision, and refuses another one.
    let ckpt = dir.join("w.ckpt.safetensors");
    let resume = |extra: &[&str]| dpr(&[&["train", "--resume", s(&ckpt), "--out", s(&out)], extra].concat());
    if dpr_gpu::cpu::gemm::Precision::Bf16.is_available() {
        assert_clean_failure(&resume(&["--steps", "2", "--precision", "bf16"]), &["--precision", "cannot change"]);
    }
    let o = resume(&["--steps", "2"]);
    assert!(o.status.success(), "{:?}", text(&o));
    assert_eq!(saved_precision(), "f32");
}

// ------------------------------------------------------------------------------ 4. awkward input

#[test]
fn six_column_xyz_is_decided_by_content_or_by_xyz_columns() {
    let dir = temp_dir("hard-xyz");
    let cloud = room_corner(7, 400);
    let rgb = dir.join("rgb.xyz");
    let normals = dir.join("normals.xyz");
    let (mut a, mut b) = (String::new(), String::new());
    for (i, p) in cloud.points.iter().enumerate() {
        a.push_str(&format!("{} {} {} {} {} {}\n", p[0], p[1], p[2], i % 256, 255 - i % 256, 17));
        let n = Vector3::new(1.0 + i as f64, 2.0, -3.0).normalize();
        b.push_str(&format!("{} {} {} {:.6} {:.6} {:.6}\n", p[0], p[1], p[2], n.x, n.y, n.z));
    }
    std::fs::write(&rgb, a).unwrap();
    std::fs::write(&normals, b).unwrap();
    let err = read_cloud(&rgb, &LoadOptions::default()).unwrap_err().to_string();
    assert!(err.contains("rgb.xyz") && err.contains("--xyz-columns") && err.contains("line 1"), "{err}");
    let columns = dpr_gpu::io::XyzColumns::parse("x,y,z,r,g,b").unwrap();
    let opts = LoadOptions { xyz_columns: Some(columns), ..LoadOptions::default() };
    let (read, _) = read_cloud(&rgb, &opts).unwrap();
    assert_eq!(read.points, cloud.points);
    assert!(read.normals.is_none());
    let (read, _) = read_cloud(&normals, &LoadOptions::default()).unwrap();
    assert_eq!(read.normals.as_ref().map(Vec::len), Some(cloud.len()));
    // The CLI takes the option too.
    let weights = small_weights(&dir);
    let o = dpr(&["register", s(&rgb), s(&rgb), "--weights", s(&weights), "--keypoints", "30"]);
    assert_clean_failure(&o, &["--xyz-columns"]);
    let o = dpr(&[
        "register",
        s(&rgb),
        s(&rgb),
        "--weights",
        s(&weights),
        "--keypoints",
        "30",
        "--xyz-columns",
        "x,y,z,r,g,b",
    ]);
    assert!(matches!(o.status.code(), Some(0 | 3)), "{:?}", text(&o));
    for spec in ["x,y", "x,y,q", "x,y,z,nx", "x,x,y,z"] {
        assert!(dpr_gpu::io::XyzColumns::parse(spec).is_err(), "{spec}");
    }
}

#[test]
fn georeferenced_clouds_register_as_well_as_local_ones() {
    // The same pair twice: in a local frame (f32 PLY) and georeferenced at (5e5, 4.2e6, 100) (f64 text, where f32
    // keeps only 0.25-0.5 m: unshifted, this registers tens of degrees off). The CLI shifts georeferenced clouds
    // by the source's first point rounded to whole units; the local frame here is exactly that shifted frame, so
    // both runs solve the same problem and the georeferenced answer must be the local one moved back, and right.
    let dir = temp_dir("hard-geo");
    let weights = small_weights(&dir);
    let (mut source, target, truth) = room_pair(1, 20_000);
    // The room's corner (on its floor and walls) first, so the shift (the first point, rounded) is `origin` and
    // the shifted frame is the local one, where the normals' viewpoint (the frame's origin) is the same.
    source.points.insert(0, [0.0; 3]);
    let origin = Vector3::new(500_000.0, 4_200_000.0, 100.0);
    let geo = |cloud: &PointCloud| -> Vec<Vector3<f64>> {
        cloud.points.iter().map(|p| Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64) + origin).collect()
    };
    let (gs, gt) = (geo(&source), geo(&target));
    let as_text =
        |pts: &[Vector3<f64>]| pts.iter().map(|p| format!("{:.5} {:.5} {:.5}\n", p.x, p.y, p.z)).collect::<String>();
    let (sp, tp) = (dir.join("s.xyz"), dir.join("t.xyz"));
    std::fs::write(&sp, as_text(&gs)).unwrap();
    std::fs::write(&tp, as_text(&gt)).unwrap();
    let first: Vec<f64> =
        std::fs::read_to_string(&sp).unwrap().split_whitespace().take(3).map(|v| v.parse().unwrap()).collect();
    let shift = Vector3::new(first[0].round(), first[1].round(), first[2].round());
    let local = |pts: &[Vector3<f64>]| {
        PointCloud::from_points(pts.iter().map(|p| (p - shift).map(|c| c as f32).into()).collect())
    };
    let (lsp, ltp) = (dir.join("ls.ply"), dir.join("lt.ply"));
    write_ply(&lsp, &local(&gs)).unwrap();
    write_ply(&ltp, &local(&gt)).unwrap();
    let pose = |a: &Path, b: &Path| {
        let o = dpr(&[&["register", s(a), s(b), "--weights", s(&weights), "--json"], QUICK].concat());
        let (stdout, stderr) = text(&o);
        assert!(matches!(o.status.code(), Some(0 | 3)), "{stderr}");
        let v: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
        let rows = v["target_from_source"].as_array().unwrap().clone();
        (Matrix4::from_fn(|r, c| rows[r][c].as_f64().unwrap()), v)
    };
    let (m_geo, v_geo) = pose(&sp, &tp);
    let (m_local, v_local) = pose(&lsp, &ltp);
    assert_eq!(v_geo["origin"], serde_json::json!([shift.x as i64, shift.y as i64, shift.z as i64]));
    // Compared by how far they move the scan's own points: at 4e6 m from the origin, a rotation difference of
    // 1e-6 rad moves the translation column by metres without moving the scan.
    let displacement = |a: &Matrix4<f64>, b: &Matrix4<f64>| {
        gs.iter()
            .map(|p| (a.transform_point(&(*p).into()) - b.transform_point(&(*p).into())).norm())
            .fold(0.0, f64::max)
    };
    let moved_back = Matrix4::new_translation(&shift) * m_local * Matrix4::new_translation(&-shift);
    assert!(rotation_error_deg(&m_geo, &moved_back) < 0.05, "{}", rotation_error_deg(&m_geo, &moved_back));
    assert!(displacement(&m_geo, &moved_back) < 0.01, "{}", displacement(&m_geo, &moved_back));
    assert_eq!(v_geo["success"], v_local["success"]);
    // And right: p_t = T (p_s - o) + o in georeferenced frames.
    let want = Matrix4::new_translation(&origin) * truth * Matrix4::new_translation(&-origin);
    assert!(rotation_error_deg(&m_geo, &want) < 1.0, "rotation error {}", rotation_error_deg(&m_geo, &want));
    assert!(displacement(&m_geo, &want) < 0.05, "points moved {} off", displacement(&m_geo, &want));
}

#[test]
fn degenerate_clouds_never_get_a_trusted_pose() {
    let dir = temp_dir("hard-degenerate");
    let weights = small_weights(&dir);
    let mut rng = dpr_gpu::rng::Rng::new(9);
    let clouds: Vec<(&str, Vec<[f32; 3]>)> = vec![
        ("collinear", (0..3000).map(|i| [i as f32 * 1e-3, 0.0, 0.0]).collect()),
        ("coplanar-line-pair", (0..3000).map(|i| [(i % 1500) as f32 * 2e-3, (i / 1500) as f32 * 0.05, 0.0]).collect()),
        ("identical", vec![[1.0, 2.0, 3.0]; 500]),
        ("two-valued", (0..600).map(|i| if i % 2 == 0 { [0.0; 3] } else { [0.1, 0.0, 0.0] }).collect()),
        ("tiny", (0..12).map(|_| [0; 3].map(|_: i32| rng.unit_f64() as f32 * 0.05)).collect()),
    ];
    for (name, points) in clouds {
        let path = dir.join(format!("{name}.ply"));
        write_ply(&path, &PointCloud::from_points(points)).unwrap();
        for estimator in ["relativenet", "ransac"] {
            let o = dpr(&[
                "register",
                s(&path),
                s(&path),
                "--weights",
                s(&weights),
                "--keypoints",
                "100",
                "--json",
                "--estimator",
                estimator,
            ]);
            let (stdout, stderr) = text(&o);
            assert!(!stderr.contains("panicked"), "{name}: {stderr}");
            match o.status.code() {
                Some(1) => assert_clean_failure(&o, &[name]),
                Some(3) => {
                    let v: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
                    assert_eq!(v["success"], false, "{name}");
                    assert!(v["reason"].as_str().is_some_and(|r| !r.is_empty()), "{name}");
                }
                other => panic!("{name} with {estimator}: a degenerate cloud got status {other:?}: {stdout}"),
            }
        }
    }
}

// ------------------------------------------------------------------------------ 5. verdict

#[test]
fn register_reports_a_verdict_and_exits_3_when_untrusted() {
    let dir = temp_dir("hard-verdict");
    let weights = small_weights(&dir);
    let (sp, tp, truth) = pair_files(&dir, 1, 20_000);
    // One round (no progressive schedule, no context round) and the estimator's choice alone (no pose
    // candidates compete for an untrusted result), so that the untrusted run below ends with the same pose.
    let one_round = ["--first-keypoints", "0", "--context-radius", "off", "--pose-candidates", "1"];
    let o = dpr(&[&["register", s(&sp), s(&tp), "--weights", s(&weights), "--json"], QUICK, &one_round].concat());
    let (stdout, stderr) = text(&o);
    assert_eq!(o.status.code(), Some(0), "{stderr}");
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(v["success"], true);
    assert!(v["reason"].is_null());
    let rows = v["target_from_source"].as_array().unwrap();
    assert!(rotation_error_deg(&Matrix4::from_fn(|r, c| rows[r][c].as_f64().unwrap()), &truth) < 1.0);
    // The same pair with an unreachable verdict threshold: status 3, the pose still printed, the reason named.
    let unreachable = ["--min-inliers", "100000"];
    let o =
        dpr(&[&["register", s(&sp), s(&tp), "--weights", s(&weights), "--json"], QUICK, &one_round, &unreachable]
            .concat());
    let (stdout, stderr) = text(&o);
    assert_eq!(o.status.code(), Some(3), "{stderr}");
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(v["success"], false);
    assert!(v["reason"].as_str().unwrap().contains("too few inliers"), "{v}");
    assert_eq!(v["target_from_source"], serde_json::Value::Array(rows.clone()));
    // Unrelated clouds (a room corner against a sphere shell): not trusted, text output says so.
    let mut rng = dpr_gpu::rng::Rng::new(4);
    let shell: Vec<[f32; 3]> = (0..20_000)
        .map(|_| {
            let v = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize() * 1.5;
            [v.x as f32, v.y as f32, v.z as f32]
        })
        .collect();
    let other = dir.join("shell.ply");
    write_ply(&other, &PointCloud::from_points(shell)).unwrap();
    let o = dpr(&[&["register", s(&sp), s(&other), "--weights", s(&weights)], QUICK].concat());
    let (stdout, _) = text(&o);
    assert_eq!(o.status.code(), Some(3), "{stdout}");
    assert!(stdout.contains("verdict: NOT TRUSTED") && stdout.contains("target_from_source"), "{stdout}");
}

#[test]
fn library_result_carries_the_verdict() {
    let (source, target, _) = room_pair(3, 6_000);
    let weights = dpr_gpu::model::Weights::init(
        &dpr_gpu::model::ModelConfig { points_per_patch: 32, grid: [4, 4], ..Default::default() },
        1,
    )
    .unwrap();
    let settings = RegistrationSettings {
        keypoints: 150,
        estimator: dpr_gpu::Estimator::Ransac,
        voxel: Some(0.02),
        ..RegistrationSettings::default()
    };
    let registrar = dpr_gpu::Registrar::with_weights(&settings, &weights).unwrap();
    let result = registrar.register(&source, &target).unwrap();
    assert_eq!(result.success, result.reason.is_none());
    let strict = RegistrationSettings {
        verdict: dpr_gpu::verdict::VerdictSettings { min_inliers: 0, min_inlier_ratio: 1.0, ..Default::default() },
        ..settings.clone()
    };
    let strict_result =
        dpr_gpu::Registrar::with_weights(&strict, &weights).unwrap().register(&source, &target).unwrap();
    let ratio = result.estimate.inliers as f64 / result.correspondences as f64;
    assert!(ratio < 1.0, "some correspondences are outliers");
    assert!(!strict_result.success && strict_result.reason.unwrap().contains("inlier ratio"));
}

// ------------------------------------------------------------------------------ 6. errors name the problem

#[test]
fn errors_name_the_problem_and_the_file() {
    let dir = temp_dir("hard-errors");
    let weights = small_weights(&dir);
    let (sp, tp, _) = pair_files(&dir, 6, 500);
    let register = |src: &Path| dpr(&["register", s(src), s(&tp), "--weights", s(&weights)]);
    let bom = dir.join("bom.xyz");
    std::fs::write(&bom, b"\xEF\xBB\xBF1 2 3\n4 5 6\n").unwrap();
    assert_clean_failure(&register(&bom), &["bom.xyz", "byte-order mark"]);
    let cr = dir.join("cr.xyz");
    std::fs::write(&cr, b"1 2 3\r4 5 6\r7 8 9\r").unwrap();
    assert_clean_failure(&register(&cr), &["cr.xyz", "CR-only"]);
    let no_end = dir.join("noend.ply");
    let mut bytes = b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\n".to_vec();
    bytes.extend([0xff, 0xfe, 0x80, 0x81, 0x00, 0x9f]);
    std::fs::write(&no_end, bytes).unwrap();
    let o = register(&no_end);
    assert_clean_failure(&o, &["noend.ply", "end_header"]);
    assert!(!text(&o).1.contains("UTF-8"));
    // OS errors once, not repeated by the error chain.
    let o = register(&dir.join("missing.ply"));
    assert_clean_failure(&o, &["missing.ply"]);
    let line = text(&o).1;
    assert_eq!(line.matches("No such file").count(), 1, "{line}");
    // Setting errors are not blamed on the model.
    let o = dpr(&["register", s(&sp), s(&tp), "--weights", s(&weights), "--radius=-1"]);
    assert_clean_failure(&o, &["radius"]);
    assert!(!text(&o).1.contains("loading the model"));
    // Truncated weights are called truncated.
    let cut = dir.join("cut.safetensors");
    let w = std::fs::read(&weights).unwrap();
    std::fs::write(&cut, &w[..w.len() / 2]).unwrap();
    assert_clean_failure(&dpr(&["register", s(&sp), s(&tp), "--weights", s(&cut)]), &["cut.safetensors", "truncated"]);
    // A cloud with too few points names its file.
    let few = dir.join("few.xyz");
    std::fs::write(&few, "1 2 3\n4 5 6\n").unwrap();
    assert_clean_failure(&register(&few), &["few.xyz"]);
}

// ------------------------------------------------------------------------------ 9. thread pool

#[test]
fn an_absurd_rayon_thread_count_is_capped() {
    let dir = temp_dir("hard-rayon");
    let weights = small_weights(&dir);
    let (sp, tp, _) = pair_files(&dir, 8, 3000);
    let started = Instant::now();
    let o = Command::new(env!("CARGO_BIN_EXE_dpr-gpu"))
        .args(["register", s(&sp), s(&tp), "--weights", s(&weights), "--keypoints", "100", "--json"])
        .env("RAYON_NUM_THREADS", "5000")
        .output()
        .unwrap();
    let (stdout, stderr) = text(&o);
    assert!(matches!(o.status.code(), Some(0 | 3)), "{stderr}");
    assert!(started.elapsed() < Duration::from_secs(60), "took {:?}", started.elapsed());
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    let backend = v["backend"].as_str().unwrap();
    let threads: usize = backend.split(['(', ' ']).find_map(|w| w.parse().ok()).unwrap();
    let cores = std::thread::available_parallelism().map_or(1, usize::from);
    assert!(threads <= cores, "{backend} on {cores} cores");
}
