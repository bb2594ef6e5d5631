//! `dpr-gpu init-weights` and `dpr-gpu info`.

use crate::model::config::{PoseFrame, RotationOutput};
use crate::model::{ModelConfig, Weights};
use std::path::{Path, PathBuf};

/// Model-size options.
#[derive(clap::Args, Debug, Clone)]
pub struct ConfigOptions {
    /// Start from a preset: compact (256 points, 16x16 grid) or paper (2048 points, 45x45 grid).
    #[arg(long, default_value = "compact")]
    pub config: String,
    /// Points per patch.
    #[arg(long)]
    pub points: Option<usize>,
    /// Folding grid side (grid x grid points).
    #[arg(long)]
    pub grid: Option<usize>,
    /// Patch radius the model is trained for.
    #[arg(long)]
    pub model_radius: Option<f32>,
    /// Frame of PC-FoldNet's patches: normal (compact's default) or fragment (the paper's).
    #[arg(long)]
    pub pose_frame: Option<PoseFrame>,
    /// RelativeNet's rotation output: angle-bins[:BINS[:CANDIDATES]] (compact's default), six-d or quaternion
    /// (the paper's).
    #[arg(long)]
    pub rotation_output: Option<RotationOutput>,
}

impl ConfigOptions {
    /// The config described.
    pub fn to_config(&self) -> anyhow::Result<ModelConfig> {
        let mut c = match self.config.as_str() {
            "compact" => ModelConfig::default(),
            "paper" => ModelConfig::paper(),
            other => anyhow::bail!("unknown config preset '{other}' (expected compact or paper)"),
        };
        if let Some(p) = self.points {
            c.points_per_patch = p;
        }
        if let Some(g) = self.grid {
            c.grid = [g, g];
        }
        if let Some(r) = self.model_radius {
            c.radius = r;
        }
        c.pose_frame = self.pose_frame.unwrap_or(c.pose_frame);
        c.rotation_output = self.rotation_output.unwrap_or(c.rotation_output);
        c.validate()?;
        Ok(c)
    }
}

/// Arguments of `dpr-gpu init-weights`.
#[derive(clap::Args, Debug)]
pub struct InitArgs {
    /// Output safetensors file.
    pub out: PathBuf,
    /// Seed of the initialisation.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Model sizes.
    #[command(flatten)]
    pub config: ConfigOptions,
}

/// Refuses a weights output (`flag` names it) whose name does not end in `.safetensors` (an existing device such
/// as /dev/null excepted), so that a slip such as `init-weights cloud.ply` cannot replace another kind of file;
/// then checks the path as every output is checked ([`crate::io::check_output_path`]).
pub fn check_weights_path(flag: &str, path: &Path) -> anyhow::Result<()> {
    let special = std::fs::metadata(path).is_ok_and(|m| !m.is_file() && !m.is_dir());
    let named = path.file_name().is_some_and(|n| n.to_string_lossy().to_ascii_lowercase().ends_with(".safetensors"));
    if !named && !special {
        anyhow::bail!("{flag} {}: weights are written as safetensors; name the file *.safetensors", path.display());
    }
    crate::io::check_output_path(flag, path)?;
    Ok(())
}

/// Runs `dpr-gpu init-weights`.
pub fn run_init(args: InitArgs) -> anyhow::Result<()> {
    let config = args.config.to_config()?;
    check_weights_path("output", &args.out)?;
    let mut weights = Weights::init(&config, args.seed)?;
    weights.notes.insert("dpr_gpu.origin".into(), format!("random initialisation, seed {}", args.seed));
    weights.save(&args.out)?;
    println!("wrote {} ({} parameters)", args.out.display(), weights.parameter_count());
    Ok(())
}

/// Arguments of `dpr-gpu info`.
#[derive(clap::Args, Debug)]
pub struct InfoArgs {
    /// A weights file.
    pub weights: PathBuf,
}

/// Runs `dpr-gpu info`.
pub fn run_info(args: InfoArgs) -> anyhow::Result<()> {
    let w = Weights::load(&args.weights)?;
    println!("{}", args.weights.display());
    println!("config: {}", serde_json::to_string_pretty(&w.config)?);
    for (net, count) in w.parameter_counts_by_net() {
        println!("parameters {net:<10} {count:>10}");
    }
    println!("parameters total      {:>10}", w.parameter_count());
    for (k, v) in &w.notes {
        println!("{k}: {v}");
    }
    Ok(())
}
