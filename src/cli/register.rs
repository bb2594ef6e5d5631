//! `dpr-gpu register` and the registration options shared with `eval`.

use crate::io::{LoadOptions, read_cloud, write_atomic, write_ply};
use crate::pipeline::Registrar;
use crate::settings::*;
use anyhow::{Context, bail};
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
    /// Keypoint selection: random (3DMatch convention) or uniform (farthest-point sampling).
    #[arg(long, default_value = "random")]
    pub keypoint_mode: String,
    /// Patch radius in cloud units (default: the radius the weights were trained with, 0.30 m).
    #[arg(long)]
    pub radius: Option<f32>,
    /// Voxel size for downsampling (cloud units); default: none.
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
    /// Inlier threshold in cloud units (default: radius / 3).
    #[arg(long)]
    pub inlier_threshold: Option<f32>,
    /// RANSAC iteration limit.
    #[arg(long, default_value_t = 100_000)]
    pub ransac_iterations: usize,
    /// Seed for every random choice.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Refine the final pose with point-to-plane ICP.
    #[arg(long)]
    pub icp: bool,
    /// Drop exact (0,0,0) points when loading.
    #[arg(long)]
    pub drop_zero: bool,
    /// Compute backend: cpu, gpu or auto.
    #[arg(long, default_value = "cpu")]
    pub backend: String,
}

/// Parses `relativenet` / `ransac`.
pub fn parse_estimator(s: &str) -> anyhow::Result<Estimator> {
    match s {
        "relativenet" => Ok(Estimator::RelativeNet),
        "ransac" => Ok(Estimator::Ransac),
        other => bail!("unknown estimator '{other}' (expected relativenet or ransac)"),
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
            normal_neighbors: self.normal_k,
            inlier_threshold: self.inlier_threshold,
            seed: self.seed,
            drop_zero_points: self.drop_zero,
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
        s.ransac.max_iterations = self.ransac_iterations.max(1);
        if self.icp {
            let radius = self.radius.unwrap_or(0.30);
            s.icp = Some(IcpSettings { max_correspondence_distance: radius / 6.0, max_iterations: 30 });
        }
        Ok(s)
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
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

/// The 4x4 matrix as text, one row per line.
pub fn matrix_text(m: &nalgebra::Matrix4<f64>) -> String {
    (0..4).map(|r| (0..4).map(|c| format!("{:.9}", m[(r, c)])).collect::<Vec<_>>().join(" ") + "\n").collect()
}

fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(x), Ok(y)) => x == y,
        _ => a == b,
    }
}

/// Refuses output paths that would overwrite an input.
pub fn check_outputs(inputs: &[&Path], outputs: &[&Path]) -> anyhow::Result<()> {
    for o in outputs {
        if inputs.iter().any(|i| same_file(i, o)) {
            bail!("refusing to overwrite input file {}", o.display());
        }
    }
    Ok(())
}

/// Runs `dpr-gpu register`.
pub fn run(args: Args) -> anyhow::Result<()> {
    let settings = args.options.to_settings()?;
    parse_estimator(&args.options.estimator)?;
    let outputs: Vec<&Path> = args.out.iter().chain(&args.aligned).map(PathBuf::as_path).collect();
    check_outputs(&[&args.source, &args.target], &outputs)?;
    let load = LoadOptions { drop_zero_points: settings.drop_zero_points };
    let started = std::time::Instant::now();
    let (source, source_report) = read_cloud(&args.source, &load)?;
    let (target, target_report) = read_cloud(&args.target, &load)?;
    let load_seconds = started.elapsed().as_secs_f64();
    let registrar = Registrar::new(&settings).context("loading the model")?;
    let mut result = registrar.register(&source, &target)?;
    result.timings.insert(0, StageTime { stage: "load".into(), seconds: load_seconds });
    let t = result.estimate.target_from_source;
    if let Some(path) = &args.out {
        write_atomic(path, matrix_text(&t).as_bytes())?;
    }
    if let Some(path) = &args.aligned {
        write_ply(path, &source.transformed(&t))?;
    }
    if args.json {
        let mut value = serde_json::to_value(&result)?;
        value["source_points"] = source.len().into();
        value["target_points"] = target.len().into();
        value["dropped_points"] = (source_report.dropped_non_finite
            + source_report.dropped_zero
            + target_report.dropped_non_finite
            + target_report.dropped_zero)
            .into();
        println!("{}", serde_json::to_string(&value)?);
    } else {
        for (name, r, cloud) in [("source", &source_report, &source), ("target", &target_report, &target)] {
            print!("{name}: {} points", cloud.len());
            if r.dropped_non_finite + r.dropped_zero > 0 {
                print!(" ({} non-finite and {} zero points dropped)", r.dropped_non_finite, r.dropped_zero);
            }
            println!();
        }
        println!("backend: {}", result.backend);
        println!("target_from_source (p_target = T p_source):");
        print!("{}", matrix_text(&t));
        let e = &result.estimate;
        if result.empty_patches > 0 {
            println!("keypoints without neighbours within the radius (dropped): {}", result.empty_patches);
        }
        println!("correspondences: {}", result.correspondences);
        println!("hypotheses scored: {}", e.hypotheses_scored);
        println!("inliers: {} (fitness {:.4}, inlier RMSE {:.5})", e.inliers, e.fitness, e.inlier_rmse);
        println!("stage times (s):");
        for st in &result.timings {
            println!("  {:<24} {:>9.3}", st.stage, st.seconds);
        }
    }
    Ok(())
}
