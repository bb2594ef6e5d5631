//! `dpr-gpu multiway`: register a collection of scans into one trajectory (see [`crate::multiway`]), resumable.
//!
//! The output folder holds `trajectory.log`, `edges.json`, `scans.txt` (scan k's path per line), optionally
//! `fused.ply`, and `pairs/`: one `<i>_<j>.json` per finished pair and one `pooled_<k>.json` per pooled codeword,
//! each written atomically with a key of the settings, the weights' bytes and each scan's path and contents (a
//! hash of the points as loaded). A rerun reuses every file whose key matches, so an interrupted run resumes
//! where it stopped; a scan whose contents changed is registered again.

use crate::cli::register::{RegisterOptions, parse_estimator, unshifted};
use crate::cloud::PointCloud;
use crate::io::{
    LoadOptions, OriginShift, SUPPORTED_EXTENSIONS, check_outputs, check_scan, parse_scan_list, read_cloud, read_list,
    write_atomic, write_cloud,
};
use crate::multiway::{
    MultiwaySettings, PairResult, PairSelection, PairStore, Progress, Trajectory, fuse, multiway_detailed,
};
use crate::pipeline::Registrar;
use anyhow::{Context, bail};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Arguments of `dpr-gpu multiway`.
#[derive(clap::Args, Debug)]
#[command(after_help = "Exit status: 0 when every scan is placed; 3 when some scan is connected to scan 0 by no \
surviving edge (its pose is a guess; every output is still written, and edges.json lists which); 1 on an error.")]
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
        let text = read_list(input, "a scan list (one scan path per line) or a folder of scans")?;
        parse_scan_list(&text, input.parent().unwrap_or(Path::new(".")))
    };
    if paths.len() < 2 {
        bail!("{}: multiway registration needs at least 2 scans, found {}", input.display(), paths.len());
    }
    Ok(paths)
}

