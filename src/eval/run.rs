//! Running an evaluation: scoring an existing result log, or registering every pair with the pipeline.
//!
//! Direction: gt.log record `i j` maps fragment j into fragment i, so the pipeline registers source =
//! fragment j onto target = fragment i and its target_from_source goes into the result log under `i j`.
//! A rotation sweep ([`run_scene_sweep`], [`score_log_sweep`]) moves every source first; see
//! [`super::rotate`] for its frames.

use super::dataset::{GtEntry, Protocol, SceneData};
use super::groundtruth::{GroundTruthRule, PreparedFragment, pair_information};
use super::gtlog::LogRecord;
use super::metrics::{count_feature_inliers, information_error, rmse_between};
use super::report::FragmentReport;
use super::rotate::{FragmentRotation, RotationSweep, original_frame_estimate, rotated_ground_truth};
use super::score::{
    FeatureMatch, PairReport, PairRun, SceneScore, Thresholds, add_feature_matches, score_registration,
};
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::estimate::visibility::PairViews;
use crate::io::LoadOptions;
use crate::pipeline::{Registrar, ScanFeatures};
use crate::pose::is_identity_angle;
use crate::rng::Rng;
use crate::settings::{Estimator, StageTime};
use nalgebra::Matrix4;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Options of an evaluation run.
#[derive(Clone, Debug)]
pub struct EvalOptions {
    /// Success and inlier thresholds.
    pub thresholds: Thresholds,
    /// Seed for computing missing gt.info matrices (subsampling) and for the pipeline.
    pub seed: u64,
    /// How clouds are loaded.
    pub load: LoadOptions,
    /// Register every pair i < j of a 3DMatch scene (not only gt.log pairs) and report those whose estimated
    /// overlap exceeds `min_overlap`, as the 3DMatch toolbox does; otherwise register and report the gt.log
    /// pairs.
    pub all_pairs: bool,
    /// Overlap needed to report a pair with `all_pairs` (0.23 in `register2Fragments.m`).
    pub min_overlap: f64,
    /// When set, [`run_scene`] and [`run_scene_sweep`] write a snapshot (see [`crate::snapshot`]) of every pair
    /// they register, for every estimator and angle, at [`snapshot_path`] under this folder.
    pub snapshots: Option<PathBuf>,
}

impl Default for EvalOptions {
    fn default() -> Self {
        EvalOptions {
            thresholds: Thresholds::default(),
            seed: 0,
            load: LoadOptions::default(),
            all_pairs: false,
            min_overlap: 0.23,
            snapshots: None,
        }
    }
}

/// The lowercase name of an estimator, as used in file names and reports.
pub fn estimator_name(e: Estimator) -> &'static str {
    match e {
        Estimator::RelativeNet => "relativenet",
        Estimator::Ransac => "ransac",
    }
}

/// Where `eval --snapshots DIR` writes the picture of pair (i, j) (source fragment j onto target fragment i):
/// `DIR/<estimator>[/rot<DEG>]/<scene>/<source>_to_<target>.png`, where `<source>` and `<target>` are the
/// fragments' file stems (e.g. `cloud_bin_5_to_cloud_bin_2.png`), or their indices when two fragment files of
/// the scene share a stem.
pub fn snapshot_path(
    dir: &Path,
    estimator: Estimator,
    rotation_deg: Option<f64>,
    scene: &SceneData,
    (i, j): (usize, usize),
) -> PathBuf {
    let stems: Vec<String> = scene
        .files
        .iter()
        .map(|f| f.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default())
        .collect();
    let unique = stems.iter().enumerate().all(|(k, s)| !s.is_empty() && !stems[..k].contains(s));
    let label = |f: usize| if unique && f < stems.len() { stems[f].clone() } else { f.to_string() };
    let mut path = dir.join(estimator_name(estimator));
    if let Some(d) = rotation_deg {
        path.push(format!("rot{}", super::rotate::angle_label(d)));
    }
    path.push(&scene.name);
    path.push(format!("{}_to_{}.png", label(j), label(i)));
    path
}

