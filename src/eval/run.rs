//! Running an evaluation: scoring an existing result log, or registering every pair with the pipeline.
//!
//! Direction: gt.log record `i j` maps fragment j into fragment i, so the pipeline registers source =
//! fragment j onto target = fragment i and its target_from_source goes into the result log under `i j`.

use super::dataset::{GtEntry, Protocol, SceneData};
use super::groundtruth::{GroundTruthRule, PreparedFragment, pair_information};
use super::gtlog::LogRecord;
use super::metrics::{count_feature_inliers, information_error, rmse_between};
use super::report::FragmentReport;
use super::score::{
    FeatureMatch, PairReport, PairRun, SceneScore, Thresholds, add_feature_matches, score_registration,
};
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::io::LoadOptions;
use crate::pipeline::{Registrar, ScanFeatures};
use crate::rng::Rng;
use crate::settings::{Estimator, StageTime};
use nalgebra::Matrix4;
use std::collections::HashMap;
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
}

impl Default for EvalOptions {
    fn default() -> Self {
        EvalOptions {
            thresholds: Thresholds::default(),
            seed: 0,
            load: LoadOptions::default(),
            all_pairs: false,
            min_overlap: 0.23,
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
                Ok(information_error(&gt.transform, estimate, &info))
            }
            Criterion::Rmse(points) => {
                let p = points.get(&gt.j).map(Vec::as_slice).unwrap_or(&[]);
                Ok(rmse_between(p, estimate, &gt.transform))
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
                let (i, j, t) = (scene.gt[k].i, scene.gt[k].j, scene.gt[k].transform);
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

/// A described fragment and, with `all_pairs`, an index over its preprocessed points.
struct Described {
    features: ScanFeatures,
    index: Option<PreparedFragment>,
}

/// The pairs [`run_scene`] registers, in order.
pub fn pairs_to_run(scene: &SceneData, opts: &EvalOptions) -> Vec<(usize, usize)> {
    if opts.all_pairs && scene.protocol == Protocol::ThreeDMatch {
        let n = scene.fragment_count();
        (0..n).flat_map(|i| (i + 1..n).map(move |j| (i, j))).collect()
    } else {
        scene.gt.iter().map(|g| (g.i, g.j)).collect()
    }
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
    let criterion = prepare_criterion(scene, opts)?;
    let pairs = pairs_to_run(scene, opts);
    let mut last_use: HashMap<usize, usize> = HashMap::new();
    for (k, &(i, j)) in pairs.iter().enumerate() {
        last_use.insert(i, k);
        last_use.insert(j, k);
    }
    let n = scene.fragment_count();
    let mut cache: HashMap<usize, Described> = HashMap::new();
    let mut fragments = Vec::new();
    let mut logs: Vec<Vec<LogRecord>> = vec![Vec::new(); estimators.len()];
    let mut runs: Vec<HashMap<(usize, usize), PairRun>> = vec![HashMap::new(); estimators.len()];
    let mut matches: HashMap<(usize, usize), FeatureMatch> = HashMap::new();
    for (k, &(i, j)) in pairs.iter().enumerate() {
        for f in [j, i] {
            if cache.contains_key(&f) {
                continue;
            }
            let path = scene.files.get(f).ok_or_else(|| {
                Error::invalid(format!("{}: pair ({i}, {j}) names fragment {f}, which has no file", scene.name))
            })?;
            let cloud = load_cloud(path, &opts.load)?;
            let features = registrar.describe(&cloud, f as u64)?;
            fragments.push(FragmentReport {
                scene: scene.name.clone(),
                index: f,
                points: features.cloud.len(),
                keypoints: features.keypoints.len(),
                timings: features.timings.clone(),
            });
            let index = opts.all_pairs.then(|| {
                PreparedFragment::from_points(
                    features.cloud.points.iter().map(|p| p.map(f64::from)).collect(),
                    opts.thresholds.overlap_distance,
                )
            });
            cache.insert(f, Described { features, index });
        }
        let (source, target) = (&cache[&j], &cache[&i]);
        let started = Instant::now();
        let correspondences = registrar.correspond(&source.features, &target.features);
        let correspond_s = started.elapsed().as_secs_f64();
        let gt = scene.lookup(i, j);
        if let (Some(g), Ok(c)) = (gt, &correspondences) {
            let inliers = count_feature_inliers(
                c.iter().map(|c| (c.target_point, c.source_point)),
                &g.transform,
                opts.thresholds.tau1,
            );
            matches.insert((i, j), FeatureMatch { correspondences: c.len(), inliers });
        }
        for (e, &estimator) in estimators.iter().enumerate() {
            let mut run = PairRun {
                timings: vec![StageTime { stage: "correspond".into(), seconds: correspond_s }],
                ..PairRun::default()
            };
            let pose = match &correspondences {
                Ok(c) => {
                    run.correspondences = c.len();
                    let started = Instant::now();
                    let pose = registrar.estimate(&source.features, &target.features, c, estimator);
                    run.timings.push(StageTime { stage: "estimate".into(), seconds: started.elapsed().as_secs_f64() });
                    run.trusted = pose.as_ref().ok().map(|p| registrar.judge(p, c).success);
                    pose
                }
                Err(err) => Err(Error::invalid(err.to_string())),
            };
            match pose {
                Ok(p) => {
                    run.hypotheses = p.hypotheses_scored;
                    run.estimator_inliers = p.inliers;
                    let report = match (&target.index, &source.index) {
                        (Some(ti), Some(si)) if opts.all_pairs => {
                            let overlap =
                                estimated_overlap(ti, si, &p.target_from_source, opts.thresholds.overlap_distance);
                            run.estimated_overlap = Some(overlap);
                            overlap > opts.min_overlap
                        }
                        _ => true,
                    };
                    if report {
                        logs[e].push(LogRecord { i, j, n, matrix: p.target_from_source });
                    }
                }
                Err(err) => run.error = Some(err.to_string()),
            }
            runs[e].insert((i, j), run);
        }
        cache.retain(|f, _| last_use.get(f).is_some_and(|&last| last > k));
        on_pair();
    }
    let max_error = criterion.max_error(&opts.thresholds);
    let mut out = Vec::new();
    for (e, &estimator) in estimators.iter().enumerate() {
        let mut score = score_registration(scene, &logs[e], &|g, t| criterion.error(g, t), max_error)?;
        add_feature_matches(&mut score, &matches, opts.thresholds.tau2);
        for p in score.pairs.iter_mut() {
            p.run = runs[e].remove(&(p.i, p.j));
        }
        // Pairs that were registered but neither reported nor in gt.log (with --all-pairs) are listed too.
        for ((i, j), run) in runs[e].drain() {
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
        out.push((estimator, score, std::mem::take(&mut logs[e])));
    }
    Ok(SceneRun { estimators: out, fragments })
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
