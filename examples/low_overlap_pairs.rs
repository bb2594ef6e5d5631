//! Cuts low-overlap pairs from real scans with known poses, for evaluation only (never training or tuning):
//! for every pair of a pairs file, the source is cut by a plane until the pair shares a chosen overlap, the
//! same measure `dpr-gpu eval` bins recall by (the share of target points within `--distance` of the moved
//! source, on 1 cm grid averages). The plane faces away from the shared part: its normal runs from the centroid
//! of the source points that overlap the target to the centroid of those that do not (source frame), so what
//! is cut is shared surface and what stays is the source's own part plus a strip of the shared one.
//!
//!     cargo run --release --example low_overlap_pairs -- ../shared/data/3dmatch_redkitchen/pairs.txt OUT \
//!         --overlap 0.1,0.2,0.3
//!     dpr-gpu eval OUT/pairs.txt
//!
//! OUT holds the cut sources (`<source stem>_for_<target stem>_<pct>.ply`), links-free copies of the targets,
//! and `pairs.txt` with the unchanged ground truth (a cut moves no point). Pairs already below an overlap keep
//! the whole source for it; pairs that cannot reach it are skipped, and each line printed says what was made.

use dpr_gpu::eval::dataset::load_pairs_file;
use dpr_gpu::eval::groundtruth::PreparedFragment;
use dpr_gpu::eval::run::estimated_overlap;
use dpr_gpu::io::{read_cloud, write_cloud};
use dpr_gpu::{Matrix4, PointCloud};
use std::path::{Path, PathBuf};

/// Overlap distance in the pairs' units at 0.60 m-equivalent scale: the protocol's 0.05 m.
const DEFAULT_DISTANCE: f64 = 0.05;
/// Grid of the overlap measure (the 3DMatch rule's 1 cm).
const GRID: f64 = 0.01;

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 2 {
        return Err("usage: low_overlap_pairs PAIRS.txt OUT [--overlap 0.1,0.2,0.3] [--distance 0.05]".into());
    }
    let (pairs_path, out) = (PathBuf::from(&args[0]), PathBuf::from(&args[1]));
    let mut overlaps = vec![0.1, 0.2, 0.3];
    let mut distance = DEFAULT_DISTANCE;
    let mut rest = args[2..].iter();
    while let Some(flag) = rest.next() {
        let value = rest.next().ok_or_else(|| format!("{flag} needs a value"))?;
        match flag.as_str() {
            "--overlap" => overlaps = value.split(',').map(str::parse).collect::<std::result::Result<_, _>>()?,
            "--distance" => distance = value.parse()?,
            other => return Err(format!("unknown option {other}").into()),
        }
    }
    if overlaps.iter().any(|o| !(*o > 0.0 && *o < 1.0)) || !(distance.is_finite() && distance > 0.0) {
        return Err("overlaps must be in (0, 1) and the distance positive".into());
    }
    let scene = load_pairs_file(&pairs_path)?;
    std::fs::create_dir_all(&out)?;
    let mut lines = vec![format!(
        "# Low-overlap pairs cut from {} by examples/low_overlap_pairs.rs (evaluation only); p_target = T p_source",
        pairs_path.display()
    )];
    for g in &scene.gt {
        let (source_path, target_path) = (&scene.files[g.j], &scene.files[g.i]);
        let (source, _) = read_cloud(source_path, &Default::default())?;
        let (target, _) = read_cloud(target_path, &Default::default())?;
        let target_name = format!("{}.ply", stem(target_path));
        let target_copy = out.join(&target_name);
        if !target_copy.exists() {
            write_cloud(&target_copy, &target)?;
        }
        let target_index = PreparedFragment::new(&target, GRID, distance);
        let overlap_of = |cloud: &PointCloud| {
            estimated_overlap(&target_index, &PreparedFragment::new(cloud, GRID, distance), &g.i_from_j, distance)
        };
        let full = overlap_of(&source);
        let direction = away_from_shared(&source, &target, &g.i_from_j, distance);
        for &goal in &overlaps {
            let Some(cut) = cut_to(&source, direction, goal, full, &overlap_of) else {
                println!(
                    "{} -> {}: cannot reach {goal} (full overlap {full:.3}); skipped",
                    stem(source_path),
                    target_name
                );
                continue;
            };
            let name = format!("{}_for_{}_{:02}.ply", stem(source_path), stem(target_path), (goal * 100.0).round());
            write_cloud(&out.join(&name), &cut.0)?;
            println!(
                "{name}: {} of {} source points, overlap {:.3} (full {full:.3})",
                cut.0.len(),
                source.len(),
                cut.1
            );
            let t: Vec<String> = g.i_from_j.transpose().iter().map(|v| format!("{v}")).collect();
            lines.push(format!("{name} {target_name} {}", t.join(" ")));
        }
    }
    dpr_gpu::io::write_atomic(&out.join("pairs.txt"), (lines.join("\n") + "\n").as_bytes())?;
    println!("wrote {} pairs to {}", lines.len() - 1, out.join("pairs.txt").display());
    Ok(())
}

fn stem(p: &Path) -> String {
    p.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default()
}

/// Unit direction (source frame) from the centroid of the source points within `distance` of the target under
/// `target_from_source` to the centroid of the others.
fn away_from_shared(source: &PointCloud, target: &PointCloud, t: &Matrix4<f64>, distance: f64) -> [f64; 3] {
    let tree = PreparedFragment::from_points(target.points.iter().map(|p| p.map(f64::from)).collect(), distance);
    let mut sums = [[0.0f64; 4]; 2];
    for p in &source.points {
        let q = dpr_gpu::pose::transform_point(t, *p).map(f64::from);
        let shared = usize::from(tree.is_within(&q, distance));
        let s = &mut sums[shared];
        for k in 0..3 {
            s[k] += f64::from(p[k]);
        }
        s[3] += 1.0;
    }
    let c = |s: &[f64; 4]| [0, 1, 2].map(|k| s[k] / s[3].max(1.0));
    let (own, shared) = (c(&sums[0]), c(&sums[1]));
    let d = [0, 1, 2].map(|k| own[k] - shared[k]);
    let n = d.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-12);
    d.map(|v| v / n)
}

/// The source cut to the points with (p . direction) >= s, s chosen by bisection so the overlap is `goal`
/// (within 0.01); the whole source when it is below the goal already; `None` when no cut reaches it.
fn cut_to(
    source: &PointCloud,
    direction: [f64; 3],
    goal: f64,
    full: f64,
    overlap_of: &dyn Fn(&PointCloud) -> f64,
) -> Option<(PointCloud, f64)> {
    if full <= goal {
        return Some((source.clone(), full));
    }
    let along: Vec<f64> = source.points.iter().map(|p| (0..3).map(|k| f64::from(p[k]) * direction[k]).sum()).collect();
    let keep = |s: f64| {
        PointCloud::from_points(source.points.iter().zip(&along).filter(|(_, a)| **a >= s).map(|(p, _)| *p).collect())
    };
    let (mut lo, mut hi) = along.iter().fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        let cut = keep(mid);
        let overlap = overlap_of(&cut);
        if (overlap - goal).abs() < 0.01 && cut.len() >= 100 {
            return Some((cut, overlap));
        }
        // A higher cut keeps less of the shared part.
        if overlap > goal { lo = mid } else { hi = mid }
    }
    None
}
