//! Parity cases of the preprocessing kernels (cell grid, sort, scan, runs, voxel averages, kNN, normals, patch
//! sampling and gathering, farthest points) and of the device paths built from them, against their CPU twins.
//! Integer kernels must match exactly; the tolerances of the float kernels are named constants with their
//! derivation.

use super::Outcome;
use super::inference::{EPS, assert_close, seed, unit};
use crate::PointCloud;
use crate::cpu::cell_bounds::cell_bounds;
use crate::cpu::cell_keys::{PAD_KEY, SortKey, cell_keys};
use crate::cpu::segments::segments;
use crate::cpu::{bitonic_sort, prefix_scan, voxel_average};
use crate::gpu::{self, Gpu};
use crate::rng::Rng;

/// voxel_average points: twin and kernel run the same f32 operations in the same order; only the division
/// `sum / count` may differ (Vulkan allows 2.5 ulp, and a compiler may rewrite it as a product with a
/// reciprocal: two roundings), then the correctly rounded `p0 + q` rounds the differing `q`. So
/// `|diff| <= 4 eps |q| + 2 eps |mean|`, with `|q| <= voxel` (q is an offset within the voxel); doubled.
fn voxel_point_tol(mean: f32, voxel: f32) -> f32 {
    2.0 * (4.0 * EPS * voxel + 2.0 * EPS * mean.abs())
}

/// voxel_average normals: the length's three products may be contracted into FMAs (2 ulp), `sqrt` is a few
/// ulp on a GPU and the division 2.5 ulp: under 8 ulp of a unit component; doubled.
const VOXEL_NORMAL_ATOL: f32 = 16.0 * EPS;

/// `n` points on a few scales: a cluster near the origin, far-off points, negative coordinates.
fn cloud(rng: &mut Rng, n: usize, extent: f64, offset: f64) -> Vec<[f32; 3]> {
    (0..n).map(|_| [0; 3].map(|_: i32| (offset + rng.uniform(-extent, extent)) as f32)).collect()
}

/// `cell_bounds` against its CPU twin.
pub async fn cell_bounds_matches_cpu(g: &Gpu) -> Outcome {
    let s = seed(101);
    let mut rng = Rng::new(s);
    for (n, extent, offset, inv_cell) in
        [(1, 1.0, 0.0, 10.0), (255, 2.0, -5.0, 7.0), (257, 50.0, 1000.0, 3.0), (4000, 1.0, 0.0, 100.0)]
    {
        let pts = cloud(&mut rng, n, extent, offset);
        let want = cell_bounds(&pts, inv_cell).unwrap();
        assert_eq!(gpu::cell_bounds::run(g, &pts, inv_cell).await.unwrap(), want, "n {n} (seed {s})");
    }
    // A point whose cell is out of range, and no points: errors on both sides.
    let mut pts = cloud(&mut rng, 300, 1.0, 0.0);
    pts[200] = [0.0, 3e9, 0.0];
    assert!(cell_bounds(&pts, 1.0).is_err());
    let e = gpu::cell_bounds::run(g, &pts, 1.0).await.unwrap_err().to_string();
    assert!(e.contains("2^30"), "{e}");
    assert!(gpu::cell_bounds::run(g, &[], 1.0).await.is_err());
    assert!(gpu::cell_bounds::run(g, &pts[..1], 0.0).await.is_err());
    Outcome::Passed
}

/// `cell_keys` against its CPU twin.
pub async fn cell_keys_matches_cpu(g: &Gpu) -> Outcome {
    let s = seed(102);
    let mut rng = Rng::new(s);
    for (n, extent, offset, inv_cell) in [(1, 1.0, 0.0, 10.0), (300, 2.0, -5.0, 7.0), (1025, 1.0, 3.0, 1000.0)] {
        let pts = cloud(&mut rng, n, extent, offset);
        let b = cell_bounds(&pts, inv_cell).unwrap();
        let want = cell_keys(&pts, inv_cell, &b).unwrap();
        let got = gpu::cell_keys::run(g, &pts, inv_cell, &b).await.unwrap();
        assert_eq!(got.len(), n.next_power_of_two());
        assert_eq!(&got[..n], &want[..], "n {n} (seed {s})");
        assert!(got[n..].iter().all(|k| *k == PAD_KEY), "padding (seed {s})");
    }
    // A cloud wider than 2^21 cells on y: the same error on both sides, never keys.
    let pts = vec![[0.0, 0.0, 0.0], [0.5, 2.5e6, 0.25]];
    let b = cell_bounds(&pts, 1.0).unwrap();
    let want = cell_keys(&pts, 1.0, &b).unwrap_err().to_string();
    let got = gpu::cell_keys::run(g, &pts, 1.0, &b).await.unwrap_err().to_string();
    assert_eq!(got, want);
    assert!(got.contains("axis 1"), "{got}");
    Outcome::Passed
}

