//! Mutation fuzzing on stable Rust (proptest): valid PLY (ascii and binary), PCD (ascii and binary), XYZ, g2o
//! pose-graph, weights, trajectory (.log and poses.txt), gt.info and scan-list files are mutated (bytes flipped,
//! set, inserted, removed, truncated, ranges duplicated) and fed to the readers (a g2o graph that reads is also
//! optimised), and random registration settings to the pipeline. Nothing may panic; what reads must be a
//! valid cloud or graph. Each target runs a fixed number of cases (`FUZZ_CASES`, default 1000), about 2 s in all in
//! release builds, well under the 2 minutes CI allows in total. The generator is seeded (`FUZZ_SEED`, fixed by
//! default; `FUZZ_SEED=random` explores new inputs), so CI runs the same cases every time. Failing inputs are kept by proptest in
//! `tests/fuzz.proptest-regressions` and replayed first; inputs that once failed are also pinned below as
//! plain tests.

mod common;

use dpr_gpu::eval::gtlog::{InfoRecord, format_info, parse_info};
use dpr_gpu::io::{LoadOptions, ZeroPoints, list_text, parse_scan_list, read_cloud};
use dpr_gpu::model::{ModelConfig, Weights};
use dpr_gpu::multiway::Trajectory;
use dpr_gpu::pose_graph::g2o::parse_g2o;
use dpr_gpu::pose_graph::{Init, SolveOptions, solve};
use dpr_gpu::{PointCloud, Registrar, RegistrationSettings};
use proptest::prelude::*;
use proptest::test_runner::RngSeed;
use std::path::PathBuf;
use std::sync::OnceLock;

