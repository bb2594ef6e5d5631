//! `dpr-gpu train`: trains PPF-FoldNet, PC-FoldNet and RelativeNet on registered fragment pairs, with a
//! progress bar, a CSV loss log, periodic atomic checkpoints and exact resumption.

use crate::cpu::gemm::Precision;
use crate::model::config::{PoseFrame, RotationOutput};
use crate::model::{ModelConfig, Weights};
use crate::train::checkpoint::read_checkpoint;
use crate::train::data::discover_pairs;
use crate::train::{Losses, TrainSettings, Trainer};
use anyhow::{Context, bail};
use clap::ValueEnum;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Model size presets.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum ConfigPreset {
    /// `ModelConfig::default()`: the paper's widths, 256 points per patch, 16 x 16 grid.
    Compact,
    /// `ModelConfig::paper()`: 2048 points per patch, 45 x 45 grid.
    Paper,
}

/// Arguments of `dpr-gpu train`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Training data: dataset folders, scene folders (cloud_bin_k.ply + gt.log), gt.log files or pairs files.
    /// Never the evaluation set.
    #[arg(long, num_args = 1.., required_unless_present = "resume")]
    pub data: Vec<PathBuf>,
    /// Where the final weights go (safetensors).
    #[arg(long)]
    pub out: PathBuf,
    /// Model size preset [default: compact].
    #[arg(long, value_enum)]
    pub config: Option<ConfigPreset>,
    /// Points per patch (overrides the preset).
    #[arg(long)]
    pub points: Option<usize>,
    /// Folding grid G x G (overrides the preset).
    #[arg(long)]
    pub grid: Option<usize>,
    /// Patch radius the model is trained at, in cloud units [default: the preset's 0.30, or the --init weights'].
    /// With --init, a different radius fine-tunes the weights for patches of that size.
    #[arg(long)]
    pub radius: Option<f32>,
    /// Frame of PC-FoldNet's patches: `normal` (each patch rotated so its keypoint normal is +z; the default) or
    /// `fragment` (the paper). With --init, a different head keeps the FoldNets and re-initialises RelativeNet.
    #[arg(long)]
    pub pose_frame: Option<PoseFrame>,
    /// RelativeNet's rotation output: `angle-bins[:BINS[:CANDIDATES]]` (the default, 36 bins and 3 candidates:
    /// classify the angle about the normal, one hypothesis per candidate; normal frame only), `six-d`
    /// (Gram-Schmidt, chordal loss) or `quaternion` (the paper's L2 loss).
    #[arg(long)]
    pub rotation_output: Option<RotationOutput>,
    /// Train until this many steps are done in total (a resumed run counts the checkpoint's steps).
    #[arg(long, default_value_t = 1000)]
    pub steps: u64,
    /// Pairs per step [default: 32].
    #[arg(long)]
    pub batch: Option<usize>,
    /// Initial learning rate [default: 1e-3].
    #[arg(long)]
    pub lr: Option<f64>,
    /// Learning-rate factor per `--lr-decay-every` steps (smooth exponential decay) [default: 0.5].
    #[arg(long)]
    pub lr_decay: Option<f64>,
    /// Steps per `--lr-decay` factor; 0 keeps the rate constant [default: steps / 3].
    #[arg(long)]
    pub lr_decay_every: Option<u64>,
    /// Decoupled (AdamW) weight decay on weight matrices [default: 1e-6].
    #[arg(long)]
    pub weight_decay: Option<f64>,
    /// lambda1, weight of the pose loss [default: 1].
    #[arg(long)]
    pub lambda_pose: Option<f64>,
    /// lambda2, weight of the feature-consistency loss [default: 0.1].
    #[arg(long)]
    pub lambda_feat: Option<f64>,
    /// Drop the reconstruction loss (ablation).
    #[arg(long)]
    pub no_rec: bool,
    /// Drop the pose loss (ablation).
    #[arg(long)]
    pub no_pose: bool,
    /// Drop the feature-consistency loss (ablation).
    #[arg(long)]
    pub no_feat: bool,
    /// Add the batch contrastive loss on PPF codewords with this weight (lambda3; each pair's codewords closer
    /// to each other than to the hardest other pair's, by a margin): trains descriptors that match [default:
    /// off].
    #[arg(long)]
    pub lambda_contrast: Option<f64>,
    /// The contrastive margin, as a fraction of the batch's mean distance between non-corresponding codewords
    /// [default: 0.5].
    #[arg(long)]
    pub contrast_margin: Option<f64>,
    /// Let the pose loss train PPF-FoldNet too (by default the PPF codeword is held constant for it).
    #[arg(long)]
    pub pose_trains_ppf: bool,
    /// Seed of the initial weights and of the sampling [default: 0].
    #[arg(long)]
    pub seed: Option<u64>,
    /// Voxel size for downsampling fragments (cloud units) [default: 0.025].
    #[arg(long)]
    pub voxel: Option<f32>,
    /// Distance within which a mapped source point has a corresponding target point [default: 0.03].
    #[arg(long)]
    pub match_distance: Option<f32>,
    /// Also rotate target fragments by uniform random rotations.
    #[arg(long)]
    pub rotate_target: bool,
    /// Do not rotate source fragments (labels are then the dataset's own relative rotations).
    #[arg(long)]
    pub no_rotate_source: bool,
    /// Largest augmentation rotation in degrees (180: uniform over SO(3)) [default: 180, what the default
    /// angle-bin head trains on; the paper's quaternion head did not learn beyond about 45 (docs/experiments/paper-head.md)].
    #[arg(long)]
    pub max_rotation: Option<f64>,
    /// Samples per drawn fragment pair, at keypoints a patch radius apart: patches of one scene side by side in
    /// a batch are the contrastive loss's hard negatives [default: 1].
    #[arg(long)]
    pub patches_per_pair: Option<usize>,
    /// Share of the drawn fragment pairs (0..1) that give only wide-view matches: points the two fragments'
    /// sensors see from directions at least --wide-view-deg apart [default: 0, every match drawn uniformly].
    #[arg(long)]
    pub wide_view_share: Option<f64>,
    /// Smallest angle between the two sensors' view directions of a wide-view match, in degrees [default: 60].
    #[arg(long)]
    pub wide_view_deg: Option<f64>,
    /// Share of the training patches (0..1) cut to the points a second, virtual sensor also sees: the part of a
    /// patch two scans seen from far apart share [default: 0, no cuts].
    #[arg(long)]
    pub occlusion_share: Option<f64>,
    /// Smallest and largest angle, in degrees, between a cut patch's sensor and the virtual one, seen from the
    /// keypoint [default: 30,120].
    #[arg(long, value_name = "LO,HI", value_parser = angle_range)]
    pub occlusion_deg: Option<[f64; 2]>,
    /// Cut only the PPF branch's patches (the rotation-invariant codewords); the PC branch, RelativeNet's input,
    /// keeps whole patches.
    #[arg(long)]
    pub occlusion_ppf_only: bool,
    /// Start from these weights instead of a random initialisation (their config is used).
    #[arg(long)]
    pub init: Option<PathBuf>,
    /// Distil this trained model (its weights file) into a cheaper student: each step trains only the student's
    /// encoders to reproduce the teacher's PPF and PC codewords (mean squared difference); RelativeNet and the
    /// decoders are the teacher's, copied. The student's config is the teacher's with `--head-widths`. The loss
    /// flags do not apply; the log's `total` is the distillation loss. CPU only.
    #[arg(long, conflicts_with = "init")]
    pub distill_from: Option<PathBuf>,
    /// Widths of the per-point layers after the skip concatenation (the last is the codeword length, which a
    /// student keeps): e.g. 256,512 for a student about half the teacher's 512,512 cost [default: the teacher's
    /// or the preset's].
    #[arg(long, value_delimiter = ',')]
    pub head_widths: Option<Vec<usize>>,
    /// Save a checkpoint every K steps (0: only at the end).
    #[arg(long, default_value_t = 100)]
    pub checkpoint_every: u64,
    /// Checkpoint file [default: OUT with extension .ckpt.safetensors].
    #[arg(long)]
    pub checkpoint: Option<PathBuf>,
    /// Continue the run saved in this checkpoint, exactly where it stopped.
    #[arg(long)]
    pub resume: Option<PathBuf>,
    /// Stop this many seconds after the command started, data preparation included (at the end of the step
    /// that passes it), then save the checkpoint and the weights as at the last step: a run that must fit a
    /// time slot (0: no limit).
    #[arg(long, default_value_t = 0)]
    pub max_seconds: u64,
    /// Where the steps run: cpu (the reference trainer) or gpu (`gpu::train::DeviceTrainer`: the batch's
    /// activations, gradients, optimiser moments and weights stay on the device; f32 GEMM; any adapter). The
    /// sampling, checkpoints and logs are the same; `--pose-trains-ppf` is CPU-only.
    #[arg(long, default_value = "cpu", value_parser = ["cpu", "gpu"])]
    pub backend: String,
    /// Arithmetic of the CPU step's multiplies: f32, bf16 (bf16 products summed in f32 in the wide layers, on
    /// AMX tiles where the CPU has them; weights and Adam stay f32; needs AVX-512 BF16) or auto (bf16 where the
    /// CPU has it) [default: DPR_GPU_CPU_PRECISION, else auto; f32 with --backend gpu]. A resumed run keeps its
    /// own.
    #[arg(long, value_parser = ["f32", "bf16", "auto"])]
    pub precision: Option<String>,
    /// Append per-step losses to this CSV file (the header is written only when the file is new or empty; a
    /// resumed run first drops the rows after the checkpoint's step, which will be redone).
    #[arg(long)]
    pub log: Option<PathBuf>,
}

