//! `dpr-gpu register` and the registration options shared with `eval`.

use crate::cloud::PointCloud;
use crate::io::{
    LoadOptions, LoadReport, OriginShift, XyzColumns, ZeroPoints, check_outputs, check_scan, check_writable_cloud_path,
    read_cloud, write_atomic, write_cloud, write_ply_with_colors,
};
use crate::pipeline::{Registrar, weights_file};
use crate::settings::*;
use anyhow::bail;
use nalgebra::Matrix4;
use std::path::{Path, PathBuf};

/// Registration options (shared by `register` and `eval`).
#[derive(clap::Args, Debug, Clone)]
pub struct RegisterOptions {
    /// Weights file (safetensors); default: the shipped weights/default.safetensors.
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// Keypoints per scan.
    #[arg(long, default_value_t = 2500)]
    pub keypoints: usize,
    /// Progressive schedule: describe this many keypoints per scan first and double them, up to --keypoints,
    /// only while the result is not trusted; 0 describes --keypoints at once.
    #[arg(long, default_value_t = crate::settings::DEFAULT_FIRST_KEYPOINTS)]
    pub first_keypoints: usize,
    /// Keypoint selection: random (3DMatch convention) or uniform (farthest-point sampling).
    #[arg(long, default_value = "random")]
    pub keypoint_mode: String,
    /// Patch radius in cloud units [default: chosen from the scans, 0.6 x their median distance from their
    /// centre (median over the scans of the job), printed as `scale:`; the voxel, inlier threshold and ICP
    /// distance follow it].
    #[arg(long)]
    pub radius: Option<f32>,
    /// Voxel size for downsampling before normals and keypoints (cloud units); 0 keeps every point [default:
    /// for a file without normals radius / 24, the density the weights' normals were estimated at in training
    /// (2.5 cm at a 0.60 m radius); a file with normals keeps every point].
    #[arg(long)]
    pub voxel: Option<f32>,
    /// Neighbours for PCA normals (when the file has none).
    #[arg(long, default_value_t = 30)]
    pub normal_k: usize,
    /// Pose estimator: relativenet or ransac (`eval` also takes `both`).
    #[arg(long, default_value = "relativenet")]
    pub estimator: String,
    /// Mutual K nearest neighbours (1..4), or 0 for the "closest" rule.
    #[arg(long, default_value_t = 1)]
    pub mutual: usize,
    /// Inlier threshold in cloud units (default: radius / 6).
    #[arg(long)]
    pub inlier_threshold: Option<f32>,
    /// RANSAC iteration limit.
    #[arg(long, default_value_t = 100_000)]
    pub ransac_iterations: usize,
    /// Seed for every random choice.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Skip the point-to-plane ICP that refines the final pose (on by default, about 0.2 s a pair).
    #[arg(long, conflicts_with_all = ["icp", "icp_distance", "icp_iterations"])]
    pub no_icp: bool,
    /// Refine the final pose with point-to-plane ICP (the default; kept for scripts that ask for it).
    #[arg(long)]
    pub icp: bool,
    /// ICP's largest point-pair distance in cloud units (default: radius / 12).
    #[arg(long)]
    pub icp_distance: Option<f32>,
    /// ICP's iteration limit.
    #[arg(long, default_value_t = DEFAULT_ICP_ITERATIONS)]
    pub icp_iterations: usize,
    /// Drop every point exactly at (0,0,0) when loading [default: dropped when there are two or more, the
    /// no-return pattern of LiDAR and depth sensors; one alone is kept].
    #[arg(long, conflicts_with = "keep_zero")]
    pub drop_zero: bool,
    /// Keep points exactly at (0,0,0) (see --drop-zero).
    #[arg(long)]
    pub keep_zero: bool,
    /// Compute backend: auto (a hardware GPU when there is one, else the CPU; never a software rasteriser
    /// unless DPR_GPU_ALLOW_SOFTWARE=1), gpu (any adapter, software ones included) or cpu.
    #[arg(long, default_value = "auto")]
    pub backend: String,
    /// What the columns of XYZ/TXT/PTS inputs hold, e.g. x,y,z,nx,ny,nz or x,y,z,r,g,b (other names are
    /// ignored); default: columns 4-6 are normals when every row has unit length there, else the file is refused.
    #[arg(long)]
    pub xyz_columns: Option<String>,
    /// Also describe each keypoint with patches FACTOR times the radius (1..8) and match on the codewords of
    /// every radius side by side, each at unit length, this one weighted by WEIGHT (the main radius's by 1);
    /// repeatable (given ones replace the default); `off`: the main radius alone. The pose features stay the
    /// main radius's.
    #[arg(long, value_name = "FACTOR:WEIGHT", default_value = "2:1")]
    pub context_radius: Vec<String>,
    /// Which rounds match on the context radii too: untrusted (only a last round on all keypoints, run when
    /// matching on the main radius alone gave no trusted result), or always.
    #[arg(long, value_name = "WHEN", default_value = "untrusted")]
    pub context_when: String,
    /// How many of the estimator's best distinct poses compete: the one with most inliers stays when the
    /// verdict trusts it, or unless another with at least half its inliers puts clearly fewer points in space
    /// the other scan saw empty from its sensor (each scan's frame origin); 1: most inliers alone (for clouds
    /// in a shared world frame).
    #[arg(long, value_name = "N", default_value_t = crate::settings::DEFAULT_POSE_CANDIDATES)]
    pub pose_candidates: usize,
    /// Verdict: fewest inliers for a trusted result.
    #[arg(long, default_value_t = crate::verdict::VerdictSettings::default().min_inliers)]
    pub min_inliers: usize,
    /// Verdict: smallest inliers / correspondences ratio for a trusted result.
    #[arg(long, default_value_t = crate::verdict::VerdictSettings::default().min_inlier_ratio)]
    pub min_inlier_ratio: f64,
    /// Verdict: smallest spread of the inliers across their main axis, in multiples of the inlier threshold.
    #[arg(long, default_value_t = crate::verdict::VerdictSettings::default().min_spread_over_threshold)]
    pub min_inlier_spread: f64,
    /// Verdict: skip the free-space check (a pose that puts more points in space the other scan saw empty from
    /// its sensor, each scan's frame origin, than the scans' own views leave unexplained is not trusted); for
    /// clouds in a shared world frame.
    #[arg(long)]
    pub no_free_space_check: bool,
}