/// `bitonic_sort` against its CPU twin.
pub async fn bitonic_sort_matches_cpu(g: &Gpu) -> Outcome {
    let s = seed(103);
    let mut rng = Rng::new(s);
    for (n, levels) in [(1, 1), (2, 1), (3, 2), (100, 3), (1000, 50), (4097, 1 << 20)] {
        // Few distinct cell keys (heavy ties broken by index), indices shuffled.
        let idx = rng.sample_without_replacement(n, n);
        let keys: Vec<SortKey> = idx
            .iter()
            .map(|&i| {
                [rng.below(levels) as u32, (rng.below(levels.min(3)) as u32).wrapping_mul(0x8000_0001), i as u32, 0]
            })
            .collect();
        let mut want = keys.clone();
        bitonic_sort::bitonic_sort(&mut want);
        assert_eq!(gpu::bitonic_sort::run(g, &keys).await.unwrap(), want, "n {n} (seed {s})");
    }
    Outcome::Passed
}

/// `prefix_scan` against its CPU twin.
pub async fn prefix_scan_matches_cpu(g: &Gpu) -> Outcome {
    let s = seed(104);
    let mut rng = Rng::new(s);
    for (n, max) in [(0, 1), (1, 5), (255, 2), (256, 2), (257, 1000), (70_001, 2), (1000, u32::MAX as usize)] {
        let values: Vec<u32> = (0..n).map(|_| rng.below(max) as u32).collect();
        assert_eq!(
            gpu::prefix_scan::run(g, &values).await.unwrap(),
            prefix_scan::prefix_scan(&values),
            "n {n} (seed {s})"
        );
    }
    Outcome::Passed
}

/// `segments` against its CPU twin.
pub async fn segments_matches_cpu(g: &Gpu) -> Outcome {
    let s = seed(105);
    let mut rng = Rng::new(s);
    for (n, cells) in [(1, 1), (7, 1), (300, 20), (3000, 2500)] {
        let mut keys: Vec<SortKey> =
            (0..n).map(|i| [rng.below(cells) as u32, rng.below(2) as u32, i as u32, 0]).collect();
        bitonic_sort::bitonic_sort(&mut keys);
        assert_eq!(gpu::segments::run(g, &keys).await.unwrap(), segments(&keys), "n {n} (seed {s})");
    }
    Outcome::Passed
}

/// `voxel_average` against its CPU twin.
pub async fn voxel_average_matches_cpu(g: &Gpu) -> Outcome {
    let s = seed(106);
    let mut rng = Rng::new(s);
    for (n, voxel, offset) in [(1, 0.1, 0.0), (500, 0.2, 0.0), (3000, 0.05, 250.0)] {
        let pts = cloud(&mut rng, n, 1.0, offset);
        let normals: Vec<[f32; 3]> = (0..n).map(|_| unit(&mut rng)).collect();
        let (_, sorted, seg) = voxel_average::sorted_cells(&pts, 1.0 / voxel).unwrap();
        let (want_p, want_n) = voxel_average::voxel_average(&pts, Some(&normals), &sorted, &seg);
        let (got_p, got_n) = gpu::voxel_average::run(g, &pts, Some(&normals), &sorted, &seg).await.unwrap();
        let (wp, gp) = (want_p.concat(), got_p.concat());
        assert_close("voxel_average points", s, &gp, &wp, |i| voxel_point_tol(wp[i], voxel));
        assert_close("voxel_average normals", s, &got_n.unwrap().concat(), &want_n.unwrap().concat(), |_| {
            VOXEL_NORMAL_ATOL
        });
        let (no_normals, none) = gpu::voxel_average::run(g, &pts, None, &sorted, &seg).await.unwrap();
        assert!(none.is_none());
        assert_close("voxel_average points", s, &no_normals.concat(), &wp, |i| voxel_point_tol(wp[i], voxel));
    }
    Outcome::Passed
}

