//! Training pairs of corresponding patches from registered fragment pairs.
//!
//! Sources: any layout `crate::eval::dataset::load_dataset` reads — 3DMatch scene folders (`cloud_bin_k.ply` +
//! `gt.log`, record `i j` maps fragment j into fragment i, so j is the source and i the target), folders of
//! such scenes, or a pairs file (`source target` + 16 numbers, p_target = T p_source).
//!
//! Each fragment is prepared once and cached: voxel downsampling, PCA normals facing the origin (the sensor of
//! a 3DMatch fragment), a k-d tree, and a flag per point telling whether its patch would have enough points.
//! Each fragment pair gets, once, its list of matches: every usable source point whose mapped position has a
//! usable target point within `match_distance` (the target keypoint is that nearest point).
//!
//! A sample draws a pair, a match, two patch seeds and two rotations from the step's random stream, then builds
//! both patches with `crate::preprocess`. With `wide_view_share` > 0 that share of the drawn pairs gives only
//! wide-view matches: correspondences whose two sensors (each fragment's origin) see the point from directions
//! at least `wide_view_deg` apart, the views that random draws from ordinary trajectories rarely give. With
//! `occlusion_share` > 0 that share of the patches is cut to what a virtual second sensor sees too
//! (`super::occlusion`), the part of a patch two scans seen from far apart share.
//!
//! Augmentation rotates the source fragment about the origin by a uniform random rotation R_s (and, when enabled,
//! the target fragment by R_t); the label is the rotation of the augmented target_from_source, R_t R R_s^T, which
//! is uniform over SO(3) when R_s is. Rotating about the origin rather than the keypoint only changes the
//! translation, which the centred patch inputs cancel; the normals are rotated with the points (their viewpoint,
//! the origin, is fixed by the rotation). With normal-frame patches (`PoseFrame::Normal`) each patch is further
//! rotated by its keypoint's normal frame F, and the label becomes the rotation between the two aligned patches,
//! `F_t (R_t R R_s^T) F_s^T`.

use super::objective::PairSample;
use super::occlusion::{second_sensor, visible_from};
use crate::cloud::PointCloud;
use crate::cpu::rotation_head::normal_frame;
use crate::error::{Error, Result};
use crate::io::{LoadOptions, read_cloud};
use crate::model::ModelConfig;
use crate::model::config::PoseFrame;
use crate::pose::{matrix_from_quaternion, nearest_rotation, random_rotation};
use crate::preprocess::{
    GatheredPatches, Patches, estimate_normals, extract_patch_where, extract_patches, gather, voxel_downsample,
};
use crate::rng::Rng;
use crate::spatial::PointIndex;
use nalgebra::{Matrix3, Matrix4, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// How training pairs are drawn.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DataSettings {
    /// Voxel size for downsampling each fragment (cloud units); 0 keeps every point.
    pub voxel: f32,
    /// Neighbours for PCA normals.
    pub normal_neighbors: usize,
    /// A source point has a correspondence when a target point lies within this distance of its mapped
    /// position.
    pub match_distance: f32,
    /// A keypoint is usable when at least this many other points lie within the patch radius.
    pub min_patch_points: usize,
    /// Rotate the source fragment by a uniform random rotation.
    pub rotate_source: bool,
    /// Rotate the target fragment too (independently).
    pub rotate_target: bool,
    /// Largest augmentation rotation angle in degrees: 180 draws uniformly from all of SO(3); smaller values
    /// draw uniformly from the rotations up to this angle (uniform SO(3) restricted by rejection).
    #[serde(default = "full_turn")]
    pub max_rotation_deg: f64,
    /// Samples drawn from each drawn fragment pair (at keypoints at least a patch radius apart in the target
    /// fragment). More than one puts patches of the same scene side by side in a batch: the hard negatives of
    /// the contrastive loss (repeated structure in one room), where one per pair mostly contrasts unrelated
    /// scenes.
    #[serde(default = "one")]
    pub patches_per_pair: usize,
    /// Share of the drawn fragment pairs (0..=1) whose samples are all wide-view matches (see
    /// `wide_view_deg`), drawn among the pairs that have some; 0 draws every match uniformly.
    #[serde(default)]
    pub wide_view_share: f64,
    /// A match is wide-view when the directions from its point to the two fragments' sensors (each fragment's
    /// origin) are at least this many degrees apart.
    #[serde(default = "sixty")]
    pub wide_view_deg: f64,
    /// Share of the patches (0..=1, each of a sample's two drawn independently) cut to what a second sensor
    /// would see too (`super::occlusion`): the part two scans seen from far apart share. 0 cuts none.
    #[serde(default)]
    pub occlusion_share: f64,
    /// Range of the angle (degrees) between a cut patch's own sensor and its second sensor, seen from the
    /// keypoint.
    #[serde(default = "occlusion_angles")]
    pub occlusion_deg: [f64; 2],
    /// Cuts reach the PPF branch only: the pose-variant PC branch (RelativeNet's input) keeps the whole patch.
    #[serde(default)]
    pub occlusion_ppf_only: bool,
}

