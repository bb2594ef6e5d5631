//! Scene styles: `kinect` (the original generator), `randomized` (domain randomisation for training), and two
//! generalisation checks that are never to be trained or tuned on, each with its own sensor and scene families:
//! `heldout` (structured light in open-plan halls) and `heldout-tof` (time of flight in attic flats).
//!
//! A styled scene first draws a [`SceneRecipe`] from its seed (sensor, noise model and level, density, fusion
//! voxel, room or object family, trajectory or viewpoints, per-fragment variations), then scans it. The recipe
//! is written next to the fragments as `style.json`.

use super::attic::{AtticRecord, camera_room, generate_attic};
use super::camera::{MotionModel, OrbitModel, PinholeImage, look_pose, plan_trajectory};
use super::heldout::{HallRecord, generate_hall};
use super::object::{ObjectFamily, generate_object};
use super::room::{Room, RoomShape, RoomSpec, generate_room_with};
use super::sensor::{DepthNoise, Sensor};
use crate::cloud::PointCloud;
use crate::rng::Rng;
use nalgebra::{Matrix4, Vector3};
use rayon::prelude::*;
use serde::Serialize;

/// How a scene is generated.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "snake_case")]
pub enum Style {
    /// The original generator: Kinect-like camera, hand-held trajectory, fixed ranges (byte-identical to
    /// earlier versions for the same arguments).
    #[default]
    Kinect,
    /// Domain randomisation for training: noise model and level, density, fusion voxel, dropouts and holes,
    /// intrinsics and range, room and furniture families, wide trajectories, and object-scale scenes.
    Randomized,
    /// The generalisation check: a structured-light camera (quantised disparity, projector shadows) in halls
    /// with families no other style builds. Never train or tune on it.
    Heldout,
    /// The second generalisation check: a low-mounted time-of-flight camera (noise growing with depth squared
    /// over the incidence cosine, periodic depth bias, mixed pixels at depth edges) in attic flats under
    /// pitched roofs with families no other style builds. Never train or tune on it.
    HeldoutTof,
    /// Outdoor LiDAR: a 32-ring spinning scanner on a vehicle driving through a street (buildings, curbs,
    /// poles, parked cars, vegetation); one sweep per fragment ([`super::outdoor`]).
    Lidar,
    /// The LiDAR generalisation check: a 64-ring scanner with another vertical field of view in an
    /// industrial yard with families `lidar` never builds. Never train or tune on it.
    HeldoutLidar,
}

impl Style {
    /// The default gt.log overlap threshold: 0.30 (the 3DMatch rule), 0.20 for `randomized` so training sees
    /// low-overlap pairs.
    pub fn default_min_overlap(self) -> f64 {
        match self {
            Style::Randomized => 0.20,
            Style::Kinect | Style::Heldout | Style::HeldoutTof | Style::Lidar | Style::HeldoutLidar => 0.30,
        }
    }
}

/// Values that replace drawn ones in the styled generators (`None`: drawn).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Overrides {
    /// Fusion voxel size.
    pub voxel: Option<f64>,
    /// Frames fused into each fragment.
    pub frames_per_fragment: Option<usize>,
    /// Rays per image row (the column count keeps the drawn aspect ratio).
    pub width: Option<usize>,
    /// `randomized` only: `Some(true)` makes every scene object-scale, `Some(false)` none (about 30 % are by
    /// default).
    pub object_scenes: Option<bool>,
    /// `randomized` rooms only: furnish rows of identical pieces first ([`RoomSpec::repeated`]).
    pub repeated: bool,
    /// `randomized` rooms only: the camera walks around the room looking across it ([`OrbitModel`]) instead of
    /// turning near its centre.
    pub orbit: bool,
}

/// Fragments larger than this are fused again with a coarser voxel.
pub const MAX_FRAGMENT_POINTS: usize = 300_000;

/// What an object scene drew.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ObjectRecord {
    /// The object family.
    pub family: ObjectFamily,
    /// Largest extent of the object (scene units).
    pub size: f64,
    /// Camera distance from the object centre, per fragment.
    pub distance: Vec<f64>,
    /// Camera azimuth per fragment (degrees).
    pub azimuth_deg: Vec<f64>,
    /// Camera elevation per fragment (degrees).
    pub elevation_deg: Vec<f64>,
}