/// Writes the snapshot of one registered pair, creating its folder.
fn write_pair_snapshot(
    path: &Path,
    source: &ScanFeatures,
    target: &ScanFeatures,
    target_from_source: &Matrix4<f64>,
    lines: Vec<([f32; 3], [f32; 3])>,
) -> Result<()> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    let options = crate::snapshot::SnapshotOptions { lines, ..Default::default() };
    crate::snapshot::write_snapshot(path, &source.cloud, &target.cloud, target_from_source, &options)
}

/// Loads one cloud.
pub fn load_cloud(path: &std::path::Path, load: &LoadOptions) -> Result<PointCloud> {
    crate::io::read_cloud(path, load).map(|(c, _)| c)
}

/// How a scene decides whether a pair is registered.
pub enum Criterion {
    /// 3DMatch: eᵀΣe/Σ₁₁ with the gt.info matrix.
    Information,
    /// Pairs files: RMSE of the source points (fragment j's cloud, by index) under the estimate vs the truth.
    Rmse(HashMap<usize, Vec<[f32; 3]>>),
}

impl Criterion {
    /// The criterion value of `estimate` for the gt pair `gt`.
    pub fn error(&self, gt: &GtEntry, estimate: &Matrix4<f64>) -> Result<f64> {
        match self {
            Criterion::Information => {
                let info = gt
                    .information
                    .ok_or_else(|| Error::invalid(format!("pair ({}, {}) has no information matrix", gt.i, gt.j)))?;
                Ok(information_error(&gt.i_from_j, estimate, &info))
            }
            Criterion::Rmse(points) => {
                let p = points.get(&gt.j).map(Vec::as_slice).unwrap_or(&[]);
                Ok(rmse_between(p, estimate, &gt.i_from_j))
            }
        }
    }

    /// The largest value that counts as success.
    pub fn max_error(&self, t: &Thresholds) -> f64 {
        match self {
            Criterion::Information => t.max_information_error,
            Criterion::Rmse(_) => t.max_rmse,
        }
    }
}

/// Prepares the success criterion of `scene`. A 3DMatch scene without gt.info (or with pairs missing from it)
/// gets the information matrices computed from its fragments exactly as spec 3.3 steps 5-6 (pair k of gt.log
/// subsamples with `Rng::derived(seed, k)`); a pairs file loads its source clouds.
pub fn prepare_criterion(scene: &mut SceneData, opts: &EvalOptions) -> Result<Criterion> {
    match scene.protocol {
        Protocol::ThreeDMatch => {
            let missing: Vec<usize> = (0..scene.gt.len()).filter(|&k| scene.gt[k].information.is_none()).collect();
            if missing.is_empty() {
                return Ok(Criterion::Information);
            }
            let rule = GroundTruthRule::default();
            let mut prepared: HashMap<usize, PreparedFragment> = HashMap::new();
            for &k in &missing {
                let (i, j, t) = (scene.gt[k].i, scene.gt[k].j, scene.gt[k].i_from_j);
                for f in [i, j] {
                    if let std::collections::hash_map::Entry::Vacant(v) = prepared.entry(f) {
                        let path = scene.files.get(f).ok_or_else(|| {
                            Error::invalid(format!("{}: gt.log names fragment {f}, which has no file", scene.name))
                        })?;
                        v.insert(PreparedFragment::new(
                            &load_cloud(path, &opts.load)?,
                            rule.grid,
                            rule.overlap_distance,
                        ));
                    }
                }
                let mut rng = Rng::derived(opts.seed, k as u64);
                scene.gt[k].information = Some(pair_information(&prepared[&i], &prepared[&j], &t, &rule, &mut rng));
            }
            Ok(Criterion::Information)
        }
        Protocol::PairsFile => {
            let mut points = HashMap::new();
            for g in &scene.gt {
                if let std::collections::hash_map::Entry::Vacant(v) = points.entry(g.j) {
                    v.insert(load_cloud(&scene.files[g.j], &opts.load)?.points);
                }
            }
            Ok(Criterion::Rmse(points))
        }
    }
}