/// Cases per target: `FUZZ_CASES` or 1000.
fn cases() -> u32 {
    std::env::var("FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(1000)
}

/// The generator seed: `FUZZ_SEED`, or a fixed default so that CI runs the same cases every time. Set
/// `FUZZ_SEED=random` to explore new inputs while developing.
fn rng_seed() -> RngSeed {
    match std::env::var("FUZZ_SEED").ok().as_deref() {
        Some("random") => RngSeed::Random,
        Some(text) => RngSeed::Fixed(text.parse().expect("FUZZ_SEED must be an integer or 'random'")),
        None => RngSeed::Fixed(0x5eed_f022),
    }
}

fn config() -> ProptestConfig {
    ProptestConfig { cases: cases(), rng_seed: rng_seed(), ..ProptestConfig::default() }
}

/// One mutation of a byte string.
#[derive(Clone, Debug)]
enum Mutation {
    /// XOR a byte (position as a fraction of the length).
    Flip(f64, u8),
    /// Set a byte to an interesting value.
    Set(f64, u8),
    /// Insert bytes.
    Insert(f64, Vec<u8>),
    /// Remove up to n bytes.
    Remove(f64, usize),
    /// Cut the file here.
    Truncate(f64),
    /// Copy a range to another place.
    Duplicate(f64, usize, f64),
    /// Replace an ascii digit run by a huge or odd number.
    Number(f64, &'static str),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    let at = 0.0..1.0f64;
    let interesting = prop_oneof![Just(0u8), Just(0xff), Just(b'\n'), Just(b'\r'), Just(b' '), Just(b'-'), any::<u8>()];
    let numbers = prop_oneof![
        Just("99999999999999999999"),
        Just("-1"),
        Just("4294967296"),
        Just("nan"),
        Just("1e39"),
        Just("0"),
        Just("18446744073709551615")
    ];
    prop_oneof![
        (at.clone(), 1..=255u8).prop_map(|(p, x)| Mutation::Flip(p, x)),
        (at.clone(), interesting).prop_map(|(p, x)| Mutation::Set(p, x)),
        (at.clone(), proptest::collection::vec(any::<u8>(), 1..16)).prop_map(|(p, b)| Mutation::Insert(p, b)),
        (at.clone(), 1..64usize).prop_map(|(p, n)| Mutation::Remove(p, n)),
        at.clone().prop_map(Mutation::Truncate),
        (at.clone(), 1..256usize, at.clone()).prop_map(|(p, n, q)| Mutation::Duplicate(p, n, q)),
        (at, numbers).prop_map(|(p, s)| Mutation::Number(p, s)),
    ]
}

/// Applies `mutations` to `bytes`.
fn mutate(mut bytes: Vec<u8>, mutations: &[Mutation]) -> Vec<u8> {
    let pos = |f: f64, len: usize| ((f * len as f64) as usize).min(len);
    for m in mutations {
        let len = bytes.len();
        match m {
            Mutation::Flip(p, x) if len > 0 => bytes[pos(*p, len - 1)] ^= x,
            Mutation::Set(p, x) if len > 0 => bytes[pos(*p, len - 1)] = *x,
            Mutation::Insert(p, b) => {
                let i = pos(*p, len);
                bytes.splice(i..i, b.iter().copied());
            }
            Mutation::Remove(p, n) => {
                let i = pos(*p, len);
                bytes.drain(i..(i + n).min(len));
            }
            Mutation::Truncate(p) => bytes.truncate(pos(*p, len)),
            Mutation::Duplicate(p, n, q) => {
                let i = pos(*p, len);
                let chunk = bytes[i..(i + n).min(len)].to_vec();
                let j = pos(*q, len);
                bytes.splice(j..j, chunk);
            }
            Mutation::Number(p, s) => {
                let i = pos(*p, len);
                if let Some(start) = bytes[i..].iter().position(u8::is_ascii_digit).map(|k| i + k) {
                    let end = bytes[start..].iter().position(|b| !b.is_ascii_digit()).map_or(len, |k| start + k);
                    bytes.splice(start..end, s.bytes());
                }
            }
            _ => {}
        }
    }
    bytes
}

/// A valid g2o graph of five poses: a chain and two loop closures.
fn seed_g2o() -> &'static str {
    "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n\
     VERTEX_SE3:QUAT 1 1 0 0 0 0 0.0998 0.995\n\
     VERTEX_SE3:QUAT 2 2 0.2 0 0 0 0.198 0.980\n\
     VERTEX_SE3:QUAT 3 3 0.5 0.1 0 0.01 0.295 0.955\n\
     VERTEX_SE3:QUAT 4 4 1 0 0 0 0.389 0.921\n\
     EDGE_SE3:QUAT 0 1 1 0 0 0 0 0.0998 0.995 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 4 0 0 4 0 4\n\
     EDGE_SE3:QUAT 1 2 1 0.1 0 0 0 0.0998 0.995 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 4 0 0 4 0 4\n\
     EDGE_SE3:QUAT 2 3 1 0.1 0 0 0 0.0998 0.995 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 4 0 0 4 0 4\n\
     EDGE_SE3:QUAT 3 4 1 0.1 0 0 0 0.0998 0.995 2 0.1 0 0 0 0 2 0 0 0 0 2 0 0 0 4 0 0 4 0 4\n\
     # a comment\n\
     EDGE_SE3:QUAT 0 4 4 1 0 0 0 0.389 0.921 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 4 0 0 4 0 4\n\
     EDGE_SE3:QUAT 4 1 -3 0 0 0 0 -0.295 0.955 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 4 0 0 4 0 4\n"
}

/// A small cloud with normals.
fn seed_cloud() -> PointCloud {
    let mut c = common::room_corner(1, 40);
    c.normals = Some(c.points.iter().map(|_| [0.0, 0.0, 1.0]).collect());
    c
}

/// The valid files mutations start from: (extension, bytes).
fn seeds() -> &'static Vec<(&'static str, Vec<u8>)> {
    static SEEDS: OnceLock<Vec<(&'static str, Vec<u8>)>> = OnceLock::new();
    SEEDS.get_or_init(|| {
        let dir = common::temp_dir("fuzz-seeds");
        let cloud = seed_cloud();
        let mut out = Vec::new();
        for ext in ["ply", "pcd", "xyz"] {
            let path = dir.join(format!("seed.{ext}"));
            dpr_gpu::io::write_cloud(&path, &cloud).unwrap();
            out.push((ext, std::fs::read(&path).unwrap()));
        }
        let mut ascii_ply = format!(
            "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
             property uchar red\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n",
            cloud.len()
        );
        for p in &cloud.points {
            ascii_ply.push_str(&format!("{} {} {} 7\n", p[0], p[1], p[2]));
        }
        ascii_ply.push_str("3 0 1 2\n");
        out.push(("ply", ascii_ply.into_bytes()));
        let mut ascii_pcd = format!(
            "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F U\nCOUNT 1 1 1 1\nWIDTH {n}\n\
             HEIGHT 1\nPOINTS {n}\nDATA ascii\n",
            n = cloud.len()
        );
        for p in &cloud.points {
            ascii_pcd.push_str(&format!("{} {} {} 4278190335\n", p[0], p[1], p[2]));
        }
        out.push(("pcd", ascii_pcd.into_bytes()));
        let mut csv = String::from("# x,y,z\n40\n");
        for p in &cloud.points {
            csv.push_str(&format!("{},{},{}\n", p[0], p[1], p[2]));
        }
        out.push(("txt", csv.into_bytes()));
        out
    })
}

/// A fresh path for one fuzz case (each case removes its file; the folder, a static, stays in `target/tmp`).
fn case_path(ext: &str) -> PathBuf {
    static DIR: OnceLock<common::TestDir> = OnceLock::new();
    static N: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let dir = DIR.get_or_init(|| common::temp_dir("fuzz-cases"));
    let n = N.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    dir.join(format!("case{n}.{ext}"))
}

/// Reads `bytes` as a file with extension `ext`: an error is fine, a panic is not, and a cloud must be valid.
fn read_must_not_panic(ext: &str, bytes: &[u8]) {
    let path = case_path(ext);
    std::fs::write(&path, bytes).unwrap();
    for opts in [LoadOptions::default(), LoadOptions { zero_points: ZeroPoints::Drop, ..LoadOptions::default() }] {
        if let Ok((cloud, _)) = read_cloud(&path, &opts) {
            cloud.validate("fuzzed").unwrap();
        }
    }
    let _ = std::fs::remove_file(path);
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn cloud_readers_survive_mutated_files(
        which in 0..6usize,
        mutations in proptest::collection::vec(mutation(), 1..6),
    ) {
        let (ext, bytes) = &seeds()[which];
        read_must_not_panic(ext, &mutate(bytes.clone(), &mutations));
    }

    #[test]
    fn g2o_reader_and_solver_survive_mutated_files(mutations in proptest::collection::vec(mutation(), 1..6)) {
        let bytes = mutate(seed_g2o().as_bytes().to_vec(), &mutations);
        if let Ok(read) = parse_g2o(std::path::Path::new("fuzz.g2o"), &bytes) {
            read.graph.validate().unwrap();
            assert_eq!(read.ids.len(), read.graph.world_from_node.len());
            for init in [Init::Chordal, Init::File] {
                if let Ok(s) = solve(&read.graph, &SolveOptions { init, ..SolveOptions::default() }) {
                    assert!(s.world_from_node.iter().all(|w| w.iter().all(|v| v.is_finite())));
                }
            }
        }
    }

    #[test]
    fn weights_reader_survives_mutated_files(mutations in proptest::collection::vec(mutation(), 1..4)) {
        let bytes = mutate(small_weights_bytes().clone(), &mutations);
        if let Ok(w) = Weights::from_bytes(&bytes, "fuzz") {
            w.config.validate().unwrap();
        }
    }
}

/// The valid pose and list texts the text readers' mutations start from: a trajectory .log, synth's poses.txt,
/// a gt.info and a scan list.
fn text_seeds() -> &'static [Vec<u8>; 4] {
    static SEEDS: OnceLock<[Vec<u8>; 4]> = OnceLock::new();
    SEEDS.get_or_init(|| {
        let poses: Vec<nalgebra::Matrix4<f64>> = (0..3).map(|k| common::known_pose(k + 1)).collect();
        let trajectory = Trajectory { world_from_scan: poses.clone() };
        let mut poses_txt = String::from("# k and 16 numbers\n");
        for (k, m) in poses.iter().enumerate() {
            let values: Vec<String> = (0..16).map(|c| format!("{:e}", m[(c / 4, c % 4)])).collect();
            poses_txt.push_str(&format!("{k} {}\n", values.join(" ")));
        }
        let info = InfoRecord { i: 0, j: 1, n: 3, information: nalgebra::Matrix6::identity() * 1000.0 };
        let list = "# scans\ncloud_bin_0.ply\n /abs/cloud_bin_1.pcd \n\nscans/cloud_bin_2.xyz\n";
        [trajectory.to_log_text().into_bytes(), poses_txt.into_bytes(), format_info(&[info]).into_bytes(), list.into()]
    })
}

