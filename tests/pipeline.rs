//! Properties of the CPU reference pipeline against independent oracles: invariance and equivariance of the
//! patch features, permutation invariance of the encoders, matching against a brute-force ranking, and pose
//! recovery from correspondences with a known transform.

mod common;

use dpr_gpu::backend::{Backend, CpuBackend, best_hypothesis, hypotheses_of};
use dpr_gpu::cpu::codeword_distance::codeword_distance;
use dpr_gpu::cpu::mutual_knn::mutual_knn;
use dpr_gpu::cpu::patch_features::point_features;
use dpr_gpu::cpu::rotation_head::quaternion_rotation;
use dpr_gpu::estimate::candidates::same_pose;
use dpr_gpu::estimate::{ransac, ransac_candidates, refine};
use dpr_gpu::model::{Model, Weights};
use dpr_gpu::pose::{
    matrix_from_hypothesis, matrix_from_parts, matrix_from_quaternion, quaternion_from_matrix, rotation_error_deg,
    transform_point, translation_error,
};
use dpr_gpu::rng::Rng;
use dpr_gpu::settings::{MatchMode, PoseEstimate, RansacSettings};
use nalgebra::{Matrix4, Vector3};
use proptest::prelude::*;

/// f32 features after a rigid motion agree to this (angles near 0 or pi lose a few bits through atan2).
const FEATURE_TOLERANCE: f32 = 2e-4;

fn random_pose(rng: &mut Rng) -> Matrix4<f64> {
    let r = matrix_from_quaternion(rng.unit_quaternion());
    matrix_from_parts(&r, &Vector3::new(rng.uniform(-3.0, 3.0), rng.uniform(-3.0, 3.0), rng.uniform(-3.0, 3.0)))
}

fn rotate_vec(t: &Matrix4<f64>, v: [f32; 3]) -> [f32; 3] {
    let q = t.fixed_view::<3, 3>(0, 0) * Vector3::new(v[0] as f64, v[1] as f64, v[2] as f64);
    [q.x as f32, q.y as f32, q.z as f32]
}

fn unit(rng: &mut Rng) -> [f32; 3] {
    let v = [rng.normal(), rng.normal(), rng.normal()];
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    v.map(|c| (c / n) as f32)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    #[test]
    fn ppf_is_invariant_and_pc_equivariant_under_rigid_motion(seed in any::<u64>()) {
        let mut rng = Rng::new(seed);
        let t = random_pose(&mut rng);
        let pr = [0; 3].map(|_: i32| rng.uniform(-1.0, 1.0) as f32);
        let pi = [0; 3].map(|_: i32| rng.uniform(-1.0, 1.0) as f32);
        let (nr, ni) = (unit(&mut rng), unit(&mut rng));
        let (f, c) = point_features(pr, nr, pi, ni, 0.3);
        let (g, d) = point_features(transform_point(&t, pr), rotate_vec(&t, nr), transform_point(&t, pi), rotate_vec(&t, ni), 0.3);
        for k in 0..4 {
            prop_assert!((f[k] - g[k]).abs() < FEATURE_TOLERANCE * (1.0 + f[k].abs()), "ppf {k}: {f:?} vs {g:?}");
        }
        for angle in &f[..3] {
            prop_assert!((0.0..=1.0).contains(angle));
        }
        let rc = rotate_vec(&t, c);
        for k in 0..3 {
            prop_assert!((rc[k] - d[k]).abs() < FEATURE_TOLERANCE * (1.0 + rc[k].abs()), "pc: {rc:?} vs {d:?}");
        }
    }
}

#[test]
fn ppf_of_degenerate_geometry_is_finite() {
    let (f, c) = point_features([1.0, 2.0, 3.0], [0.0; 3], [1.0, 2.0, 3.0], [0.0, 0.0, 1.0], 0.3);
    assert!(f.iter().chain(c.iter()).all(|v| v.is_finite()));
    assert_eq!(f, [0.0, 0.0, 0.0, 0.0]);
    let (f, _) = point_features([0.0; 3], [0.0, 0.0, 1.0], [0.1, 0.0, 0.0], [0.0, 0.0, 1.0], 0.3);
    assert!((f[0] - 0.5).abs() < 1e-6 && (f[1] - 0.5).abs() < 1e-6 && f[2] == 0.0);
}

