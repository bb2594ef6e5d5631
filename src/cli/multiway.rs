//! `dpr-gpu multiway`: register a collection of scans into one trajectory (see [`crate::multiway`]), resumable.
//!
//! The output folder holds `trajectory.log`, `edges.json`, `scans.txt` (scan k's path per line), optionally
//! `fused.ply`, and `pairs/`: one `<i>_<j>.json` per finished pair and one `pooled_<k>.json` per pooled codeword,
//! each written atomically with a key of the settings and the scan files' size and modification time. A rerun
//! reuses every file whose key matches, so an interrupted run resumes where it stopped.

use crate::cli::register::{RegisterOptions, parse_estimator, unshifted};
use crate::io::{LoadOptions, OriginShift, SUPPORTED_EXTENSIONS, check_outputs, read_cloud, write_atomic, write_cloud};
use crate::multiway::{
    MultiwaySettings, PairResult, PairSelection, PairStore, Progress, Trajectory, fuse, multiway_detailed,
};
use crate::pipeline::Registrar;
use anyhow::{Context, bail};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Arguments of `dpr-gpu multiway`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// A folder of scans (its PLY, PCD, XYZ and PTS files in natural name order, so cloud_bin_2 comes before
    /// cloud_bin_10; .txt files are skipped as they are usually metadata such as pairs.txt), or a list file with
    /// one scan path per line (any supported format; relative to the list's folder; `#` comments).
    pub input: PathBuf,
    /// Output folder (created if missing; a partial one from an interrupted run is resumed).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Registration options.
    #[command(flatten)]
    pub options: RegisterOptions,
    /// Candidate pairs: `all`, or `consecutive+retrieval` (consecutive scans plus the --retrieval-k most similar
    /// scans of each scan by pooled codewords).
    #[arg(long, default_value = "consecutive+retrieval")]
    pub pairs: String,
    /// Scans retrieved per scan with --pairs consecutive+retrieval.
    #[arg(long, default_value_t = 5, value_name = "K")]
    pub retrieval_k: usize,
    /// Register at most N pairs (consecutive pairs first, then the most similar).
    #[arg(long, value_name = "N")]
    pub max_pairs: Option<usize>,
    /// Also write DIR/fused.ply: every scan in the world frame, merged and downsampled to this voxel size.
    #[arg(long, value_name = "VOXEL")]
    pub fused: Option<f32>,
    /// Correspondence distance of the edge information matrices (default: the inlier threshold).
    #[arg(long)]
    pub information_distance: Option<f64>,
    /// Line-process preference: larger keeps more loop closures (Open3D's preference_loop_closure).
    #[arg(long, default_value_t = 1.0)]
    pub loop_preference: f64,
    /// Also write the pose graph as g2o (optimised poses, the edges in the graph and their final weights as
    /// comments), in the scans' registration frames, for GTSAM or g2o (`dpr-gpu pose-graph` reads it).
    #[arg(long, value_name = "GRAPH.g2o")]
    pub graph_out: Option<PathBuf>,
}

/// Orders names with digit runs compared as numbers (`cloud_bin_2` < `cloud_bin_10`).
pub fn natural_cmp(a: &str, b: &str) -> std::cmp::Ordering {
    fn runs(s: &str) -> Vec<(bool, &str)> {
        let mut out = Vec::new();
        let mut start = 0;
        let bytes = s.as_bytes();
        for k in 1..=bytes.len() {
            if k == bytes.len() || bytes[k].is_ascii_digit() != bytes[start].is_ascii_digit() {
                out.push((bytes[start].is_ascii_digit(), &s[start..k]));
                start = k;
            }
        }
        out
    }
    let (ra, rb) = (runs(a), runs(b));
    for ((da, sa), (db, sb)) in ra.iter().zip(&rb) {
        let ord = if *da && *db {
            let (ta, tb) = (sa.trim_start_matches('0'), sb.trim_start_matches('0'));
            ta.len().cmp(&tb.len()).then(ta.cmp(tb))
        } else {
            sa.cmp(sb)
        };
        if ord.is_ne() {
            return ord;
        }
    }
    ra.len().cmp(&rb.len()).then(a.cmp(b))
}