/// Parses `relativenet` / `ransac`.
pub fn parse_estimator(s: &str) -> anyhow::Result<Estimator> {
    match s {
        "relativenet" => Ok(Estimator::RelativeNet),
        "ransac" => Ok(Estimator::Ransac),
        other => bail!("unknown estimator '{other}' (expected relativenet or ransac)"),
    }
}

/// Parses the `--context-radius` values: `off` alone (no context radius) or `FACTOR:WEIGHT` each.
pub fn parse_context_radii(values: &[String]) -> anyhow::Result<Vec<ContextRadius>> {
    if values.iter().any(|v| v.trim() == "off") {
        if values.len() > 1 {
            bail!("--context-radius off cannot be combined with other context radii");
        }
        return Ok(Vec::new());
    }
    values.iter().map(|v| parse_context_radius(v)).collect()
}

/// Parses `FACTOR:WEIGHT` (a `--context-radius`); the ranges are checked with the settings.
fn parse_context_radius(s: &str) -> anyhow::Result<ContextRadius> {
    let parsed = s.split_once(':').and_then(|(f, w)| Some((f.trim().parse().ok()?, w.trim().parse().ok()?)));
    match parsed {
        Some((factor, weight)) => Ok(ContextRadius { factor, weight }),
        None => bail!("--context-radius expects FACTOR:WEIGHT, e.g. 2:1, got '{s}'"),
    }
}