/// The composed GPU downsampling against the CPU path's definition: the same voxels (count and order), averages
/// within the voxel_average tolerance, on random clouds and on a lattice whose points sit exactly on voxel
/// boundaries (membership decided by the f32 product both sides compute).
pub async fn voxel_downsample_matches_cpu(g: &Gpu) -> Outcome {
    let s = seed(107);
    let mut rng = Rng::new(s);
    let lattice: Vec<[f32; 3]> = (0..1000)
        .map(|i| [(i % 10) as f32 * 0.1, ((i / 10) % 10) as f32 * 0.1, (i / 100) as f32 * 0.1 - 0.3])
        .collect();
    let clouds = [
        (PointCloud::from_points(cloud(&mut rng, 2000, 1.0, -3.0)), 0.1),
        (
            PointCloud {
                points: cloud(&mut rng, 777, 0.5, 40.0),
                normals: Some((0..777).map(|_| unit(&mut rng)).collect()),
            },
            0.07,
        ),
        (PointCloud::from_points(lattice), 0.1),
        (PointCloud::from_points(cloud(&mut rng, 5, 1.0, 0.0)), 10.0),
    ];
    for (c, voxel) in &clouds {
        let want = crate::preprocess::voxel_downsample(c, *voxel).unwrap();
        let got = gpu::preprocess::voxel_downsample(g, c, *voxel).await.unwrap();
        assert_eq!(got.len(), want.len(), "voxels (seed {s})");
        let (wp, gp) = (want.points.concat(), got.points.concat());
        assert_close("voxel_downsample points", s, &gp, &wp, |i| voxel_point_tol(wp[i], *voxel));
        assert_eq!(got.normals.is_some(), want.normals.is_some());
        if let (Some(gn), Some(wn)) = (&got.normals, &want.normals) {
            assert_close("voxel_downsample normals", s, &gn.concat(), &wn.concat(), |_| VOXEL_NORMAL_ATOL);
        }
    }
    // Too wide for the keys: the CPU path's error, not a wrong answer; bad voxel sizes; an empty cloud.
    let wide = PointCloud::from_points(vec![[0.0; 3], [3e5, 0.0, 0.0]]);
    let want = crate::preprocess::voxel_downsample(&wide, 0.1).unwrap_err().to_string();
    assert_eq!(gpu::preprocess::voxel_downsample(g, &wide, 0.1).await.unwrap_err().to_string(), want);
    assert!(gpu::preprocess::voxel_downsample(g, &wide, 0.0).await.is_err());
    assert!(gpu::preprocess::voxel_downsample(g, &PointCloud::default(), 0.1).await.unwrap().is_empty());
    Outcome::Passed
}

/// grid_knn on random data: both sides compute `dx*dx + dy*dy + dz*dz`, but a GPU may contract it into FMAs,
/// so a squared distance may differ by 2 roundings (4 ulp, doubled: 8 eps relative) and two neighbours that
/// near-tie may swap slots; any other difference is a wrong neighbour.
const KNN_D2_RTOL: f32 = 8.0 * EPS;

/// pca_normals: each side's Jacobi sweeps are backward stable with an error of some tens of ulp of the
/// largest eigenvalue (FMA contraction and 2.5-ulp divisions make them round differently), so the normals
/// differ by at most `error / gap` radians (Davis-Kahan): 64 eps / (relative eigengap), plus 16 eps for the
/// normalisation. Points whose relative gap is under [`PCA_MIN_GAP`] are ill-conditioned and only checked
/// for unit length and orientation.
fn pca_tol(gap: f32) -> f32 {
    64.0 * EPS / gap + 16.0 * EPS
}

/// Relative eigengap `(second - smallest) / largest` below which a normal is not compared.
const PCA_MIN_GAP: f64 = 0.02;

fn brute_knn(points: &[[f32; 3]], q: usize, k: usize) -> Vec<(f32, u32)> {
    let mut all: Vec<(f32, u32)> = points
        .iter()
        .enumerate()
        .map(|(i, p)| (crate::cpu::grid_knn::distance_squared(p, &points[q]), i as u32))
        .collect();
    all.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    all.truncate(k);
    all
}