/// The checkpoint path: `--checkpoint`, or OUT with its extension replaced by `ckpt.safetensors`.
fn checkpoint_path(args: &Args) -> PathBuf {
    args.checkpoint.clone().unwrap_or_else(|| args.out.with_extension("ckpt.safetensors"))
}

/// The model configuration of a fresh run.
fn model_config(args: &Args) -> anyhow::Result<ModelConfig> {
    let mut config = match args.config.unwrap_or(ConfigPreset::Compact) {
        ConfigPreset::Compact => ModelConfig::default(),
        ConfigPreset::Paper => ModelConfig::paper(),
    };
    if let Some(n) = args.points {
        config.points_per_patch = n;
    }
    if let Some(g) = args.grid {
        config.grid = [g, g];
    }
    if let Some(widths) = &args.head_widths {
        config.head_widths.clone_from(widths);
    }
    config.radius = args.radius.unwrap_or(config.radius);
    config.pose_frame = args.pose_frame.unwrap_or(config.pose_frame);
    config.rotation_output = args.rotation_output.unwrap_or(config.rotation_output);
    config.validate()?;
    Ok(config)
}

/// The CPU step's precision `--precision` asks for (without it: `DPR_GPU_CPU_PRECISION`, else auto; f32 on the
/// device, whose trainer multiplies in f32).
fn train_precision(args: &Args) -> anyhow::Result<Precision> {
    let bf16 = Precision::Bf16.is_available();
    Ok(match (args.precision.as_deref(), args.backend.as_str()) {
        (Some("bf16"), "gpu") => bail!("--precision bf16 is for the CPU trainer; --backend gpu trains in f32"),
        (_, "gpu") | (Some("f32"), _) => Precision::F32,
        (Some("bf16"), _) if !bf16 => bail!("--precision bf16: this CPU has no AVX-512 BF16 (use f32 or auto)"),
        (Some(_), _) => {
            if bf16 {
                Precision::Bf16
            } else {
                Precision::F32
            }
        }
        (None, _) => crate::cpu::gemm::EncoderPrecision::from_env()?.0.for_training(),
    })
}