#[test]
fn encoders_are_invariant_to_the_order_of_patch_points() {
    let config = common::tiny_config();
    let model = Model::from_weights(&Weights::init(&config, 3).unwrap()).unwrap();
    let mut rng = Rng::new(8);
    let (patches, n) = (5, config.points_per_patch);
    let input: Vec<f32> = (0..patches * n * 4).map(|_| rng.uniform(0.0, 1.0) as f32).collect();
    let mut shuffled = input.clone();
    for p in 0..patches {
        let order = rng.sample_without_replacement(n, n);
        for (dst, &src) in order.iter().enumerate() {
            shuffled[(p * n + dst) * 4..][..4].copy_from_slice(&input[(p * n + src) * 4..][..4]);
        }
    }
    let a = model.ppf.encode(&input, patches, n);
    let b = model.ppf.encode(&shuffled, patches, n);
    assert_eq!(a.len(), patches * config.codeword());
    for (x, y) in a.iter().zip(&b) {
        assert!((x - y).abs() <= 1e-5 * (1.0 + x.abs()), "{x} vs {y}");
    }
    // Patches are encoded independently: one patch alone gives the same codeword.
    let single = model.ppf.encode(&input[..n * 4], 1, n);
    for (x, y) in single.iter().zip(&a[..config.codeword()]) {
        assert!((x - y).abs() <= 1e-5 * (1.0 + x.abs()));
    }
}

/// Brute-force oracle: rank of each entry in its row and column (ties by index), mutual when both < K.
fn brute_force_matches(d: &[f32], ns: usize, nt: usize, mode: MatchMode) -> Vec<(u32, u32)> {
    let row_rank = |i: usize, j: usize| {
        (0..nt).filter(|&k| d[i * nt + k] < d[i * nt + j] || (d[i * nt + k] == d[i * nt + j] && k < j)).count()
    };
    let col_rank = |i: usize, j: usize| {
        (0..ns).filter(|&k| d[k * nt + j] < d[i * nt + j] || (d[k * nt + j] == d[i * nt + j] && k < i)).count()
    };
    let mut out = Vec::new();
    for i in 0..ns {
        for j in 0..nt {
            let keep = match mode {
                MatchMode::Closest => row_rank(i, j) == 0,
                MatchMode::Mutual(k) => row_rank(i, j) < k && col_rank(i, j) < k,
            };
            if keep {
                out.push((i as u32, j as u32));
            }
        }
    }
    out
}

#[test]
fn matching_agrees_with_brute_force_ranking() {
    let mut rng = Rng::new(21);
    for &(ns, nt, dim, quantised) in &[(40, 37, 5, false), (25, 30, 3, true), (1, 6, 2, false), (9, 1, 4, true)] {
        // Quantised codewords create many exact distance ties.
        let mut make = |n: usize| -> Vec<f32> {
            (0..n * dim).map(|_| if quantised { rng.below(3) as f32 } else { rng.normal() as f32 }).collect()
        };
        let (s, t) = (make(ns), make(nt));
        let d = codeword_distance(&s, &t, dim);
        for mode in [MatchMode::Mutual(1), MatchMode::Mutual(2), MatchMode::Mutual(4), MatchMode::Closest] {
            let got: Vec<(u32, u32)> = mutual_knn(&d, ns, nt, mode).iter().map(|m| (m.source, m.target)).collect();
            assert_eq!(got, brute_force_matches(&d, ns, nt, mode), "{ns}x{nt} {mode:?}");
        }
    }
}

struct Problem {
    truth: Matrix4<f64>,
    source: Vec<[f32; 3]>,
    target: Vec<[f32; 3]>,
    quaternions: Vec<[f32; 4]>,
}