fn full_turn() -> f64 {
    180.0
}

fn one() -> usize {
    1
}

fn sixty() -> f64 {
    60.0
}

fn occlusion_angles() -> [f64; 2] {
    [30.0, 120.0]
}

impl Default for DataSettings {
    /// 2.5 cm voxels, 30 normal neighbours (as inference), 3 cm matches, at least 32 points per patch,
    /// source rotation only, uniform over SO(3), one sample per drawn pair, matches drawn uniformly, no
    /// occlusion cuts.
    fn default() -> Self {
        DataSettings {
            voxel: 0.025,
            normal_neighbors: 30,
            match_distance: 0.03,
            min_patch_points: 32,
            rotate_source: true,
            rotate_target: false,
            max_rotation_deg: 180.0,
            patches_per_pair: 1,
            wide_view_share: 0.0,
            wide_view_deg: 60.0,
            occlusion_share: 0.0,
            occlusion_deg: occlusion_angles(),
            occlusion_ppf_only: false,
        }
    }
}

/// Two registered fragments.
#[derive(Clone, Debug, PartialEq)]
pub struct FragmentPair {
    /// The source fragment's file.
    pub source: PathBuf,
    /// The target fragment's file.
    pub target: PathBuf,
    /// p_target = target_from_source p_source.
    pub target_from_source: Matrix4<f64>,
}

/// Every registered fragment pair under `paths` (each a dataset folder, scene folder, gt.log or pairs file).
pub fn discover_pairs(paths: &[PathBuf]) -> Result<Vec<FragmentPair>> {
    let mut out = Vec::new();
    for path in paths {
        for scene in crate::eval::dataset::load_dataset(path)? {
            for e in &scene.gt {
                let file = |k: usize| {
                    scene.files.get(k).cloned().ok_or_else(|| {
                        Error::invalid(format!(
                            "{}: pair ({}, {}) names a fragment that does not exist",
                            scene.dir.display(),
                            e.i,
                            e.j
                        ))
                    })
                };
                out.push(FragmentPair { source: file(e.j)?, target: file(e.i)?, target_from_source: e.i_from_j });
            }
        }
    }
    if out.is_empty() {
        return Err(Error::invalid("no registered fragment pairs found in the training data"));
    }
    Ok(out)
}

/// A fragment prepared for sampling.
pub struct Fragment {
    /// Downsampled points.
    pub points: Vec<[f32; 3]>,
    /// Their normals.
    pub normals: Vec<[f32; 3]>,
    /// Index over `points`.
    pub index: PointIndex,
    /// Whether each point has at least `min_patch_points` others within the radius.
    pub usable: Vec<bool>,
}

impl Fragment {
    /// Loads and prepares `path`.
    pub fn load(path: &Path, settings: &DataSettings, radius: f32) -> Result<Fragment> {
        let (cloud, _) = read_cloud(path, &LoadOptions::default())?;
        Fragment::prepare(&cloud, settings, radius).map_err(|e| Error::invalid(format!("{}: {e}", path.display())))
    }

    /// Prepares a cloud already in memory.
    pub fn prepare(cloud: &PointCloud, settings: &DataSettings, radius: f32) -> Result<Fragment> {
        let cloud = if settings.voxel > 0.0 { voxel_downsample(cloud, settings.voxel)? } else { cloud.clone() };
        if cloud.len() < 2 {
            return Err(Error::invalid(format!("fragment has {} points after downsampling", cloud.len())));
        }
        let index = PointIndex::new(&cloud.points)?;
        let normals = estimate_normals(&cloud.points, &index, settings.normal_neighbors, [0.0; 3]);
        let k = settings.min_patch_points + 1;
        let usable = cloud
            .points
            .par_iter()
            .map(|p| {
                let nn = index.nearest_n(p, k);
                nn.len() == k && nn[k - 1].distance_squared <= radius * radius
            })
            .collect();
        Ok(Fragment { points: cloud.points, normals, index, usable })
    }
}