/// Scores an existing result log against `scene` (registration recall and precision only).
pub fn score_log(scene: &mut SceneData, log: &[LogRecord], opts: &EvalOptions) -> Result<SceneScore> {
    let criterion = prepare_criterion(scene, opts)?;
    score_registration(scene, log, &|g, t| criterion.error(g, t), criterion.max_error(&opts.thresholds))
}

/// What [`run_scene`] produced.
pub struct SceneRun {
    /// Per estimator: its scores and its result log.
    pub estimators: Vec<(Estimator, SceneScore, Vec<LogRecord>)>,
    /// How each fragment was described.
    pub fragments: Vec<FragmentReport>,
}

/// The results of one angle of a rotation sweep.
pub struct AngleRun {
    /// The angle (degrees).
    pub rotation_deg: f64,
    /// Per estimator: its scores (original frames) and its result log (target_from_rotated_source).
    pub estimators: Vec<(Estimator, SceneScore, Vec<LogRecord>)>,
}

/// What [`run_scene_sweep`] produced.
pub struct SweepRun {
    /// One entry per angle, in sweep order.
    pub angles: Vec<AngleRun>,
    /// How each fragment was described (rotated descriptions carry their angle).
    pub fragments: Vec<FragmentReport>,
    /// The rotation of every fragment used as a source, by index.
    pub rotations: Vec<FragmentRotation>,
}

/// A described fragment and, with `all_pairs`, an index over its preprocessed points.
struct Described {
    features: ScanFeatures,
    index: Option<PreparedFragment>,
}

/// A description in the cache: fragment index and the sweep angle (index into the angles) it was rotated by,
/// `None` when it is as loaded.
type DescKey = (usize, Option<usize>);

/// The pairs [`run_scene`] registers, in order.
pub fn pairs_to_run(scene: &SceneData, opts: &EvalOptions) -> Vec<(usize, usize)> {
    if opts.all_pairs && scene.protocol == Protocol::ThreeDMatch {
        let n = scene.fragment_count();
        (0..n).flat_map(|i| (i + 1..n).map(move |j| (i, j))).collect()
    } else {
        scene.gt.iter().map(|g| (g.i, g.j)).collect()
    }
}

/// The radius chosen from the data for `scene` ([`crate::scale::choose`] over every fragment its pairs use), so
/// one scene is described at one radius and a scene in millimetres is evaluated as the same scene in metres.
pub fn scene_scale(scene: &SceneData, opts: &EvalOptions) -> Result<crate::scale::ScaleChoice> {
    let mut used: Vec<usize> = pairs_to_run(scene, opts).into_iter().flat_map(|(i, j)| [i, j]).collect();
    used.sort_unstable();
    used.dedup();
    let sizes = used
        .into_iter()
        .map(|f| {
            let path = scene.files.get(f).ok_or_else(|| {
                Error::invalid(format!("{}: a pair names fragment {f}, which has no file", scene.name))
            })?;
            let cloud = load_cloud(path, &opts.load)?;
            crate::scale::scan_size(&cloud, &path.display().to_string())
        })
        .collect::<Result<Vec<f64>>>()?;
    crate::scale::choose(&sizes)
}

/// Registers the pairs of `scene` (see [`pairs_to_run`]) with every estimator on the same correspondences,
/// describing each fragment once (random stream = fragment index) and dropping it after its last pair.
/// `on_pair` is called after each pair.
pub fn run_scene(
    scene: &mut SceneData,
    registrar: &Registrar,
    estimators: &[Estimator],
    opts: &EvalOptions,
    on_pair: &mut dyn FnMut(),
) -> Result<SceneRun> {
    let mut run = run_views(scene, registrar, estimators, opts, None, on_pair)?;
    let view = run.angles.pop().expect("one view");
    Ok(SceneRun { estimators: view.estimators, fragments: run.fragments })
}