/// `n` correspondences, a fraction `inlier_ratio` consistent with a known pose (with 1 cm noise) and carrying
/// its rotation; the rest random points with random rotations.
fn problem(seed: u64, n: usize, inlier_ratio: f64) -> Problem {
    let mut rng = Rng::new(seed);
    let truth = random_pose(&mut rng);
    let q = quaternion_from_matrix(&truth.fixed_view::<3, 3>(0, 0).into_owned()).map(|v| v as f32);
    let inliers = (n as f64 * inlier_ratio).round() as usize;
    let mut p = Problem { truth, source: vec![], target: vec![], quaternions: vec![] };
    for i in 0..n {
        let s = [0; 3].map(|_: i32| rng.uniform(-2.0, 2.0) as f32);
        if i < inliers {
            let t = transform_point(&truth, s);
            p.target.push(t.map(|c| c + (rng.normal() * 0.01) as f32));
            p.quaternions.push(q);
        } else {
            p.target.push([0; 3].map(|_: i32| rng.uniform(-5.0, 5.0) as f32));
            p.quaternions.push(rng.unit_quaternion().map(|v| v as f32));
        }
        p.source.push(s);
    }
    p
}

/// RelativeNet's hypothesize-and-verify on host inputs: one hypothesis per correspondence (its rotation, t =
/// p_target - R p_source), all scored on `backend`, the best ([`best_hypothesis`]) refined on its inliers.
fn verify(
    backend: &dyn Backend,
    rotations: &[[f32; 9]],
    source: &[[f32; 3]],
    target: &[[f32; 3]],
    threshold: f32,
) -> dpr_gpu::Result<PoseEstimate> {
    let hypotheses = dpr_gpu::block_on(hypotheses_of(backend, rotations, source, target, 1))?;
    let scores = dpr_gpu::block_on(backend.score_hypotheses(&hypotheses, source, target, threshold))?;
    let best = best_hypothesis(&scores).expect("hypotheses to verify");
    Ok(refine(matrix_from_hypothesis(&hypotheses[best]), source, target, threshold, hypotheses.len()))
}

#[test]
fn verifier_and_ransac_recover_a_known_transform_with_80_percent_outliers() {
    let model = Model::from_weights(&Weights::init(&common::tiny_config(), 0).unwrap()).unwrap();
    let backend = CpuBackend::new(model);
    for seed in 0..5 {
        let p = problem(seed, 200, 0.2);
        let rotations: Vec<[f32; 9]> = p.quaternions.iter().map(|&q| quaternion_rotation(q)).collect();
        let est = verify(&backend, &rotations, &p.source, &p.target, 0.05).unwrap();
        assert!(rotation_error_deg(&est.target_from_source, &p.truth) < 1.0, "seed {seed}");
        assert!(translation_error(&est.target_from_source, &p.truth) < 0.02, "seed {seed}");
        assert!(est.inliers >= 38 && est.inliers <= 45, "inliers {}", est.inliers);
        assert_eq!(est.hypotheses_scored, 200);

        let est = ransac(&p.source, &p.target, 0.05, &RansacSettings::default(), seed).unwrap();
        assert!(rotation_error_deg(&est.target_from_source, &p.truth) < 1.0, "ransac seed {seed}");
        assert!(translation_error(&est.target_from_source, &p.truth) < 0.02, "ransac seed {seed}");
        // Early exit: at 20 % inliers ~860 samples reach 0.999 confidence, far below the limit.
        assert!(est.hypotheses_scored < 5_000, "{}", est.hypotheses_scored);
    }
}

#[test]
fn ransac_is_deterministic_per_seed() {
    let p = problem(3, 100, 0.3);
    let a = ransac(&p.source, &p.target, 0.05, &RansacSettings::default(), 9).unwrap();
    let b = ransac(&p.source, &p.target, 0.05, &RansacSettings::default(), 9).unwrap();
    assert_eq!(a.target_from_source, b.target_from_source);
    assert_eq!(a.hypotheses_scored, b.hypotheses_scored);
    assert!(ransac(&p.source[..2], &p.target[..2], 0.05, &RansacSettings::default(), 9).is_err());
}