/// Parses mutated `bytes` with the reader of seed `which`: an error is fine, a panic is not; a trajectory read
/// has every pose rigid, and a scan list only paths that name a file.
fn parse_text_must_not_panic(which: usize, bytes: Vec<u8>) {
    let path = std::path::Path::new("fuzzed.txt");
    let text = match list_text(path, bytes, "fuzzed text") {
        Ok(text) => text,
        Err(e) => return assert!(e.to_string().contains("fuzzed.txt"), "{e}"),
    };
    let trajectory = match which {
        0 => Trajectory::parse_log(&text, path).ok(),
        1 => Trajectory::parse_poses(&text, path).ok(),
        2 => {
            let _ = parse_info(&text, path);
            None
        }
        _ => {
            // Every path names something below the base folder, or is absolute.
            for p in parse_scan_list(&text, std::path::Path::new("base")) {
                assert!(p.is_absolute() || p.as_os_str().len() > "base/".len(), "{p:?}");
            }
            None
        }
    };
    for pose in trajectory.iter().flat_map(|t| &t.world_from_scan) {
        assert_eq!(dpr_gpu::pose::rigidity_problem(pose), None, "{pose}");
    }
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn trajectory_info_and_scan_list_readers_survive_mutated_files(
        which in 0..4usize,
        mutations in proptest::collection::vec(mutation(), 1..6),
    ) {
        parse_text_must_not_panic(which, mutate(text_seeds()[which].clone(), &mutations));
    }
}

