//! Point-to-plane ICP on the device: the `icp_normal_equations` kernel against its CPU twin (bit for bit),
//! and the GPU backend's ICP against the host's on a generated scene. Part of the `gpu_parity` binary (its
//! `main` runs [`TESTS`] too).

use super::{ROOM_VIEWPOINT, backends, seed};
use dpr_gpu::cpu::grid_knn::{CellGrid, distance_squared};
use dpr_gpu::cpu::icp_normal_equations::{IcpTarget, icp_normal_equations, nearest_within, pose_rows};
use dpr_gpu::estimate::icp::{IcpProblem, MAX_ICP_POINTS};
use dpr_gpu::gpu;
use dpr_gpu::gpu::testing::gpu_or_skip as gpu;
use dpr_gpu::pose::{matrix_from_parts, rotation_error_deg, translation_error};
use dpr_gpu::rng::Rng;
use nalgebra::{Matrix4, Rotation3, Vector3};

fn unit(rng: &mut Rng) -> [f32; 3] {
    let v = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
    [v.x as f32, v.y as f32, v.z as f32]
}

fn uniform(rng: &mut Rng, n: usize, lo: f64, hi: f64) -> Vec<[f32; 3]> {
    (0..n).map(|_| [0; 3].map(|_: i32| rng.uniform(lo, hi) as f32)).collect()
}

/// A small rigid motion: rotation vector `omega` (rad), translation `t`.
fn motion(omega: [f64; 3], t: [f64; 3]) -> Matrix4<f64> {
    matrix_from_parts(&Rotation3::new(Vector3::from(omega)).into_inner(), &Vector3::from(t))
}