#[test]
fn ransac_candidates_keep_distinct_poses_and_the_first_is_ransacs() {
    // 30 % of the correspondences follow the true pose, 25 % a second pose (a repeated structure), the rest noise.
    let mut p = problem(5, 200, 0.3);
    let mut rng = Rng::new(55);
    let second = random_pose(&mut rng);
    for i in 60..110 {
        p.target[i] = transform_point(&second, p.source[i]);
    }
    let settings = RansacSettings::default();
    let (one, iterations_one) = ransac_candidates(&p.source, &p.target, 0.05, &settings, 4, 1).unwrap();
    let (many, iterations_many) = ransac_candidates(&p.source, &p.target, 0.05, &settings, 4, 8).unwrap();
    assert_eq!(one.len(), 1);
    assert_eq!(iterations_one, iterations_many, "keeping more poses changes neither the samples nor the exit");
    assert_eq!(many[0].target_from_source, one[0].target_from_source);
    assert!(rotation_error_deg(&many[0].target_from_source, &p.truth) < 2.0);
    assert!(many.iter().any(|c| rotation_error_deg(&c.target_from_source, &second) < 2.0), "the second pose is kept");
    for (a, b) in many.iter().enumerate().flat_map(|(i, a)| many[i + 1..].iter().map(move |b| (a, b))) {
        assert!(!same_pose(&a.target_from_source, &b.target_from_source, 0.05), "two kept poses are one");
    }
    assert!(many.windows(2).all(|w| w[0].inliers >= w[1].inliers), "best first");
    let refined = ransac(&p.source, &p.target, 0.05, &settings, 4).unwrap();
    let first = refine(one[0].target_from_source, &p.source, &p.target, 0.05, iterations_one);
    assert_eq!(refined.target_from_source, first.target_from_source);
}

#[test]
fn a_moved_scan_described_from_its_moved_sensor_gets_the_moved_normals() {
    // Estimated normals face the sensor. Moving a scan without its sensor (as a rotation about the centroid does)
    // flips some of them; `describe_from` with the moved viewpoint must give exactly the moved normals.
    let cloud = common::room_corner(3, 3000);
    let settings = dpr_gpu::RegistrationSettings {
        keypoints: 50,
        voxel: Some(0.0),
        viewpoint: [1.5, 1.5, 1.0],
        ..Default::default()
    };
    let weights = Weights::init(&common::tiny_config(), 0).unwrap();
    let registrar = dpr_gpu::Registrar::with_weights(&settings, &weights).unwrap();
    let original = registrar.describe(&cloud, 0).unwrap();
    let m = dpr_gpu::pose::matrix_from_parts(
        &nalgebra::Rotation3::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI).into_inner(),
        &Vector3::new(0.5, 3.0, 2.0),
    );
    let moved = cloud.transformed(&m);
    let rotate = |n: [f32; 3]| {
        transform_point(&m, n).iter().zip(transform_point(&m, [0.0; 3])).map(|(a, b)| a - b).collect::<Vec<f32>>()
    };
    // Among normals whose direction is well defined on both sides (|cos| > 0.9; PCA at edges is ill-conditioned
    // and may turn in f32), the share that point the other way.
    let flipped = |f: &dpr_gpu::pipeline::ScanFeatures| {
        let (a, b) = (original.cloud.normals.as_ref().unwrap(), f.cloud.normals.as_ref().unwrap());
        let cos: Vec<f32> =
            a.iter().zip(b).map(|(n, g)| rotate(*n).iter().zip(g.iter()).map(|(x, y)| x * y).sum::<f32>()).collect();
        let defined = cos.iter().filter(|c| c.abs() > 0.9).count();
        cos.iter().filter(|&&c| c < -0.9).count() as f64 / defined.max(1) as f64
    };
    let with_sensor = registrar.describe_from(&moved, 0, transform_point(&m, settings.viewpoint)).unwrap();
    assert!(flipped(&with_sensor) < 0.002, "{}", flipped(&with_sensor));
    // Control: the sensor left behind at the old viewpoint flips a good share of the normals.
    let left_behind = registrar.describe(&moved, 0).unwrap();
    assert!(flipped(&left_behind) > 0.05, "{}", flipped(&left_behind));
}