/// The settings of a fresh run.
fn fresh_settings(args: &Args) -> anyhow::Result<TrainSettings> {
    let mut s = TrainSettings { data: args.data.clone(), ..TrainSettings::default() };
    s.precision = train_precision(args)?;
    s.batch = args.batch.unwrap_or(s.batch);
    s.seed = args.seed.unwrap_or(s.seed);
    s.adam.lr = args.lr.unwrap_or(s.adam.lr);
    s.adam.lr_decay = args.lr_decay.unwrap_or(s.adam.lr_decay);
    s.adam.lr_decay_every = args.lr_decay_every.unwrap_or((args.steps / 3).max(1));
    s.adam.weight_decay = args.weight_decay.unwrap_or(s.adam.weight_decay);
    s.loss.lambda_pose = args.lambda_pose.unwrap_or(s.loss.lambda_pose);
    s.loss.lambda_feat = args.lambda_feat.unwrap_or(s.loss.lambda_feat);
    s.loss.rec = !args.no_rec;
    s.loss.pose = !args.no_pose;
    s.loss.feat = !args.no_feat;
    s.loss.pose_trains_ppf = args.pose_trains_ppf;
    s.loss.contrast = args.lambda_contrast.is_some_and(|v| v > 0.0);
    s.loss.lambda_contrast = args.lambda_contrast.unwrap_or(s.loss.lambda_contrast);
    s.loss.contrast_margin = args.contrast_margin.unwrap_or(s.loss.contrast_margin);
    s.sampling.voxel = args.voxel.unwrap_or(s.sampling.voxel);
    s.sampling.match_distance = args.match_distance.unwrap_or(s.sampling.match_distance);
    s.sampling.rotate_target = args.rotate_target;
    s.sampling.rotate_source = !args.no_rotate_source;
    s.sampling.max_rotation_deg = args.max_rotation.unwrap_or(s.sampling.max_rotation_deg);
    s.sampling.patches_per_pair = args.patches_per_pair.unwrap_or(s.sampling.patches_per_pair);
    s.sampling.wide_view_share = args.wide_view_share.unwrap_or(s.sampling.wide_view_share);
    s.sampling.wide_view_deg = args.wide_view_deg.unwrap_or(s.sampling.wide_view_deg);
    s.sampling.occlusion_share = args.occlusion_share.unwrap_or(s.sampling.occlusion_share);
    s.sampling.occlusion_deg = args.occlusion_deg.unwrap_or(s.sampling.occlusion_deg);
    s.sampling.occlusion_ppf_only = args.occlusion_ppf_only;
    s.distill_from = args.distill_from.clone();
    Ok(s)
}