impl RegisterOptions {
    /// The settings these options describe. The estimator string is parsed only when it is
    /// `relativenet|ransac`; callers that allow more (`eval --estimator both`) handle it themselves.
    pub fn to_settings(&self) -> anyhow::Result<RegistrationSettings> {
        let mut s = RegistrationSettings {
            weights: self.weights.clone(),
            radius: self.radius,
            voxel: self.voxel,
            keypoints: self.keypoints,
            first_keypoints: (self.first_keypoints > 0).then_some(self.first_keypoints),
            normal_neighbors: self.normal_k,
            inlier_threshold: self.inlier_threshold,
            seed: self.seed,
            zero_points: self.zero_points(),
            pose_candidates: self.pose_candidates,
            ..RegistrationSettings::default()
        };
        s.keypoint_mode = match self.keypoint_mode.as_str() {
            "random" => KeypointMode::Random,
            "uniform" => KeypointMode::Uniform,
            other => bail!("unknown keypoint mode '{other}' (expected random or uniform)"),
        };
        s.matching = match self.mutual {
            0 => MatchMode::Closest,
            k @ 1..=4 => MatchMode::Mutual(k),
            k => bail!("--mutual must be 0 (closest) or 1..4, got {k}"),
        };
        if let Ok(e) = parse_estimator(&self.estimator) {
            s.estimator = e;
        }
        s.backend = match self.backend.as_str() {
            "cpu" => BackendKind::Cpu,
            "gpu" => BackendKind::Gpu,
            "auto" => BackendKind::Auto,
            other => bail!("unknown backend '{other}' (expected cpu, gpu or auto)"),
        };
        s.context_radii = parse_context_radii(&self.context_radius)?;
        s.context_when = match self.context_when.as_str() {
            "always" => ContextWhen::Always,
            "untrusted" => ContextWhen::Untrusted,
            other => bail!("unknown --context-when '{other}' (expected always or untrusted)"),
        };
        s.ransac.max_iterations = self.ransac_iterations.max(1);
        s.verdict = crate::verdict::VerdictSettings {
            min_inliers: self.min_inliers,
            min_inlier_ratio: self.min_inlier_ratio,
            min_spread_over_threshold: self.min_inlier_spread,
            free_space_check: !self.no_free_space_check,
            ..crate::verdict::VerdictSettings::default()
        };
        s.icp = (!self.no_icp).then_some(IcpSettings {
            max_correspondence_distance: self.icp_distance,
            max_iterations: self.icp_iterations,
        });
        s.validate()?;
        Ok(s)
    }

    /// The load options these options describe (no origin shift).
    pub fn load_options(&self) -> anyhow::Result<LoadOptions> {
        let xyz_columns = self.xyz_columns.as_deref().map(XyzColumns::parse).transpose()?;
        Ok(LoadOptions { zero_points: self.zero_points(), xyz_columns, ..LoadOptions::default() })
    }

    /// What `--drop-zero` / `--keep-zero` ask for (neither: the default rule).
    fn zero_points(&self) -> ZeroPoints {
        ZeroPoints::from_flag((self.drop_zero || self.keep_zero).then_some(self.drop_zero))
    }

    /// The weights file these options load, if not the built-in weights (for comparing outputs with it).
    pub fn weights_path(&self) -> anyhow::Result<Option<PathBuf>> {
        Ok(weights_file(&self.to_settings()?))
    }
}

/// Arguments of `dpr-gpu register`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The scan to move (PLY, PCD or XYZ).
    pub source: PathBuf,
    /// The scan to align to.
    pub target: PathBuf,
    /// Registration options.
    #[command(flatten)]
    pub options: RegisterOptions,
    /// Write target_from_source (4x4, row-major text) here.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Write the source transformed into the target frame here (binary PLY).
    #[arg(long)]
    pub aligned: Option<PathBuf>,
    /// With --aligned: write the moved source and the target together, coloured (source orange, target
    /// blue; vertex red/green/blue), into that PLY file.
    #[arg(long, requires = "aligned")]
    pub merged: bool,
    /// Write a PNG picture of the two scans before and after registration here (2 rows: before / after; 3
    /// columns: top, front and side views along the target's principal axes; source orange, target blue,
    /// overlap olive).
    #[arg(long, value_name = "OUT.png")]
    pub snapshot: Option<PathBuf>,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

/// `cloud` (in the frame shifted by `-origin`) back in the input frame.
pub(crate) fn unshifted(mut cloud: PointCloud, origin: [i64; 3]) -> PointCloud {
    if origin != [0; 3] {
        let o = origin.map(|c| c as f64);
        for p in &mut cloud.points {
            *p = [0, 1, 2].map(|i| (f64::from(p[i]) + o[i]) as f32);
        }
    }
    cloud
}

/// True for a `.ply` path, or an existing device or FIFO (`/dev/null`), which takes binary PLY.
fn is_ply_or_special(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("ply"))
        || std::fs::metadata(path).is_ok_and(|m| !m.is_file() && !m.is_dir())
}

/// A pipeline error with the file names added, so every error about a cloud names its file: after "source" or
/// "target" when the error names one, else as "registering SOURCE onto TARGET".
fn name_files(e: crate::Error, source: &Path, target: &Path) -> anyhow::Error {
    let text = e.to_string();
    let named = text.replacen("source: ", &format!("source {}: ", source.display()), 1).replacen(
        "target: ",
        &format!("target {}: ", target.display()),
        1,
    );
    if named != text {
        return anyhow::anyhow!(named);
    }
    anyhow::anyhow!("registering {} onto {}: {text}", source.display(), target.display())
}

