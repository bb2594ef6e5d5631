//! The parity case of ICP's kernel (`icp_normal_equations`, bit for bit against its twin) and the scene helpers
//! the device ICP test (`tests/gpu_icp`) shares.

use super::Outcome;
use super::inference::seed;
use crate::cpu::grid_knn::{CellGrid, distance_squared};
use crate::cpu::icp_normal_equations::{IcpTarget, icp_normal_equations, nearest_within, pose_rows};
use crate::gpu::{self, Gpu};
use crate::pose::matrix_from_parts;
use crate::rng::Rng;
use nalgebra::{Matrix4, Rotation3, Vector3};

/// A random unit vector (f64 normal draws, normalised).
pub fn unit(rng: &mut Rng) -> [f32; 3] {
    let v = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
    [v.x as f32, v.y as f32, v.z as f32]
}

/// `n` points uniform in `[lo, hi]^3`.
pub fn uniform(rng: &mut Rng, n: usize, lo: f64, hi: f64) -> Vec<[f32; 3]> {
    (0..n).map(|_| [0; 3].map(|_: i32| rng.uniform(lo, hi) as f32)).collect()
}

/// A small rigid motion: rotation vector `omega` (rad), translation `t`.
pub fn motion(omega: [f64; 3], t: [f64; 3]) -> Matrix4<f64> {
    matrix_from_parts(&Rotation3::new(Vector3::from(omega)).into_inner(), &Vector3::from(t))
}

/// The kernel and its twin run the same f32 operations in the same order (products fenced against FMA
/// contraction, the same reduction tree, the same pair choice by (d2, index)), so both stages must match bit
/// for bit: every workgroup partial and the total, over random clouds with points that have no neighbour
/// within the distance (some in an empty block of cells inside the grid, some outside it), exact ties (a
/// dyadic lattice with sources at midpoints, identity pose), more than 64 partials (stage 1 lanes sum several)
/// and a stride.
pub async fn icp_normal_equations_matches_cpu(g: &Gpu) -> Outcome {
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
        let got = gpu::icp_normal_equations::run(g, &source, stride, &t, &rows, max_distance).await.unwrap();
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
    let empty =
        gpu::icp_normal_equations::run(g, &[], 1, &t, &pose_rows(&Matrix4::identity()), max_distance).await.unwrap();
    assert_eq!(empty.total, [0.0; 28]);
    assert!(empty.partials.is_empty());
    let bad = IcpTarget { grid: &grid, normals: &normals[1..] };
    assert!(gpu::icp_normal_equations::run(g, &source, 1, &bad, &pose_rows(&Matrix4::identity()), 0.1).await.is_err());
    assert!(gpu::icp_normal_equations::run(g, &source, 1, &t, &pose_rows(&Matrix4::identity()), 1.0).await.is_err());
    Outcome::Passed
}