/// Parses `LO,HI` (degrees).
fn angle_range(text: &str) -> Result<[f64; 2], String> {
    let parts: Vec<&str> = text.split(',').collect();
    let [lo, hi] = parts[..] else {
        return Err(format!("expected two angles LO,HI in degrees, got {text:?}"));
    };
    let angle = |t: &str| t.trim().parse::<f64>().map_err(|e| format!("{t:?} is not an angle: {e}"));
    Ok([angle(lo)?, angle(hi)?])
}

/// Refuses options that would change a resumed run.
fn check_resume_args(args: &Args, s: &TrainSettings, config: &ModelConfig) -> anyhow::Result<()> {
    let mut clashes = Vec::new();
    let mut check = |name: &str, differs: bool| {
        if differs {
            clashes.push(name.to_string());
        }
    };
    let sized = args.config.is_some() || args.points.is_some() || args.grid.is_some();
    check("--config/--points/--grid", sized && model_config(args).ok().as_ref() != Some(config));
    check("--radius", args.radius.is_some_and(|v| v != config.radius));
    check("--pose-frame", args.pose_frame.is_some_and(|v| v != config.pose_frame));
    check("--rotation-output", args.rotation_output.is_some_and(|v| v != config.rotation_output));
    check("--batch", args.batch.is_some_and(|v| v != s.batch));
    check("--seed", args.seed.is_some_and(|v| v != s.seed));
    check("--lr", args.lr.is_some_and(|v| v != s.adam.lr));
    check("--lr-decay", args.lr_decay.is_some_and(|v| v != s.adam.lr_decay));
    check("--lr-decay-every", args.lr_decay_every.is_some_and(|v| v != s.adam.lr_decay_every));
    check("--weight-decay", args.weight_decay.is_some_and(|v| v != s.adam.weight_decay));
    check("--lambda-pose", args.lambda_pose.is_some_and(|v| v != s.loss.lambda_pose));
    check("--lambda-feat", args.lambda_feat.is_some_and(|v| v != s.loss.lambda_feat));
    check("--no-rec", args.no_rec && s.loss.rec);
    check("--no-pose", args.no_pose && s.loss.pose);
    check("--no-feat", args.no_feat && s.loss.feat);
    let contrast_differs = |v: f64| (v > 0.0) != s.loss.contrast || (v > 0.0 && v != s.loss.lambda_contrast);
    check("--lambda-contrast", args.lambda_contrast.is_some_and(contrast_differs));
    check("--contrast-margin", args.contrast_margin.is_some_and(|v| v != s.loss.contrast_margin));
    check("--pose-trains-ppf", args.pose_trains_ppf && !s.loss.pose_trains_ppf);
    check("--distill-from", args.distill_from.is_some() && args.distill_from != s.distill_from);
    check("--head-widths", args.head_widths.as_ref().is_some_and(|w| *w != config.head_widths));
    check("--voxel", args.voxel.is_some_and(|v| v != s.sampling.voxel));
    check("--match-distance", args.match_distance.is_some_and(|v| v != s.sampling.match_distance));
    check("--rotate-target", args.rotate_target && !s.sampling.rotate_target);
    check("--no-rotate-source", args.no_rotate_source && s.sampling.rotate_source);
    check("--max-rotation", args.max_rotation.is_some_and(|v| v != s.sampling.max_rotation_deg));
    check("--patches-per-pair", args.patches_per_pair.is_some_and(|v| v != s.sampling.patches_per_pair));
    check("--wide-view-share", args.wide_view_share.is_some_and(|v| v != s.sampling.wide_view_share));
    check("--wide-view-deg", args.wide_view_deg.is_some_and(|v| v != s.sampling.wide_view_deg));
    check("--occlusion-share", args.occlusion_share.is_some_and(|v| v != s.sampling.occlusion_share));
    check("--occlusion-deg", args.occlusion_deg.is_some_and(|v| v != s.sampling.occlusion_deg));
    check("--occlusion-ppf-only", args.occlusion_ppf_only && !s.sampling.occlusion_ppf_only);
    check("--init", args.init.is_some());
    check("--precision", args.precision.is_some() && train_precision(args).ok() != Some(s.precision));
    if clashes.is_empty() {
        Ok(())
    } else {
        bail!("{} differ from the checkpoint's run and cannot change when resuming", clashes.join(", "))
    }
}

/// Opens the CSV log: fresh runs start it (header), resumed runs keep only the rows up to the checkpoint's
/// step (later rows belong to steps that will be redone) and append.
fn open_log(path: &Path, resumed_at: Option<u64>) -> anyhow::Result<std::fs::File> {
    const HEADER: &str = "step,total,rec,pose,feat,lr,seconds,contrast";
    if resumed_at.is_none() {
        let mut file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .with_context(|| format!("opening {}", path.display()))?;
        if file.metadata().map(|m| m.len() == 0).unwrap_or(true) {
            writeln!(file, "{HEADER}").with_context(|| format!("writing {}", path.display()))?;
        }
        return Ok(file);
    }
    let mut kept = vec![HEADER.to_string()];
    if let Some(step) = resumed_at
        && path.is_file()
    {
        let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        for line in text.lines().skip(1) {
            let s = line.split(',').next().and_then(|v| v.parse::<u64>().ok());
            if s.is_some_and(|s| s <= step) {
                kept.push(line.to_string());
            }
        }
    }
    crate::io::write_atomic(path, format!("{}\n", kept.join("\n")).as_bytes())?;
    std::fs::OpenOptions::new().append(true).open(path).with_context(|| format!("opening {}", path.display()))
}