/// What a room scene drew.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RoomRecord {
    /// The ranges the room was drawn from (the floor plan is fixed by the style).
    pub spec: RoomSpec,
    /// How the camera moved.
    pub motion: MotionModel,
    /// The orbit the camera walked (`Overrides::orbit`): `motion` then gives only height, pitch, roll and
    /// wall margin.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub orbit: Option<OrbitModel>,
}

/// Per-fragment variation of the scene's sensor.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FragmentRecord {
    /// Noise level relative to the scene's.
    pub noise_scale: f64,
    /// Random dropout probability of this fragment.
    pub dropout: f64,
    /// Fusion voxel actually used (larger than the scene's when the fragment had to be capped).
    pub voxel: f64,
    /// Points in the fused fragment.
    pub points: usize,
}

/// Every parameter a styled scene drew (written as `style.json`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SceneRecipe {
    /// The style.
    pub style: Style,
    /// The scene seed.
    pub seed: u64,
    /// "room", "corridor", "l_room", "hall", "attic" or "object".
    pub kind: String,
    /// The sensor (scene-level values; see `fragments` for per-fragment changes).
    pub sensor: Sensor,
    /// Fusion voxel size.
    pub voxel: f64,
    /// Frames fused into each fragment.
    pub frames_per_fragment: usize,
    /// Probability that an object has an absorbing material.
    pub dark_probability: f64,
    /// Extra dropout of absorbing objects.
    pub dark_dropout: f64,
    /// Room draws (room and corridor scenes).
    pub room: Option<RoomRecord>,
    /// Hall draws (`heldout`).
    pub hall: Option<HallRecord>,
    /// Attic draws (`heldout-tof`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub attic: Option<AtticRecord>,
    /// Object draws (object scenes).
    pub object: Option<ObjectRecord>,
    /// Per fragment.
    pub fragments: Vec<FragmentRecord>,
}

/// Random stream ids of a styled scene.
const STREAM_RECIPE: u64 = 3;
const STREAM_SCENE: u64 = 4;
const STREAM_POSES: u64 = 5;
const STREAM_MATERIALS: u64 = 6;
const STREAM_FRAGMENT: u64 = 1 << 20;
const STREAM_FRAMES: u64 = 1 << 32;

/// A fully generated styled scene.
pub struct StyledScene {
    /// Fused fragments in their first camera's frame.
    pub fragments: Vec<PointCloud>,
    /// x_world = world_from_fragment[k] x_fragment.
    pub world_from_fragment: Vec<Matrix4<f64>>,
    /// Every frame's pose.
    pub world_from_camera: Vec<Matrix4<f64>>,
    /// The scanned scene (for object scenes: an empty floor plan holding the object's parts).
    pub room: Room,
    /// What was drawn.
    pub recipe: SceneRecipe,
}

fn aspect_height(width: usize, hfov_deg: f64, vfov_deg: f64) -> usize {
    let ratio = (vfov_deg.to_radians() / 2.0).tan() / (hfov_deg.to_radians() / 2.0).tan();
    ((width as f64 * ratio).round() as usize).max(1)
}

/// A pinhole image `width` rays wide with fields of view `fov_deg` (horizontal, vertical), as many rows as
/// keep square pixels, returning depths in `depth` at incidence angles up to `max_incidence_deg`.
fn aspect_image(width: usize, fov_deg: (f64, f64), depth: (f64, f64), max_incidence_deg: f64) -> PinholeImage {
    PinholeImage {
        width,
        height: aspect_height(width, fov_deg.0, fov_deg.1),
        hfov_deg: fov_deg.0,
        vfov_deg: fov_deg.1,
        min_depth: depth.0,
        max_depth: depth.1,
        max_incidence_deg,
    }
}