/// A pair's correspondences and, when wide-view draws are on, which of them are wide-view.
struct PairMatches {
    /// (source point, target point) indices into the prepared fragments.
    all: Vec<(u32, u32)>,
    /// Indices into `all`.
    wide: Vec<u32>,
}

type Matches = Arc<PairMatches>;

/// Where one sample comes from: everything random about it, drawn in the sequential phase.
#[derive(Clone, Copy, Debug)]
struct Plan {
    pair: usize,
    source_point: u32,
    target_point: u32,
    seeds: [u64; 2],
    rotations: [[f64; 4]; 2],
    /// Per patch, the stream of its occlusion cut, if cut.
    cuts: [Option<u64>; 2],
}

/// Draws training samples; deterministic given (seed, step).
pub struct Sampler {
    pairs: Vec<FragmentPair>,
    /// Fragment id of each pair's (source, target).
    pair_fragments: Vec<(usize, usize)>,
    files: Vec<PathBuf>,
    fragments: Vec<Option<Arc<Fragment>>>,
    matches: Vec<Option<Matches>>,
    settings: DataSettings,
    radius: f32,
    points_per_patch: usize,
    pose_frame: PoseFrame,
}

/// Occluders of an occlusion cut: the points within this many patch radii of the keypoint.
const OCCLUDER_RADII: f32 = 2.0;

/// Pair draws per sample before giving up (pairs without any match are skipped).
const MAX_DRAWS: usize = 1000;

/// Largest `DataSettings::patches_per_pair`.
pub const MAX_PATCHES_PER_PAIR: usize = 64;

/// Match draws per extra sample of a pair while looking for one a patch radius away from those drawn; after
/// that the nearest-to-separate draw is taken anyway (a small overlap region may not fit them all).
const SEPARATION_DRAWS: usize = 32;

fn squared_distance(a: [f32; 3], b: [f32; 3]) -> f32 {
    (0..3).map(|k| (a[k] - b[k]) * (a[k] - b[k])).sum()
}

/// The angle (radians) at `point` between the directions to two sensors.
fn view_angle(point: &Vector3<f64>, sensor_a: &Vector3<f64>, sensor_b: &Vector3<f64>) -> f64 {
    (sensor_a - point).angle(&(sensor_b - point))
}

fn rotate(r: &Matrix3<f64>, v: [f32; 3]) -> [f32; 3] {
    let w = r * Vector3::new(v[0] as f64, v[1] as f64, v[2] as f64);
    [w.x as f32, w.y as f32, w.z as f32]
}

impl Sampler {
    /// A sampler over `pairs` for patches of `config`'s radius and size.
    pub fn new(pairs: Vec<FragmentPair>, settings: DataSettings, config: &ModelConfig) -> Result<Sampler> {
        if pairs.is_empty() {
            return Err(Error::invalid("no training pairs"));
        }
        let voxel_ok = settings.voxel.is_finite() && settings.voxel >= 0.0;
        let match_ok = settings.match_distance.is_finite() && settings.match_distance > 0.0;
        let angle_ok = settings.max_rotation_deg.is_finite() && settings.max_rotation_deg > 0.0;
        let group_ok = (1..=MAX_PATCHES_PER_PAIR).contains(&settings.patches_per_pair);
        let wide_ok = (0.0..=1.0).contains(&settings.wide_view_share)
            && settings.wide_view_deg > 0.0
            && settings.wide_view_deg <= 180.0;
        let [lo, hi] = settings.occlusion_deg;
        let cut_ok = (0.0..=1.0).contains(&settings.occlusion_share) && 0.0 <= lo && lo <= hi && hi <= 180.0;
        if !(voxel_ok && match_ok && angle_ok && group_ok && wide_ok && cut_ok) {
            return Err(Error::invalid(format!("data settings out of range: {settings:?}")));
        }
        let mut ids: HashMap<PathBuf, usize> = HashMap::new();
        let mut files = Vec::new();
        let mut id = |p: &PathBuf| {
            *ids.entry(p.clone()).or_insert_with(|| {
                files.push(p.clone());
                files.len() - 1
            })
        };
        let pair_fragments = pairs.iter().map(|p| (id(&p.source), id(&p.target))).collect();
        let n_files = files.len();
        Ok(Sampler {
            matches: vec![None; pairs.len()],
            pairs,
            pair_fragments,
            files,
            fragments: vec![None; n_files],
            settings,
            radius: config.radius,
            points_per_patch: config.points_per_patch,
            pose_frame: config.pose_frame,
        })
    }