/// Mean of the losses of the last steps.
fn mean(losses: &[Losses]) -> Losses {
    let k = 1.0 / losses.len().max(1) as f64;
    let mut m = Losses::default();
    losses.iter().for_each(|l| m.add_scaled(l, k));
    m
}

/// Most pairs per step.
pub const MAX_BATCH: usize = 4_096;

/// Fails early (not after hours of training) when an output cannot be written (a directory in its place, a
/// missing or read-only folder, weights not named .safetensors) or would destroy an input: any file of a dataset
/// folder (fragments, gt.log, poses.txt, ...), the `--init` weights, or (for `--out` and `--log`) the `--resume`
/// checkpoint, compared by file identity. Two outputs may not share a path.
fn check_train_outputs(args: &Args, ckpt: &Path) -> anyhow::Result<()> {
    let mut outputs: Vec<(&str, &Path)> = vec![("--out", &args.out), ("--checkpoint", ckpt)];
    if let Some(log) = &args.log {
        outputs.push(("--log", log));
    }
    for (flag, path) in &outputs {
        crate::io::check_output_path(flag, path)?;
    }
    let mut inputs: Vec<PathBuf> = Vec::new();
    for path in &args.data {
        inputs.extend(crate::eval::dataset::dataset_files(path)?);
    }
    inputs.extend(args.init.iter().cloned());
    let refs: Vec<&Path> = inputs.iter().map(PathBuf::as_path).collect();
    crate::io::check_outputs(&refs, &outputs)?;
    crate::cli::weights::check_weights_path("--out", &args.out)?;
    crate::cli::weights::check_weights_path("--checkpoint", ckpt)?;
    if let Some(resume) = &args.resume {
        // The checkpoint may be the resumed one (it is updated in place); the other outputs may not.
        outputs.retain(|(flag, _)| *flag != "--checkpoint");
        crate::io::check_outputs(&[resume], &outputs)?;
    }
    Ok(())
}

/// Runs `dpr-gpu train`.
pub fn run(args: Args) -> anyhow::Result<()> {
    let started = std::time::Instant::now();
    let ckpt = checkpoint_path(&args);
    if args.resume.is_none() && args.init.is_none() {
        model_config(&args)?;
    }
    check_train_outputs(&args, &ckpt)?;
    if let Some(b) = args.batch
        && !(1..=MAX_BATCH).contains(&b)
    {
        bail!("--batch must be 1..={MAX_BATCH}, got {b}");
    }
    let mut trainer = build_trainer(&args)?;
    let start = trainer.step_count();
    if start > args.steps {
        bail!("the checkpoint is already at step {start}, past --steps {}", args.steps);
    }
    if start == args.steps {
        // Nothing left to train: export the checkpoint's weights (e.g. to evaluate a run in progress).
        let mut weights = trainer.weights().clone();
        weights.notes.insert("dpr_gpu.train.steps".into(), start.to_string());
        weights.notes.insert("dpr_gpu.train.settings".into(), serde_json::to_string(trainer.settings())?);
        weights.save(&args.out)?;
        eprintln!("wrote {} from the checkpoint at step {start}", args.out.display());
        return Ok(());
    }
    // The device first: a run that cannot have it fails before preparing the data.
    let mut device = match args.backend.as_str() {
        "gpu" => Some(DeviceRun::new(&trainer)?),
        _ => None,
    };
    let sampler = trainer.sampler_mut();
    eprintln!("preparing {} fragments of {} pairs...", sampler.fragment_count(), sampler.pair_count());
    let usable = sampler.preload()?;
    if usable == 0 {
        bail!("no fragment pair has corresponding patches (check the data, --voxel and --match-distance)");
    }
    eprintln!("{usable} pairs with corresponding patches; {} parameters", trainer.weights().parameter_count());
    if device.is_none() {
        eprintln!("CPU step multiplies in {} (--precision)", trainer.settings().precision.name());
    }
    let recent = train_steps(&args, &mut trainer, device.as_mut(), (&ckpt, started))?;
    if let Some(d) = &device {
        d.sync(&mut trainer)?;
    }
    trainer.save_checkpoint(&ckpt)?;
    write_trained(&args, &trainer, &recent, &ckpt)
}