/// GPU lists against the twin's: equal on exact data; on random data equal up to near-tie swaps.
fn check_knn_lists(what: &str, s: u64, k: usize, got: &(Vec<u32>, Vec<f32>), want: &(Vec<u32>, Vec<f32>), exact: bool) {
    if exact {
        assert_eq!(got.0, want.0, "{what}: indices (seed {s})");
        assert_eq!(got.1, want.1, "{what}: squared distances (seed {s})");
        return;
    }
    assert_close(what, s, &got.1, &want.1, |i| KNN_D2_RTOL * want.1[i].abs());
    for (q, (g, w)) in got.0.chunks_exact(k).zip(want.0.chunks_exact(k)).enumerate() {
        for slot in 0..k {
            if g[slot] != w[slot] {
                let (d, kth) = (got.1[q * k + slot], want.1[q * k + k - 1]);
                let near = |a: f32, b: f32| (a - b).abs() <= KNN_D2_RTOL * a.abs().max(b.abs());
                // A swap with a near-tied neighbour of the twin's list, or a near-tie at the list's end.
                let swapped = (0..k).any(|t| w[t] == g[slot] && near(want.1[q * k + t], d));
                assert!(
                    swapped || near(d, kth),
                    "{what}: query {q} slot {slot}: gpu {} vs cpu {} is no near-tie (seed {s})",
                    g[slot],
                    w[slot]
                );
            }
        }
    }
}

/// A noisy curved surface far from the origin, duplicates and, with `outlier`, a far isolated point (whose
/// search visits many cells: only with coarse cells, as lavapipe ends an invocation's loops after 65,535
/// iterations).
fn knn_scene(rng: &mut Rng, n: usize, outlier: bool) -> Vec<[f32; 3]> {
    let mut pts: Vec<[f32; 3]> = (0..n)
        .map(|_| {
            let (x, y) = (rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0));
            [(x + 20.0) as f32, y as f32, (0.3 * x * x - 0.2 * y + 0.01 * rng.normal()) as f32]
        })
        .collect();
    pts.extend_from_slice(&[[20.5, 0.5, 0.1]; 3]);
    if outlier {
        pts.push([35.0, -9.0, 4.0]);
    }
    pts
}

/// `grid_knn` against its CPU twin.
pub async fn grid_knn_matches_cpu(g: &Gpu) -> Outcome {
    use crate::cpu::grid_knn::{CellGrid, grid_knn};
    let s = seed(108);
    let mut rng = Rng::new(s);
    // A lattice: squared distances are exact (multiples of 1/16), so both sides agree bit for bit, ties included.
    let lattice: Vec<[f32; 3]> =
        (0..343).map(|i| [(i % 7) as f32 * 0.25, ((i / 7) % 7) as f32 * 0.25, (i / 49) as f32 * 0.25 - 1.0]).collect();
    for (inv_cell, k) in [(4.0, 7), (2.5, 27), (1.0, 64), (4.0, 1)] {
        let grid = CellGrid::new(&lattice, inv_cell).unwrap();
        let queries: Vec<u32> = (0..lattice.len() as u32).rev().collect();
        let want = grid_knn(&grid, &queries, k).unwrap();
        for (i, &q) in queries.iter().enumerate().step_by(17) {
            let b = brute_knn(&lattice, q as usize, k);
            assert_eq!(want.0[i * k..][..k], b.iter().map(|x| x.1).collect::<Vec<_>>()[..], "twin vs brute force");
        }
        check_knn_lists(
            "grid_knn lattice",
            s,
            k,
            &gpu::grid_knn::run(g, &grid, &queries, k).await.unwrap(),
            &want,
            true,
        );
    }
    for (cell, k, outlier) in [(0.15, 10, false), (0.08, 30, false), (2.0, 5, true)] {
        let pts = knn_scene(&mut rng, 700, outlier);
        let grid = CellGrid::new(&pts, 1.0 / cell).unwrap();
        let queries: Vec<u32> = (0..pts.len() as u32).collect();
        let want = grid_knn(&grid, &queries, k).unwrap();
        for q in (0..pts.len()).step_by(31).chain([pts.len() - 1]) {
            let b: Vec<u32> = brute_knn(&pts, q, k).iter().map(|x| x.1).collect();
            assert_eq!(want.0[q * k..][..k], b[..], "twin vs brute force, query {q}");
        }
        let got = gpu::grid_knn::run(g, &grid, &queries, k).await.unwrap();
        check_knn_lists("grid_knn random", s, k, &got, &want, false);
        // The composed GPU path (cell table built on the GPU) gives the same lists.
        let composed = gpu::preprocess::knn(g, &pts, k, cell).await.unwrap();
        check_knn_lists("preprocess::knn", s, k, &composed, &want, false);
    }
    // Fewer points than k: unused slots.
    let pts = knn_scene(&mut rng, 10, false);
    let grid = CellGrid::new(&pts[..4], 1.0).unwrap();
    check_knn_lists(
        "grid_knn small",
        s,
        6,
        &gpu::grid_knn::run(g, &grid, &[3, 0], 6).await.unwrap(),
        &grid_knn(&grid, &[3, 0], 6).unwrap(),
        true,
    );
    assert!(gpu::grid_knn::run(g, &grid, &[0], 65).await.is_err());
    assert!(gpu::preprocess::knn(g, &pts, 0, 0.1).await.is_err());
    Outcome::Passed
}