/// The scan paths of INPUT: a folder's cloud files in natural order, or the lines of a list file.
pub fn scan_paths(input: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let paths = if input.is_dir() {
        let mut files: Vec<PathBuf> = std::fs::read_dir(input)
            .with_context(|| format!("reading folder {}", input.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| {
                p.is_file()
                    && p.extension()
                        .and_then(|e| e.to_str())
                        .map(str::to_ascii_lowercase)
                        .is_some_and(|e| e != "txt" && SUPPORTED_EXTENSIONS.contains(&e.as_str()))
            })
            .collect();
        files.sort_by(|a, b| natural_cmp(&a.to_string_lossy(), &b.to_string_lossy()));
        files
    } else {
        let text = std::fs::read_to_string(input).with_context(|| format!("reading scan list {}", input.display()))?;
        let base = input.parent().unwrap_or(Path::new("."));
        text.lines().map(str::trim).filter(|l| !l.is_empty() && !l.starts_with('#')).map(|l| base.join(l)).collect()
    };
    if paths.len() < 2 {
        bail!("{}: multiway registration needs at least 2 scans, found {}", input.display(), paths.len());
    }
    Ok(paths)
}

/// Size and modification time of a file, for the resume keys.
fn file_stamp(path: &Path) -> String {
    match std::fs::metadata(path) {
        Ok(m) => {
            let modified = m.modified().ok().and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok());
            format!("{}:{}:{}", path.display(), m.len(), modified.map_or(0, |d| d.as_nanos()))
        }
        Err(_) => format!("{}:missing", path.display()),
    }
}

/// A stored file: the key it was computed under and the value.
#[derive(Serialize, Deserialize)]
struct Stored<T> {
    key: String,
    value: T,
}

/// The resume state in DIR/pairs.
struct FolderStore {
    dir: PathBuf,
    /// Key of everything but the scans: settings, weights, information and version.
    base: String,
    /// Key of each scan file.
    scans: Vec<String>,
}

impl FolderStore {
    fn read<T: for<'de> Deserialize<'de>>(&self, name: &str, key: &str) -> Option<T> {
        let text = std::fs::read_to_string(self.dir.join(name)).ok()?;
        let stored: Stored<T> = serde_json::from_str(&text).ok()?;
        (stored.key == key).then_some(stored.value)
    }

    fn write<T: Serialize>(&self, name: &str, key: String, value: &T) -> crate::Result<()> {
        let text = serde_json::to_string(&Stored { key, value })
            .map_err(|e| crate::Error::invalid(format!("cannot serialise {name}: {e}")))?;
        crate::io::write_atomic(&self.dir.join(name), text.as_bytes())
    }

    fn pair_key(&self, i: usize, j: usize) -> String {
        format!("{}|{}|{}", self.base, self.scans[i], self.scans[j])
    }
}

impl PairStore for FolderStore {
    fn load_pair(&mut self, i: usize, j: usize) -> crate::Result<Option<PairResult>> {
        Ok(self.read(&format!("{i}_{j}.json"), &self.pair_key(i, j)))
    }
    fn save_pair(&mut self, r: &PairResult) -> crate::Result<()> {
        self.write(&format!("{}_{}.json", r.i, r.j), self.pair_key(r.i, r.j), r)
    }
    fn load_pooled(&mut self, k: usize) -> crate::Result<Option<Vec<f32>>> {
        Ok(self.read(&format!("pooled_{k}.json"), &format!("{}|{}", self.base, self.scans[k])))
    }
    fn save_pooled(&mut self, k: usize, pooled: &[f32]) -> crate::Result<()> {
        self.write(&format!("pooled_{k}.json"), format!("{}|{}", self.base, self.scans[k]), &pooled)
    }
}