/// The trainer `args` ask for: resumed from a checkpoint, or fresh (from `--init` weights or new ones).
fn build_trainer(args: &Args) -> anyhow::Result<Trainer> {
    Ok(if let Some(resume) = &args.resume {
        let (meta, weights, adam) = read_checkpoint(resume)?;
        check_resume_args(args, &meta.settings, &meta.config)?;
        let mut settings = meta.settings;
        if !args.data.is_empty() {
            settings.data = args.data.clone();
        }
        let pairs = discover_pairs(&settings.data)?;
        Trainer::from_checkpoint_parts(weights, settings, pairs, adam, meta.step)?
    } else {
        let settings = fresh_settings(args)?;
        if args.init.is_some() && (args.config.is_some() || args.points.is_some() || args.grid.is_some()) {
            bail!("--init takes the model size from the weights file: drop --config, --points and --grid");
        }
        let sized = args.config.is_some() || args.points.is_some() || args.grid.is_some() || args.radius.is_some();
        if args.distill_from.is_some() && (sized || args.pose_frame.is_some() || args.rotation_output.is_some()) {
            bail!(
                "--distill-from takes the model from the teacher (with --head-widths): drop --config, --points, \
                 --grid, --radius, --pose-frame and --rotation-output"
            );
        }
        if args.distill_from.is_some() && args.backend != "cpu" {
            bail!("--distill-from runs on the CPU: drop --backend {}", args.backend);
        }
        let weights = initial_weights(args, &settings)?;
        let pairs = discover_pairs(&settings.data)?;
        Trainer::with_pairs(weights, settings, pairs)?
    })
}

/// The weights a fresh run starts from: `--init` (with `--radius` and a new pose head applied) or new ones.
fn initial_weights(args: &Args, settings: &TrainSettings) -> anyhow::Result<Weights> {
    if let Some(teacher) = &args.distill_from {
        let teacher = Weights::load(teacher)?;
        let mut config = teacher.config.clone();
        if let Some(widths) = &args.head_widths {
            config.head_widths.clone_from(widths);
        }
        config.validate().context("--head-widths")?;
        return Ok(crate::train::distill::student_weights(&teacher, &config, settings.seed)?);
    }
    Ok(match &args.init {
        Some(p) => {
            let mut w = Weights::load(p)?;
            if let Some(r) = args.radius {
                w.config.radius = r;
                w.config.validate().with_context(|| format!("--radius {r}"))?;
            }
            let frame = args.pose_frame.unwrap_or(w.config.pose_frame);
            let output = args.rotation_output.unwrap_or(w.config.rotation_output);
            if (frame, output) == (w.config.pose_frame, w.config.rotation_output) {
                w
            } else {
                eprintln!("--init: new pose head ({frame:?}, {output:?}): RelativeNet starts from random weights");
                w.with_pose_head(frame, output, settings.seed)?
            }
        }
        None => Weights::init(&model_config(args)?, settings.seed)?,
    })
}

/// Trains up to `--steps` (or `--max-seconds` after `started`), with the progress bar, the loss log and the
/// periodic checkpoints at `ckpt`; returns the last (up to 50) steps' losses.
fn train_steps(
    args: &Args,
    trainer: &mut Trainer,
    mut device: Option<&mut DeviceRun>,
    (ckpt, started): (&Path, std::time::Instant),
) -> anyhow::Result<Vec<Losses>> {
    let start = trainer.step_count();
    let mut log = match &args.log {
        Some(p) => Some(open_log(p, args.resume.as_ref().map(|_| start))?),
        None => None,
    };
    let bar = indicatif::ProgressBar::new(args.steps);
    bar.set_position(start);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} eta {eta} {msg}")
            .context("progress style")?
            .progress_chars("=> "),
    );
    let clock = std::time::Instant::now();
    let mut recent: Vec<Losses> = Vec::new();
    while trainer.step_count() < args.steps {
        let lr = trainer.learning_rate();
        let losses = match device.as_deref_mut() {
            Some(d) => trainer.step_with(|batch| crate::block_on(d.trainer.step(&d.gpu, batch)))?,
            None => trainer.step()?,
        };
        let step = trainer.step_count();
        if let Some(f) = log.as_mut() {
            let secs = clock.elapsed().as_secs_f64();
            let (t, r, p, e) = (losses.total, losses.rec, losses.pose, losses.feat);
            let c = losses.contrast;
            writeln!(f, "{step},{t:.6},{r:.6},{p:.6},{e:.6},{lr:.3e},{secs:.2},{c:.6}").context("writing the log")?;
        }
        recent.push(losses);
        if recent.len() > 50 {
            recent.remove(0);
        }
        let m = mean(&recent);
        bar.set_message(format!(
            "loss {:.4} rec {:.4} pose {:.4} feat {:.4} contrast {:.4}",
            m.total, m.rec, m.pose, m.feat, m.contrast
        ));
        bar.set_position(step);
        let out_of_time = args.max_seconds > 0 && started.elapsed().as_secs() >= args.max_seconds;
        if out_of_time {
            eprintln!("--max-seconds {}: stopping at step {step}", args.max_seconds);
            break;
        }
        if args.checkpoint_every > 0 && step.is_multiple_of(args.checkpoint_every) {
            if let Some(d) = &device {
                d.sync(trainer)?;
            }
            trainer.save_checkpoint(ckpt)?;
        }
    }
    bar.finish();
    Ok(recent)
}