/// `(second - smallest) / largest` eigenvalue of the neighbourhood `nbrs` (f64).
fn gap_ratio(points: &[[f32; 3]], nbrs: &[u32]) -> f64 {
    use nalgebra::{Matrix3, SymmetricEigen, Vector3};
    let pts: Vec<Vector3<f64>> =
        nbrs.iter().filter(|&&j| j != u32::MAX).map(|&j| Vector3::from(points[j as usize].map(f64::from))).collect();
    if pts.len() < 3 {
        return 0.0;
    }
    let mean = pts.iter().sum::<Vector3<f64>>() / pts.len() as f64;
    let cov = pts.iter().fold(Matrix3::zeros(), |acc, q| acc + (q - mean) * (q - mean).transpose());
    let mut w: Vec<f64> = SymmetricEigen::new(cov).eigenvalues.iter().copied().collect();
    w.sort_by(f64::total_cmp);
    if w[2] > 0.0 { (w[1] - w[0]) / w[2] } else { 0.0 }
}

/// Normals against the twin's: within [`pca_tol`] and of the same sign where well-conditioned; unit length
/// and facing the viewpoint everywhere. Returns how many were compared.
fn check_normals(
    what: &str,
    s: u64,
    points: &[[f32; 3]],
    lists: &[u32],
    k: usize,
    view: [f32; 3],
    (got, want): (&[[f32; 3]], &[[f32; 3]]),
) -> usize {
    assert_eq!(got.len(), want.len(), "{what} (seed {s})");
    let mut compared = 0;
    for (i, (gn, wn)) in got.iter().zip(want).enumerate() {
        let len = (gn[0] * gn[0] + gn[1] * gn[1] + gn[2] * gn[2]).sqrt();
        assert!((len - 1.0).abs() <= 16.0 * EPS, "{what}: normal {i} {gn:?} is not unit (seed {s})");
        let p = points[i];
        let facing = gn[0] * (view[0] - p[0]) + gn[1] * (view[1] - p[1]) + gn[2] * (view[2] - p[2]);
        assert!(facing >= -1e-4, "{what}: normal {i} {gn:?} faces away from the viewpoint (seed {s})");
        let gap = gap_ratio(points, &lists[i * k..][..k]);
        if gap < PCA_MIN_GAP {
            continue;
        }
        compared += 1;
        let err = (0..3).map(|a| (gn[a] - wn[a]).powi(2)).sum::<f32>().sqrt();
        assert!(
            err <= pca_tol(gap as f32),
            "{what}: normal {i}: gpu {gn:?} vs cpu {wn:?} (err {err:e}, gap {gap:.3}, seed {s})"
        );
    }
    compared
}

/// `pca_normals` against its CPU twin.
pub async fn pca_normals_matches_cpu(g: &Gpu) -> Outcome {
    use crate::cpu::grid_knn::{CellGrid, grid_knn};
    use crate::cpu::pca_normals::pca_normals;
    let s = seed(109);
    let mut rng = Rng::new(s);
    let pts = knn_scene(&mut rng, 800, true);
    let view = [20.0, 0.0, 3.0];
    for k in [3, 12, 30] {
        let grid = CellGrid::new(&pts, 1.0 / 0.15).unwrap();
        let queries: Vec<u32> = (0..pts.len() as u32).collect();
        let (lists, _) = grid_knn(&grid, &queries, k).unwrap();
        let want = pca_normals(&pts, &queries, &lists, k, view).unwrap();
        let got = gpu::pca_normals::run(g, &pts, &queries, &lists, k, view).await.unwrap();
        let compared = check_normals("pca_normals", s, &pts, &lists, k, view, (&got, &want));
        assert!(compared > pts.len() / 2, "only {compared} well-conditioned normals (seed {s})");
    }
    // Degenerate neighbourhoods: fewer than 3 neighbours, identical points, a collinear set, a point on the
    // viewpoint: the fallback (direction to the viewpoint, +z on it) or a well-defined normal.
    let pts =
        vec![[1.0, 1.0, 1.0], [1.0, 1.0, 1.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]];
    let lists = vec![0, 1, u32::MAX, 0, 1, 2, 3, 4, 5, 3, 4, 5];
    let queries = [0, 1, 3, 4];
    for view in [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]] {
        let want = pca_normals(&pts, &queries, &lists, 3, view).unwrap();
        let got = gpu::pca_normals::run(g, &pts, &queries, &lists, 3, view).await.unwrap();
        assert_close("pca_normals degenerate", s, &got.concat(), &want.concat(), |_| 16.0 * EPS);
        for n in &got {
            assert!(((n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt() - 1.0).abs() <= 16.0 * EPS, "{n:?}");
        }
    }
    assert!(gpu::pca_normals::run(g, &pts, &[0], &[0, 9, 1], 3, [0.0; 3]).await.is_err());
    Outcome::Passed
}