/// The kernel and its twin run the same f32 operations in the same order (products fenced against FMA
/// contraction, the same reduction tree, the same pair choice by (d2, index)), so both stages must match bit
/// for bit: every workgroup partial and the total, over random clouds with points that have no neighbour
/// within the distance (some in an empty block of cells inside the grid, some outside it), exact ties (a
/// dyadic lattice with sources at midpoints, identity pose), more than 64 partials (stage 1 lanes sum several)
/// and a stride.
fn icp_normal_equations_matches_cpu() {
    let Some(g) = gpu() else { return };
    let s = seed(131);
    let mut rng = Rng::new(s);
    let max_distance = 0.2f32;
    // Random points, a lattice of spacing 0.25, and a far cluster: the box between them is empty cells.
    let mut target = uniform(&mut rng, 3000, -1.0, 1.0);
    target.extend((0..64).map(|i| [(i % 4) as f32 * 0.25, ((i / 4) % 4) as f32 * 0.25, 2.0 + (i / 16) as f32 * 0.25]));
    target.extend(uniform(&mut rng, 200, 6.0, 6.5));
    let normals: Vec<[f32; 3]> = (0..target.len()).map(|_| unit(&mut rng)).collect();
    let cell = gpu::icp::icp_cell(max_distance, max_distance / 2.0, 30);
    let grid = CellGrid::new(&target, 1.0 / cell).unwrap();
    let mut source = uniform(&mut rng, 5000, -1.2, 1.2);
    // Lattice midpoints along x: two target points at exactly the same distance (dyadic coordinates).
    source.extend((0..27).map(|i| [(i % 3) as f32 * 0.25 + 0.125, ((i / 3) % 3) as f32 * 0.25, 2.25]));
    let hole = uniform(&mut rng, 100, 3.5, 4.5);
    source.extend(&hole);
    source.extend(uniform(&mut rng, 30, 20.0, 30.0));
    let nearest_target = |p: &[f32; 3]| target.iter().map(|q| distance_squared(q, p)).fold(f32::INFINITY, f32::min);
    assert!(hole.iter().all(|p| nearest_target(p).sqrt() > 2.0 * cell), "the hole's cell blocks are empty");
    let t = IcpTarget { grid: &grid, normals: &normals };
    let cases = [
        (Matrix4::identity(), 1),
        (motion([0.03, -0.02, 0.01], [0.02, -0.01, 0.03]), 1),
        (motion([-0.01, 0.04, 0.02], [0.0, 0.05, -0.02]), 7),
    ];
    for (pose, stride) in cases {
        let rows = pose_rows(&pose);
        let want = icp_normal_equations(&source, stride, &t, &rows, max_distance).unwrap();
        let got =
            dpr_gpu::block_on(gpu::icp_normal_equations::run(&g, &source, stride, &t, &rows, max_distance)).unwrap();
        assert_eq!(got.partials.len(), want.partials.len(), "stride {stride} (seed {s})");
        for (w, (a, b)) in got.partials.iter().zip(&want.partials).enumerate() {
            assert_eq!(a.map(f32::to_bits), b.map(f32::to_bits), "partial {w}, stride {stride} (seed {s})");
        }
        assert_eq!(got.total.map(f32::to_bits), want.total.map(f32::to_bits), "total, stride {stride} (seed {s})");
        let used = source.len().div_ceil(stride);
        let paired = want.total[27] as usize;
        assert!(paired > 100 && paired < used, "{paired} of {used} sources paired (seed {s})");
        if stride == 1 {
            assert!(want.partials.len() > 64, "stage 1 lanes sum several partials");
        }
    }
    // The midpoints tie (identity pose: they stay put): each is equidistant from two lattice points, and the
    // twin, hence the kernel, takes the lower index.
    let max_d2 = max_distance * max_distance;
    let ties = source[5000..5027]
        .iter()
        .filter(|m| {
            let Some((d2, j)) = nearest_within(&grid, m, max_d2).unwrap() else { return false };
            let equal: Vec<usize> = (0..target.len()).filter(|&i| distance_squared(&target[i], m) == d2).collect();
            equal.len() > 1 && equal[0] == j as usize
        })
        .count();
    assert!(ties > 0, "no midpoint has a tie (seed {s})");
    // Empty source: zeros on both sides; mismatched inputs: errors.
    let empty = dpr_gpu::block_on(gpu::icp_normal_equations::run(
        &g,
        &[],
        1,
        &t,
        &pose_rows(&Matrix4::identity()),
        max_distance,
    ))
    .unwrap();
    assert_eq!(empty.total, [0.0; 28]);
    assert!(empty.partials.is_empty());
    let bad = IcpTarget { grid: &grid, normals: &normals[1..] };
    assert!(
        dpr_gpu::block_on(gpu::icp_normal_equations::run(&g, &source, 1, &bad, &pose_rows(&Matrix4::identity()), 0.1))
            .is_err()
    );
    assert!(
        dpr_gpu::block_on(gpu::icp_normal_equations::run(&g, &source, 1, &t, &pose_rows(&Matrix4::identity()), 1.0))
            .is_err()
    );
}

