//! `dpr-gpu eval`: the 3DMatch evaluation protocol on a dataset, by running the pipeline on every gt.log pair
//! or by scoring an existing result log.

use crate::cli::register::{RegisterOptions, parse_estimator};
use crate::eval::dataset::{SceneData, load_dataset};
use crate::eval::gtlog::{LogRecord, format_log, read_log};
use crate::eval::report::{
    EstimatorReport, Report, RotationReport, SceneScale, format_pairs, format_table, legend, protocol_notes,
    rotation_notes,
};
use crate::eval::rotate::{FragmentRotation, RotationSweep, angle_label};
use crate::eval::run::{
    EvalOptions, estimator_name, pairs_to_run, run_scene, run_scene_sweep, scene_scale, score_log, score_log_sweep,
};
use crate::eval::score::{REFERENCE_RADIUS, Thresholds};
use crate::io::write_atomic;
use crate::pipeline::Registrar;
use crate::scale::ScaleChoice;
use crate::settings::Estimator;
use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressStyle};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};

/// Arguments of `dpr-gpu eval`.
#[derive(clap::Args, Debug)]
#[command(after_help = "--estimator also accepts `both`: RelativeNet and RANSAC on the same correspondences, side by \
side. Registration recall counts gt.log pairs with j - i > 1 (success: e^T Sigma e / Sigma_11 <= 0.04; for a pairs \
file: source-point RMSE <= 0.2 m); feature-match recall counts every gt.log pair (inlier: |x_i - T_ij x_j| < 0.10 m; \
matched: inlier ratio > 0.05, strict). Distances scale by radius / 0.60 unless --protocol-scale sets the factor. Results go to \
OUT/<estimator>/<scene>.log (3DMatch format) and OUT/report.json.

Rotation sweep (--rotate DEG[,DEG...]): every source fragment j of a pair (i, j) is moved by M, a rotation by \
exactly DEG degrees about a random unit axis through the centroid of its points (one axis per scene and fragment, \
seeded by --rotate-seed, the same for every angle); targets stay put. Every pair is registered again at each angle \
and every metric is reported per angle and estimator (report.json: one `estimators` entry per angle and \
estimator with `rotation_deg`, and a `rotation` object listing each fragment's axis and centre). Registration is \
scored in the original frames (T_est' M against gt.log and gt.info), feature matches on the moved data with \
T_gt M^-1. Result logs go to OUT/<estimator>/rot<DEG>/<scene>.log and hold target_from_rotated_source. With \
--log, the logs are results on the moved data: the path must contain {rotation} (replaced by each angle in \
shortest form, e.g. 90 or 22.5).")]
pub struct Args {
    /// A folder of scenes (each with cloud_bin_*.ply, gt.log and gt.info), one scene folder, or a pairs file
    /// (`source target` + 16 numbers, p_target = T p_source, paths relative to the file).
    pub dataset: PathBuf,
    /// Registration options; `--estimator` also accepts `both` (RelativeNet and RANSAC on the same
    /// correspondences, side by side).
    #[command(flatten)]
    pub register: RegisterOptions,
    /// Score this result log instead of running the pipeline: a .log file (single-scene dataset), a folder
    /// holding `<scene>.log` per scene, or a path template containing `{scene}`.
    #[arg(long)]
    pub log: Option<String>,
    /// Output folder for the result logs (`<estimator>/<scene>.log`) and `report.json`.
    #[arg(long, default_value = "eval_out")]
    pub out: PathBuf,
    /// Register every fragment pair i < j (not only gt.log pairs) and report those whose estimated overlap
    /// exceeds --min-overlap, as the 3DMatch toolbox does (this is what makes precision meaningful).
    #[arg(long)]
    pub all_pairs: bool,
    /// Scale of the protocol's distances (feature-match inlier 0.10 m, success 0.2 m, overlap 0.05 m) [default:
    /// --radius / 0.60, so data in other units keeps proportional thresholds]. 1 keeps the protocol's metres
    /// whatever the radius, to compare patch radii on one measure.
    #[arg(long, value_name = "S")]
    pub protocol_scale: Option<f64>,
    /// Estimated overlap needed to report a pair with --all-pairs.
    #[arg(long, default_value_t = 0.23)]
    pub min_overlap: f64,
    /// Rotation sweep: rotate every source fragment by each of these angles (degrees, comma-separated) about a
    /// seeded random axis through its centroid, and report every metric per angle (see below).
    #[arg(long, value_name = "DEG[,DEG...]", value_delimiter = ',', allow_hyphen_values = true)]
    pub rotate: Option<Vec<f64>>,
    /// Seed of the rotation axes of --rotate [default: 0].
    #[arg(long, value_name = "S")]
    pub rotate_seed: Option<u64>,
    /// Write a PNG picture of every registered pair (before / after, three views) into this folder, as
    /// DIR/<estimator>[/rot<DEG>]/<scene>/<source>_to_<target>.png.
    #[arg(long, value_name = "DIR")]
    pub snapshots: Option<PathBuf>,
}

