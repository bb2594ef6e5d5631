//! `dpr-gpu eval-trajectory`: a multiway trajectory against ground truth (see [`crate::multiway::evaluate`]).

use crate::eval::gtlog::{LogRecord, read_info, read_log};
use crate::multiway::evaluate::{LoopClosureCounts, is_correct, pairwise_errors, trajectory_errors};
use crate::multiway::{EdgeKind, EdgeRecord, Trajectory};
use anyhow::{Context, bail};
use nalgebra::{Matrix4, Matrix6};
use serde::Deserialize;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Arguments of `dpr-gpu eval-trajectory`.
#[derive(clap::Args, Debug)]
#[command(after_help = "ATE: RMS distance of the scan origins from the true ones after the best rigid alignment \
(Kabsch, no scale). A loop closure is true when its estimate meets the 3DMatch criterion against the true relative \
pose (e^T Sigma e / Sigma_11 <= 0.04 with Sigma from gt.info beside the ground truth, else from the edge's own \
information matrix; without either: rotation error <= 15 deg and translation error <= 0.3), and kept when it \
survived the line processes.")]
pub struct Args {
    /// The trajectory (.log with `k k N` records), e.g. DIR/trajectory.log of `multiway`.
    pub trajectory: PathBuf,
    /// Ground truth: synth's poses.txt or its scene folder, a trajectory .log, or a pairwise gt.log (relative
    /// poses only; gt.info beside any of them is used when present).
    pub ground_truth: PathBuf,
    /// The multiway edges file [default: edges.json beside the trajectory, when present].
    #[arg(long)]
    pub edges: Option<PathBuf>,
    /// Ground-truth fragment number of each trajectory scan, comma-separated [default: K of cloud_bin_K names in
    /// scans.txt beside the trajectory, else 0, 1, 2, ...].
    #[arg(long, value_delimiter = ',')]
    pub ids: Option<Vec<usize>>,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

/// What GROUND_TRUTH held.
enum Truth {
    /// Absolute poses, indexed by fragment number.
    Poses(Trajectory),
    /// Relative poses of some pairs.
    Pairs(Vec<LogRecord>),
}

fn load_truth(path: &Path) -> anyhow::Result<(Truth, Option<PathBuf>)> {
    let file = if path.is_dir() { path.join("poses.txt") } else { path.to_path_buf() };
    if !file.is_file() {
        bail!("{}: no such ground-truth file (expected poses.txt, a trajectory .log or a gt.log)", file.display());
    }
    let info = file.parent().map(|d| d.join("gt.info")).filter(|p| p.is_file());
    let is_txt = file.extension().is_some_and(|e| e.eq_ignore_ascii_case("txt"));
    if is_txt {
        return Ok((Truth::Poses(Trajectory::read_poses(&file)?), info));
    }
    let records = read_log(&file)?;
    if !records.is_empty() && records.iter().all(|r| r.i == r.j) {
        return Ok((Truth::Poses(Trajectory::from_log_records(&records, &file)?), info));
    }
    Ok((Truth::Pairs(records), info))
}

/// `K` of a `cloud_bin_K.*` file name.
fn cloud_bin_number(path: &str) -> Option<usize> {
    let name = Path::new(path.trim()).file_stem()?.to_str()?;
    name.strip_prefix("cloud_bin_")?.parse().ok()
}

/// The ground-truth fragment number of each of the `n` trajectory scans when `--ids` is not given, from the
/// `scans.txt` beside the trajectory: K of every `cloud_bin_K` name; the scans' order (0, 1, 2, ...) when
/// there is no such file or none of its names has that form. A list that names some scans `cloud_bin_K` and
/// others not, or another number of scans than the trajectory, is refused: the scans' order would silently
/// pair them with the wrong poses.
fn default_ids(trajectory: &Path, n: usize) -> anyhow::Result<Vec<usize>> {
    let scans = trajectory.parent().unwrap_or(Path::new(".")).join("scans.txt");
    if !scans.is_file() {
        return Ok((0..n).collect());
    }
    let text = crate::io::read_list(&scans, "a scan list")?;
    let names: Vec<(usize, &str)> =
        text.lines().enumerate().map(|(k, l)| (k + 1, l.trim())).filter(|(_, l)| !l.is_empty()).collect();
    let ids: Vec<Option<usize>> = names.iter().map(|(_, name)| cloud_bin_number(name)).collect();
    if ids.iter().all(Option::is_none) {
        return Ok((0..n).collect());
    }
    if let Some(((line, name), _)) = names.iter().zip(&ids).find(|(_, id)| id.is_none()) {
        bail!(
            "{}: line {line}: `{name}` is not a cloud_bin_K name while other scans are, so the ground-truth \
             fragment of each scan is unknown; give them with --ids",
            scans.display()
        );
    }
    if ids.len() != n {
        bail!(
            "{}: lists {} scans but the trajectory has {n}; give the fragment ids with --ids",
            scans.display(),
            ids.len()
        );
    }
    Ok(ids.into_iter().flatten().collect())
}

#[derive(Deserialize)]
struct EdgesFile {
    edges: Vec<EdgeRecord>,
}

/// The multiway edges file `--edges`, else edges.json beside the trajectory when present (no edges without one).
fn read_edges(args: &Args, n: usize) -> anyhow::Result<Vec<EdgeRecord>> {
    let edges_path = args.edges.clone().or_else(|| {
        let p = args.trajectory.parent().unwrap_or(Path::new(".")).join("edges.json");
        p.is_file().then_some(p)
    });
    let Some(p) = &edges_path else { return Ok(Vec::new()) };
    let text = std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
    let edges = serde_json::from_str::<EdgesFile>(&text)
        .with_context(|| format!("{}: not a multiway edges file", p.display()))?
        .edges;
    if let Some(e) = edges.iter().find(|e| e.pair.i >= n || e.pair.j >= n) {
        bail!("{}: edge ({}, {}) names a scan beyond the trajectory's {n}", p.display(), e.pair.i, e.pair.j);
    }
    Ok(edges)
}

/// The true relative pose x_i = T x_j of trajectory scans (a, b), when known.
type TrueRelative = Box<dyn Fn(usize, usize) -> Option<Matrix4<f64>>>;

/// Scores the trajectory against the truth into `report` ("trajectory" or "pairs"); returns the true relative
/// pose of any two trajectory scans, where the truth knows it.
fn score_poses(
    trajectory: &Trajectory,
    truth: &Truth,
    ids: &[usize],
    info_of: &dyn Fn(usize, usize) -> Option<Matrix6<f64>>,
    report: &mut serde_json::Map<String, serde_json::Value>,
) -> anyhow::Result<TrueRelative> {
    match truth {
        Truth::Poses(gt) => {
            if let Some(&bad) = ids.iter().find(|&&id| id >= gt.len()) {
                bail!("fragment {bad} is not in the ground truth ({} poses)", gt.len());
            }
            let sub = Trajectory { world_from_scan: ids.iter().map(|&id| gt.world_from_scan[id]).collect() };
            let errors = trajectory_errors(trajectory, &sub)?;
            report.insert("trajectory".into(), serde_json::to_value(&errors)?);
            Ok(Box::new(move |a, b| Some(sub.i_from_j(a, b))))
        }
        Truth::Pairs(records) => {
            let pairs = pairwise_errors(trajectory, records, ids, info_of);
            report.insert("pairs".into(), serde_json::to_value(&pairs)?);
            let by_pair: HashMap<(usize, usize), Matrix4<f64>> =
                records.iter().map(|r| ((r.i, r.j), r.i_from_j)).collect();
            let ids = ids.to_vec();
            Ok(Box::new(move |a, b| by_pair.get(&(ids[a], ids[b])).copied()))
        }
    }
}

/// Counts the loop closures among `edges` that are true and kept; returns the counts and the number of loop
/// closures without ground truth.
fn count_loop_closures(
    edges: &[EdgeRecord],
    true_relative: &TrueRelative,
    ids: &[usize],
    info_of: &dyn Fn(usize, usize) -> Option<Matrix6<f64>>,
) -> (LoopClosureCounts, usize) {
    let mut counts = LoopClosureCounts::default();
    let mut unknown = 0;
    for e in edges.iter().filter(|e| e.kind == EdgeKind::Loop) {
        let Some(gt) = true_relative(e.pair.i, e.pair.j) else {
            unknown += 1;
            continue;
        };
        let info = info_of(ids[e.pair.i], ids[e.pair.j]).unwrap_or_else(|| e.pair.information_matrix());
        let (correct, _) = is_correct(&e.pair.transform(), &gt, Some(&info));
        counts.add(correct, e.survived);
    }
    (counts, unknown)
}

/// Runs `dpr-gpu eval-trajectory`.
pub fn run(args: Args) -> anyhow::Result<()> {
    let trajectory = Trajectory::read_log(&args.trajectory)?;
    let n = trajectory.len();
    let ids = match args.ids.clone() {
        Some(ids) => ids,
        None => default_ids(&args.trajectory, n)?,
    };
    if ids.len() != n {
        bail!("--ids names {} fragments but the trajectory has {n} scans", ids.len());
    }
    let (truth, info_path) = load_truth(&args.ground_truth)?;
    let infos: HashMap<(usize, usize), Matrix6<f64>> = match &info_path {
        Some(p) => read_info(p)?.into_iter().map(|r| ((r.i, r.j), r.information)).collect(),
        None => HashMap::new(),
    };
    let info_of = |i: usize, j: usize| infos.get(&(i, j)).copied();
    let edges = read_edges(&args, n)?;
    let mut report = serde_json::Map::new();
    let true_relative = score_poses(&trajectory, &truth, &ids, &info_of, &mut report)?;
    let (counts, unknown) = count_loop_closures(&edges, &true_relative, &ids, &info_of);
    if !edges.is_empty() {
        report.insert("loop_closures".into(), serde_json::to_value(counts)?);
        report.insert("loop_closures_without_truth".into(), unknown.into());
    }
    if args.json {
        println!("{}", serde_json::Value::Object(report));
        return Ok(());
    }
    println!("trajectory: {} ({n} scans)", args.trajectory.display());
    if let Some(t) = report.get("trajectory") {
        let f = |k: &str| t[k].as_f64().unwrap_or(f64::NAN);
        // Distances are in the scans' unit: metres unless the scans say otherwise.
        println!("ATE RMSE: {:.4} m (max {:.4} m) after {} alignment", f("ate_rmse"), f("ate_max"), t["alignment"]);
        println!("rotation error: mean {:.3} deg, max {:.3} deg", f("rotation_mean_deg"), f("rotation_max_deg"));
    }
    if let Truth::Pairs(records) = &truth {
        let pairs = pairwise_errors(&trajectory, records, &ids, &info_of);
        println!(
            "pairwise poses against {} ({} of {} pairs among these scans):",
            args.ground_truth.display(),
            pairs.len(),
            records.len()
        );
        for p in &pairs {
            println!(
                "  ({:>3}, {:>3})  rotation {:>8.3} deg  translation {:>8.4} m  {}",
                p.i,
                p.j,
                p.rotation_deg,
                p.translation,
                if p.correct { "correct" } else { "WRONG" }
            );
        }
    }
    if !edges.is_empty() {
        println!(
            "loop closures: true kept {}/{}, false kept {}/{}{}",
            counts.true_kept,
            counts.true_total,
            counts.false_kept,
            counts.false_total,
            if unknown > 0 { format!(" ({unknown} without ground truth)") } else { String::new() }
        );
    }
    Ok(())
}