/// The composed GPU normals (table, search and PCA on the GPU) and downsampling + normals against the twins.
pub async fn normals_and_downsampling_match_cpu(g: &Gpu) -> Outcome {
    use crate::cpu::grid_knn::{CellGrid, grid_knn};
    use crate::cpu::pca_normals::pca_normals;
    let s = seed(110);
    let mut rng = Rng::new(s);
    let pts = knn_scene(&mut rng, 1500, false);
    let (k, view) = (10, [20.0, 0.0, 3.0]);
    let twin = |points: &[[f32; 3]], cell: f32| {
        let grid = CellGrid::new(points, 1.0 / cell).unwrap();
        let queries: Vec<u32> = (0..points.len() as u32).collect();
        let (lists, _) = grid_knn(&grid, &queries, k).unwrap();
        let normals = pca_normals(points, &queries, &lists, k, view).unwrap();
        (lists, normals)
    };
    let (lists, want) = twin(&pts, 0.1);
    let got = gpu::preprocess::normals(g, &pts, k, view, 0.1).await.unwrap();
    assert!(check_normals("preprocess::normals", s, &pts, &lists, k, view, (&got, &want)) > pts.len() / 2);

    let voxel = 0.04;
    let cloud = PointCloud::from_points(pts);
    let down = gpu::preprocess::downsample_and_normals(g, &cloud, voxel, k, view).await.unwrap();
    let want_down = crate::preprocess::voxel_downsample(&cloud, voxel).unwrap();
    assert_eq!(down.len(), want_down.len(), "voxels (seed {s})");
    let (wp, gp) = (want_down.points.concat(), down.points.concat());
    assert_close("downsample_and_normals points", s, &gp, &wp, |i| voxel_point_tol(wp[i], voxel));
    // Normals of the GPU's own downsampled points (within rounding of the CPU's), against the twin on them.
    let (lists, want) = twin(&down.points, gpu::preprocess::knn_cell(voxel, k));
    let got = down.normals.clone().expect("estimated normals");
    assert!(check_normals("downsample_and_normals", s, &down.points, &lists, k, view, (&got, &want)) > down.len() / 2);
    Outcome::Passed
}

/// A scene for patch sampling: a lattice (exact distances: many points exactly at the radius), a random
/// cluster, points on a shell at the radius up to rounding around one keypoint (where an FMA would flip the
/// boundary test), an isolated point (0 neighbours), a pair (1 neighbour) and a sparse line (< N).
fn patch_scene(rng: &mut Rng) -> (Vec<[f32; 3]>, Vec<u32>, f32) {
    let radius = 0.25f32;
    let mut pts: Vec<[f32; 3]> =
        (0..512).map(|i| [(i % 8) as f32 * 0.125, ((i / 8) % 8) as f32 * 0.125, (i / 64) as f32 * 0.125]).collect();
    pts.extend(cloud(rng, 1500, 0.3, 2.0));
    let centre = [5.3f32, -1.7, 0.9];
    let shell_at = pts.len() as u32;
    pts.push(centre);
    for _ in 0..400 {
        let u = unit(rng);
        let scale = 1.0 + (rng.uniform(-2.0, 2.0) as f32) * EPS;
        pts.push([0, 1, 2].map(|a| centre[a] + radius * scale * u[a]));
    }
    let isolated = pts.len() as u32;
    pts.push([-6.0, 6.0, 6.0]);
    pts.extend_from_slice(&[[9.0, 9.0, 9.0], [9.1, 9.0, 9.0]]);
    let line_at = pts.len() as u32;
    pts.extend((0..6).map(|i| [-4.0 + i as f32 * 0.1, 0.0, 0.0]));
    let mut keypoints: Vec<u32> = (0..512).step_by(5).chain((512..2012).step_by(11)).collect();
    keypoints.extend([shell_at, isolated, isolated + 1, line_at + 2, 0, 511]);
    (pts, keypoints, radius)
}