/// The estimators named by `--estimator` (`relativenet`, `ransac` or `both`).
pub fn parse_estimators(s: &str) -> anyhow::Result<Vec<Estimator>> {
    if s == "both" {
        return Ok(vec![Estimator::RelativeNet, Estimator::Ransac]);
    }
    parse_estimator(s)
        .map(|e| vec![e])
        .map_err(|_| anyhow::anyhow!("unknown estimator '{s}' (expected relativenet, ransac or both)"))
}

/// Where the result log of `scene` is, given the `--log` argument.
fn log_path_for(log: &str, scene: &SceneData, scene_count: usize) -> anyhow::Result<PathBuf> {
    if log.contains("{scene}") {
        return Ok(PathBuf::from(log.replace("{scene}", &scene.name)));
    }
    let p = PathBuf::from(log);
    if p.is_dir() {
        return Ok(p.join(format!("{}.log", scene.name)));
    }
    if scene_count > 1 {
        bail!(
            "--log {log} is one file but the dataset has {scene_count} scenes; pass a folder of <scene>.log files or a \
             path with {{scene}}"
        );
    }
    Ok(p)
}

fn write_report(out: &Path, report: &Report) -> anyhow::Result<()> {
    let json = serde_json::to_string_pretty(report).context("serialising the report")?;
    write_atomic(&out.join("report.json"), json.as_bytes())?;
    print!("{}", format_pairs(report));
    println!();
    print!("{}", format_table(report));
    print!("{}", legend(&report.thresholds));
    for s in &report.scales {
        println!("scale of {}: radius {} ({})", s.scene, crate::scale::significant(f64::from(s.radius)), s.rule);
    }
    if report.estimators.iter().all(|e| e.mean.registration_recall.is_none()) {
        println!(
            "note: RR is '-' because no gt.log pair here counts for registration recall (the 3DMatch protocol counts \
             only non-consecutive fragments, j - i > 1); pass the folder's pairs.txt to score every pair"
        );
    }
    for e in &report.estimators {
        if let Some(line) = verdict_summary(e) {
            println!("{}: {line}", e.estimator);
        }
        if let Some(line) = overlap_recall(e) {
            println!("{}: {line}", e.estimator);
        }
    }
    println!("report: {}", out.join("report.json").display());
    Ok(())
}

/// Reads the result log of `scene` at `path`; a missing file warns and counts every pair as missing.
fn read_result_log(scene: &SceneData, path: &Path) -> anyhow::Result<Vec<LogRecord>> {
    if path.is_file() {
        Ok(read_log(path)?)
    } else {
        eprintln!("warning: {}: no result log at {}; every pair counts as missing", scene.name, path.display());
        Ok(Vec::new())
    }
}

/// The rotation part of a report.
fn rotation_report(sweep: &RotationSweep, fragments: Vec<FragmentRotation>) -> RotationReport {
    RotationReport { degrees: sweep.degrees.clone(), seed: sweep.seed, notes: rotation_notes(), fragments }
}

