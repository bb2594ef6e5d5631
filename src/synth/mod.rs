//! Synthetic indoor scans in the 3DMatch layout.
//!
//! A scene is a procedural room ([`room`]) built from analytic primitives ([`geometry`], [`furniture`]),
//! scanned by a simulated Kinect-like depth camera ([`camera`]) along a smooth trajectory. Every
//! `frames_per_fragment` consecutive frames are fused by voxel averaging ([`fuse`]) into one fragment, expressed
//! in the camera frame of its first frame, so relative poses between fragments are arbitrary, as in 3DMatch.
//! [`write_dataset`] writes `scene_XX/cloud_bin_k.ply` with the official ground truth (`gt.log`, `gt.info`,
//! spec 3.3) plus `pairs.txt` and `poses.txt`.
//!
//! [`style`] selects the generator: `kinect` (the one described above, the default), `randomized` (domain
//! randomisation for training, including object-scale scenes), `heldout` and `heldout-tof` (each a different
//! sensor and scene families, kept for the generalisation check), `lidar` and `heldout-lidar` (outdoor sweeps of a
//! spinning LiDAR, [`lidar`] and [`outdoor`]: one sweep per fragment); styled scenes also write the parameters they
//! drew to `style.json`.
//!
//! Everything is deterministic per seed: each frame draws from its own derived random stream and results are
//! collected in order, so thread scheduling does not matter.

pub mod attic;
pub mod camera;
pub mod furniture;
pub mod fuse;
pub mod geometry;
pub mod heldout;
pub mod lidar;
pub mod object;
pub mod outdoor;
pub mod room;
pub mod sensor;
pub mod style;

use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::eval::groundtruth::{GroundTruthRule, GtPair, ground_truth_pairs};
use crate::eval::gtlog::{InfoRecord, LogRecord, format_info, format_log};
use crate::rng::Rng;
use camera::{CameraModel, MotionModel};
use nalgebra::Matrix4;
use rayon::prelude::*;
use room::Room;
use serde::Serialize;
use std::path::{Path, PathBuf};
use style::{Overrides, SceneRecipe, Style};

/// Everything that shapes a synthetic scene besides its seed.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SynthSettings {
    /// Fragments per scene.
    pub fragments: usize,
    /// Depth frames fused into each fragment.
    pub frames_per_fragment: usize,
    /// Fusion voxel size (metres); one output point per occupied voxel.
    pub voxel: f64,
    /// The depth camera.
    pub camera: CameraModel,
    /// How the camera moves.
    pub motion: MotionModel,
    /// The ground-truth rule for gt.log / gt.info.
    pub ground_truth: GroundTruthRule,
    /// The generator. `frames_per_fragment`, `voxel` and `camera` apply to [`Style::Kinect`] only; the other
    /// styles draw them per scene unless `overrides` fixes them.
    pub style: Style,
    /// Fixed values for the drawn parameters of the styled generators (every style but `kinect`).
    pub overrides: Overrides,
}

impl Default for SynthSettings {
    fn default() -> Self {
        SynthSettings {
            fragments: 10,
            frames_per_fragment: 15,
            voxel: 0.006,
            camera: CameraModel::default(),
            motion: MotionModel::default(),
            ground_truth: GroundTruthRule::default(),
            style: Style::Kinect,
            overrides: Overrides::default(),
        }
    }
}

/// One generated scene.
#[derive(Clone, Debug)]
pub struct Scene {
    /// The fused fragments, each in the camera frame of its first frame, with normals facing the cameras.
    pub fragments: Vec<PointCloud>,
    /// Pose of each fragment: x_world = world_from_fragment[k] x_fragment.
    pub world_from_fragment: Vec<Matrix4<f64>>,
    /// Every frame's world_from_camera pose, in scanning order.
    pub world_from_camera: Vec<Matrix4<f64>>,
    /// The room that was scanned (for object scenes: an empty floor plan whose objects are the object's parts).
    pub room: Room,
    /// What a styled scene drew (`None` for `kinect` and the LiDAR styles).
    pub recipe: Option<SceneRecipe>,
    /// What a LiDAR scene drew (`lidar`, `heldout-lidar`); its fragments are sweeps.
    pub lidar: Option<outdoor::LidarRecipe>,
}

impl Scene {
    /// The gt.log / gt.info pairs of this scene (spec 3.3); `seed` drives the subsampling of step 5.
    pub fn ground_truth(&self, rule: &GroundTruthRule, seed: u64) -> Vec<GtPair> {
        if self.lidar.is_some() {
            let pairs =
                ground_truth_pairs(&self.fragments, &self.world_from_fragment, &outdoor::lidar_rule(rule), seed);
            return outdoor::within_pair_distance(pairs, &self.world_from_fragment);
        }
        ground_truth_pairs(&self.fragments, &self.world_from_fragment, rule, seed)
    }

