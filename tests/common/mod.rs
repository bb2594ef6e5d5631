//! Shared test helpers: small generated scenes and temp directories.
#![allow(dead_code)]

use dpr_gpu::PointCloud;
use dpr_gpu::model::ModelConfig;
use dpr_gpu::pose::{matrix_from_parts, matrix_from_quaternion, transform_point};
use dpr_gpu::rng::Rng;
use nalgebra::{Matrix4, Vector3};
use std::path::Path;

/// A fresh, empty scratch folder for one test, under Cargo's scratch folder for integration tests (`target/tmp`),
/// removed with everything in it when dropped. It dereferences to its path.
pub struct TestDir(tempfile::TempDir);

impl std::ops::Deref for TestDir {
    type Target = Path;
    fn deref(&self) -> &Path {
        self.0.path()
    }
}

impl AsRef<Path> for TestDir {
    fn as_ref(&self) -> &Path {
        self.0.path()
    }
}

/// A new [`TestDir`] whose name starts with `name` (in the system's temp folder where Cargo's is missing: a test
/// binary carried to another machine, as `benches/device/pack.sh` does).
pub fn temp_dir(name: &str) -> TestDir {
    let cargo = Path::new(env!("CARGO_TARGET_TMPDIR"));
    let parent = if cargo.is_dir() { cargo.to_path_buf() } else { std::env::temp_dir() };
    TestDir(tempfile::Builder::new().prefix(&format!("{name}-")).tempdir_in(parent).unwrap())
}

/// `n` points sampled uniformly (by count per part) from a small room corner: floor, two walls, a box, a sphere
/// and a cylinder, about 2 m across. Different seeds give different samples of the same surfaces.
pub fn room_corner(seed: u64, n: usize) -> PointCloud {
    let mut rng = Rng::new(seed);
    let mut pts = Vec::with_capacity(n);
    for i in 0..n {
        let (u, v) = (rng.unit_f64(), rng.unit_f64());
        let p = match i % 6 {
            0 => [2.0 * u, 2.0 * v, 0.0],
            1 => [2.0 * u, 0.0, 1.5 * v],
            2 => [0.0, 2.0 * u, 1.5 * v],
            3 => {
                // Box 0.5 x 0.4 x 0.6 at (1.2, 1.0): one of its five visible faces.
                let (x0, y0, sx, sy, sz) = (1.2, 1.0, 0.5, 0.4, 0.6);
                match rng.below(5) {
                    0 => [x0 + sx * u, y0 + sy * v, sz],
                    1 => [x0, y0 + sy * u, sz * v],
                    2 => [x0 + sx, y0 + sy * u, sz * v],
                    3 => [x0 + sx * u, y0, sz * v],
                    _ => [x0 + sx * u, y0 + sy, sz * v],
                }
            }
            4 => {
                let (th, z) = (std::f64::consts::TAU * u, 2.0 * v - 1.0);
                let r = (1.0 - z * z).sqrt() * 0.25;
                [0.6 + r * th.cos(), 1.4 + r * th.sin(), 0.25 + 0.25 * z]
            }
            _ => {
                let th = std::f64::consts::TAU * u;
                [1.5 + 0.15 * th.cos(), 0.5 + 0.15 * th.sin(), 0.8 * v]
            }
        };
        pts.push(p.map(|c| c as f32));
    }
    PointCloud::from_points(pts)
}

/// A rigid transform with a sizeable rotation, seeded.
pub fn known_pose(seed: u64) -> Matrix4<f64> {
    let mut rng = Rng::new(seed);
    let q = rng.unit_quaternion();
    matrix_from_parts(
        &matrix_from_quaternion(q),
        &Vector3::new(rng.uniform(-2.0, 2.0), rng.uniform(-2.0, 2.0), rng.uniform(-2.0, 2.0)),
    )
}

/// (source, target, target_from_source): two independent samples of the room, the target moved by the pose.
pub fn room_pair(seed: u64, n: usize) -> (PointCloud, PointCloud, Matrix4<f64>) {
    let truth = known_pose(seed);
    let source = room_corner(seed * 2 + 1, n);
    let target = room_corner(seed * 2 + 2, n);
    let target = PointCloud::from_points(target.points.iter().map(|&p| transform_point(&truth, p)).collect());
    (source, target, truth)
}

/// A tiny model configuration (12 points per patch, narrow layers) for tests that need a network, not a good one.
pub fn tiny_config() -> ModelConfig {
    ModelConfig {
        points_per_patch: 12,
        encoder_widths: vec![8, 8, 16],
        head_widths: vec![16, 12],
        fold_widths: vec![8, 8],
        grid: [3, 3],
        relative_widths: vec![16, 8],
        ..ModelConfig::default()
    }
}

/// A tiny synthetic dataset (one scene, three fragments, made by the `synth` command) in `dir/data`.
pub fn tiny_dataset(dir: &Path) -> std::path::PathBuf {
    let data = dir.join("data");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_dpr-gpu"))
        .args(["synth", data.to_str().unwrap(), "--fragments", "3", "--frames", "4", "--width", "64"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    data
}