/// `--log` with `--rotate`: the logs (one per angle, `{rotation}` in the path) are results on the moved data.
fn score_logs_sweep(
    args: &Args,
    log: &str,
    scenes: Vec<SceneData>,
    opts: &EvalOptions,
    sweep: &RotationSweep,
) -> anyhow::Result<Report> {
    if !log.contains("{rotation}") {
        bail!(
            "--log {log}: with --rotate the result logs are results on the rotated data, one per angle; put \
             {{rotation}} in the path (e.g. OUT/ransac/rot{{rotation}})"
        );
    }
    let count = scenes.len();
    let mut per_angle: Vec<Vec<_>> = vec![Vec::new(); sweep.degrees.len()];
    let mut rotations = Vec::new();
    let mut scales = SceneScales::default();
    for mut scene in scenes {
        let opts = &scales.options(args, &scene, opts)?;
        let mut logs = Vec::new();
        let mut paths = Vec::new();
        for &d in &sweep.degrees {
            let path = log_path_for(&log.replace("{rotation}", &angle_label(d)), &scene, count)?;
            logs.push(read_result_log(&scene, &path)?);
            paths.push(path.display().to_string());
        }
        let (scores, r) =
            score_log_sweep(&mut scene, &logs, opts, sweep).with_context(|| format!("scoring {}", paths.join(", ")))?;
        for (v, score) in scores.into_iter().enumerate() {
            per_angle[v].push(score);
        }
        rotations.extend(r);
    }
    let thresholds = scales.thresholds.unwrap_or(opts.thresholds);
    Ok(Report {
        dataset: args.dataset.display().to_string(),
        mode: "log".into(),
        log: Some(log.to_string()),
        thresholds,
        protocol: protocol_notes(&thresholds),
        scales: scales.scenes,
        settings: None,
        rotation: Some(rotation_report(sweep, rotations)),
        estimators: sweep
            .degrees
            .iter()
            .zip(per_angle)
            .map(|(&d, scores)| EstimatorReport::new("log", scores).at_rotation(d))
            .collect(),
        fragments: Vec::new(),
    })
}

/// How often the success verdict was right over the gt pairs an estimator registered: trusted and correct
/// (true successes), trusted but wrong (false alarms), untrusted but correct (missed), untrusted and wrong.
/// Overlap bins of [`overlap_recall`]: lower bounds, the 3DLoMatch band (10-30 %) first.
pub const OVERLAP_BINS: [f64; 4] = [0.0, 0.1, 0.3, 0.5];

/// Registration recall by ground-truth overlap (gt pairs that count for recall): "< 10 %: 0/1, 10-30 %: 3/5,
/// 30-50 %: 4/4, >= 50 %: 10/10" (empty bins left out); `None` without overlaps (log scoring).
fn overlap_recall(e: &EstimatorReport) -> Option<String> {
    let samples: Vec<(f64, bool)> = e
        .scenes
        .iter()
        .flat_map(|s| &s.pairs)
        .filter(|p| p.counts_for_recall)
        .filter_map(|p| Some((p.run.as_ref()?.gt_overlap?, p.success?)))
        .collect();
    overlap_recall_line(&samples)
}

/// [`overlap_recall`]'s line for (overlap, registered correctly) samples.
fn overlap_recall_line(samples: &[(f64, bool)]) -> Option<String> {
    let mut bins = [[0usize; 2]; OVERLAP_BINS.len()];
    for &(overlap, good) in samples {
        let bin = OVERLAP_BINS.iter().rposition(|&low| overlap >= low).unwrap_or(0);
        bins[bin][0] += 1;
        bins[bin][1] += usize::from(good);
    }
    let parts: Vec<String> = bins
        .iter()
        .enumerate()
        .filter(|(_, b)| b[0] > 0)
        .map(|(k, b)| {
            let pct = |v: f64| (v * 100.0).round();
            let label = match (k, OVERLAP_BINS.get(k + 1)) {
                (0, Some(&hi)) => format!("< {} %", pct(hi)),
                (_, Some(&hi)) => format!("{}-{} %", pct(OVERLAP_BINS[k]), pct(hi)),
                (_, None) => format!(">= {} %", pct(OVERLAP_BINS[k])),
            };
            format!("{label}: {}/{}", b[1], b[0])
        })
        .collect();
    (!parts.is_empty()).then(|| format!("recall by ground-truth overlap: {}", parts.join(", ")))
}