/// Writes the trained weights to `--out` with the run's notes (command, steps, the mean of `recent` losses,
/// settings), and says so.
fn write_trained(args: &Args, trainer: &Trainer, recent: &[Losses], ckpt: &Path) -> anyhow::Result<()> {
    let mut weights = trainer.weights().clone();
    let m = mean(recent);
    let final_losses = serde_json::json!({
        "steps_averaged": recent.len(),
        "total": m.total, "rec": m.rec, "pose": m.pose, "feat": m.feat, "contrast": m.contrast,
    });
    weights.notes.insert("dpr_gpu.train.command".into(), std::env::args().collect::<Vec<_>>().join(" "));
    weights.notes.insert("dpr_gpu.train.steps".into(), trainer.step_count().to_string());
    weights.notes.insert("dpr_gpu.train.final_losses".into(), final_losses.to_string());
    weights.notes.insert("dpr_gpu.train.settings".into(), serde_json::to_string(trainer.settings())?);
    weights.save(&args.out)?;
    eprintln!(
        "wrote {} after {} steps (mean of the last {}: loss {:.4}, rec {:.4}, pose {:.4}, feat {:.4}); checkpoint {}",
        args.out.display(),
        trainer.step_count(),
        recent.len(),
        m.total,
        m.rec,
        m.pose,
        m.feat,
        ckpt.display()
    );
    Ok(())
}

/// The device a `--backend gpu` run trains on, and the model's state there.
struct DeviceRun {
    gpu: crate::gpu::Gpu,
    trainer: crate::gpu::train::DeviceTrainer,
}

impl DeviceRun {
    /// Any adapter (the user asked for the GPU backend), on an f32 GEMM, starting from `trainer`'s state.
    fn new(trainer: &Trainer) -> anyhow::Result<DeviceRun> {
        if trainer.settings().loss.pose_trains_ppf {
            bail!("--pose-trains-ppf runs on the CPU trainer only (drop --backend gpu)");
        }
        let gpu = crate::gpu::train::training_gpu().context("--backend gpu: creating the device")?;
        eprintln!("training on {}", gpu.adapter_info());
        let settings = trainer.settings();
        let device = crate::gpu::train::DeviceTrainer::new(&gpu, trainer.weights(), settings.loss, trainer.adam())?;
        Ok(DeviceRun { gpu, trainer: device })
    }

    /// Brings the host copy of the weights and optimiser state up to date (before a checkpoint or the output).
    fn sync(&self, trainer: &mut Trainer) -> anyhow::Result<()> {
        trainer.set_state(
            crate::block_on(self.trainer.weights(&self.gpu))?,
            crate::block_on(self.trainer.adam(&self.gpu))?,
        )?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cloud::PointCloud;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        args: Args,
    }

    fn parse(line: &str) -> Args {
        Cli::try_parse_from(std::iter::once("train").chain(line.split_whitespace())).expect("arguments parse").args
    }