/// The bf16 encoders (the default where the CPU has AVX-512 BF16 and AMX or no VNNI, see `Precision::choose`)
/// against the f32 ones on the shipped example pair with the shipped weights: codewords within the rounding the
/// encoders' four bf16 layers can add (each rounds both factors of every product to 8 significant bits, a
/// relative 2 x 2^-8 at most, so 4 x 2 x 2^-8 ~ 0.031 without cancellation), nearly the same correspondences,
/// and after ICP the same pose.
#[test]
fn bf16_encoders_register_the_example_pair_like_f32() {
    if !dpr_gpu::cpu::gemm::Precision::Bf16.is_available() {
        eprintln!("SKIPPED: this CPU has no AVX-512 BF16, so the bf16 encoders are never used here");
        return;
    }
    reduced_precision_registers_the_example_pair_like_f32(dpr_gpu::cpu::gemm::Precision::Bf16, 4.0 * 2.0 / 256.0);
}

/// The int8 encoders (the default for both where the CPU has AVX-512 VNNI and no BF16, for PC-FoldNet where it
/// has both and no AMX) likewise: each of the four int8
/// layers rounds every input to half a step of its row's largest value (1/255 of it, or 1/127 for a row with
/// negative values) and every weight to half a step of its column's (1/127), so about 4 x (1/255 + 1/127) ~
/// 0.047 relative to the codeword without cancellation.
#[test]
fn int8_encoders_register_the_example_pair_like_f32() {
    if !dpr_gpu::cpu::gemm::Precision::Int8.is_available() {
        eprintln!("SKIPPED: this CPU has no AVX-512 VNNI, so the int8 encoders are never used here");
        return;
    }
    reduced_precision_registers_the_example_pair_like_f32(
        dpr_gpu::cpu::gemm::Precision::Int8,
        4.0 * (1.0 / 255.0 + 1.0 / 127.0),
    );
}

/// The default where the CPU has AVX-512 BF16 and VNNI and no AMX: each encoder at its own precision,
/// PPF-FoldNet in bf16 and PC-FoldNet in int8. Oracle: the backends with one precision for both, whose codewords
/// each encoder must reproduce bit for bit (and which differ from each other, so the check can fail).
#[test]
fn each_encoder_runs_at_its_own_precision() {
    use dpr_gpu::cpu::gemm::{EncoderPrecision, Precision};
    use dpr_gpu::model::Net;
    if !(Precision::Bf16.is_available() && Precision::Int8.is_available()) {
        eprintln!("SKIPPED: this CPU lacks AVX-512 BF16 or VNNI, so no encoder precision per network runs here");
        return;
    }
    let model = Model::from_weights(&Weights::built_in().unwrap()).unwrap();
    let backend = |p: EncoderPrecision| CpuBackend::with_precision(model.clone(), p).unwrap();
    let mixed = backend(EncoderPrecision { ppf: Precision::Bf16, pc: Precision::Int8 });
    let (bf16, int8) = (backend(Precision::Bf16.into()), backend(Precision::Int8.into()));
    let (patches, points) = (5, model.config.points_per_patch);
    let mut rng = Rng::new(17);
    for net in [Net::Ppf, Net::Pc] {
        let input: Vec<f32> = (0..patches * points * net.io_width()).map(|_| rng.normal() as f32 * 0.3).collect();
        let encode = |b: &CpuBackend| dpr_gpu::block_on(b.encode(net, &input, patches)).unwrap();
        let (got, want_bf16, want_int8) = (encode(&mixed), encode(&bf16), encode(&int8));
        assert_ne!(want_bf16, want_int8, "{net:?}: bf16 and int8 codewords must differ for the check to mean anything");
        let want = if net == Net::Ppf { want_bf16 } else { want_int8 };
        assert_eq!(got, want, "{net:?}");
    }
    assert_eq!(mixed.name(), format!("cpu ({} threads, bf16,int8)", rayon::current_num_threads()));
}