/// [`run_scene`] once per angle of `sweep`, with every source fragment moved by its sweep rotation (see
/// [`super::rotate`]). Targets are never moved, so their descriptions serve every angle; a source is described
/// once per angle (with the same random stream, its index), and not at all again for angles that are multiples
/// of 360 degrees. Result logs hold target_from_rotated_source; scores are computed in the original frames
/// (T'_est M against gt.log), feature matches on the moved data with T_gt M⁻¹. `on_pair` is called after each
/// pair and angle.
pub fn run_scene_sweep(
    scene: &mut SceneData,
    registrar: &Registrar,
    estimators: &[Estimator],
    opts: &EvalOptions,
    sweep: &RotationSweep,
    on_pair: &mut dyn FnMut(),
) -> Result<SweepRun> {
    run_views(scene, registrar, estimators, opts, Some(sweep), on_pair)
}

/// The cache key of the source of view `v` (`None` = no sweep, one view).
fn source_key(j: usize, sweep: Option<&RotationSweep>, v: usize) -> DescKey {
    match sweep {
        Some(s) if !is_identity_angle(s.degrees[v]) => (j, Some(v)),
        _ => (j, None),
    }
}

/// M of fragment `f` for view `v` (identity without a sweep).
fn motion(
    rotations: &HashMap<usize, FragmentRotation>,
    sweep: Option<&RotationSweep>,
    f: usize,
    v: usize,
) -> Matrix4<f64> {
    match (sweep, rotations.get(&f)) {
        (Some(s), Some(r)) => r.rotated_from_original(s.degrees[v]),
        _ => Matrix4::identity(),
    }
}

/// Loads a fragment's cloud, naming the pair that needs it when it has no file.
fn load_fragment(scene: &SceneData, f: usize, pair: (usize, usize), opts: &EvalOptions) -> Result<PointCloud> {
    let path = scene.files.get(f).ok_or_else(|| {
        Error::invalid(format!("{}: pair ({}, {}) names fragment {f}, which has no file", scene.name, pair.0, pair.1))
    })?;
    load_cloud(path, &opts.load)
}

/// The shared body of [`run_scene`] (one view, no sweep) and [`run_scene_sweep`] (one view per angle).
fn run_views(
    scene: &mut SceneData,
    registrar: &Registrar,
    estimators: &[Estimator],
    opts: &EvalOptions,
    sweep: Option<&RotationSweep>,
    on_pair: &mut dyn FnMut(),
) -> Result<SweepRun> {
    let criterion = prepare_criterion(scene, opts)?;
    let pairs = pairs_to_run(scene, opts);
    let run = ViewRun { scene, registrar, estimators, opts, sweep };
    let views = sweep.map_or(1, |s| s.degrees.len());
    let last_use = last_uses(&pairs, sweep, views);
    let mut described = Descriptions::default();
    let mut results = ViewResults {
        logs: vec![vec![Vec::new(); estimators.len()]; views],
        runs: vec![vec![HashMap::new(); estimators.len()]; views],
        matches: vec![HashMap::new(); views],
    };
    for (k, &(i, j)) in pairs.iter().enumerate() {
        run.describe_pair(&mut described, (i, j), views)?;
        let target = &described.cache[&(i, None)];
        for v in 0..views {
            let source = &described.cache[&source_key(j, sweep, v)];
            let m = motion(&described.rotations, sweep, j, v);
            run.register_view((source, target), (i, j), (v, &m), &mut results)?;
            on_pair();
        }
        described.cache.retain(|key, _| last_use.get(key).is_some_and(|&last| last > k));
    }
    let angles = run.score_views(&criterion, results, &described.rotations)?;
    let mut rotations: Vec<FragmentRotation> = described.rotations.into_values().collect();
    rotations.sort_by_key(|r| r.index);
    Ok(SweepRun { angles, fragments: described.fragments, rotations })
}

/// For each description [`run_views`] needs, the index of the last pair that uses it (it is dropped after).
fn last_uses(pairs: &[(usize, usize)], sweep: Option<&RotationSweep>, views: usize) -> HashMap<DescKey, usize> {
    let mut last_use: HashMap<DescKey, usize> = HashMap::new();
    for (k, &(i, j)) in pairs.iter().enumerate() {
        last_use.insert((i, None), k);
        for v in 0..views {
            last_use.insert(source_key(j, sweep, v), k);
        }
    }
    last_use
}