/// A progress bar on stderr when it is a terminal (hidden when piped).
fn progress_bar(scans: usize) -> indicatif::ProgressBar {
    use std::io::IsTerminal;
    if !std::io::stderr().is_terminal() {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(scans as u64);
    let style = indicatif::ProgressStyle::with_template("{spinner} {elapsed_precise} [{bar:30}] {pos}/{len} {msg}")
        .expect("valid template");
    bar.set_style(style.progress_chars("=> "));
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    bar.set_message("describing scans");
    bar
}

/// The edges file: every registered pair and its fate in the pose graph.
#[derive(Serialize)]
struct EdgesFile<'a> {
    scans: usize,
    line_process_weight: f64,
    connected: &'a [bool],
    edges: &'a [crate::multiway::EdgeRecord],
}

/// Runs `dpr-gpu multiway`.
pub fn run(args: Args) -> anyhow::Result<()> {
    let registration = args.options.to_settings()?;
    parse_estimator(&args.options.estimator)?;
    let pairs = match args.pairs.as_str() {
        "all" => PairSelection::All,
        "consecutive+retrieval" => PairSelection::ConsecutiveAndRetrieval { k: args.retrieval_k },
        other => bail!("unknown --pairs '{other}' (expected all or consecutive+retrieval)"),
    };
    let settings = MultiwaySettings {
        registration: registration.clone(),
        pairs,
        max_pairs: args.max_pairs,
        information_distance: args.information_distance,
        preference_loop_closure: args.loop_preference,
        ..MultiwaySettings::default()
    };
    let paths = scan_paths(&args.input)?;
    if args.out.is_file() {
        bail!("--out {} is a file; it must be a folder", args.out.display());
    }
    if args.input.is_dir() && crate::io::file_id(&args.input) == crate::io::file_id(&args.out) {
        bail!("--out {} is the input folder; write the results to a folder of their own", args.out.display());
    }
    std::fs::create_dir_all(args.out.join("pairs")).with_context(|| format!("creating {}", args.out.display()))?;
    let (trajectory_path, edges_path, scans_path, fused_path) = (
        args.out.join("trajectory.log"),
        args.out.join("edges.json"),
        args.out.join("scans.txt"),
        args.out.join("fused.ply"),
    );
    let weights = args.options.weights_path()?;
    let mut inputs: Vec<&Path> = paths.iter().map(PathBuf::as_path).collect();
    inputs.extend(weights.as_deref());
    let mut outputs: Vec<(&str, &Path)> =
        vec![("--out", &trajectory_path), ("--out", &edges_path), ("--out", &scans_path)];
    if args.fused.is_some() {
        outputs.push(("--fused", &fused_path));
    }
    outputs.extend(args.graph_out.as_deref().map(|p| ("--graph-out", p)));
    check_outputs(&inputs, &outputs)?;
    if let Some(v) = args.fused
        && !(v.is_finite() && v > 0.0)
    {
        bail!("--fused must be a positive voxel size, got {v}");
    }

    // Georeferenced scans: all shifted by one origin (from the first scan) before the f32 conversion.
    let load = args.options.load_options()?;
    let mut scans = Vec::with_capacity(paths.len());
    let mut origin = [0i64; 3];
    for (k, path) in paths.iter().enumerate() {
        let shift = if k == 0 { OriginShift::Auto } else { OriginShift::At(origin) };
        let (cloud, report) = read_cloud(path, &LoadOptions { origin: shift, ..load })?;
        if k == 0 {
            origin = report.origin;
        }
        scans.push(cloud);
    }

    let base = format!(
        "v1|{}|{}|{:?}|{:?}|{}",
        serde_json::to_string(&registration)?,
        weights.as_deref().map_or_else(|| "built-in".to_string(), file_stamp),
        settings.information_distance,
        settings.max_information_points,
        origin.map(|c| c.to_string()).join(",")
    );
    let mut store =
        FolderStore { dir: args.out.join("pairs"), base, scans: paths.iter().map(|p| file_stamp(p)).collect() };
    let registrar = Registrar::new(&registration)?;
    let bar = progress_bar(paths.len());
    let started = std::time::Instant::now();
    let outcome = {
        let bar = bar.clone();
        let report = move |p: Progress| match p {
            Progress::Described { k } => {
                bar.inc(1);
                bar.set_message(format!("described scan {k}"));
            }
            Progress::Selected { pairs } => {
                bar.set_position(0);
                bar.set_length(pairs as u64);
                bar.set_message("registering pairs");
            }
            Progress::Pair { i, j, reused } => {
                bar.inc(1);
                bar.set_message(format!("pair ({i}, {j}){}", if reused { " (reused)" } else { "" }));
            }
        };
        multiway_detailed(&registrar, &scans, &settings, &mut store, &report)
    };
    bar.finish_and_clear();
    let result = outcome?;

    let trajectory = Trajectory {
        world_from_scan: result
            .trajectory
            .world_from_scan
            .iter()
            .map(|w| crate::pose::unshift_pose(w, origin))
            .collect(),
    };
    trajectory.write_log(&trajectory_path)?;
    if let Some(path) = &args.graph_out {
        result.write_g2o(path)?;
    }
    let edges = EdgesFile {
        scans: paths.len(),
        line_process_weight: result.line_process_weight,
        connected: &result.connected,
        edges: &result.edges,
    };
    write_atomic(&edges_path, format!("{}\n", serde_json::to_string_pretty(&edges)?).as_bytes())?;
    let list: String = paths.iter().map(|p| format!("{}\n", p.display())).collect();
    write_atomic(&scans_path, list.as_bytes())?;
    if let Some(voxel) = args.fused {
        let fused = fuse(&scans, &result.trajectory, voxel)?;
        write_cloud(&fused_path, &unshifted(fused, origin))?;
    }

    let loops: Vec<_> = result.edges.iter().filter(|e| e.kind == crate::multiway::EdgeKind::Loop).collect();
    let odometry_trusted =
        result.edges.iter().filter(|e| e.kind == crate::multiway::EdgeKind::Odometry && e.pair.trusted).count();
    println!("scans: {} ({} described, {} pairs reused)", paths.len(), result.described, result.reused_pairs);
    if let Some(scale) = &result.scale {
        println!("scale: {scale}");
    }
    println!("pairs registered: {} ({} odometry trusted of {})", result.edges.len(), odometry_trusted, paths.len() - 1);
    println!(
        "loop closures: {} candidates, {} trusted, {} kept after the line processes",
        loops.len(),
        loops.iter().filter(|e| e.in_graph).count(),
        loops.iter().filter(|e| e.survived).count()
    );
    let unplaced: Vec<usize> = (0..paths.len()).filter(|&k| !result.connected[k]).collect();
    if !unplaced.is_empty() {
        eprintln!(
            "warning: scans {unplaced:?} are not connected to scan 0 by any surviving edge; their poses are guesses"
        );
    }
    println!("time: {:.1} s", started.elapsed().as_secs_f64());
    println!("wrote {}, {}, {}", trajectory_path.display(), edges_path.display(), scans_path.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::natural_cmp;

    #[test]
    fn natural_order_compares_digit_runs_as_numbers() {
        let mut names = vec!["cloud_bin_10.ply", "cloud_bin_2.ply", "cloud_bin_1.ply", "a.ply", "cloud_bin_02.ply"];
        names.sort_by(|a, b| natural_cmp(a, b));
        assert_eq!(names, ["a.ply", "cloud_bin_1.ply", "cloud_bin_02.ply", "cloud_bin_2.ply", "cloud_bin_10.ply"]);
    }
}