fn reduced_precision_registers_the_example_pair_like_f32(
    precision: dpr_gpu::cpu::gemm::Precision,
    codeword_relative_tol: f64,
) {
    const ROTATION_DEG_TOL: f64 = 0.25;
    const TRANSLATION_TOL: f64 = 0.01;
    let weights = Weights::built_in().unwrap();
    let model = Model::from_weights(&weights).unwrap();
    let pair = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/pair");
    let load = |name: &str| dpr_gpu::io::read_cloud(&pair.join(name), &Default::default()).unwrap().0;
    let (source, target) = (load("cloud_bin_1.ply"), load("cloud_bin_0.ply"));
    let settings = dpr_gpu::RegistrationSettings { keypoints: 500, first_keypoints: None, ..Default::default() };
    let f32_reg = dpr_gpu::Registrar::with_backend(&settings, Box::new(CpuBackend::new(model.clone()))).unwrap();
    let reduced_backend = CpuBackend::with_precision(model, precision).unwrap();
    let reduced_reg = dpr_gpu::Registrar::with_backend(&settings, Box::new(reduced_backend)).unwrap();

    let (a, b) = (f32_reg.describe(&source, 0).unwrap(), reduced_reg.describe(&source, 0).unwrap());
    assert_eq!(a.keypoints, b.keypoints, "the same keypoints and patches");
    let (ca, cb) = (a.read_codewords().unwrap(), b.read_codewords().unwrap());
    let dim = ca.len() / a.keypoints.len();
    let mut worst = 0.0f64;
    for (ra, rb) in ca.chunks(dim).zip(cb.chunks(dim)) {
        let norm = ra.iter().map(|&v| f64::from(v).powi(2)).sum::<f64>().sqrt();
        let diff = ra.iter().zip(rb).map(|(&x, &y)| f64::from(x - y).powi(2)).sum::<f64>().sqrt();
        worst = worst.max(diff / norm.max(1e-12));
    }
    assert!(worst <= codeword_relative_tol, "codewords differ by {worst} (relative)");
    assert!(worst > 0.0, "the rounding must show: the {precision:?} layers did not run");

    let (ta, tb) = (f32_reg.describe(&target, 1).unwrap(), reduced_reg.describe(&target, 1).unwrap());
    let pairs = |reg: &dpr_gpu::Registrar, s, t| -> std::collections::HashSet<(u32, u32)> {
        reg.correspond(s, t).unwrap().iter().map(|c| (c.source_index, c.target_index)).collect()
    };
    let (pa, pb) = (pairs(&f32_reg, &a, &ta), pairs(&reduced_reg, &b, &tb));
    // A mutual nearest neighbour flips where its runner-up is within the perturbation (here about 1 in 9).
    let shared = pa.intersection(&pb).count();
    assert!(shared * 4 >= 3 * pa.len().max(pb.len()), "{shared} shared of {} / {}", pa.len(), pb.len());

    let (ra, rb) = (f32_reg.register(&source, &target).unwrap(), reduced_reg.register(&source, &target).unwrap());
    let (ea, eb) = (&ra.estimate, &rb.estimate);
    let angle = rotation_error_deg(&ea.target_from_source, &eb.target_from_source);
    let shift = translation_error(&ea.target_from_source, &eb.target_from_source);
    assert!(angle < ROTATION_DEG_TOL && shift < TRANSLATION_TOL, "poses differ by {angle} deg, {shift}");
    assert!(
        ra.success && rb.success,
        "both registrations are trusted: {} {} ({} / {} inliers)",
        ra.success,
        rb.success,
        ea.inliers,
        eb.inliers
    );
}