/// The randomized style's sensor, before resolution and range are fitted to the scene kind.
fn randomized_sensor(rng: &mut Rng, object: bool) -> Sensor {
    let hfov = rng.uniform(45.0, 90.0);
    let aspect = [4.0 / 3.0, 16.0 / 9.0, 5.0 / 4.0, 16.0 / 10.0][rng.below(4)];
    let vfov = 2.0 * ((hfov / 2.0f64).to_radians().tan() / aspect).atan().to_degrees();
    let width = if object { 320 + rng.below(241) } else { 128 + rng.below(97) };
    // Object scenes are in units of about a tenth of a metre: noise levels scale down accordingly.
    let unit = if object { 0.5 } else { 1.0 };
    let noise = match rng.below(3) {
        0 => DepthNoise::Constant { sigma: rng.uniform(0.0005, 0.006) * unit },
        1 => DepthNoise::Proportional { per_unit: rng.uniform(0.0005, 0.004) * unit * unit },
        _ => DepthNoise::Quadratic {
            a: rng.uniform(0.0005, 0.002) * unit,
            b: rng.uniform(0.0008, 0.004) * unit * unit * unit,
            z0: rng.uniform(0.3, 0.6),
        },
    };
    let small_hole = rng.uniform(0.02, 0.05);
    // Drawn in this order (the generator's streams depend on it).
    let (min_depth, max_depth, dropout, max_incidence_deg) =
        (rng.uniform(0.2, 0.6), rng.uniform(3.0, 8.0), rng.uniform(0.0, 0.12), rng.uniform(65.0, 85.0));
    Sensor {
        image: aspect_image(width, (hfov, vfov), (min_depth, max_depth), max_incidence_deg),
        dropout,
        noise,
        max_holes: rng.below(5),
        hole_radius: [small_hole, small_hole + rng.uniform(0.02, 0.1)],
        projector_baseline: None,
        mixed_pixel_footprint: None,
    }
}

/// The held-out structured-light camera.
fn heldout_sensor(rng: &mut Rng) -> Sensor {
    let hfov = rng.uniform(58.0, 72.0);
    let aspect = [4.0 / 3.0, 16.0 / 10.0][rng.below(2)];
    let vfov = 2.0 * ((hfov / 2.0f64).to_radians().tan() / aspect).atan().to_degrees();
    let width = 128 + rng.below(65);
    let native_width = [640.0, 848.0, 1280.0][rng.below(3)];
    let baseline = rng.uniform(0.05, 0.09);
    // Drawn in this order (the generator's streams depend on it).
    let (min_depth, max_depth, dropout, max_incidence_deg) =
        (rng.uniform(0.4, 0.6), rng.uniform(4.0, 6.0), rng.uniform(0.01, 0.04), rng.uniform(70.0, 80.0));
    Sensor {
        image: aspect_image(width, (hfov, vfov), (min_depth, max_depth), max_incidence_deg),
        dropout,
        noise: DepthNoise::Disparity {
            focal_px: native_width / 2.0 / (hfov.to_radians() / 2.0).tan(),
            baseline,
            sigma_px: rng.uniform(0.05, 0.15),
            subpixel: [4.0, 8.0][rng.below(2)],
        },
        max_holes: rng.below(2),
        hole_radius: [0.02, 0.05],
        projector_baseline: Some(baseline),
        mixed_pixel_footprint: None,
    }
}

/// The held-out time-of-flight camera: low resolution, short range, mixed pixels.
fn tof_sensor(rng: &mut Rng) -> Sensor {
    let hfov = rng.uniform(62.0, 80.0);
    let aspect = [1.0, 5.0 / 4.0, 4.0 / 3.0][rng.below(3)];
    let vfov = 2.0 * ((hfov / 2.0f64).to_radians().tan() / aspect).atan().to_degrees();
    let width = 112 + rng.below(81);
    // Drawn in this order (the generator's streams depend on it).
    let (min_depth, max_depth, dropout, max_incidence_deg) =
        (rng.uniform(0.25, 0.4), rng.uniform(3.5, 5.5), rng.uniform(0.005, 0.03), rng.uniform(75.0, 85.0));
    Sensor {
        image: aspect_image(width, (hfov, vfov), (min_depth, max_depth), max_incidence_deg),
        dropout,
        noise: DepthNoise::TimeOfFlight {
            sigma_at_1m: rng.uniform(0.0015, 0.004),
            wiggle_amplitude: rng.uniform(0.003, 0.01),
            wiggle_period: rng.uniform(0.6, 1.5),
            wiggle_phase: rng.uniform(0.0, std::f64::consts::TAU),
        },
        max_holes: rng.below(2),
        hole_radius: [0.02, 0.06],
        projector_baseline: None,
        mixed_pixel_footprint: Some(rng.uniform(1.0, 2.0)),
    }
}