fn verdict_summary(e: &EstimatorReport) -> Option<String> {
    let mut counts = [[0usize; 2]; 2];
    let (mut outside, mut outside_trusted) = (0, 0);
    for p in e.scenes.iter().flat_map(|s| &s.pairs) {
        match (p.success, p.run.as_ref().and_then(|r| r.trusted)) {
            (Some(correct), Some(trusted)) => counts[usize::from(trusted)][usize::from(correct)] += 1,
            (None, Some(trusted)) if !p.in_gt => {
                outside += 1;
                outside_trusted += usize::from(trusted);
            }
            _ => {}
        }
    }
    let total: usize = counts.iter().flatten().sum();
    (total + outside > 0).then(|| {
        let mut line = format!(
            "verdict over {total} gt pairs: {} true successes, {} false alarms (trusted but wrong), {} missed \
             (untrusted but right), {} correctly rejected",
            counts[1][1], counts[1][0], counts[0][1], counts[0][0]
        );
        if outside > 0 {
            line.push_str(&format!("; {outside_trusted} of {outside} registered pairs outside gt.log trusted"));
        }
        line
    })
}

fn score_logs(args: &Args, log: &str, scenes: Vec<SceneData>, opts: &EvalOptions) -> anyhow::Result<Report> {
    let count = scenes.len();
    let mut scores = Vec::new();
    let mut scales = SceneScales::default();
    for mut scene in scenes {
        let path = log_path_for(log, &scene, count)?;
        let records = read_result_log(&scene, &path)?;
        let opts = scales.options(args, &scene, opts)?;
        scores.push(score_log(&mut scene, &records, &opts).with_context(|| format!("scoring {}", path.display()))?);
    }
    let thresholds = scales.thresholds.unwrap_or(opts.thresholds);
    Ok(Report {
        dataset: args.dataset.display().to_string(),
        mode: "log".into(),
        log: Some(log.to_string()),
        thresholds,
        protocol: protocol_notes(&thresholds),
        scales: scales.scenes,
        settings: None,
        rotation: None,
        estimators: vec![EstimatorReport::new("log", scores)],
        fragments: Vec::new(),
    })
}

/// Writes one result log, creating its folder.
fn write_result_log(path: &Path, log: &[LogRecord]) -> anyhow::Result<()> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    write_atomic(path, format_log(log).as_bytes())?;
    Ok(())
}