#[test]
fn the_default_voxel_follows_the_radius_for_clouds_without_normals() {
    use dpr_gpu::settings::VOXEL_PER_RADIUS;
    let weights = Weights::init(&common::tiny_config(), 0).unwrap();
    let registrar = |voxel, radius| {
        let settings = dpr_gpu::RegistrationSettings { voxel, radius, keypoints: 50, ..Default::default() };
        dpr_gpu::Registrar::with_weights(&settings, &weights).unwrap()
    };
    // By default: a fixed share of the radius in use where normals must be estimated, every point where the file
    // has them.
    assert_eq!(registrar(None, Some(0.6)).voxel(false), Some(0.6 * VOXEL_PER_RADIUS));
    assert_eq!(registrar(None, Some(0.6)).voxel(true), None);
    // The default radius is a multiple of the weights' training radius, and the default voxel follows it.
    let radius = common::tiny_config().radius * dpr_gpu::settings::RADIUS_PER_TRAINING_RADIUS;
    assert_eq!(registrar(None, None).radius(), radius);
    assert_eq!(registrar(None, None).voxel(false), Some(radius * VOXEL_PER_RADIUS));
    // Set: 0 keeps every point, any other size is used as given.
    assert_eq!(registrar(Some(0.0), None).voxel(false), None);
    assert_eq!(registrar(Some(0.04), None).voxel(true), Some(0.04));
    let invalid = dpr_gpu::RegistrationSettings { voxel: Some(-0.1), ..Default::default() };
    assert!(invalid.validate().unwrap_err().to_string().contains("voxel"));

    // A described cloud without normals is the voxel grid's downsampling of it.
    let cloud = common::room_corner(5, 4000);
    let voxel = 0.6 * VOXEL_PER_RADIUS;
    let described = registrar(None, Some(0.6)).describe(&cloud, 0).unwrap();
    let expected = dpr_gpu::preprocess::voxel_downsample(&cloud, voxel).unwrap();
    assert!(expected.len() < cloud.len(), "the voxel must thin the cloud");
    assert_eq!(described.cloud.points, expected.points);
    // With normals the cloud is described as it is.
    let normals = vec![[0.0, 0.0, 1.0]; cloud.len()];
    let with_normals = dpr_gpu::PointCloud { points: cloud.points.clone(), normals: Some(normals) };
    let described = registrar(None, Some(0.6)).describe(&with_normals, 0).unwrap();
    assert_eq!(described.cloud.len(), cloud.len());
    // Normals that are all zero are estimated like missing ones, so the cloud is downsampled like one without.
    let zero = dpr_gpu::PointCloud { points: cloud.points.clone(), normals: Some(vec![[0.0; 3]; cloud.len()]) };
    let described = registrar(None, Some(0.6)).describe(&zero, 0).unwrap();
    assert_eq!(described.cloud.points, expected.points);
}