/// What one evaluation run of a scene works with.
struct ViewRun<'a> {
    scene: &'a SceneData,
    registrar: &'a Registrar,
    estimators: &'a [Estimator],
    opts: &'a EvalOptions,
    sweep: Option<&'a RotationSweep>,
}

/// The descriptions [`run_views`] keeps for later pairs, the sweep rotation of every source seen, and how each
/// fragment was described.
#[derive(Default)]
struct Descriptions {
    cache: HashMap<DescKey, Described>,
    rotations: HashMap<usize, FragmentRotation>,
    fragments: Vec<FragmentReport>,
}

/// What [`run_views`] gathers, indexed `[view][estimator]` (feature matches `[view]`).
struct ViewResults {
    logs: Vec<Vec<Vec<LogRecord>>>,
    runs: Vec<Vec<HashMap<(usize, usize), PairRun>>>,
    matches: Vec<HashMap<(usize, usize), FeatureMatch>>,
}

impl ViewRun<'_> {
    /// Describes what pair (i, j) needs and the cache lacks: the target as loaded, the source in every view
    /// (moved by its sweep rotation, drawn when the source is first seen).
    fn describe_pair(&self, described: &mut Descriptions, (i, j): (usize, usize), views: usize) -> Result<()> {
        let (scene, registrar, sweep) = (self.scene, self.registrar, self.sweep);
        let mut needed: Vec<DescKey> = (0..views).map(|v| source_key(j, sweep, v)).collect();
        needed.push((i, None));
        needed.retain(|key| !described.cache.contains_key(key));
        needed.sort_unstable();
        needed.dedup();
        for f in [j, i] {
            let keys: Vec<DescKey> = needed.iter().copied().filter(|key| key.0 == f).collect();
            let rotation_missing = sweep.is_some() && f == j && !described.rotations.contains_key(&j);
            if keys.is_empty() && !rotation_missing {
                continue;
            }
            let cloud = load_fragment(scene, f, (i, j), self.opts)?;
            if let Some(s) = sweep
                && rotation_missing
            {
                described.rotations.insert(f, FragmentRotation::for_fragment(s.seed, &scene.name, f, &cloud));
            }
            for key in keys {
                let (features, rotation_deg) = match key.1 {
                    Some(v) => {
                        // The sensor moves with the scan: estimated normals keep facing it.
                        let m = motion(&described.rotations, sweep, f, v);
                        let viewpoint = crate::pose::transform_point(&m, registrar.settings.viewpoint);
                        let moved = cloud.transformed(&m);
                        (registrar.describe_from(&moved, f as u64, viewpoint)?, sweep.map(|s| s.degrees[v]))
                    }
                    None => (registrar.describe(&cloud, f as u64)?, None),
                };
                described.fragments.push(FragmentReport {
                    scene: scene.name.clone(),
                    index: f,
                    rotation_deg,
                    points: features.cloud.len(),
                    keypoints: features.keypoints.len(),
                    timings: features.timings.clone(),
                });
                // For the estimated overlap (--all-pairs) and the ground-truth overlap of gt pairs.
                let index = Some(PreparedFragment::from_points(
                    features.cloud.points.iter().map(|p| p.map(f64::from)).collect(),
                    self.opts.thresholds.overlap_distance,
                ));
                described.cache.insert(key, Described { features, index });
            }
        }
        Ok(())
    }

    /// Pair (i, j) in view `v` (the source moved by `m`): its feature matches and ground-truth overlap, and
    /// every estimator's registration.
    fn register_view(
        &self,
        (source, target): (&Described, &Described),
        (i, j): (usize, usize),
        (v, m): (usize, &Matrix4<f64>),
        results: &mut ViewResults,
    ) -> Result<()> {
        let (scene, opts) = (self.scene, self.opts);
        let started = Instant::now();
        let correspondences = self.registrar.correspond(&source.features, &target.features);
        let correspond_s = started.elapsed().as_secs_f64();
        if let (Some(g), Ok(c)) = (scene.lookup(i, j), &correspondences) {
            let inliers = count_feature_inliers(
                c.iter().map(|c| (c.target_point, c.source_point)),
                &rotated_ground_truth(&g.i_from_j, m),
                opts.thresholds.tau1,
            );
            results.matches[v].insert((i, j), FeatureMatch { correspondences: c.len(), inliers });
        }
        let gt_overlap = match (scene.lookup(i, j), &target.index, &source.index) {
            (Some(g), Some(ti), Some(si)) => {
                Some(estimated_overlap(ti, si, &rotated_ground_truth(&g.i_from_j, m), opts.thresholds.overlap_distance))
            }
            _ => None,
        };
        for (e, &estimator) in self.estimators.iter().enumerate() {
            let run = PairRun {
                timings: vec![StageTime { stage: "correspond".into(), seconds: correspond_s }],
                gt_overlap,
                ..PairRun::default()
            };
            let (run, record) = self.register_pair((source, target), (i, j), v, estimator, run)?;
            results.logs[v][e].extend(record);
            results.runs[v][e].insert((i, j), run);
        }
        Ok(())
    }

    /// One estimator on pair (i, j) in view `v`: the progressive schedule `register` runs, over prefixes of the
    /// described keypoints, added to `run`; the snapshot when asked; the result log record when reported.
    fn register_pair(
        &self,
        (source, target): (&Described, &Described),
        (i, j): (usize, usize),
        v: usize,
        estimator: Estimator,
        mut run: PairRun,
    ) -> Result<(PairRun, Option<LogRecord>)> {
        let (registrar, opts) = (self.registrar, self.opts);
        let started = Instant::now();
        let round = registrar.register_described(&source.features, &target.features, estimator);
        run.timings.push(StageTime { stage: "estimate".into(), seconds: started.elapsed().as_secs_f64() });
        let pose = round.map(|r| {
            run.correspondences = r.correspondences.len();
            run.keypoints = r.keypoints;
            run.trusted = Some(r.verdict.success);
            run.reason = r.verdict.reason;
            (r.estimate, r.correspondences)
        });
        let (p, used) = match pose {
            Ok(found) => found,
            Err(err) => {
                run.error = Some(err.to_string());
                return Ok((run, None));
            }
        };
        if let Some(dir) = &opts.snapshots {
            let rotation = self.sweep.map(|s| s.degrees[v]);
            let path = snapshot_path(dir, estimator, rotation, self.scene, (i, j));
            let lines = crate::snapshot::inlier_lines(&used, &p.target_from_source, registrar.inlier_threshold());
            write_pair_snapshot(&path, &source.features, &target.features, &p.target_from_source, lines)?;
        }
        run.hypotheses = p.hypotheses_scored;
        run.estimator_inliers = p.inliers;
        let (s, t) = (&source.features, &target.features);
        let views = PairViews::new(
            (&s.cloud.points, s.viewpoint),
            (&t.cloud.points, t.viewpoint),
            registrar.inlier_threshold(),
        );
        run.free_space = Some(views.consistency(&p.target_from_source));
        let report = match (&target.index, &source.index) {
            (Some(ti), Some(si)) if opts.all_pairs => {
                let overlap = estimated_overlap(ti, si, &p.target_from_source, opts.thresholds.overlap_distance);
                run.estimated_overlap = Some(overlap);
                overlap > opts.min_overlap
            }
            _ => true,
        };
        let n = self.scene.fragment_count();
        Ok((run, report.then_some(LogRecord { i, j, n, i_from_j: p.target_from_source })))
    }

    /// Scores every view's result logs in the original frames (each estimate mapped back with its source's
    /// sweep rotation), with the feature matches and every registered pair listed.
    fn score_views(
        &self,
        criterion: &Criterion,
        mut results: ViewResults,
        rotations: &HashMap<usize, FragmentRotation>,
    ) -> Result<Vec<AngleRun>> {
        let (scene, opts, sweep) = (self.scene, self.opts, self.sweep);
        let max_error = criterion.max_error(&opts.thresholds);
        let mut angles = Vec::new();
        for v in 0..results.logs.len() {
            let mut out = Vec::new();
            for (e, &estimator) in self.estimators.iter().enumerate() {
                let log = std::mem::take(&mut results.logs[v][e]);
                let original: Vec<LogRecord> = log
                    .iter()
                    .map(|r| LogRecord {
                        i_from_j: original_frame_estimate(&r.i_from_j, &motion(rotations, sweep, r.j, v)),
                        ..r.clone()
                    })
                    .collect();
                let mut score = score_registration(scene, &original, &|g, t| criterion.error(g, t), max_error)?;
                add_feature_matches(&mut score, &results.matches[v], opts.thresholds.tau2);
                list_runs(scene, &mut score, &mut results.runs[v][e]);
                out.push((estimator, score, log));
            }
            angles.push(AngleRun { rotation_deg: sweep.map_or(0.0, |s| s.degrees[v]), estimators: out });
        }
        Ok(angles)
    }
}

