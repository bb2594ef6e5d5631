//! `dpr-gpu synth`: procedural indoor scenes scanned by a simulated depth camera, in the 3DMatch layout.

use crate::synth::camera::CameraModel;
use crate::synth::{SynthSettings, write_dataset};
use anyhow::{Context, bail};
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `dpr-gpu synth`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Output folder; scenes go to OUT/scene_00, OUT/scene_01, ...
    pub out: PathBuf,
    /// Number of scenes.
    #[arg(long, default_value_t = 1)]
    pub scenes: usize,
    /// Fragments per scene.
    #[arg(long, default_value_t = 10)]
    pub fragments: usize,
    /// Seed; the same seed gives identical files.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Fusion voxel size in metres.
    #[arg(long, default_value_t = 0.006)]
    pub voxel: f64,
    /// Depth frames fused into each fragment.
    #[arg(long, default_value_t = 15)]
    pub frames: usize,
    /// Camera rays per row (the column count follows the 4:3 aspect ratio).
    #[arg(long, default_value_t = 160)]
    pub width: usize,
    /// Overwrite existing non-empty scene folders.
    #[arg(long)]
    pub force: bool,
}

/// Most scenes per run.
pub const MAX_SCENES: usize = 10_000;
/// Most fragments per scene.
pub const MAX_FRAGMENTS: usize = 10_000;
/// Most depth frames per fragment.
pub const MAX_FRAMES: usize = 1_000;
/// Widest camera (rays per row; 4096 x 3072 rays per frame).
pub const MAX_WIDTH: usize = 4_096;
/// Most camera rays per fragment (width x height x frames): bounds the memory of one fused fragment.
pub const MAX_RAYS_PER_FRAGMENT: usize = 1 << 30;

/// Checks every size against its bound before anything is allocated; the error names the option and limit.
fn check_bounds(args: &Args) -> anyhow::Result<()> {
    for (flag, value, max) in [
        ("--scenes", args.scenes, MAX_SCENES),
        ("--fragments", args.fragments, MAX_FRAGMENTS),
        ("--frames", args.frames, MAX_FRAMES),
    ] {
        if !(1..=max).contains(&value) {
            bail!("{flag} must be 1..={max}, got {value}");
        }
    }
    if !(4..=MAX_WIDTH).contains(&args.width) {
        bail!("--width must be 4..={MAX_WIDTH}, got {}", args.width);
    }
    let rays = args.width * (args.width * 3 / 4) * args.frames;
    if rays > MAX_RAYS_PER_FRAGMENT {
        bail!(
            "--width {} x --frames {} makes {rays} rays per fragment, over the limit of {MAX_RAYS_PER_FRAGMENT}",
            args.width,
            args.frames
        );
    }
    if !(args.voxel.is_finite() && args.voxel >= 1e-4) {
        bail!("--voxel must be at least 0.0001 m, got {}", args.voxel);
    }
    Ok(())
}

/// Runs `dpr-gpu synth`.
pub fn run(args: Args) -> anyhow::Result<()> {
    check_bounds(&args)?;
    let settings = SynthSettings {
        fragments: args.fragments,
        frames_per_fragment: args.frames,
        voxel: args.voxel,
        camera: CameraModel { width: args.width, height: args.width * 3 / 4, ..CameraModel::default() },
        ..SynthSettings::default()
    };
    let started = Instant::now();
    let mut last = Instant::now();
    let summaries = write_dataset(&args.out, args.seed, args.scenes, &settings, args.force, |s| {
        let mean_points = s.points.iter().sum::<usize>() / s.points.len().max(1);
        let overlap = s.overlap_range.map_or_else(|| "-".into(), |[lo, hi]| format!("{lo:.2}-{hi:.2}"));
        println!(
            "{}: {} fragments, {} points per fragment on average, {} gt pairs ({} non-consecutive), overlap {}, {:.1} s",
            s.dir.display(),
            s.points.len(),
            mean_points,
            s.pairs,
            s.non_consecutive,
            overlap,
            last.elapsed().as_secs_f64()
        );
        last = Instant::now();
    })
    .with_context(|| format!("synth into {}", args.out.display()))?;
    let pairs: usize = summaries.iter().map(|s| s.pairs).sum();
    println!("{} scenes, {} gt pairs in {:.1} s", summaries.len(), pairs, started.elapsed().as_secs_f64());
    Ok(())
}