    /// The pose of fragment j in fragment i's frame: x_i = i_from_j x_j.
    pub fn i_from_j(&self, i: usize, j: usize) -> Matrix4<f64> {
        crate::pose::inverse(&self.world_from_fragment[i]) * self.world_from_fragment[j]
    }
}

/// Random stream ids of the parts of a scene.
const STREAM_ROOM: u64 = 0;
const STREAM_TRAJECTORY: u64 = 1;
const STREAM_GROUND_TRUTH: u64 = 2;
const STREAM_FRAMES: u64 = 1 << 32;

/// Builds a room (or an object), plans the trajectory, scans and fuses the fragments, in `settings.style`.
pub fn generate_scene(seed: u64, settings: &SynthSettings) -> Result<Scene> {
    if matches!(settings.style, Style::Lidar | Style::HeldoutLidar) {
        let s = outdoor::generate_lidar_scene(seed, settings.style, settings.fragments, &settings.overrides)?;
        let world_from_camera = s.world_from_fragment.clone();
        let (fragments, world_from_fragment, room) = (s.fragments, s.world_from_fragment, s.room);
        return Ok(Scene {
            fragments,
            world_from_fragment,
            world_from_camera,
            room,
            recipe: None,
            lidar: Some(s.recipe),
        });
    }
    if settings.style != Style::Kinect {
        let s = style::generate_styled_scene(seed, settings.style, settings.fragments, &settings.overrides)?;
        return Ok(Scene {
            fragments: s.fragments,
            world_from_fragment: s.world_from_fragment,
            world_from_camera: s.world_from_camera,
            room: s.room,
            recipe: Some(s.recipe),
            lidar: None,
        });
    }
    // The kinect generator has one room family and one trajectory: refuse what would silently be ignored.
    if settings.overrides.repeated || settings.overrides.orbit {
        return Err(Error::invalid("synth: repeated rooms and orbits apply to the randomized style only"));
    }
    if settings.fragments == 0 || settings.frames_per_fragment == 0 {
        return Err(Error::invalid("synth: fragments and frames per fragment must be at least 1"));
    }
    if !(settings.voxel > 0.0 && settings.voxel.is_finite()) {
        return Err(Error::invalid(format!("synth: voxel size must be positive, got {}", settings.voxel)));
    }
    if settings.camera.image.width == 0 || settings.camera.image.height == 0 {
        return Err(Error::invalid("synth: the camera needs at least one ray per row and column"));
    }
    let room = room::generate_room(&mut Rng::derived(seed, STREAM_ROOM));
    let m = settings.frames_per_fragment;
    let poses = camera::plan_trajectory(
        &room,
        &settings.motion,
        None,
        settings.fragments,
        m,
        &mut Rng::derived(seed, STREAM_TRAJECTORY),
    );
    let mut fragments = Vec::with_capacity(settings.fragments);
    let mut world_from_fragment = Vec::with_capacity(settings.fragments);
    for k in 0..settings.fragments {
        let base = poses[k * m];
        let fragment_from_world = crate::pose::inverse(&base);
        let frames: Vec<Vec<([f64; 3], [f64; 3])>> = (k * m..(k + 1) * m)
            .into_par_iter()
            .map(|n| {
                let mut rng = Rng::derived(seed, STREAM_FRAMES + n as u64);
                settings.camera.scan(&room.objects, &poses[n], &(fragment_from_world * poses[n]), &mut rng)
            })
            .collect();
        let samples: Vec<_> = frames.into_iter().flatten().collect();
        fragments.push(fuse::fuse_voxels(&samples, settings.voxel));
        world_from_fragment.push(base);
    }
    Ok(Scene { fragments, world_from_fragment, world_from_camera: poses, room, recipe: None, lidar: None })
}

/// What [`write_dataset`] produced for one scene.
#[derive(Clone, Debug, Serialize)]
pub struct SceneSummary {
    /// Folder name (`scene_XX`).
    pub name: String,
    /// Folder path.
    pub dir: PathBuf,
    /// The scene's own seed.
    pub seed: u64,
    /// Points per fragment.
    pub points: Vec<usize>,
    /// gt.log pairs.
    pub pairs: usize,
    /// gt.log pairs with j - i > 1 (the registration-recall set).
    pub non_consecutive: usize,
    /// Smallest and largest overlap among the gt.log pairs.
    pub overlap_range: Option<[f64; 2]>,
    /// What the scene is ("room" for `kinect`; see [`SceneRecipe::kind`]).
    pub kind: String,
}

