//! Point-to-plane ICP on the device: the `icp_normal_equations` kernel against its CPU twin (bit for bit),
//! and the GPU backend's ICP against the host's on a generated scene. Part of the `gpu_parity` binary (its
//! `main` runs [`TESTS`] too).

use super::{ROOM_VIEWPOINT, backends, seed};
use dpr_gpu::estimate::icp::{IcpProblem, MAX_ICP_POINTS};
use dpr_gpu::gpu::parity::icp::motion;
use dpr_gpu::gpu::testing::gpu_or_skip as gpu;
use dpr_gpu::pose::{rotation_error_deg, translation_error};

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
pub const TESTS: &[dpr_gpu::gpu::testing::GpuTest] =
    &[("device_icp_converges_like_the_host", device_icp_converges_like_the_host)];
