//! `dpr-gpu synth`: procedural indoor scenes scanned by a simulated depth camera (or outdoor scenes scanned by a
//! simulated LiDAR), in the 3DMatch layout.

use crate::eval::groundtruth::GroundTruthRule;
use crate::synth::camera::CameraModel;
use crate::synth::style::{Overrides, Style};
use crate::synth::{SynthSettings, write_dataset};
use anyhow::{Context, bail};
use std::path::PathBuf;
use std::time::Instant;

/// Which scene kinds `--style randomized` generates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum SceneKind {
    /// Rooms and corridors, and about 30 % object-scale scenes.
    Mixed,
    /// Rooms and corridors only.
    Room,
    /// Object-scale scenes only.
    Object,
    /// Rooms and corridors that first get rows of identical pieces (classroom desks, library shelves, rows of
    /// chairs, canteen tables, cabinets side by side): repetition for training and tuning.
    Repeated,
}

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
    /// Seed; the same seed (and arguments) gives identical files.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Generator style. kinect: the original Kinect-like generator. randomized: domain randomisation for
    /// training (noise model and level, density, voxel, dropouts and holes, intrinsics and range, room and
    /// furniture families, wide trajectories, about 30 % object-scale scenes); writes the drawn parameters to
    /// style.json. heldout: structured-light camera in halls with families no other style builds;
    /// heldout-tof: low time-of-flight camera in attic flats with families no other style builds. lidar: a
    /// 32-ring spinning LiDAR (range noise growing with range, beam divergence, returns thinning with range,
    /// no sky returns) on a vehicle driving through a street (buildings with recessed facades, curbs, poles,
    /// parked cars, trees and bushes); one sweep per fragment, 1-3 m apart, gt pairs 1-10 m apart; --width
    /// sets the azimuth steps. heldout-lidar: a 64-ring scanner with another vertical field of view in an
    /// industrial yard (containers, tanks, sheds, trailers, heaps) that lidar never builds. The three
    /// held-out styles are the generalisation checks - never train or tune on them.
    #[arg(long, value_enum, default_value_t = Style::Kinect)]
    pub style: Style,
    /// Smallest overlap for a pair to enter gt.log [default: 0.30 (3DMatch rule); 0.20 for --style randomized].
    #[arg(long)]
    pub min_overlap: Option<f64>,
    /// Largest overlap for a pair to enter gt.log [default: 1]; with --min-overlap 0.1, 0.3 gives
    /// 3DLoMatch-style low-overlap pairs (for evaluation: `eval` reports recall by overlap bin).
    #[arg(long)]
    pub max_overlap: Option<f64>,
    /// Scene kinds of --style randomized: mixed (about 30 % object-scale scenes), room, object, or repeated
    /// (rooms with rows of identical pieces).
    #[arg(long, value_enum, default_value_t = SceneKind::Mixed)]
    pub scene_kind: SceneKind,
    /// --style randomized rooms: the camera walks around the room's centre looking across it, instead of
    /// turning near the centre, so fragments see the same surfaces from directions far apart (60 degrees and
    /// more). Object-scale scenes already circle their object.
    #[arg(long)]
    pub orbit: bool,
    /// Fusion voxel size in metres [default: 0.006 for kinect; drawn per scene by the other styles].
    #[arg(long)]
    pub voxel: Option<f64>,
    /// Depth frames fused into each fragment [default: 15 for kinect; drawn per scene by the other styles].
    #[arg(long)]
    pub frames: Option<usize>,
    /// Camera rays per row [default: 160 for kinect, 4:3; drawn per scene by the other styles, which keep their
    /// drawn aspect ratio].
    #[arg(long)]
    pub width: Option<usize>,
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
    for (flag, value, max) in [("--scenes", args.scenes, MAX_SCENES), ("--fragments", args.fragments, MAX_FRAGMENTS)] {
        if !(1..=max).contains(&value) {
            bail!("{flag} must be 1..={max}, got {value}");
        }
    }
    if let Some(frames) = args.frames
        && !(1..=MAX_FRAMES).contains(&frames)
    {
        bail!("--frames must be 1..={MAX_FRAMES}, got {frames}");
    }
    if let Some(width) = args.width
        && !(4..=MAX_WIDTH).contains(&width)
    {
        bail!("--width must be 4..={MAX_WIDTH}, got {width}");
    }
    // The styles draw their own sizes well inside the limit; overrides are checked with the defaults they
    // combine with.
    let defaults = SynthSettings::default();
    let (width, frames) =
        (args.width.unwrap_or(defaults.camera.image.width), args.frames.unwrap_or(defaults.frames_per_fragment));
    let rays = width * (width * 3 / 4) * frames;
    if rays > MAX_RAYS_PER_FRAGMENT {
        bail!(
            "--width {width} x --frames {frames} makes {rays} rays per fragment, over the limit of {MAX_RAYS_PER_FRAGMENT}"
        );
    }
    if let Some(voxel) = args.voxel
        && !(voxel.is_finite() && voxel >= 1e-4)
    {
        bail!("--voxel must be at least 0.0001 m, got {voxel}");
    }
    Ok(())
}

/// Runs `dpr-gpu synth`.
pub fn run(args: Args) -> anyhow::Result<()> {
    check_bounds(&args)?;
    if args.scene_kind != SceneKind::Mixed && args.style != Style::Randomized {
        bail!("--scene-kind applies to --style randomized only");
    }
    if args.orbit && (args.style != Style::Randomized || args.scene_kind == SceneKind::Object) {
        bail!("--orbit applies to the rooms of --style randomized only");
    }
    let min_overlap = args.min_overlap.unwrap_or(args.style.default_min_overlap());
    if !(0.0..=1.0).contains(&min_overlap) {
        bail!("--min-overlap must be between 0 and 1, got {min_overlap}");
    }
    let max_overlap = args.max_overlap.unwrap_or(1.0);
    if !(min_overlap..=1.0).contains(&max_overlap) {
        bail!("--max-overlap must be between --min-overlap ({min_overlap}) and 1, got {max_overlap}");
    }
    let defaults = SynthSettings::default();
    let width = args.width.unwrap_or(defaults.camera.image.width);
    let settings = SynthSettings {
        fragments: args.fragments,
        frames_per_fragment: args.frames.unwrap_or(defaults.frames_per_fragment),
        voxel: args.voxel.unwrap_or(defaults.voxel),
        camera: CameraModel::default().with_size(width, width * 3 / 4),
        ground_truth: GroundTruthRule { min_overlap, max_overlap, ..GroundTruthRule::default() },
        style: args.style,
        overrides: Overrides {
            voxel: args.voxel,
            frames_per_fragment: args.frames,
            width: args.width,
            object_scenes: match args.scene_kind {
                SceneKind::Mixed => None,
                SceneKind::Room | SceneKind::Repeated => Some(false),
                SceneKind::Object => Some(true),
            },
            repeated: args.scene_kind == SceneKind::Repeated,
            orbit: args.orbit,
        },
        ..defaults
    };
    let started = Instant::now();
    let mut last = Instant::now();
    let summaries = write_dataset(&args.out, args.seed, args.scenes, &settings, args.force, |s| {
        let mean_points = s.points.iter().sum::<usize>() / s.points.len().max(1);
        let overlap = s.overlap_range.map_or_else(|| "-".into(), |[lo, hi]| format!("{lo:.2}-{hi:.2}"));
        println!(
            "{} ({}): {} fragments, {} points per fragment on average, {} gt pairs ({} non-consecutive), overlap {}, {:.1} s",
            s.dir.display(),
            s.kind,
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