fn run_pipeline(
    args: &Args,
    scenes: Vec<SceneData>,
    opts: &EvalOptions,
    sweep: Option<&RotationSweep>,
) -> anyhow::Result<Report> {
    let estimators = parse_estimators(&args.register.estimator)?;
    let settings = args.register.to_settings()?;
    let registrar = Registrar::new(&settings).context("preparing the pipeline")?;
    let views = sweep.map_or(1, |s| s.degrees.len());
    let total: usize = scenes.iter().map(|s| pairs_to_run(s, opts).len() * views).sum();
    let bar = if std::io::stderr().is_terminal() { ProgressBar::new(total as u64) } else { ProgressBar::hidden() };
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} pairs {msg} [{elapsed_precise} < {eta_precise}]")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    // Indexed [angle][estimator] (one angle without a sweep).
    let mut scores: Vec<Vec<Vec<_>>> = vec![vec![Vec::new(); estimators.len()]; views];
    let mut fragments = Vec::new();
    let mut rotations = Vec::new();
    let mut scales = SceneScales::default();
    for mut scene in scenes {
        bar.set_message(scene.name.clone());
        let opts = &scales.options(args, &scene, opts)?;
        let registrar = &match scales.last.clone() {
            Some(choice) => registrar.at_scale(choice),
            None => registrar.at_scale(ScaleChoice::given(registrar.radius())),
        };
        let name = scene.name.clone();
        let context = || format!("evaluating scene {name}");
        let angles = match sweep {
            None => {
                let run =
                    run_scene(&mut scene, registrar, &estimators, opts, &mut || bar.inc(1)).with_context(context)?;
                fragments.extend(run.fragments);
                vec![(None, run.estimators)]
            }
            Some(s) => {
                let run = run_scene_sweep(&mut scene, registrar, &estimators, opts, s, &mut || bar.inc(1))
                    .with_context(context)?;
                fragments.extend(run.fragments);
                rotations.extend(run.rotations);
                run.angles.into_iter().map(|a| (Some(a.rotation_deg), a.estimators)).collect()
            }
        };
        for (v, (rotation, runs)) in angles.into_iter().enumerate() {
            for (e, (estimator, score, log)) in runs.into_iter().enumerate() {
                let mut dir = args.out.join(estimator_name(estimator));
                if let Some(d) = rotation {
                    dir = dir.join(format!("rot{}", angle_label(d)));
                }
                write_result_log(&dir.join(format!("{}.log", scene.name)), &log)?;
                scores[v][e].push(score);
            }
        }
    }
    bar.finish_and_clear();
    let mut entries = Vec::new();
    for (v, per_estimator) in scores.into_iter().enumerate() {
        for (&e, s) in estimators.iter().zip(per_estimator) {
            let entry = EstimatorReport::new(estimator_name(e), s);
            entries.push(match sweep {
                Some(sw) => entry.at_rotation(sw.degrees[v]),
                None => entry,
            });
        }
    }
    let thresholds = scales.thresholds.unwrap_or(opts.thresholds);
    Ok(Report {
        dataset: args.dataset.display().to_string(),
        mode: "pipeline".into(),
        log: None,
        thresholds,
        protocol: protocol_notes(&thresholds),
        scales: scales.scenes,
        settings: Some(settings),
        rotation: sweep.map(|s| rotation_report(s, rotations)),
        estimators: entries,
        fragments,
    })
}

/// The protocol's thresholds for a scene registered at `radius`: `--protocol-scale` when given, else scaled by
/// radius / 0.60.
fn protocol_thresholds(args: &Args, radius: f64) -> Thresholds {
    match args.protocol_scale {
        Some(s) => Thresholds::scaled(s),
        None => Thresholds::for_radius(radius),
    }
}

/// The radius chosen for each scene when --radius is not given, and the protocol's thresholds of the first.
#[derive(Default)]
struct SceneScales {
    scenes: Vec<SceneScale>,
    thresholds: Option<Thresholds>,
    /// The last scene's choice.
    last: Option<ScaleChoice>,
}

impl SceneScales {
    /// `opts` for `scene`: with no --radius, the protocol's distances follow the radius chosen from the scene's
    /// clouds ([`scene_scale`]; unless --protocol-scale fixes them), and the choice is recorded.
    fn options(&mut self, args: &Args, scene: &SceneData, opts: &EvalOptions) -> anyhow::Result<EvalOptions> {
        self.last = None;
        if args.register.radius.is_some() {
            return Ok(opts.clone());
        }
        let choice = scene_scale(scene, opts).with_context(|| format!("choosing the scale of scene {}", scene.name))?;
        let thresholds = protocol_thresholds(args, f64::from(choice.radius));
        self.thresholds.get_or_insert(thresholds);
        self.scenes.push(SceneScale { scene: scene.name.clone(), radius: choice.radius, rule: choice.rule() });
        self.last = Some(choice);
        Ok(EvalOptions { thresholds, ..opts.clone() })
    }
}