/// `patch_sample` against its CPU twin.
pub async fn patch_sample_matches_cpu(g: &Gpu) -> Outcome {
    use crate::cpu::grid_knn::CellGrid;
    use crate::cpu::patch_sample::patch_sample;
    let s = seed(111);
    let mut rng = Rng::new(s);
    let (pts, keypoints, radius) = patch_scene(&mut rng);
    for cell in [radius, 1.7 * radius] {
        let grid = CellGrid::new(&pts, 1.0 / cell).unwrap();
        let want = patch_sample(&grid, &keypoints, radius, s).unwrap();
        let got = gpu::patch_sample::run(g, &grid, &keypoints, radius, s).await.unwrap();
        assert_eq!(got.counts, want.counts, "counts, cell {cell} (seed {s})");
        assert_eq!(got.sorted, want.sorted, "ranked candidates, cell {cell} (seed {s})");
        // The cases the scene is built for are there.
        let count = |k: u32| want.counts[keypoints.iter().position(|&x| x == k).unwrap()];
        assert_eq!(count(*keypoints.iter().rev().nth(4).unwrap()), 0, "isolated keypoint");
        assert_eq!(count(*keypoints.iter().rev().nth(3).unwrap()), 1, "pair");
        let shell = count(*keypoints.iter().rev().nth(5).unwrap());
        assert!(shell > 50 && shell < 400, "shell: {shell} of 400 at the radius up to rounding are in");
    }
    // Cells narrower than the radius, a keypoint that is not a point: the twin's errors.
    let grid = CellGrid::new(&pts, 1.0 / (radius / 3.0)).unwrap();
    let want = patch_sample(&grid, &keypoints[..3], radius, s).unwrap_err().to_string();
    assert_eq!(gpu::patch_sample::run(g, &grid, &keypoints[..3], radius, s).await.unwrap_err().to_string(), want);
    let grid = CellGrid::new(&pts, 1.0 / radius).unwrap();
    assert!(gpu::patch_sample::run(g, &grid, &[pts.len() as u32], radius, s).await.is_err());
    Outcome::Passed
}

/// `patch_gather` against its CPU twin.
pub async fn patch_gather_matches_cpu(g: &Gpu) -> Outcome {
    use crate::cpu::grid_knn::CellGrid;
    use crate::cpu::patch_gather::patch_gather;
    use crate::cpu::patch_sample::patch_sample;
    let s = seed(112);
    let mut rng = Rng::new(s);
    let (pts, keypoints, radius) = patch_scene(&mut rng);
    let normals: Vec<[f32; 3]> = (0..pts.len()).map(|_| unit(&mut rng)).collect();
    let c = patch_sample(&CellGrid::new(&pts, 1.0 / radius).unwrap(), &keypoints, radius, s).unwrap();
    let (mut table, mut start) = (Vec::new(), 0);
    for (slot, &count) in c.counts.iter().enumerate() {
        if count > 0 {
            table.push([keypoints[slot], start, count, 0]);
        }
        start += count;
    }
    for (n, centers) in [(16, false), (1, false), (40, false), (16, true)] {
        let want = patch_gather(&pts, &normals, &c.sorted, &table, n, centers).unwrap();
        let got = gpu::patch_gather::run(g, &pts, &normals, &c.sorted, &table, n, centers).await.unwrap();
        assert_eq!(got, want, "n {n}, centers {centers} (seed {s})");
    }
    assert!(gpu::patch_gather::run(g, &pts, &normals, &c.sorted, &[[0, 0, 0, 0]], 4, false).await.is_err());
    Outcome::Passed
}