    /// Number of fragment pairs.
    pub fn pair_count(&self) -> usize {
        self.pairs.len()
    }

    /// Number of distinct fragments.
    pub fn fragment_count(&self) -> usize {
        self.files.len()
    }

    /// Prepares every fragment and every pair's matches now, in parallel (otherwise this happens the first
    /// time a pair is drawn). Returns the number of pairs with at least one match.
    pub fn preload(&mut self) -> Result<usize> {
        let todo: Vec<usize> = (0..self.files.len()).filter(|&i| self.fragments[i].is_none()).collect();
        let loaded: Vec<Result<Fragment>> =
            todo.par_iter().map(|&i| Fragment::load(&self.files[i], &self.settings, self.radius)).collect();
        for (i, f) in todo.into_iter().zip(loaded) {
            self.fragments[i] = Some(Arc::new(f?));
        }
        let todo: Vec<usize> = (0..self.pairs.len()).filter(|&i| self.matches[i].is_none()).collect();
        let found: Vec<PairMatches> = todo.par_iter().map(|&i| self.compute_matches(i)).collect();
        for (i, m) in todo.into_iter().zip(found) {
            self.matches[i] = Some(Arc::new(m));
        }
        Ok(self.matches.iter().filter(|m| m.as_ref().is_some_and(|m| !m.all.is_empty())).count())
    }

    fn fragment(&mut self, id: usize) -> Result<Arc<Fragment>> {
        if let Some(f) = &self.fragments[id] {
            return Ok(f.clone());
        }
        let f = Arc::new(Fragment::load(&self.files[id], &self.settings, self.radius)?);
        self.fragments[id] = Some(f.clone());
        Ok(f)
    }