/// A 64-bit FNV-1a hash of `bytes`, continuing from `hash` (start from [`FNV_OFFSET`]).
fn fnv1a(mut hash: u64, bytes: &[u8]) -> u64 {
    for &b in bytes {
        hash = (hash ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
    }
    hash
}

/// FNV-1a's offset basis.
const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;

/// The resume key of a loaded scan: its path, point count and a hash of its coordinates and normals as loaded,
/// so a scan whose contents change is registered again even when its size and modification time are kept
/// (`cp -p`, `rsync -t`).
fn scan_key(path: &Path, cloud: &PointCloud) -> String {
    let mut hash = FNV_OFFSET;
    for p in &cloud.points {
        hash = fnv1a(hash, bytemuck::cast_slice(p));
    }
    for n in cloud.normals.iter().flatten() {
        hash = fnv1a(hash, bytemuck::cast_slice(n));
    }
    format!("{}:{}:{hash:016x}", path.display(), cloud.len())
}

/// The resume key of the weights: their path and a hash of their bytes ("built-in" for the shipped ones).
fn weights_key(weights: Option<&Path>) -> anyhow::Result<String> {
    let Some(path) = weights else { return Ok("built-in".into()) };
    let bytes = crate::io::read_file_bounded(path, 1 << 30)?;
    Ok(format!("{}:{:016x}", path.display(), fnv1a(FNV_OFFSET, &bytes)))
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

/// Most scans retrieved per scan (`--retrieval-k`).
pub const MAX_RETRIEVAL_K: usize = 1000;

/// The multiway settings the arguments describe; every numeric flag is checked here, before any work.
fn multiway_settings(args: &Args) -> anyhow::Result<MultiwaySettings> {
    let registration = args.options.to_settings()?;
    parse_estimator(&args.options.estimator)?;
    let pairs = match args.pairs.as_str() {
        "all" => PairSelection::All,
        "consecutive+retrieval" => PairSelection::ConsecutiveAndRetrieval { k: args.retrieval_k },
        other => bail!("unknown --pairs '{other}' (expected all or consecutive+retrieval)"),
    };
    if !(1..=MAX_RETRIEVAL_K).contains(&args.retrieval_k) {
        bail!("--retrieval-k must be 1..={MAX_RETRIEVAL_K}, got {}", args.retrieval_k);
    }
    if args.max_pairs == Some(0) {
        bail!("--max-pairs must be at least 1 (no pair registered places no scan)");
    }
    if let Some(v) = args.fused
        && !(v.is_finite() && v > 0.0)
    {
        bail!("--fused must be a positive voxel size, got {v}");
    }
    if let Some(d) = args.information_distance
        && !(d.is_finite() && d > 0.0)
    {
        bail!("--information-distance must be a positive distance, got {d}");
    }
    if !(args.loop_preference.is_finite() && args.loop_preference > 0.0) {
        bail!("--loop-preference must be positive, got {}", args.loop_preference);
    }
    Ok(MultiwaySettings {
        registration,
        pairs,
        max_pairs: args.max_pairs,
        information_distance: args.information_distance,
        preference_loop_closure: args.loop_preference,
        ..MultiwaySettings::default()
    })
}

/// The files multiway writes into DIR.
struct OutputFiles {
    trajectory: PathBuf,
    edges: PathBuf,
    scans: PathBuf,
    fused: PathBuf,
}

/// Creates the output folder after checking that no output lands on an input: the scans, the weights, and the
/// scan list itself (compared by file identity), nor on the input folder.
fn prepare_outputs(args: &Args, paths: &[PathBuf], weights: Option<&Path>) -> anyhow::Result<OutputFiles> {
    if args.out.is_file() {
        bail!("--out {} is a file; it must be a folder", args.out.display());
    }
    if args.input.is_dir() && crate::io::file_id(&args.input) == crate::io::file_id(&args.out) {
        bail!("--out {} is the input folder; write the results to a folder of their own", args.out.display());
    }
    std::fs::create_dir_all(args.out.join("pairs")).with_context(|| format!("creating {}", args.out.display()))?;
    let files = OutputFiles {
        trajectory: args.out.join("trajectory.log"),
        edges: args.out.join("edges.json"),
        scans: args.out.join("scans.txt"),
        fused: args.out.join("fused.ply"),
    };
    let mut inputs: Vec<&Path> = paths.iter().map(PathBuf::as_path).collect();
    inputs.extend(weights);
    if args.input.is_file() {
        inputs.push(&args.input);
    }
    let mut outputs: Vec<(&str, &Path)> =
        vec![("--out", &files.trajectory), ("--out", &files.edges), ("--out", &files.scans)];
    if args.fused.is_some() {
        outputs.push(("--fused", &files.fused));
    }
    outputs.extend(args.graph_out.as_deref().map(|p| ("--graph-out", p)));
    check_outputs(&inputs, &outputs)?;
    Ok(files)
}

/// Loads every scan, all shifted by one origin (from the first scan; georeferenced scans) before the f32
/// conversion; each is checked ([`check_scan`]) naming its file.
fn load_scans(paths: &[PathBuf], load: &LoadOptions) -> anyhow::Result<(Vec<PointCloud>, [i64; 3])> {
    let mut scans = Vec::with_capacity(paths.len());
    let mut origin = [0i64; 3];
    for (k, path) in paths.iter().enumerate() {
        let shift = if k == 0 { OriginShift::Auto } else { OriginShift::At(origin) };
        let (cloud, report) = read_cloud(path, &LoadOptions { origin: shift, ..*load })?;
        check_scan(path, &cloud, &report, crate::pipeline::MIN_POINTS)?;
        if k == 0 {
            origin = report.origin;
        }
        scans.push(cloud);
    }
    Ok((scans, origin))
}

/// Refuses a `--fused` voxel so small that the scans' coordinates (in their own frames; the world frame is the
/// first scan's) lie beyond the voxel grid's 2^30 cells, before any pair is registered.
fn check_fused_voxel(voxel: f32, scans: &[PointCloud]) -> anyhow::Result<()> {
    let farthest = scans.iter().flat_map(|c| &c.points).flatten().fold(0.0f32, |m, v| m.max(v.abs()));
    if f64::from(farthest) / f64::from(voxel) >= f64::from(crate::cpu::cell_bounds::CELL_COORD_LIMIT) {
        bail!(
            "--fused {voxel}: the scans reach {farthest} units from the origin, more than 2^30 voxels of that size; \
             give a larger voxel size"
        );
    }
    Ok(())
}

/// Registers the scans with a progress bar on stderr, reusing what `store` holds.
fn register_scans(
    registrar: &Registrar,
    scans: &[PointCloud],
    settings: &MultiwaySettings,
    store: &mut FolderStore,
) -> crate::Result<crate::multiway::MultiwayResult> {
    let bar = progress_bar(scans.len());
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
        multiway_detailed(registrar, scans, settings, store, &report)
    };
    bar.finish_and_clear();
    outcome
}

/// Prints the counts of scans, pairs and loop closures (stdout) and warns about unplaced scans (stderr).
fn print_summary(result: &crate::multiway::MultiwayResult, scans: usize) {
    let loops: Vec<_> = result.edges.iter().filter(|e| e.kind == crate::multiway::EdgeKind::Loop).collect();
    let odometry_trusted =
        result.edges.iter().filter(|e| e.kind == crate::multiway::EdgeKind::Odometry && e.pair.trusted).count();
    println!("scans: {} ({} described, {} pairs reused)", scans, result.described, result.reused_pairs);
    if let Some(scale) = &result.scale {
        println!("scale: {scale}");
    }
    println!("pairs registered: {} ({} odometry trusted of {})", result.edges.len(), odometry_trusted, scans - 1);
    println!(
        "loop closures: {} candidates, {} trusted, {} kept after the line processes",
        loops.len(),
        loops.iter().filter(|e| e.in_graph).count(),
        loops.iter().filter(|e| e.survived).count()
    );
    let unplaced: Vec<usize> = (0..scans).filter(|&k| !result.connected[k]).collect();
    if !unplaced.is_empty() {
        eprintln!(
            "warning: scans {unplaced:?} are not connected to scan 0 by any surviving edge; their poses are guesses \
             (exit status {})",
            crate::cli::register::EXIT_UNTRUSTED
        );
    }
}

/// Runs `dpr-gpu multiway`; returns whether every scan was placed (connected to scan 0 by surviving edges).
pub fn run(args: Args) -> anyhow::Result<bool> {
    let settings = multiway_settings(&args)?;
    let registration = settings.registration.clone();
    let paths = scan_paths(&args.input)?;
    let weights = args.options.weights_path()?;
    let files = prepare_outputs(&args, &paths, weights.as_deref())?;
    let (trajectory_path, edges_path, scans_path, fused_path) =
        (&files.trajectory, &files.edges, &files.scans, &files.fused);
    let (scans, origin) = load_scans(&paths, &args.options.load_options()?)?;
    if let Some(voxel) = args.fused {
        check_fused_voxel(voxel, &scans)?;
    }
    let base = format!(
        "v2|{}|{}|{:?}|{:?}|{}",
        serde_json::to_string(&registration)?,
        weights_key(weights.as_deref())?,
        settings.information_distance,
        settings.max_information_points,
        origin.map(|c| c.to_string()).join(",")
    );
    let keys = paths.iter().zip(&scans).map(|(p, c)| scan_key(p, c)).collect();
    let mut store = FolderStore { dir: args.out.join("pairs"), base, scans: keys };
    let registrar = Registrar::new(&registration)?;
    let started = std::time::Instant::now();
    let result = register_scans(&registrar, &scans, &settings, &mut store)?;

    let fused = match args.fused {
        Some(voxel) => Some(fuse(&scans, &result.trajectory, voxel).with_context(|| format!("--fused {voxel}"))?),
        None => None,
    };
    let trajectory = Trajectory {
        world_from_scan: result
            .trajectory
            .world_from_scan
            .iter()
            .map(|w| crate::pose::unshift_pose(w, origin))
            .collect(),
    };
    trajectory.write_log(trajectory_path)?;
    if let Some(path) = &args.graph_out {
        result.write_g2o(path)?;
    }
    let edges = EdgesFile {
        scans: paths.len(),
        line_process_weight: result.line_process_weight,
        connected: &result.connected,
        edges: &result.edges,
    };
    write_atomic(edges_path, format!("{}\n", serde_json::to_string_pretty(&edges)?).as_bytes())?;
    let list: String = paths.iter().map(|p| format!("{}\n", p.display())).collect();
    write_atomic(scans_path, list.as_bytes())?;
    if let Some(fused) = fused {
        write_cloud(fused_path, &unshifted(fused, origin))?;
    }

    print_summary(&result, paths.len());
    println!("time: {:.1} s", started.elapsed().as_secs_f64());
    let mut written = vec![trajectory_path.display(), edges_path.display(), scans_path.display()];
    if args.fused.is_some() {
        written.push(fused_path.display());
    }
    println!("wrote {}", written.iter().map(|p| p.to_string()).collect::<Vec<_>>().join(", "));
    Ok(result.connected.iter().all(|&c| c))
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