/// A progress bar over the pipeline's stages on stderr when it is a terminal (hidden when piped).
fn stage_bar() -> indicatif::ProgressBar {
    use std::io::IsTerminal;
    if !std::io::stderr().is_terminal() {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(crate::pipeline::PAIR_STAGES as u64);
    let style = indicatif::ProgressStyle::with_template("{spinner} {elapsed_precise} [{bar:20}] {pos}/{len} {msg}")
        .expect("valid template");
    bar.set_style(style.progress_chars("=> "));
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    bar.set_message("describing the source");
    bar
}

/// Exit status of `register` when the result is not trusted (the pose is still printed).
pub const EXIT_UNTRUSTED: u8 = 3;

/// The two scans as loaded: both in the frame shifted by `-origin` (georeferenced clouds), with what loading
/// dropped.
struct LoadedPair {
    source: PointCloud,
    target: PointCloud,
    source_report: LoadReport,
    target_report: LoadReport,
    /// The origin subtracted from both (from the source; zero unless coordinates are large).
    origin: [i64; 3],
}

impl LoadedPair {
    /// Reads both scans; both are shifted by one origin (from the source) in f64 before the f32 conversion.
    /// The target is read beside the source as if that origin were zero (the usual case) and read again in the
    /// rare case it is not; the source's error comes first.
    fn read(args: &Args, load: LoadOptions) -> anyhow::Result<Self> {
        let target_at = |origin| read_cloud(&args.target, &LoadOptions { origin: OriginShift::At(origin), ..load });
        let (source, target) = rayon::join(
            || read_cloud(&args.source, &LoadOptions { origin: OriginShift::Auto, ..load }),
            || target_at([0; 3]),
        );
        let (source, source_report) = source?;
        let origin = source_report.origin;
        let (target, target_report) = if origin == [0; 3] { target? } else { target_at(origin)? };
        check_scan(&args.source, &source, &source_report, crate::pipeline::MIN_POINTS)?;
        check_scan(&args.target, &target, &target_report, crate::pipeline::MIN_POINTS)?;
        Ok(LoadedPair { source, target, source_report, target_report, origin })
    }

    /// Points dropped while loading, both scans together.
    fn dropped_points(&self) -> usize {
        [&self.source_report, &self.target_report].iter().map(|r| r.dropped_non_finite + r.dropped_zero).sum()
    }
}

/// The line `register` prints for one loaded scan: its points and what was dropped, and why.
fn load_line(name: &str, cloud: &PointCloud, report: &LoadReport) -> String {
    let mut line = format!("{name}: {} points", cloud.len());
    let mut dropped = Vec::new();
    if report.dropped_zero > 0 {
        dropped.push(format!("{} no-return points at (0,0,0) dropped, --keep-zero keeps them", report.dropped_zero));
    }
    if report.dropped_non_finite > 0 {
        dropped.push(format!("{} non-finite points dropped", report.dropped_non_finite));
    }
    if !dropped.is_empty() {
        line += &format!(" ({})", dropped.join("; "));
    }
    line
}

/// Checks every output path before any work (the inputs and weights protected from being overwritten) and
/// returns them with their flags.
fn checked_outputs<'a>(args: &'a Args, weights: Option<&'a Path>) -> anyhow::Result<Vec<(&'static str, &'a Path)>> {
    let mut outputs: Vec<(&str, &Path)> = Vec::new();
    if let Some(p) = &args.out {
        outputs.push(("--out", p));
    }
    if let Some(p) = &args.aligned {
        check_writable_cloud_path(p)?;
        if args.merged && !is_ply_or_special(p) {
            bail!("--aligned {} with --merged: a merged, coloured cloud is written as PLY; name it *.ply", p.display());
        }
        outputs.push(("--aligned", p));
    }
    if let Some(p) = &args.snapshot {
        crate::snapshot::check_snapshot_path("--snapshot", p)?;
        outputs.push(("--snapshot", p));
    }
    let mut inputs = vec![args.source.as_path(), args.target.as_path()];
    inputs.extend(weights);
    check_outputs(&inputs, &outputs)?;
    Ok(outputs)
}