/// Fails before any work when report.json or a result log would land on a file of the dataset (compared by
/// identity), or cannot be written.
fn check_eval_outputs(args: &Args, scenes: &[SceneData]) -> anyhow::Result<()> {
    let mut inputs = crate::eval::dataset::dataset_files(&args.dataset)?;
    inputs.extend(args.log.as_ref().map(PathBuf::from));
    let report = args.out.join("report.json");
    let mut outputs = vec![report];
    if args.log.is_none() && args.rotate.is_none() {
        for e in parse_estimators(&args.register.estimator)? {
            outputs.extend(scenes.iter().map(|s| args.out.join(estimator_name(e)).join(format!("{}.log", s.name))));
        }
    }
    let inputs: Vec<&Path> = inputs.iter().map(PathBuf::as_path).collect();
    let report = &outputs[0];
    crate::io::check_outputs(&inputs, &[("--out", report)])?;
    for log in &outputs[1..] {
        // The estimator folders do not exist yet: only a log already there can land on an input.
        if log.exists() {
            crate::io::check_outputs(&inputs, &[("--out", log)])?;
        }
    }
    Ok(())
}

/// Runs `dpr-gpu eval`.
pub fn run(args: Args) -> anyhow::Result<()> {
    let radius = args.register.radius.map_or(REFERENCE_RADIUS, f64::from);
    if !(radius > 0.0 && radius.is_finite()) {
        bail!("--radius must be positive, got {radius}");
    }
    let thresholds = match args.protocol_scale {
        Some(s) if !(s > 0.0 && s.is_finite()) => bail!("--protocol-scale must be positive, got {s}"),
        _ => protocol_thresholds(&args, radius),
    };
    if !(0.0..=1.0).contains(&args.min_overlap) {
        bail!("--min-overlap is a fraction of the source's points, 0..=1; got {}", args.min_overlap);
    }
    let opts = EvalOptions {
        thresholds,
        seed: args.register.seed,
        load: args.register.load_options()?,
        all_pairs: args.all_pairs,
        min_overlap: args.min_overlap,
        snapshots: args.snapshots.clone(),
    };
    if let Some(dir) = &args.snapshots {
        if let Some(log) = &args.log {
            bail!("--snapshots draws the pairs the pipeline registers; --log {log} only scores a result log");
        }
        if dir.exists() && !dir.is_dir() {
            bail!("--snapshots {}: not a folder", dir.display());
        }
    }
    let sweep = match &args.rotate {
        Some(degrees) => Some(RotationSweep::new(degrees.clone(), args.rotate_seed.unwrap_or(0))?),
        None if args.rotate_seed.is_some() => bail!("--rotate-seed needs --rotate"),
        None => None,
    };
    if sweep.is_none()
        && let Some(log) = &args.log
        && log.contains("{rotation}")
    {
        bail!("--log {log} contains {{rotation}}, which only --rotate fills in");
    }
    let scenes = load_dataset(&args.dataset).with_context(|| format!("loading {}", args.dataset.display()))?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    check_eval_outputs(&args, &scenes)?;
    if let Some(dir) = &args.snapshots {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let report = match (&args.log, &sweep) {
        (Some(log), Some(s)) => score_logs_sweep(&args, log, scenes, &opts, s)?,
        (Some(log), None) => score_logs(&args, log, scenes, &opts)?,
        (None, s) => run_pipeline(&args, scenes, &opts, s.as_ref())?,
    };
    write_report(&args.out, &report)
}

#[cfg(test)]
mod tests {
    use super::overlap_recall_line;

    #[test]
    fn recall_is_binned_by_overlap() {
        let samples = [(0.05, false), (0.12, true), (0.29, false), (0.3, true), (0.49, true), (0.9, true)];
        let line = overlap_recall_line(&samples).unwrap();
        assert_eq!(line, "recall by ground-truth overlap: < 10 %: 0/1, 10-30 %: 1/2, 30-50 %: 2/2, >= 50 %: 1/1");
        assert_eq!(overlap_recall_line(&[]), None);
        let only_high = overlap_recall_line(&[(0.7, false)]).unwrap();
        assert_eq!(only_high, "recall by ground-truth overlap: >= 50 %: 0/1");
    }
}