/// The composed GPU sampling (cell table, search, sort, gather on the device) against the CPU path's
/// `extract_patches` and brute force: the same patches, every sampled point within the radius and not the
/// keypoint, distinct when there are at least N candidates, all candidates taken when fewer, empty patches
/// reported.
pub async fn sample_patches_matches_cpu_and_brute_force(g: &Gpu) -> Outcome {
    use crate::cpu::patch_sample::{in_patch, radius_squared};
    let s = seed(113);
    let mut rng = Rng::new(s);
    let (pts, keypoints, radius) = patch_scene(&mut rng);
    let n = 24;
    let ks: Vec<usize> = keypoints.iter().map(|&k| k as usize).collect();
    let index = crate::spatial::PointIndex::new(&pts).unwrap();
    let want = crate::preprocess::extract_patches(&pts, &index, &ks, radius, n, s);
    let got = gpu::preprocess::sample_patches(g, &pts, &keypoints, radius, n, s).await.unwrap();
    assert_eq!(got, want, "seed {s}");
    let r2 = radius_squared(radius);
    for (p, &k) in got.keypoints.iter().enumerate() {
        let all: Vec<u32> =
            (0..pts.len()).filter(|&j| j != k && in_patch(&pts[j], &pts[k], r2)).map(|j| j as u32).collect();
        let mut nb = got.neighbors[p * n..(p + 1) * n].to_vec();
        assert!(nb.iter().all(|j| all.binary_search(j).is_ok()), "keypoint {k}: a point outside the patch");
        nb.sort_unstable();
        nb.dedup();
        assert_eq!(nb.len(), all.len().min(n), "keypoint {k}: distinct when enough, all when fewer");
    }
    for &k in &got.empty {
        assert!((0..pts.len()).all(|j| j == k || !in_patch(&pts[j], &pts[k], r2)), "empty {k}");
    }
    assert!(!got.empty.is_empty() && got.keypoints.len() > 100);
    // Candidates that do not fit one buffer (64 KiB: the cell table fits, the ~60,000 candidates do not): the
    // keypoints are split, with the same result.
    let cap = g.context.max_buffer_bytes();
    g.context.set_max_buffer_bytes(64 * 1024);
    let grid = crate::cpu::grid_knn::CellGrid::new(&pts, 1.0 / radius).unwrap();
    let total: u32 = crate::cpu::patch_sample::patch_sample(&grid, &keypoints, radius, s).unwrap().counts.iter().sum();
    assert!(u64::from(total) * 16 > 64 * 1024, "{total} candidates fit one buffer: nothing is split");
    assert_eq!(gpu::preprocess::sample_patches(g, &pts, &keypoints, radius, n, s).await.unwrap(), want, "split");
    g.context.set_max_buffer_bytes(cap);
    Outcome::Passed
}

/// A device cloud's estimated normals (its own kNN grid, cells sized from the point density) against the twins
/// (grid_knn + pca_normals): the definition of the GPU path's normals.
pub async fn device_cloud_normals_match_cpu(g: &Gpu) -> Outcome {
    use crate::cpu::grid_knn::{CellGrid, grid_knn};
    use crate::cpu::pca_normals::pca_normals;
    let s = seed(114);
    let mut rng = Rng::new(s);
    let pts = knn_scene(&mut rng, 1500, false);
    let (k, view) = (12, [20.0, 0.0, 3.0]);
    let source = gpu::preprocess::NormalSource::Estimate { k, viewpoint: view };
    let cloud = gpu::preprocess::DeviceCloud::new(g, &pts, source, 0.3).await.unwrap();
    let got = cloud.read_normals(g).await.unwrap();
    let grid = CellGrid::new(&pts, 1.0 / 0.1).unwrap();
    let queries: Vec<u32> = (0..pts.len() as u32).collect();
    let (lists, _) = grid_knn(&grid, &queries, k).unwrap();
    let want = pca_normals(&pts, &queries, &lists, k, view).unwrap();
    assert!(check_normals("device cloud normals", s, &pts, &lists, k, view, (&got, &want)) > pts.len() / 2);
    Outcome::Passed
}

/// farthest_point: the same indices as the twin (the CPU path's definition), on random points, on a lattice
/// (many exactly tied distances: ties go to the lower index), with duplicates, past one workgroup of partials,
/// and drawing every point.
pub async fn farthest_point_matches_cpu(g: &Gpu) -> Outcome {
    use crate::cpu::farthest_point::farthest_point;
    let s = seed(115);
    let mut rng = Rng::new(s);
    let lattice: Vec<[f32; 3]> =
        (0..343).map(|i| [(i % 7) as f32 * 0.25, ((i / 7) % 7) as f32 * 0.25, (i / 49) as f32 * 0.25]).collect();
    let mut dup = cloud(&mut rng, 300, 1.0, 5.0);
    dup.extend_from_slice(&dup.clone()[..50]);
    let cases =
        [(cloud(&mut rng, 5000, 2.0, -1.0), 70), (lattice, 343), (dup, 120), (cloud(&mut rng, 70_000, 1.0, 0.0), 9)];
    for (pts, count) in &cases {
        let start = rng.below(pts.len());
        let want = farthest_point(pts, *count, start);
        assert_eq!(gpu::farthest_point::run(g, pts, *count, start).await.unwrap(), want, "n {} (seed {s})", pts.len());
    }
    assert!(gpu::farthest_point::run(g, &cases[0].0[..3], 4, 0).await.is_err());
    Outcome::Passed
}