/// The sensor with its noise level scaled by `s`.
fn scaled_noise(sensor: &Sensor, s: f64) -> DepthNoise {
    match sensor.noise.clone() {
        DepthNoise::Constant { sigma } => DepthNoise::Constant { sigma: sigma * s },
        DepthNoise::Proportional { per_unit } => DepthNoise::Proportional { per_unit: per_unit * s },
        DepthNoise::Quadratic { a, b, z0 } => DepthNoise::Quadratic { a: a * s, b: b * s, z0 },
        DepthNoise::Disparity { focal_px, baseline, sigma_px, subpixel } => {
            DepthNoise::Disparity { focal_px, baseline, sigma_px: sigma_px * s, subpixel }
        }
        DepthNoise::TimeOfFlight { sigma_at_1m, wiggle_amplitude, wiggle_period, wiggle_phase } => {
            DepthNoise::TimeOfFlight { sigma_at_1m: sigma_at_1m * s, wiggle_amplitude, wiggle_period, wiggle_phase }
        }
    }
}

/// Camera poses around an object centred on the origin: fragment k looks at the object from azimuth
/// `az[k]` and elevation `el[k]` at distance `dist[k]`; its frames are small perturbations of that view.
fn object_poses(
    rng: &mut Rng,
    fragments: usize,
    frames: usize,
    size: f64,
    sensor: &Sensor,
) -> (Vec<Matrix4<f64>>, Vec<f64>, Vec<f64>, Vec<f64>) {
    let radius = size * 0.75;
    let half_fov = sensor.image.hfov_deg.min(sensor.image.vfov_deg).to_radians() / 2.0;
    let az0 = rng.uniform(0.0, 360.0);
    let step = 360.0 / fragments as f64 * rng.uniform(0.6, 1.0);
    let sense = if rng.below(2) == 0 { 1.0 } else { -1.0 };
    let (mut poses, mut dists, mut azs, mut els) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for k in 0..fragments {
        let az = az0 + sense * k as f64 * step + rng.uniform(-0.25, 0.25) * step;
        let el = rng.uniform(-25.0, 65.0);
        let dist = radius / half_fov.sin() * rng.uniform(0.8, 1.3);
        let roll = rng.uniform(-25.0, 25.0);
        azs.push(az);
        els.push(el);
        dists.push(dist);
        for f in 0..frames {
            let (daz, del, dd) = if f == 0 {
                (0.0, 0.0, 0.0)
            } else {
                (rng.uniform(-3.0, 3.0), rng.uniform(-3.0, 3.0), rng.uniform(-0.05, 0.05) * dist)
            };
            let (a, e, d) = ((az + daz).to_radians(), (el + del).to_radians(), dist + dd);
            let position = Vector3::new(d * e.cos() * a.cos(), d * e.cos() * a.sin(), d * e.sin());
            let target = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.03 * size;
            let f = (target - position).normalize();
            let yaw = f.y.atan2(f.x);
            let pitch = f.z.clamp(-1.0, 1.0).asin();
            poses.push(look_pose(position, yaw, pitch, (roll + rng.uniform(-1.0, 1.0)).to_radians()));
        }
    }
    (poses, dists, azs, els)
}

/// Fuses `samples` at `voxel`, coarsening the voxel by 25 % steps until at most [`MAX_FRAGMENT_POINTS`].
fn fuse_capped(samples: &[([f64; 3], [f64; 3])], voxel: f64) -> (PointCloud, f64) {
    let mut v = voxel;
    loop {
        let cloud = super::fuse::fuse_voxels(samples, v);
        if cloud.len() <= MAX_FRAGMENT_POINTS {
            return (cloud, v);
        }
        v *= 1.25;
    }
}