/// Random registration settings (mostly valid, some absurd): validation refuses the bad ones with an error, and
/// the rest register a small pair without a panic, giving a finite pose and a consistent verdict.
#[test]
fn register_settings_never_panic() {
    let strategy = (
        prop_oneof![8 => 0..300usize, 1 => Just(usize::MAX), 1 => Just(1usize << 40)],
        prop_oneof![
            4 => Just(None), 4 => (0.05..2.0f32).prop_map(Some), 1 => (-1.0..0.05f32).prop_map(Some),
            1 => Just(Some(f32::NAN)), 1 => Just(Some(f32::INFINITY))
        ],
        prop_oneof![4 => Just(None), 4 => (-0.01..0.2f32).prop_map(Some), 1 => Just(Some(f32::NAN))],
        prop_oneof![4 => Just(None), 4 => (-0.1..1.0f32).prop_map(Some), 1 => Just(Some(0.0f32))],
        prop_oneof![8 => 0..5usize, 1 => 5..100usize],
        prop_oneof![8 => 0..64usize, 1 => Just(usize::MAX)],
        prop_oneof![8 => 0..500usize, 1 => Just(usize::MAX)],
        prop_oneof![8 => 0.0..1.0f64, 1 => Just(f64::NAN), 1 => Just(-1.0)],
        any::<bool>(),
        any::<u64>(),
    );
    let weights = Weights::from_bytes(small_weights_bytes(), "fuzz").unwrap();
    let registered = std::sync::atomic::AtomicUsize::new(0);
    let mut runner = proptest::test_runner::TestRunner::new(config());
    runner
        .run(&strategy, |(keypoints, radius, voxel, threshold, mutual, normal_k, iterations, ratio, ransac, seed)| {
            let mut s = RegistrationSettings {
                keypoints,
                radius,
                voxel,
                inlier_threshold: threshold,
                normal_neighbors: normal_k,
                seed,
                ..RegistrationSettings::default()
            };
            s.matching = if mutual == 0 { dpr_gpu::MatchMode::Closest } else { dpr_gpu::MatchMode::Mutual(mutual) };
            s.ransac.max_iterations = iterations;
            s.verdict.min_inlier_ratio = ratio;
            s.estimator = if ransac { dpr_gpu::Estimator::Ransac } else { dpr_gpu::Estimator::RelativeNet };
            if let Ok(registrar) = Registrar::with_weights(&s, &weights) {
                registered.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let (source, target) = small_pair();
                if let Ok(result) = registrar.register(source, target) {
                    prop_assert!(result.estimate.target_from_source.iter().all(|v| v.is_finite()));
                    prop_assert_eq!(result.success, result.reason.is_none());
                }
            }
            Ok(())
        })
        .unwrap();
    let registered = registered.into_inner();
    assert!(registered * 10 >= cases() as usize, "only {registered} of {} settings were valid", cases());
}