/// Runs the pipeline with a progress bar on a terminal.
fn register_pair(
    registrar: Registrar,
    args: &Args,
    pair: &LoadedPair,
) -> anyhow::Result<(Registrar, crate::pipeline::Registration)> {
    let bar = stage_bar();
    let registrar = registrar.with_progress({
        let bar = bar.clone();
        Box::new(move |stage, seconds| {
            if bar.position() + 1 > bar.length().unwrap_or(0) {
                bar.inc_length(crate::pipeline::ROUND_STAGES as u64);
            }
            bar.inc(1);
            bar.set_message(format!("{stage} took {seconds:.2} s"));
        })
    });
    let outcome =
        registrar.register_detailed(&pair.source, &pair.target).map_err(|e| name_files(e, &args.source, &args.target));
    bar.finish_and_clear();
    Ok((registrar, outcome?))
}

/// Writes `--out`, `--aligned` and `--snapshot`; `shifted` is the pose in the shifted frames. Returns the lines
/// saying what was written.
fn write_outputs(
    args: &Args,
    pair: &LoadedPair,
    registration: &crate::pipeline::Registration,
    shifted: &Matrix4<f64>,
) -> anyhow::Result<Vec<String>> {
    let mut written = Vec::new();
    let result = &registration.result;
    if let Some(path) = &args.out {
        write_atomic(path, crate::pose::matrix_text(&result.estimate.target_from_source).as_bytes())?;
        written.push(format!("target_from_source written to {}", path.display()));
    }
    if let Some(path) = &args.aligned {
        let aligned = unshifted(pair.source.transformed(shifted), pair.origin);
        if args.merged {
            let (merged, colors) = crate::snapshot::merged_pair(&aligned, &unshifted(pair.target.clone(), pair.origin));
            write_ply_with_colors(path, &merged, &colors)?;
            written.push(format!("moved source and target (orange, blue) written to {}", path.display()));
        } else {
            write_cloud(path, &aligned)?;
            written.push(format!("moved source written to {}", path.display()));
        }
    }
    if let Some(path) = &args.snapshot {
        // Drawn in the shifted frames: a picture does not change with a common shift, and f32 stays precise.
        let lines =
            crate::snapshot::inlier_lines(&registration.correspondences, shifted, result.scale.inlier_threshold);
        let options = crate::snapshot::SnapshotOptions { lines, ..Default::default() };
        crate::snapshot::write_snapshot(path, &pair.source, &pair.target, shifted, &options)?;
        written.push(format!(
            "snapshot written to {} ({})",
            path.display(),
            crate::snapshot::describe_layout(&options)
        ));
    }
    Ok(written)
}

/// The `--json` object: the result plus the run's own facts.
fn json_report(
    result: &RegistrationResult,
    registrar: &Registrar,
    pair: &LoadedPair,
    written: &[String],
    total_seconds: f64,
) -> anyhow::Result<serde_json::Value> {
    let mut value = serde_json::to_value(result)?;
    value["total_seconds"] = total_seconds.into();
    value["backend_reason"] = registrar.backend_reason().into();
    value["source_points"] = pair.source.len().into();
    value["target_points"] = pair.target.len().into();
    value["dropped_points"] = pair.dropped_points().into();
    value["dropped_zero_points"] = (pair.source_report.dropped_zero + pair.target_report.dropped_zero).into();
    value["origin"] = serde_json::to_value(pair.origin)?;
    value["written"] = serde_json::to_value(written)?;
    Ok(value)
}

/// The text report.
fn print_text(result: &RegistrationResult, registrar: &Registrar, pair: &LoadedPair, written: &[String], total: f64) {
    println!("{}", load_line("source", &pair.source, &pair.source_report));
    println!("{}", load_line("target", &pair.target, &pair.target_report));
    if pair.origin != [0; 3] {
        println!("large coordinates: both clouds shifted by -{:?} for the computation", pair.origin);
    }
    println!("backend: {} ({})", result.backend, registrar.backend_reason());
    println!("scale: {}", result.scale);
    println!("target_from_source (p_target = T p_source):");
    print!("{}", crate::pose::matrix_text(&result.estimate.target_from_source));
    let e = &result.estimate;
    if result.empty_patches > 0 {
        println!("keypoints without neighbours within the radius (dropped): {}", result.empty_patches);
    }
    println!("correspondences: {} (from {} keypoints per scan)", result.correspondences, result.keypoints);
    println!("hypotheses scored: {}", e.hypotheses_scored);
    println!("inliers: {} (fitness {:.4}, inlier RMSE {:.5})", e.inliers, e.fitness, e.inlier_rmse);
    println!("stage times (s):");
    for st in &result.timings {
        println!("  {:<24} {:>9.3}", st.stage, st.seconds);
    }
    println!("  {:<24} {:>9.3}", "total", total);
    for line in written {
        println!("{line}");
    }
    match &result.reason {
        None => println!("verdict: success"),
        Some(reason) => println!("verdict: NOT TRUSTED: {reason}"),
    }
}