/// Draws the recipe of a styled scene (any style but `kinect`) from `seed` and scans it into `fragments`
/// fragments.
pub fn generate_styled_scene(
    seed: u64,
    style: Style,
    fragments: usize,
    overrides: &Overrides,
) -> crate::error::Result<StyledScene> {
    check_styled_request(style, fragments, overrides)?;
    let mut rng = Rng::derived(seed, STREAM_RECIPE);
    let drawn_object = rng.unit_f64() < 0.3;
    let object = style == Style::Randomized && overrides.object_scenes.unwrap_or(drawn_object);
    let mut sensor = match style {
        Style::Heldout => heldout_sensor(&mut rng),
        Style::HeldoutTof => tof_sensor(&mut rng),
        _ => randomized_sensor(&mut rng, object),
    };
    let (voxel_range, frames_range) = match (style, object) {
        (Style::Heldout, _) => ([0.006, 0.01], [8, 15]),
        (Style::HeldoutTof, _) => ([0.005, 0.009], [6, 12]),
        (_, true) => ([0.003, 0.006], [2, 5]),
        _ => ([0.004, 0.010], [8, 20]),
    };
    let voxel = overrides.voxel.unwrap_or(rng.uniform(voxel_range[0], voxel_range[1]));
    let frames =
        overrides.frames_per_fragment.unwrap_or(frames_range[0] + rng.below(frames_range[1] - frames_range[0] + 1));
    if let Some(w) = overrides.width {
        sensor.image.height = aspect_height(w, sensor.image.hfov_deg, sensor.image.vfov_deg);
        sensor.image.width = w;
    }
    let (dark_probability, dark_dropout) = match style {
        Style::Heldout => (0.0, 0.0),
        Style::HeldoutTof => (rng.uniform(0.05, 0.2), rng.uniform(0.3, 0.7)),
        _ => (rng.uniform(0.0, 0.15), rng.uniform(0.4, 0.95)),
    };
    let mut streams = LayoutStreams {
        recipe: rng,
        scene: Rng::derived(seed, STREAM_SCENE),
        poses: Rng::derived(seed, STREAM_POSES),
        fragments,
        frames,
    };
    let layout = if object {
        object_layout(&mut streams, &mut sensor)
    } else if style == Style::Heldout {
        hall_layout(&mut streams)
    } else if style == Style::HeldoutTof {
        attic_layout(&mut streams)
    } else {
        room_layout(&mut streams, overrides)
    };
    let Layout { room, poses, kind, room_record, hall, attic, object: object_record } = layout;
    let mut material_rng = Rng::derived(seed, STREAM_MATERIALS);
    let object_dropout: Vec<f64> = room
        .objects
        .iter()
        .map(|_| if material_rng.unit_f64() < dark_probability { dark_dropout } else { 0.0 })
        .collect();
    let scanned = scan_fragments(seed, style, &sensor, (&room, &object_dropout), (&poses, frames), (fragments, voxel));
    let (clouds, world_from_fragment, records) = scanned;
    let recipe = SceneRecipe {
        style,
        seed,
        kind,
        sensor,
        voxel,
        frames_per_fragment: frames,
        dark_probability,
        dark_dropout,
        room: room_record,
        hall,
        attic,
        object: object_record,
        fragments: records,
    };
    Ok(StyledScene { fragments: clouds, world_from_fragment, world_from_camera: poses, room, recipe })
}

/// Refuses requests a styled scene cannot honour.
fn check_styled_request(style: Style, fragments: usize, overrides: &Overrides) -> crate::error::Result<()> {
    use crate::error::Error;
    if matches!(style, Style::Kinect | Style::Lidar | Style::HeldoutLidar) {
        return Err(Error::invalid("synth: the kinect and LiDAR styles are generated by generate_scene"));
    }
    if fragments == 0 || overrides.frames_per_fragment == Some(0) {
        return Err(Error::invalid("synth: fragments and frames per fragment must be at least 1"));
    }
    if let Some(v) = overrides.voxel
        && !(v > 0.0 && v.is_finite())
    {
        return Err(Error::invalid(format!("synth: voxel size must be positive, got {v}")));
    }
    if overrides.width.is_some_and(|w| w < 4) {
        return Err(Error::invalid("synth: the camera needs at least 4 rays per row"));
    }
    if overrides.orbit && (style != Style::Randomized || overrides.object_scenes == Some(true)) {
        return Err(Error::invalid("synth: orbits apply to the rooms of the randomized style only"));
    }
    Ok(())
}

/// The random streams a scene's layout draws from (the recipe's, the scene geometry's, the trajectory's) and
/// the trajectory's size.
struct LayoutStreams {
    recipe: Rng,
    scene: Rng,
    poses: Rng,
    fragments: usize,
    frames: usize,
}