/// The seed of scene `index` of a dataset generated with `seed`.
pub fn scene_seed(seed: u64, index: usize) -> u64 {
    Rng::derived(seed, index as u64).next_u64()
}

/// Files this generator writes in a scene folder (what `--force` replaces).
fn is_generated_file(name: &str) -> bool {
    matches!(name, "gt.log" | "gt.info" | "pairs.txt" | "poses.txt" | "style.json")
        || (name.starts_with("cloud_bin_") && name.ends_with(".ply"))
}

/// Refuses a non-empty existing folder unless `force`; with `force`, removes the files a previous run wrote.
fn prepare_dir(dir: &Path, force: bool) -> Result<()> {
    match std::fs::read_dir(dir) {
        Ok(entries) => {
            let entries: Vec<_> = entries.collect::<std::io::Result<_>>().map_err(|e| Error::io(dir, e))?;
            if entries.is_empty() {
                return Ok(());
            }
            if !force {
                return Err(Error::invalid(format!(
                    "{} exists and is not empty; pass --force to overwrite it",
                    dir.display()
                )));
            }
            for e in entries {
                let name = e.file_name().to_string_lossy().into_owned();
                if is_generated_file(&name) {
                    std::fs::remove_file(e.path()).map_err(|err| Error::io(e.path(), err))?;
                }
            }
            Ok(())
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))
        }
        Err(e) => Err(Error::io(dir, e)),
    }
}

fn matrix_row_major(m: &Matrix4<f64>) -> String {
    (0..16).map(|k| format!("{}", m[(k / 4, k % 4)])).collect::<Vec<_>>().join(" ")
}

/// Writes one scene folder: `cloud_bin_k.ply`, `gt.log`, `gt.info`, `pairs.txt`, `poses.txt` and, for styled
/// scenes, `style.json` (the drawn parameters). The folder must be empty or missing unless `force`.
pub fn write_scene(dir: &Path, scene: &Scene, gt: &[GtPair], force: bool) -> Result<()> {
    prepare_dir(dir, force)?;
    let n = scene.fragments.len();
    for (k, cloud) in scene.fragments.iter().enumerate() {
        crate::io::write_ply(&dir.join(format!("cloud_bin_{k}.ply")), cloud)?;
    }
    let log: Vec<LogRecord> = gt.iter().map(|p| LogRecord { i: p.i, j: p.j, n, i_from_j: p.i_from_j }).collect();
    let info: Vec<InfoRecord> =
        gt.iter().map(|p| InfoRecord { i: p.i, j: p.j, n, information: p.information }).collect();
    crate::io::write_atomic(&dir.join("gt.log"), format_log(&log).as_bytes())?;
    crate::io::write_atomic(&dir.join("gt.info"), format_info(&info).as_bytes())?;
    let mut pairs = String::from(
        "# Format: one pair per non-comment line:\n\
         #   source_file target_file t00 t01 t02 t03 t10 t11 t12 t13 t20 t21 t22 t23 t30 t31 t32 t33\n\
         # Paths are relative to this folder. T is the 4x4 ground-truth rigid transform, row-major, with\n\
         #   p_target = T * p_source. These are the gt.log pairs: record 'i j' maps fragment j into fragment i,\n\
         #   so source = cloud_bin_j.ply and target = cloud_bin_i.ply. Synthetic data: T is exact.\n",
    );
    for p in gt {
        pairs.push_str(&format!("# gt.log ({}, {}) overlap {:.3}\n", p.i, p.j, p.overlap));
        pairs.push_str(&format!("cloud_bin_{}.ply cloud_bin_{}.ply {}\n", p.j, p.i, matrix_row_major(&p.i_from_j)));
    }
    crate::io::write_atomic(&dir.join("pairs.txt"), pairs.as_bytes())?;
    let mut poses = String::from(
        "# One line per fragment: k, then world_from_fragment (x_world = T x_fragment) as 16 numbers, row-major.\n\
         # The gt.log matrix of pair (i, j) is inv(T_i) T_j.\n",
    );
    for (k, m) in scene.world_from_fragment.iter().enumerate() {
        poses.push_str(&format!("{k} {}\n", matrix_row_major(m)));
    }
    crate::io::write_atomic(&dir.join("poses.txt"), poses.as_bytes())?;
    let recipe = match (&scene.recipe, &scene.lidar) {
        (Some(r), _) => Some(serde_json::to_string_pretty(r)),
        (None, Some(l)) => Some(serde_json::to_string_pretty(l)),
        (None, None) => None,
    };
    if let Some(json) = recipe {
        let json = json.map_err(|e| Error::invalid(format!("synth: cannot serialise the scene recipe: {e}")))?;
        crate::io::write_atomic(&dir.join("style.json"), format!("{json}\n").as_bytes())?;
    }
    Ok(())
}