/// Runs `dpr-gpu register`; returns whether the result is trusted (see [`RegistrationResult::success`]).
pub fn run(args: Args) -> anyhow::Result<bool> {
    let settings = args.options.to_settings()?;
    parse_estimator(&args.options.estimator)?;
    let weights = args.options.weights_path()?;
    checked_outputs(&args, weights.as_deref())?;
    let load = args.options.load_options()?;
    let started = std::time::Instant::now();
    // The weights load on the other core while the scans are read (the scans' errors come first).
    let (pair, registrar) = rayon::join(
        || LoadedPair::read(&args, load).map(|pair| (pair, started.elapsed().as_secs_f64())),
        || Registrar::new(&settings),
    );
    let (pair, load_seconds) = pair?;
    let (registrar, mut registration) = register_pair(registrar?, &args, &pair)?;
    registration.result.timings.insert(0, StageTime { stage: "load".into(), seconds: load_seconds });
    let shifted = registration.result.estimate.target_from_source;
    registration.result.estimate.target_from_source = crate::pose::unshift_pose(&shifted, pair.origin);
    let written = write_outputs(&args, &pair, &registration, &shifted)?;
    let result = &registration.result;
    let total_seconds = started.elapsed().as_secs_f64();
    if args.json {
        let value = json_report(result, &registrar, &pair, &written, total_seconds)?;
        println!("{}", serde_json::to_string(&value)?);
    } else {
        print_text(result, &registrar, &pair, &written, total_seconds);
    }
    if !result.success {
        eprintln!(
            "warning: result not trusted ({}); exit status {EXIT_UNTRUSTED}",
            result.reason.as_deref().unwrap_or("no reason given")
        );
    }
    Ok(result.success)
}

#[cfg(test)]
mod tests {
    use super::Args;
    use crate::settings::{ContextRadius, ContextWhen, DEFAULT_CONTEXT_RADII, RegistrationSettings};
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        args: Args,
    }

    fn settings(flags: &[&str]) -> anyhow::Result<RegistrationSettings> {
        let cli = Cli::try_parse_from(["register", "s.ply", "t.ply"].iter().chain(flags))?;
        cli.args.options.to_settings()
    }

    #[test]
    fn context_radius_flags_default_to_the_library_and_off_turns_them_off() {
        let library = RegistrationSettings::default();
        let defaults = settings(&[]).unwrap();
        assert_eq!(defaults.context_radii, library.context_radii);
        assert_eq!(defaults.context_radii, DEFAULT_CONTEXT_RADII);
        assert_eq!((defaults.context_when, library.context_when), (ContextWhen::Untrusted, ContextWhen::Untrusted));
        assert!(settings(&["--context-radius", "off"]).unwrap().context_radii.is_empty());
        let given = settings(&["--context-radius", "3:0.5", "--context-radius", "1.5:2", "--context-when", "always"]);
        let given = given.unwrap();
        let expected = [ContextRadius { factor: 3.0, weight: 0.5 }, ContextRadius { factor: 1.5, weight: 2.0 }];
        assert_eq!((given.context_radii.as_slice(), given.context_when), (&expected[..], ContextWhen::Always));
        let mixed = settings(&["--context-radius", "off", "--context-radius", "2:1"]).unwrap_err().to_string();
        assert!(mixed.contains("off cannot be combined"), "{mixed}");
    }

    #[test]
    fn pose_candidates_default_to_the_library_and_are_bounded() {
        assert_eq!(settings(&[]).unwrap().pose_candidates, RegistrationSettings::default().pose_candidates);
        assert_eq!(settings(&["--pose-candidates", "4"]).unwrap().pose_candidates, 4);
        for bad in ["0", "65"] {
            let e = settings(&["--pose-candidates", bad]).unwrap_err().to_string();
            assert!(e.contains("pose candidates must be 1..=64"), "{e}");
        }
    }
}