/// What was scanned and from where, with the draws that describe it.
struct Layout {
    room: Room,
    poses: Vec<Matrix4<f64>>,
    kind: String,
    room_record: Option<RoomRecord>,
    hall: Option<HallRecord>,
    attic: Option<AtticRecord>,
    object: Option<ObjectRecord>,
}

/// An object-scale scene: one object, the camera circling it (the sensor's depth range follows).
fn object_layout(streams: &mut LayoutStreams, sensor: &mut Sensor) -> Layout {
    let rng = &mut streams.recipe;
    let family =
        [ObjectFamily::Blob, ObjectFamily::Assembly, ObjectFamily::Miniature, ObjectFamily::Cluster][rng.below(4)];
    let size = rng.uniform(1.5, 2.5);
    let objects = generate_object(&mut streams.scene, family, size);
    let (poses, distance, azimuth_deg, elevation_deg) =
        object_poses(&mut streams.poses, streams.fragments, streams.frames, size, sensor);
    let far = distance.iter().fold(0.0f64, |m, &d| m.max(d));
    sensor.image.min_depth = 0.2;
    sensor.image.max_depth = far + size;
    let room = Room { polygon: Vec::new(), height: 0.0, kernel_center: [0.0, 0.0], objects, footprints: Vec::new() };
    let record = ObjectRecord { family, size, distance, azimuth_deg, elevation_deg };
    Layout { room, poses, kind: "object".to_string(), room_record: None, hall: None, attic: None, object: Some(record) }
}

/// `heldout`: a hall.
fn hall_layout(streams: &mut LayoutStreams) -> Layout {
    let rng = &mut streams.recipe;
    let (room, hall) = generate_hall(&mut streams.scene);
    let motion = MotionModel {
        yaw_per_fragment_deg: [rng.uniform(20.0, 30.0), rng.uniform(40.0, 60.0)],
        pitch_deg: [-30.0, -5.0],
        height: [1.2, 1.8],
        wall_margin: 0.5,
        back_fraction: [0.1, 0.8],
        lateral: 0.8,
        roll_deg: 5.0,
    };
    let poses = plan_trajectory(&room, &motion, None, streams.fragments, streams.frames, &mut streams.poses);
    let record = RoomRecord { spec: RoomSpec::default(), motion, orbit: None };
    Layout {
        room,
        poses,
        kind: "hall".to_string(),
        room_record: Some(record),
        hall: Some(hall),
        attic: None,
        object: None,
    }
}

/// `heldout-tof`: an attic flat under a pitched roof (the camera kept below the roof).
fn attic_layout(streams: &mut LayoutStreams) -> Layout {
    let rng = &mut streams.recipe;
    let (room, roof, attic) = generate_attic(&mut streams.scene);
    let motion = MotionModel {
        yaw_per_fragment_deg: [rng.uniform(12.0, 20.0), rng.uniform(25.0, 35.0)],
        pitch_deg: [-25.0, 5.0],
        height: [0.6, 1.2],
        wall_margin: 0.4,
        back_fraction: [0.1, 0.7],
        lateral: 0.6,
        roll_deg: 3.0,
    };
    let planning = camera_room(&room, &roof, motion.height[1], 0.3);
    let poses = plan_trajectory(&planning, &motion, None, streams.fragments, streams.frames, &mut streams.poses);
    let record = RoomRecord { spec: RoomSpec::default(), motion, orbit: None };
    Layout {
        room,
        poses,
        kind: "attic".to_string(),
        room_record: Some(record),
        hall: None,
        attic: Some(attic),
        object: None,
    }
}