    /// Matches of pair `i`; both fragments must be loaded.
    fn compute_matches(&self, i: usize) -> PairMatches {
        let (s, t) = self.pair_fragments[i];
        let (Some(src), Some(tgt)) = (&self.fragments[s], &self.fragments[t]) else {
            return PairMatches { all: Vec::new(), wide: Vec::new() };
        };
        let t_mat = self.pairs[i].target_from_source;
        let r = t_mat.fixed_view::<3, 3>(0, 0).into_owned();
        let tr = t_mat.fixed_view::<3, 1>(0, 3).into_owned();
        let max_d2 = self.settings.match_distance * self.settings.match_distance;
        let all: Vec<(u32, u32)> = src
            .points
            .iter()
            .enumerate()
            .filter(|&(k, _)| src.usable[k])
            .filter_map(|(k, p)| {
                let q = r * Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64) + tr;
                let nn = tgt.index.nearest_one(&[q.x as f32, q.y as f32, q.z as f32]);
                (nn.distance_squared <= max_d2 && tgt.usable[nn.index]).then_some((k as u32, nn.index as u32))
            })
            .collect();
        let wide = if self.settings.wide_view_share > 0.0 {
            // Sensors in the target frame: its own at the origin, the source's at the source origin mapped.
            let min_angle = self.settings.wide_view_deg.to_radians();
            (0..all.len() as u32)
                .filter(|&m| {
                    let p = tgt.points[all[m as usize].1 as usize];
                    let p = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
                    view_angle(&p, &Vector3::zeros(), &tr) >= min_angle
                })
                .collect()
        } else {
            Vec::new()
        };
        PairMatches { all, wide }
    }

    fn pair_matches(&mut self, i: usize) -> Result<Matches> {
        if let Some(m) = &self.matches[i] {
            return Ok(m.clone());
        }
        let (s, t) = self.pair_fragments[i];
        self.fragment(s)?;
        self.fragment(t)?;
        let m = Arc::new(self.compute_matches(i));
        self.matches[i] = Some(m.clone());
        Ok(m)
    }

    /// The `batch` samples of training step `step` under `seed`: groups of `patches_per_pair` samples from one
    /// drawn pair each (the last group may be smaller).
    pub fn batch(&mut self, seed: u64, step: u64, batch: usize) -> Result<Vec<PairSample>> {
        let mut rng = Rng::derived(seed, step);
        let mut plans = Vec::with_capacity(batch);
        while plans.len() < batch {
            let group = self.settings.patches_per_pair.min(batch - plans.len());
            plans.extend(self.plan_group(&mut rng, group)?);
        }
        plans.par_iter().map(|p| self.build(p)).collect()
    }

    /// Draws a pair with matches and `group` of its matches, spread out in the target fragment: with
    /// probability `wide_view_share` a pair with wide-view matches and only those (uniform matches when no pair
    /// in `MAX_DRAWS` draws has any).
    fn plan_group(&mut self, rng: &mut Rng, group: usize) -> Result<Vec<Plan>> {
        // Drawn only when wide-view draws are on, so the default settings keep their random stream.
        let mut wide = self.settings.wide_view_share > 0.0 && rng.unit_f64() < self.settings.wide_view_share;
        for draw in 0..2 * MAX_DRAWS {
            if draw == MAX_DRAWS {
                if !wide {
                    break;
                }
                wide = false;
            }
            let pair = rng.below(self.pairs.len());
            let matches = self.pair_matches(pair)?;
            let pool = if wide { matches.wide.len() } else { matches.all.len() };
            if pool == 0 {
                continue;
            }
            let pick = |rng: &mut Rng| {
                let k = rng.below(pool);
                matches.all[if wide { matches.wide[k] as usize } else { k }]
            };
            let target = self.fragments[self.pair_fragments[pair].1].clone().expect("loaded with the matches");
            let mut chosen: Vec<(u32, u32)> = Vec::with_capacity(group);
            for _ in 0..group {
                // The candidate farthest from those chosen (squared distance), stopping at the first a radius away.
                let mut best = (f32::NEG_INFINITY, matches.all[0]);
                for _ in 0..if chosen.is_empty() { 1 } else { SEPARATION_DRAWS } {
                    let m = pick(rng);
                    let p = target.points[m.1 as usize];
                    let gap = chosen
                        .iter()
                        .map(|c| squared_distance(p, target.points[c.1 as usize]))
                        .fold(f32::INFINITY, f32::min);
                    if gap > best.0 {
                        best = (gap, m);
                    }
                    if gap >= self.radius * self.radius {
                        break;
                    }
                }
                chosen.push(best.1);
            }
            let max = self.settings.max_rotation_deg;
            return Ok(chosen
                .into_iter()
                .map(|(source_point, target_point)| {
                    let seeds = [rng.next_u64(), rng.next_u64()];
                    let rotations = [random_rotation(rng, max), random_rotation(rng, max)];
                    // Drawn only when cuts are on, so settings without them keep their random stream.
                    let share = self.settings.occlusion_share;
                    let mut cut = || (share > 0.0 && rng.unit_f64() < share).then(|| rng.next_u64());
                    let cuts = [cut(), cut()];
                    Plan { pair, source_point, target_point, seeds, rotations, cuts }
                })
                .collect());
        }
        Err(Error::invalid(format!(
            "no corresponding patches found in {MAX_DRAWS} draws: do the training pairs overlap (match distance {}, \
             at least {} points per patch)?",
            self.settings.match_distance, self.settings.min_patch_points
        )))
    }

    /// The patch of `keypoint` cut to what a second sensor drawn from stream `cut` sees too; `None` (no cut) when
    /// no second sensor faces the keypoint's surface, it does not see the keypoint, or it leaves fewer than
    /// `min_patch_points`. The fragment's own sensor is its origin; the z-buffer's cells are two voxels (or two
    /// match distances without downsampling) wide.
    fn cut_patch(&self, frag: &Fragment, keypoint: usize, seed: u64, cut: u64) -> Option<Patches> {
        let mut rng = Rng::new(cut);
        let (p, normal) = (frag.points[keypoint], frag.normals[keypoint]);
        let sensor = second_sensor(p, normal, Vector3::zeros(), self.settings.occlusion_deg, &mut rng)?;
        let cell =
            2.0 * f64::from(if self.settings.voxel > 0.0 { self.settings.voxel } else { self.settings.match_distance });
        let occluders: Vec<u32> =
            frag.index.within_unsorted(&p, OCCLUDER_RADII * self.radius).iter().map(|nb| nb.index as u32).collect();
        let (radius, n, min) = (self.radius, self.points_per_patch, self.settings.min_patch_points);
        extract_patch_where(&frag.points, &frag.index, keypoint, radius, n, seed, |candidates| {
            visible_from(&frag.points, &frag.normals, &candidates, &occluders, keypoint, &sensor, cell)
                .filter(|kept| kept.len() >= min)
        })
    }

    /// Builds one sample from its plan.
    fn build(&self, plan: &Plan) -> Result<PairSample> {
        let (s, t) = self.pair_fragments[plan.pair];
        let missing = || Error::invalid("internal: fragment not loaded");
        let src = self.fragments[s].as_ref().ok_or_else(missing)?;
        let tgt = self.fragments[t].as_ref().ok_or_else(missing)?;
        let identity = Matrix3::identity();
        let r_s = if self.settings.rotate_source { matrix_from_quaternion(plan.rotations[0]) } else { identity };
        let r_t = if self.settings.rotate_target { matrix_from_quaternion(plan.rotations[1]) } else { identity };
        let (n, radius) = (self.points_per_patch, self.radius);
        let mut ppf = Vec::with_capacity(2 * n * 4);
        let mut pc = Vec::with_capacity(2 * n * 3);
        let mut frames = [Matrix3::identity(); 2];
        for (slot, (frag, point, seed, r, cut)) in [
            (src, plan.source_point, plan.seeds[0], &r_s, plan.cuts[0]),
            (tgt, plan.target_point, plan.seeds[1], &r_t, plan.cuts[1]),
        ]
        .into_iter()
        .enumerate()
        {
            let whole = || extract_patches(&frag.points, &frag.index, &[point as usize], radius, n, seed);
            let cut = cut.and_then(|cut| self.cut_patch(frag, point as usize, seed, cut));
            let features = |patches: &Patches| -> Result<_> {
                if patches.keypoints.len() != 1 {
                    return Err(Error::invalid("internal: a usable keypoint gave an empty patch"));
                }
                let g = gather(&frag.points, &frag.normals, patches);
                let g = GatheredPatches {
                    centers: g.centers.iter().map(|&v| rotate(r, v)).collect(),
                    center_normals: g.center_normals.iter().map(|&v| rotate(r, v)).collect(),
                    points: g.points.iter().map(|&v| rotate(r, v)).collect(),
                    normals: g.normals.iter().map(|&v| rotate(r, v)).collect(),
                };
                let (f, c) = g.features(n, radius, self.pose_frame);
                Ok((f, c, g.center_normals[0]))
            };
            let (f, c, center_normal) = match cut {
                Some(cut) if self.settings.occlusion_ppf_only => {
                    let (f, _, center_normal) = features(&cut)?;
                    (f, features(&whole())?.1, center_normal)
                }
                Some(cut) => features(&cut)?,
                None => features(&whole())?,
            };
            ppf.extend(f);
            pc.extend(c);
            if self.pose_frame == PoseFrame::Normal {
                frames[slot] = Matrix3::from_row_slice(&normal_frame(center_normal).map(f64::from));
            }
        }
        let r = nearest_rotation(&self.pairs[plan.pair].target_from_source.fixed_view::<3, 3>(0, 0).into_owned());
        let label_m = frames[1] * r_t * r * r_s.transpose() * frames[0].transpose();
        let mut label = [0.0; 9];
        for (k, v) in label.iter_mut().enumerate() {
            *v = label_m[(k / 3, k % 3)];
        }
        Ok(PairSample { ppf, pc, label })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn limited_rotations_stay_within_the_angle() {
        let mut rng = Rng::new(3);
        for max in [20.0, 90.0] {
            for _ in 0..200 {
                let q = random_rotation(&mut rng, max);
                let angle = 2.0 * q[0].abs().min(1.0).acos().to_degrees();
                assert!(angle <= max + 1e-9, "{angle} > {max}");
            }
        }
        // The full range is the plain uniform draw.
        assert_eq!(random_rotation(&mut Rng::new(4), 180.0), Rng::new(4).unit_quaternion());
    }

    /// A 2 m x 2 m square of points 2 cm apart at height `z`, corner at the origin.
    fn plane_at(z: f32) -> Vec<[f32; 3]> {
        (0..100).flat_map(|i| (0..100).map(move |j| [i as f32 * 0.02, j as f32 * 0.02, z])).collect()
    }

    #[test]
    fn grouped_samples_share_a_pair_and_lie_a_radius_apart() {
        // Two pairs of 2 m x 2 m planes (each fragment paired with a copy of itself): room for many keypoints a
        // 0.3 m radius apart.
        let scratch = tempfile::tempdir().unwrap();
        let dir = scratch.path();
        let plane = plane_at(0.0);
        let mut pairs = Vec::new();
        for name in ["a", "b"] {
            let file = dir.join(format!("{name}.ply"));
            crate::io::write_ply(&file, &PointCloud::from_points(plane.clone())).unwrap();
            pairs.push(FragmentPair { source: file.clone(), target: file, target_from_source: Matrix4::identity() });
        }
        let config = ModelConfig { points_per_patch: 32, ..ModelConfig::default() };
        let settings = DataSettings { voxel: 0.0, patches_per_pair: 4, ..DataSettings::default() };
        let mut sampler = Sampler::new(pairs, settings, &config).unwrap();
        let mut rng = Rng::new(9);
        let mut seen = [false; 2];
        for _ in 0..20 {
            let plans = sampler.plan_group(&mut rng, 4).unwrap();
            assert_eq!(plans.len(), 4);
            let pair = plans[0].pair;
            seen[pair] = true;
            let target = sampler.fragments[sampler.pair_fragments[pair].1].clone().unwrap();
            for (k, a) in plans.iter().enumerate() {
                assert_eq!(a.pair, pair, "a group mixes pairs");
                for b in &plans[..k] {
                    let d2 = squared_distance(
                        target.points[a.target_point as usize],
                        target.points[b.target_point as usize],
                    );
                    assert!(d2 >= config.radius * config.radius, "keypoints {} apart", d2.sqrt());
                }
            }
        }
        assert_eq!(seen, [true, true]);
        // A batch that is not a multiple of the group size ends with a smaller group.
        assert_eq!(sampler.batch(3, 0, 6).unwrap().len(), 6);
    }

    #[test]
    fn occlusion_cuts_change_patches_only_when_on() {
        // A 2 m x 2 m plane 1 m in front of its sensor, paired with itself: no occluders, so a cut is the second
        // sensor's image edges, which cut the patches of keypoints seen near them.
        let scratch = tempfile::tempdir().unwrap();
        let file = scratch.path().join("plane.ply");
        let plane: Vec<[f32; 3]> = plane_at(1.0).iter().map(|p| [p[0] - 1.0, p[1] - 1.0, p[2]]).collect();
        crate::io::write_ply(&file, &PointCloud::from_points(plane)).unwrap();
        let pairs = vec![FragmentPair { source: file.clone(), target: file, target_from_source: Matrix4::identity() }];
        let config = ModelConfig { points_per_patch: 32, ..ModelConfig::default() };
        let batch = |settings: DataSettings, seed: u64| {
            let mut sampler = Sampler::new(pairs.clone(), settings, &config).unwrap();
            (0..4)
                .flat_map(|step| sampler.batch(seed, step, 8).unwrap())
                .map(|s| (s.ppf, s.pc))
                .unzip::<_, _, Vec<_>, Vec<_>>()
        };
        let plain = DataSettings { voxel: 0.0, ..DataSettings::default() };
        let off = batch(plain.clone(), 3);
        // Without cuts the angle range and the branch choice do not touch the random stream.
        let unused = DataSettings { occlusion_deg: [10.0, 20.0], occlusion_ppf_only: true, ..plain.clone() };
        assert_eq!(batch(unused, 3), off);
        let cut = DataSettings { occlusion_share: 1.0, ..plain.clone() };
        let on = batch(cut.clone(), 3);
        assert_eq!(batch(cut.clone(), 3), on, "cuts are drawn from the step's stream");
        assert_eq!(on.0.len(), off.0.len());
        assert_ne!(on.0, off.0);
        assert_ne!(on.1, off.1);
        // Cuts on the PPF branch only: the PPF inputs are the cut ones, the PC inputs the whole patches' of the
        // same plans. Those come from cuts whose second sensor can only look from behind the plane, never
        // facing it: drawn as `cut`'s (same stream), none made.
        let never = batch(DataSettings { occlusion_deg: [179.0, 180.0], ..cut.clone() }, 3);
        assert_ne!(never.0, on.0);
        let ppf_only = batch(DataSettings { occlusion_ppf_only: true, ..cut }, 3);
        assert_eq!(ppf_only.0, on.0);
        assert_eq!(ppf_only.1, never.1);
        assert_ne!(ppf_only.1, on.1);
        for (share, deg) in [(-0.1, [30.0, 120.0]), (1.5, [30.0, 120.0]), (0.5, [120.0, 30.0]), (0.5, [0.0, 181.0])] {
            let settings = DataSettings { occlusion_share: share, occlusion_deg: deg, ..Default::default() };
            assert!(Sampler::new(pairs.clone(), settings, &config).is_err());
        }
    }

    #[test]
    fn wide_view_draws_give_only_points_seen_from_directions_far_apart() {
        // A 2 m x 2 m plane at z = 1 in the source frame; the target fragment holds the same points moved 2 m
        // along x, so the source's sensor sits at (2, 0, 0) in the target frame and the target's at the origin.
        // The view angle at a target point q is the angle between -q and (2, 0, 0) - q: from about 63 degrees at
        // the near edge down to about 20 at the far one.
        let scratch = tempfile::tempdir().unwrap();
        let dir = scratch.path();
        let source = plane_at(1.0);
        let shift = [2.0f32, 0.0, 0.0];
        let target: Vec<[f32; 3]> = source.iter().map(|p| [p[0] + shift[0], p[1], p[2]]).collect();
        let (source_file, target_file) = (dir.join("s.ply"), dir.join("t.ply"));
        crate::io::write_ply(&source_file, &PointCloud::from_points(source)).unwrap();
        crate::io::write_ply(&target_file, &PointCloud::from_points(target)).unwrap();
        let mut target_from_source = Matrix4::identity();
        target_from_source[(0, 3)] = shift[0] as f64;
        let pairs = vec![FragmentPair { source: source_file, target: target_file, target_from_source }];
        let config = ModelConfig { points_per_patch: 32, ..ModelConfig::default() };
        let angle_deg = |q: [f32; 3]| {
            let to_target_sensor = [-q[0], -q[1], -q[2]];
            let to_source_sensor = [shift[0] - q[0], -q[1], -q[2]];
            let dot: f32 = (0..3).map(|k| to_target_sensor[k] * to_source_sensor[k]).sum();
            let norm = |v: [f32; 3]| v.iter().map(|x| x * x).sum::<f32>().sqrt();
            (dot / norm(to_target_sensor) / norm(to_source_sensor)).clamp(-1.0, 1.0).acos().to_degrees()
        };
        let angles = |share: f64| {
            let settings =
                DataSettings { voxel: 0.0, wide_view_share: share, wide_view_deg: 45.0, ..Default::default() };
            let mut sampler = Sampler::new(pairs.clone(), settings, &config).unwrap();
            let mut rng = Rng::new(5);
            let mut out = Vec::new();
            for _ in 0..200 {
                for plan in sampler.plan_group(&mut rng, 1).unwrap() {
                    let target = sampler.fragments[sampler.pair_fragments[plan.pair].1].clone().unwrap();
                    out.push(angle_deg(target.points[plan.target_point as usize]));
                }
            }
            out
        };
        let share = |a: &[f32]| a.iter().filter(|&&x| x >= 45.0).count() as f64 / a.len() as f64;
        let (uniform, wide, half) = (angles(0.0), angles(1.0), angles(0.5));
        assert!(share(&uniform) > 0.02 && share(&uniform) < 0.3, "uniform draws: {} wide", share(&uniform));
        let narrowest = wide.iter().fold(f32::INFINITY, |m, &a| m.min(a));
        assert!(narrowest >= 45.0 - 1e-3, "a match seen {narrowest} degrees apart among wide-only draws");
        let h = share(&half);
        assert!(h > 0.4 && h < 0.75, "half the draws wide-only: {h} wide");
        // No pair with wide-view matches: uniform draws instead of an error.
        let settings = DataSettings { voxel: 0.0, wide_view_share: 1.0, wide_view_deg: 89.0, ..Default::default() };
        let mut sampler = Sampler::new(pairs.clone(), settings, &config).unwrap();
        assert_eq!(sampler.plan_group(&mut Rng::new(1), 2).unwrap().len(), 2);
        // Out-of-range settings are refused.
        for (share, deg) in [(-0.1, 60.0), (1.5, 60.0), (0.5, 0.0), (0.5, 181.0)] {
            let settings = DataSettings { wide_view_share: share, wide_view_deg: deg, ..Default::default() };
            assert!(Sampler::new(pairs.clone(), settings, &config).is_err());
        }
    }
}