/// Generates `scenes` scenes into `out/scene_XX/`. Every scene folder is checked first: an existing non-empty
/// one is an error unless `force`. `on_scene` is called after each scene is written.
pub fn write_dataset(
    out: &Path,
    seed: u64,
    scenes: usize,
    settings: &SynthSettings,
    force: bool,
    mut on_scene: impl FnMut(&SceneSummary),
) -> Result<Vec<SceneSummary>> {
    let dirs: Vec<(String, PathBuf)> = (0..scenes)
        .map(|s| {
            let name = format!("scene_{s:02}");
            let dir = out.join(&name);
            (name, dir)
        })
        .collect();
    if !force {
        for (_, dir) in &dirs {
            if std::fs::read_dir(dir).map(|mut e| e.next().is_some()).unwrap_or(false) {
                return Err(Error::invalid(format!(
                    "{} exists and is not empty; pass --force to overwrite it",
                    dir.display()
                )));
            }
        }
    }
    let mut summaries = Vec::with_capacity(scenes);
    for (s, (name, dir)) in dirs.into_iter().enumerate() {
        let scene_seed = scene_seed(seed, s);
        let scene = generate_scene(scene_seed, settings)?;
        let gt = scene.ground_truth(&settings.ground_truth, Rng::derived(scene_seed, STREAM_GROUND_TRUTH).next_u64());
        write_scene(&dir, &scene, &gt, force)?;
        let overlaps = gt.iter().map(|p| p.overlap);
        let overlap_range = (!gt.is_empty())
            .then(|| [overlaps.clone().fold(f64::INFINITY, f64::min), overlaps.fold(f64::NEG_INFINITY, f64::max)]);
        let summary = SceneSummary {
            name,
            dir,
            seed: scene_seed,
            points: scene.fragments.iter().map(|f| f.len()).collect(),
            pairs: gt.len(),
            non_consecutive: gt.iter().filter(|p| p.j > p.i + 1).count(),
            overlap_range,
            kind: match (&scene.recipe, &scene.lidar) {
                (Some(r), _) => r.kind.clone(),
                (None, Some(l)) => l.kind.clone(),
                (None, None) => "room".to_string(),
            },
        };
        on_scene(&summary);
        summaries.push(summary);
    }
    Ok(summaries)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fast configuration for tests: coarse camera, few frames.
    fn tiny() -> SynthSettings {
        SynthSettings {
            fragments: 3,
            frames_per_fragment: 4,
            camera: CameraModel::default().with_size(64, 48),
            voxel: 0.01,
            ..SynthSettings::default()
        }
    }

    #[test]
    fn scenes_are_deterministic_per_seed() {
        let a = generate_scene(5, &tiny()).unwrap();
        let b = generate_scene(5, &tiny()).unwrap();
        let c = generate_scene(6, &tiny()).unwrap();
        assert_eq!(a.fragments, b.fragments);
        assert_eq!(a.world_from_fragment, b.world_from_fragment);
        assert_ne!(a.fragments, c.fragments);
        assert!(
            a.fragments.iter().all(|f| f.len() > 1000),
            "{:?}",
            a.fragments.iter().map(|f| f.len()).collect::<Vec<_>>()
        );
    }

    #[test]
    fn consecutive_fragments_overlap_under_the_ground_truth() {
        let scene = generate_scene(11, &tiny()).unwrap();
        let gt = scene.ground_truth(&GroundTruthRule::default(), 0);
        assert!(
            gt.iter().any(|p| p.i == 0 && p.j == 1),
            "{:?}",
            gt.iter().map(|p| (p.i, p.j, p.overlap)).collect::<Vec<_>>()
        );
        for p in &gt {
            assert!(p.overlap >= 0.3 && p.information[(0, 0)] > 100.0);
            assert!((p.i_from_j - scene.i_from_j(p.i, p.j)).norm() < 1e-12);
        }
    }

    #[test]
    fn invalid_settings_are_rejected() {
        assert!(generate_scene(0, &SynthSettings { fragments: 0, ..tiny() }).is_err());
        assert!(generate_scene(0, &SynthSettings { voxel: 0.0, ..tiny() }).is_err());
    }
}