/// `randomized` rooms and corridors, with the camera turning near the centre or orbiting.
fn room_layout(streams: &mut LayoutStreams, overrides: &Overrides) -> Layout {
    let rng = &mut streams.recipe;
    let shape = match rng.below(20) {
        0..=7 => RoomShape::Rectangle,
        8..=15 => RoomShape::LShape,
        _ => RoomShape::Corridor,
    };
    let spec = RoomSpec {
        width: [3.0, 9.0],
        depth: if shape == RoomShape::Corridor { [5.0, 11.0] } else { [3.0, 8.0] },
        height: [2.3, 3.5],
        shape: Some(shape),
        corridor_width: [1.6, 2.6],
        density: rng.uniform(0.6, 1.4),
        extra_families: true,
        repeated: overrides.repeated,
    };
    let yaw_lo = rng.uniform(15.0, 40.0);
    let pitch_lo = rng.uniform(-45.0, -20.0);
    let height_lo = rng.uniform(1.0, 1.4);
    let motion = MotionModel {
        yaw_per_fragment_deg: [yaw_lo, yaw_lo + rng.uniform(10.0, 60.0)],
        pitch_deg: [pitch_lo, rng.uniform(-10.0, 10.0)],
        height: [height_lo, rng.uniform(1.5, 2.0)],
        wall_margin: 0.4,
        back_fraction: [rng.uniform(0.0, 0.2), rng.uniform(0.6, 0.95)],
        lateral: rng.uniform(0.3, 1.2),
        roll_deg: rng.uniform(3.0, 15.0),
    };
    // Drawn only for orbits, so the other scenes' recipes stay as they were.
    let orbit = overrides.orbit.then(|| OrbitModel {
        arc_per_fragment_deg: [rng.uniform(25.0, 35.0), rng.uniform(45.0, 65.0)],
        radius_fraction: [rng.uniform(0.3, 0.6), rng.uniform(0.7, 0.95)],
        aim_deg: rng.uniform(10.0, 35.0),
    });
    let room = generate_room_with(&mut streams.scene, &spec);
    let (fragments, frames) = (streams.fragments, streams.frames);
    let poses = plan_trajectory(&room, &motion, orbit.as_ref(), fragments, frames, &mut streams.poses);
    let kind = match shape {
        RoomShape::Rectangle => "room",
        RoomShape::LShape => "l_room",
        RoomShape::Corridor => "corridor",
    };
    let room_record = Some(RoomRecord { spec, motion, orbit });
    Layout { room, poses, kind: kind.to_string(), room_record, hall: None, attic: None, object: None }
}

/// Scans and fuses every fragment: fragment k fuses frames `k * frames..(k + 1) * frames` of `poses` in the
/// frame of its first, with its own variation of `sensor` (noise scale and dropout, from its own stream).
fn scan_fragments(
    seed: u64,
    style: Style,
    sensor: &Sensor,
    (room, object_dropout): (&Room, &[f64]),
    (poses, frames): (&[Matrix4<f64>], usize),
    (fragments, voxel): (usize, f64),
) -> (Vec<PointCloud>, Vec<Matrix4<f64>>, Vec<FragmentRecord>) {
    let per_fragment: Vec<(Sensor, f64, f64)> = (0..fragments)
        .map(|k| {
            let mut r = Rng::derived(seed, STREAM_FRAGMENT + k as u64);
            let noise_scale =
                if matches!(style, Style::Heldout | Style::HeldoutTof) { 1.0 } else { r.uniform(0.7, 1.4) };
            let dropout = (sensor.dropout + r.uniform(-0.02, 0.05)).clamp(0.0, 0.2);
            let s = Sensor { noise: scaled_noise(sensor, noise_scale), dropout, ..sensor.clone() };
            (s, noise_scale, dropout)
        })
        .collect();
    let mut clouds = Vec::with_capacity(fragments);
    let mut world_from_fragment = Vec::with_capacity(fragments);
    let mut records = Vec::with_capacity(fragments);
    for (k, (frag_sensor, noise_scale, dropout)) in per_fragment.into_iter().enumerate() {
        let base = poses[k * frames];
        let fragment_from_world = crate::pose::inverse(&base);
        let samples: Vec<_> = (k * frames..(k + 1) * frames)
            .into_par_iter()
            .map(|n| {
                let mut r = Rng::derived(seed, STREAM_FRAMES + n as u64);
                frag_sensor.scan(&room.objects, object_dropout, &poses[n], &(fragment_from_world * poses[n]), &mut r)
            })
            .collect::<Vec<_>>()
            .into_iter()
            .flatten()
            .collect();
        let (cloud, used_voxel) = fuse_capped(&samples, voxel);
        records.push(FragmentRecord { noise_scale, dropout, voxel: used_voxel, points: cloud.len() });
        clouds.push(cloud);
        world_from_fragment.push(base);
    }
    (clouds, world_from_fragment, records)
}