/// Context radii (`RegistrationSettings::context_radii`): each kept keypoint is described again at each larger
/// radius, with exactly the codewords a registrar at that radius gives it, and correspondences are the mutual
/// nearest neighbours of the unit codewords of every radius, weighted and side by side. The oracle describes
/// the scans at each radius separately and matches by brute force in f64; a match may differ from it only
/// where two candidates lie within f32 rounding of each other.
#[test]
fn context_radii_match_on_weighted_unit_codewords_of_every_radius() {
    use dpr_gpu::settings::ContextRadius;
    let weights = Weights::init(&common::tiny_config(), 3).unwrap();
    let (source, target, _) = common::room_pair(11, 3000);
    let base = dpr_gpu::RegistrationSettings {
        keypoints: 120,
        first_keypoints: None,
        voxel: Some(0.0),
        radius: Some(0.3),
        context_radii: Vec::new(),
        ..Default::default()
    };
    let context = vec![ContextRadius { factor: 2.0, weight: 0.7 }, ContextRadius { factor: 3.5, weight: 1.3 }];
    let with_context = dpr_gpu::RegistrationSettings { context_radii: context.clone(), ..base.clone() };
    let registrar = dpr_gpu::Registrar::with_weights(&with_context, &weights).unwrap();
    let (s, t) = (registrar.describe(&source, 0).unwrap(), registrar.describe(&target, 1).unwrap());
    assert_eq!(s.context.len(), 2);

    // Rows of unit codewords times their weight, per radius, from registrars at each radius alone.
    let mut blocks = Vec::new();
    for (factor, weight) in std::iter::once((1.0, 1.0)).chain(context.iter().map(|c| (c.factor, c.weight))) {
        let alone = dpr_gpu::RegistrationSettings { radius: Some(0.3 * factor), ..base.clone() };
        let r = dpr_gpu::Registrar::with_weights(&alone, &weights).unwrap();
        let mut per_scan = Vec::new();
        for (cloud, stream, described) in [(&source, 0, &s), (&target, 1, &t)] {
            let f = r.describe(cloud, stream).unwrap();
            let codewords = f.read_codewords().unwrap();
            let dim = codewords.len() / f.keypoints.len();
            // The same keypoints (by rank) as the registrar with context radii keeps.
            let rows: Vec<Vec<f64>> = described
                .keypoint_ranks
                .iter()
                .map(|rank| {
                    let row = f.keypoint_ranks.binary_search(rank).expect("a larger patch keeps the keypoint");
                    let c = &codewords[row * dim..(row + 1) * dim];
                    let norm = c.iter().map(|&x| f64::from(x).powi(2)).sum::<f64>().sqrt();
                    c.iter().map(|&x| f64::from(x) / norm * f64::from(weight)).collect()
                })
                .collect();
            if factor > 1.0 {
                let k = context.iter().position(|c| c.factor == factor).unwrap();
                let own = dpr_gpu::block_on(described.context[k].rows.read_codewords()).unwrap();
                let picked: Vec<f32> = described
                    .keypoint_ranks
                    .iter()
                    .flat_map(|rank| {
                        let row = f.keypoint_ranks.binary_search(rank).unwrap();
                        codewords[row * dim..(row + 1) * dim].to_vec()
                    })
                    .collect();
                assert_eq!(own, picked, "context rows at {factor}x are that radius's codewords");
            }
            per_scan.push(rows);
        }
        blocks.push(per_scan);
    }
    let distance = |a: usize, b: usize| -> f64 {
        blocks.iter().map(|scan| scan[0][a].iter().zip(&scan[1][b]).map(|(x, y)| (x - y).powi(2)).sum::<f64>()).sum()
    };
    let (ns, nt) = (s.keypoints.len(), t.keypoints.len());
    let nearest_target = |a: usize| (0..nt).map(|b| distance(a, b)).fold(f64::INFINITY, f64::min);
    let nearest_source = |b: usize| (0..ns).map(|a| distance(a, b)).fold(f64::INFINITY, f64::min);
    let oracle: Vec<(usize, usize)> = (0..ns)
        .filter_map(|a| {
            let b = (0..nt).min_by(|&x, &y| distance(a, x).total_cmp(&distance(a, y)))?;
            let back = (0..ns).min_by(|&x, &y| distance(x, b).total_cmp(&distance(y, b)))?;
            (back == a).then_some((a, b))
        })
        .collect();
    let got = registrar.correspond(&s, &t).unwrap();
    let near = |d: f64, best: f64| d <= best * (1.0 + 1e-5) + 1e-9;
    for c in &got {
        let (a, b) = (c.source_index as usize, c.target_index as usize);
        let d = distance(a, b);
        assert!(near(d, nearest_target(a)) && near(d, nearest_source(b)), "({a}, {b}) is not mutual nearest");
    }
    assert!(got.len().abs_diff(oracle.len()) <= 2, "{} correspondences, the oracle {}", got.len(), oracle.len());
    assert!(oracle.len() >= 10, "the pair gives correspondences ({})", oracle.len());
    // Without context radii the matches differ (the blocks matter).
    let plain = dpr_gpu::Registrar::with_weights(&base, &weights).unwrap();
    let (ps, pt) = (plain.describe(&source, 0).unwrap(), plain.describe(&target, 1).unwrap());
    let pairs = |c: &[dpr_gpu::Correspondence]| c.iter().map(|c| (c.source_index, c.target_index)).collect::<Vec<_>>();
    assert_ne!(pairs(&plain.correspond(&ps, &pt).unwrap()), pairs(&got));
    // A scan described without context radii does not match one described with them.
    assert!(registrar.correspond(&s, &pt).is_err());
    // Factors below 1 or past the bound, and non-positive weights, are refused.
    for bad in [
        ContextRadius { factor: 0.5, weight: 1.0 },
        ContextRadius { factor: 9.0, weight: 1.0 },
        ContextRadius { factor: 2.0, weight: 0.0 },
    ] {
        let settings = dpr_gpu::RegistrationSettings { context_radii: vec![bad], ..base.clone() };
        assert!(dpr_gpu::Registrar::with_weights(&settings, &weights).is_err(), "{bad:?}");
    }
}