    /// Two views of a floor with a box, the second moved by a known motion, as a pairs file.
    fn write_data(dir: &Path) {
        let mut points = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                let (a, b) = (i as f32 * 0.025, j as f32 * 0.025);
                points.push([a, b, 0.0]);
                if (0.3..0.6).contains(&a) && (0.3..0.6).contains(&b) {
                    points.push([a, b, 0.3]);
                }
                if a < 0.6 {
                    points.push([a, 0.0, b * 0.5]);
                }
            }
        }
        let source = PointCloud::from_points(points);
        let t = nalgebra::Matrix4::new_translation(&nalgebra::Vector3::new(0.2, -0.1, 0.3))
            * nalgebra::Matrix4::from_euler_angles(0.3, -0.2, 0.9);
        crate::io::write_ply(&dir.join("a.ply"), &source).unwrap();
        crate::io::write_ply(&dir.join("b.ply"), &source.transformed(&t)).unwrap();
        let flat: Vec<String> = (0..16).map(|k| format!("{:.12}", t[(k / 4, k % 4)])).collect();
        std::fs::write(dir.join("pairs.txt"), format!("a.ply b.ply {}\n", flat.join(" "))).unwrap();
    }

    #[test]
    fn distillation_trains_a_narrower_student_that_keeps_the_teachers_pose_head() {
        let scratch = tempfile::tempdir().unwrap();
        let dir = scratch.path();
        write_data(dir);
        let d = dir.display();
        let common = format!("--data {d}/pairs.txt --batch 2 --voxel 0.03 --checkpoint-every 0");
        run(parse(&format!("{common} --points 8 --grid 3 --out {d}/t.safetensors --steps 2"))).unwrap();
        let teacher = Weights::load(&dir.join("t.safetensors")).unwrap();
        let student_run = format!("{common} --distill-from {d}/t.safetensors --head-widths 64,512 --lr 0.003");
        run(parse(&format!("{student_run} --out {d}/s.safetensors --steps 12 --log {d}/s.csv"))).unwrap();
        let student = Weights::load(&dir.join("s.safetensors")).unwrap();
        assert_eq!(student.config, ModelConfig { head_widths: vec![64, 512], ..teacher.config.clone() });
        for (name, t) in &student.tensors {
            let same = teacher.tensors.get(name) == Some(t);
            // RelativeNet and the decoders stay the teacher's; every head layer is new and trained.
            if name.starts_with("relative.") || name.contains(".fold") {
                assert!(same, "{name} changed");
            } else if name.contains(".head.") {
                assert!(!same, "{name} is the teacher's");
            }
        }
        let log = std::fs::read_to_string(dir.join("s.csv")).unwrap();
        let losses: Vec<f64> = log.lines().skip(1).map(|l| l.split(',').nth(1).unwrap().parse().unwrap()).collect();
        assert_eq!(losses.len(), 12);
        assert!(losses[11] < losses[0], "distillation loss did not fall: {losses:?}");
        // The model comes from the teacher: size flags and the GPU trainer are refused.
        let e = run(parse(&format!("{student_run} --out {d}/x.safetensors --steps 1 --points 16"))).unwrap_err();
        assert!(e.to_string().contains("--distill-from"), "{e}");
        let e = run(parse(&format!("{student_run} --out {d}/x.safetensors --steps 1 --backend gpu"))).unwrap_err();
        assert!(e.to_string().contains("CPU"), "{e}");
    }

    #[test]
    fn train_checkpoints_resumes_exactly_and_writes_notes() {
        let scratch = tempfile::tempdir().unwrap();
        let dir = scratch.path();
        write_data(dir);
        let d = dir.display();
        let common = format!(
            "--data {d}/pairs.txt --points 8 --grid 3 --batch 2 --voxel 0.03 --checkpoint-every 2 --lr-decay-every 3"
        );
        run(parse(&format!("{common} --out {d}/a.safetensors --steps 4 --log {d}/a.csv"))).unwrap();
        // Resuming may not change the run.
        let clash =
            run(parse(&format!("{common} --out {d}/a.safetensors --steps 6 --resume {d}/a.ckpt.safetensors --lr 0.5")));
        assert!(clash.unwrap_err().to_string().contains("--lr"));
        run(parse(&format!("--out {d}/a.safetensors --steps 6 --log {d}/a.csv --resume {d}/a.ckpt.safetensors")))
            .unwrap();
        run(parse(&format!("{common} --out {d}/b.safetensors --steps 6"))).unwrap();
        let a = Weights::load(&dir.join("a.safetensors")).unwrap();
        let b = Weights::load(&dir.join("b.safetensors")).unwrap();
        assert!(a.tensors == b.tensors, "resumed run differs from the uninterrupted one");
        assert_eq!(a.notes["dpr_gpu.train.steps"], "6");
        assert!(a.notes.contains_key("dpr_gpu.train.command") && a.notes.contains_key("dpr_gpu.train.final_losses"));
        let log = std::fs::read_to_string(dir.join("a.csv")).unwrap();
        let steps: Vec<&str> = log.lines().skip(1).map(|l| l.split(',').next().unwrap()).collect();
        assert_eq!(steps, ["1", "2", "3", "4", "5", "6"], "{log}");
        // Bad outputs fail before training.
        let e = run(parse(&format!("{common} --out {d}/missing/w.safetensors"))).unwrap_err().to_string();
        assert!(e.contains("does not exist"), "{e}");
        // --radius: a fresh run's config takes it; with --init it fine-tunes those weights at that radius and
        // keeps their tensors as the starting point (exported before any step); a resumed run keeps it.
        run(parse(&format!("{common} --out {d}/r.safetensors --steps 1 --radius 0.6"))).unwrap();
        assert_eq!(Weights::load(&dir.join("r.safetensors")).unwrap().config.radius, 0.6);
        let at = |r: &str| format!("--data {d}/pairs.txt --batch 2 --voxel 0.03 --steps 0 --radius={r}");
        run(parse(&format!("{} --out {d}/f.safetensors --init {d}/a.safetensors", at("0.45")))).unwrap();
        let f = Weights::load(&dir.join("f.safetensors")).unwrap();
        assert_eq!(f.config, ModelConfig { radius: 0.45, ..a.config.clone() });
        assert!(f.tensors == a.tensors);
        let e = run(parse(&format!("{} --out {d}/g.safetensors --init {d}/a.safetensors", at("-1")))).unwrap_err();
        assert!(format!("{e:#}").contains("radius"), "{e:#}");
        let clash =
            run(parse(&format!("--out {d}/a.safetensors --steps 7 --resume {d}/a.ckpt.safetensors --radius 1")));
        assert!(clash.unwrap_err().to_string().contains("--radius"));
    }
}