/// A tiny model's weights file.
fn small_weights_bytes() -> &'static Vec<u8> {
    static BYTES: OnceLock<Vec<u8>> = OnceLock::new();
    BYTES.get_or_init(|| {
        let config = ModelConfig {
            points_per_patch: 8,
            grid: [3, 3],
            encoder_widths: vec![8, 8],
            head_widths: vec![16],
            fold_widths: vec![8],
            relative_widths: vec![8],
            ..ModelConfig::default()
        };
        Weights::init(&config, 5).unwrap().to_bytes().unwrap()
    })
}

/// A small generated pair.
fn small_pair() -> &'static (PointCloud, PointCloud) {
    static PAIR: OnceLock<(PointCloud, PointCloud)> = OnceLock::new();
    PAIR.get_or_init(|| {
        let (s, t, _) = common::room_pair(2, 400);
        (s, t)
    })
}

// ------------------------------------------------------------------------- pinned regression cases

/// Inputs that once failed a reader (found while hardening), replayed as plain tests.
#[test]
fn pinned_reader_regressions() {
    let cases: &[(&str, &[u8])] = &[
        // A PLY header followed by NUL bytes and no end_header.
        ("ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n\x00\x00\x00"),
        // A CR-only XYZ file.
        ("xyz", b"1 2 3\r4 5 6\r"),
        // A vertex count that overflows the stride product.
        ("ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 18446744073709551615\nproperty double x\nproperty double y\nproperty double z\nend_header\n"),
        // PCD WIDTH x HEIGHT overflow.
        ("pcd", b"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 4294967296\nHEIGHT 4294967296\nDATA binary\n"),
        // A PCD field COUNT of 2^32 once asked for a 64 GiB token buffer.
        ("pcd", b"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 4294967296\nPOINTS 1\nDATA ascii\n1 2 3\n"),
        ("pcd", b"FIELDS x y z d\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 18446744073709551615\nPOINTS 1\nDATA binary\n"),
        // Six columns of colour.
        ("xyz", b"1 2 3 255 0 0\n"),
    ];
    for (ext, bytes) in cases {
        read_must_not_panic(ext, bytes);
    }
}

#[test]
fn g2o_seed_reads_and_solves() {
    let read = parse_g2o(std::path::Path::new("seed.g2o"), seed_g2o().as_bytes()).unwrap();
    assert_eq!((read.graph.world_from_node.len(), read.graph.edges.len()), (5, 6));
    let s = solve(&read.graph, &SolveOptions::default()).unwrap();
    assert!(s.final_error < s.given_error, "{} -> {}", s.given_error, s.final_error);
}

#[test]
fn mutate_applies_each_kind() {
    let base = b"ply 123\n".to_vec();
    assert_eq!(mutate(base.clone(), &[Mutation::Truncate(0.5)]), b"ply ");
    assert_eq!(mutate(base.clone(), &[Mutation::Number(0.0, "-1")]), b"ply -1\n");
    assert_eq!(mutate(base.clone(), &[Mutation::Remove(0.0, 4)]), b"123\n");
    assert_eq!(mutate(base, &[Mutation::Insert(1.0, vec![b'x'])]), b"ply 123\nx");
}