/// Attaches each scored pair's run, and lists the pairs that were registered but neither reported nor in
/// gt.log (with --all-pairs) too, sorted by (i, j).
fn list_runs(scene: &SceneData, score: &mut SceneScore, runs: &mut HashMap<(usize, usize), PairRun>) {
    for p in score.pairs.iter_mut() {
        p.run = runs.remove(&(p.i, p.j));
    }
    for ((i, j), run) in runs.drain() {
        score.pairs.push(PairReport {
            i,
            j,
            in_gt: false,
            counts_for_recall: scene.counts_for_recall(i, j),
            reported: false,
            error: None,
            success: None,
            rotation_error_deg: None,
            translation_error: None,
            feature_match: None,
            run: Some(run),
        });
    }
    score.pairs.sort_by_key(|p| (p.i, p.j));
}

/// Scores result logs on rotated data, one per angle of `sweep` (`logs[v]` holds target_from_rotated_source for
/// angle v): each estimate is mapped back with the source's sweep rotation (T'_est M) and scored against
/// gt.log. Also returns the rotation of every source fragment the logs name.
pub fn score_log_sweep(
    scene: &mut SceneData,
    logs: &[Vec<LogRecord>],
    opts: &EvalOptions,
    sweep: &RotationSweep,
) -> Result<(Vec<SceneScore>, Vec<FragmentRotation>)> {
    if logs.len() != sweep.degrees.len() {
        return Err(Error::invalid(format!("{} result logs for {} angles", logs.len(), sweep.degrees.len())));
    }
    let criterion = prepare_criterion(scene, opts)?;
    // Each source fragment the logs name, with one record naming it (for error messages).
    let mut sources: std::collections::BTreeMap<usize, usize> = std::collections::BTreeMap::new();
    for r in logs.iter().flatten() {
        sources.entry(r.j).or_insert(r.i);
    }
    let mut rotations = HashMap::new();
    for (j, i) in sources {
        let cloud = load_fragment(scene, j, (i, j), opts)?;
        rotations.insert(j, FragmentRotation::for_fragment(sweep.seed, &scene.name, j, &cloud));
    }
    let mut scores = Vec::new();
    for (v, log) in logs.iter().enumerate() {
        let original: Vec<LogRecord> = log
            .iter()
            .map(|r| LogRecord {
                i_from_j: original_frame_estimate(&r.i_from_j, &motion(&rotations, Some(sweep), r.j, v)),
                ..r.clone()
            })
            .collect();
        scores.push(score_registration(
            scene,
            &original,
            &|g, t| criterion.error(g, t),
            criterion.max_error(&opts.thresholds),
        )?);
    }
    let mut rotations: Vec<FragmentRotation> = rotations.into_values().collect();
    rotations.sort_by_key(|r| r.index);
    Ok((scores, rotations))
}

/// Share of target (fragment i) points within `distance` of the source (fragment j) points mapped by
/// `target_from_source` (the reporting filter of `register2Fragments.m`).
pub fn estimated_overlap(
    target: &PreparedFragment,
    source: &PreparedFragment,
    target_from_source: &Matrix4<f64>,
    distance: f64,
) -> f64 {
    super::groundtruth::overlap_fraction(target, source, target_from_source, distance)
}