/// The GPU backend's ICP (device target, f32 sums in a fixed order) against the host's (kiddo, nalgebra
/// normals, f64 sums) on a generated room pair, from the known pose perturbed by 2 degrees and 4 cm.
///
/// Both minimise the same point-to-plane objective over the same pairs up to rounding: the target's voxel
/// averages agree within f32 rounding, its normals within the f32 Jacobi vs f64 eigen-solver difference
/// (~1e-6 where well conditioned), the sums differ by ~1e-6 relative (f32 vs f64), and a moved point rounded
/// differently can flip its pair at a Voronoi or distance boundary. Each flipped pair moves the optimum by at
/// most ~ distance / pairs (a residual below the distance among thousands of pairs): 0.1 / 3000 ~ 3e-5 in
/// translation, and that over the scene's ~1.5 m lever in rotation (~1e-3 degrees). The tolerances allow
/// about ten such flips plus the convergence threshold: 5e-4 in translation and 1e-2 degrees. Both must
/// also land near the truth (independent samples: within 1 cm and 0.5 degrees).
///
/// The device ICP must also be deterministic and independent of where the points come from: the same points
/// held on the device or uploaded give the same bits.
/// Per call it reads back two tables' grid words (72 bytes) and 112 bytes per iteration, nothing per point.
fn device_icp_converges_like_the_host() {
    let Some(g) = gpu() else { return };
    let s = seed(132);
    let (gpu_b, cpu_b) = backends(std::sync::Arc::clone(&g), s);
    let settings = dpr_gpu::RegistrationSettings {
        keypoints: 16,
        first_keypoints: None,
        viewpoint: ROOM_VIEWPOINT,
        seed: s,
        ..Default::default()
    };
    let (source, target, truth) = super::common::room_pair(s, 12_000);
    let on_gpu = dpr_gpu::Registrar::with_backend(&settings, Box::new(gpu_b)).unwrap();
    let on_cpu = dpr_gpu::Registrar::with_backend(&settings, Box::new(cpu_b)).unwrap();
    let (gs, gt) = (on_gpu.describe(&source, 0).unwrap(), on_gpu.describe(&target, 1).unwrap());
    let (cs, ct) = (on_cpu.describe(&source, 0).unwrap(), on_cpu.describe(&target, 1).unwrap());
    assert!(gs.held_points.is_some() && cs.held_points.is_none());
    assert!(source.len() < MAX_ICP_POINTS, "every source point is used");
    let problem = IcpProblem { max_distance: 0.1, max_iterations: 30, normal_neighbors: settings.normal_neighbors };
    let initial = motion([0.02, -0.02, 0.015], [0.02, -0.03, 0.015]) * truth;
    let before = g.context.transfers();
    let device = dpr_gpu::block_on(on_gpu.backend().refine_icp(&gs, &gt, initial, &problem)).unwrap();
    let moved = g.context.transfers().since(before);
    let host = dpr_gpu::block_on(on_cpu.backend().refine_icp(&cs, &ct, initial, &problem)).unwrap();
    // The same points uploaded: the device-described scans without their held points (their clouds are the
    // held points read back). Host-described scans differ in the last bits of their voxel averages and normals
    // where the GPU rounds differently (FMA contraction, e.g. on NVIDIA), so they get the host tolerance below.
    let unheld =
        |scan: &dpr_gpu::pipeline::ScanFeatures| dpr_gpu::pipeline::ScanFeatures { held_points: None, ..scan.clone() };
    let uploaded =
        dpr_gpu::block_on(on_gpu.backend().refine_icp(&unheld(&gs), &unheld(&gt), initial, &problem)).unwrap();
    assert_eq!(device, uploaded, "held and uploaded points give the same pose (seed {s})");
    let host_uploaded = dpr_gpu::block_on(on_gpu.backend().refine_icp(&cs, &ct, initial, &problem)).unwrap();
    assert_eq!(
        device,
        dpr_gpu::block_on(on_gpu.backend().refine_icp(&gs, &gt, initial, &problem)).unwrap(),
        "deterministic"
    );
    let down_bound = 2 * (32 + 4) + 112 * problem.max_iterations as u64;
    assert!(moved.device_to_host_bytes <= down_bound, "{} bytes down, bound {down_bound}", moved.device_to_host_bytes);
    assert_eq!(moved.host_to_device_bytes, 2 * (32 + 4), "only the two tables' initial grid words go up");
    let start = (rotation_error_deg(&initial, &truth), translation_error(&initial, &truth));
    for (name, pose) in [("device", &device), ("host", &host)] {
        let (angle, shift) = (rotation_error_deg(pose, &truth), translation_error(pose, &truth));
        assert!(
            angle < 0.5 && shift < 0.01,
            "{name} ICP: {angle} deg, {shift} from the truth (start {start:?}; seed {s})"
        );
    }
    for (name, other) in [("host ICP", &host), ("device ICP on host-described scans", &host_uploaded)] {
        let (angle, shift) = (rotation_error_deg(&device, other), translation_error(&device, other));
        assert!(angle < 1e-2 && shift < 5e-4, "device ICP and {name} differ by {angle} deg and {shift} (seed {s})");
    }
    let (angle, shift) = (rotation_error_deg(&device, &host), translation_error(&device, &host));
    eprintln!(
        "device ICP vs host ICP: {angle:.2e} deg / {shift:.2e} apart; {} bytes down (seed {s})",
        moved.device_to_host_bytes
    );
}

/// Every test of this module.
pub const TESTS: &[dpr_gpu::gpu::testing::GpuTest] = &[
    ("icp_normal_equations_matches_cpu", icp_normal_equations_matches_cpu),
    ("device_icp_converges_like_the_host", device_icp_converges_like_the_host),
];
