//! Multiway registration: many scans into one trajectory.
//!
//! Every scan is described once ([`Registrar::describe`]: the expensive, O(N) part); candidate pairs
//! ([`pairs`]) then cost only matching, pose estimation and scoring ([`pair`]). Each registered pair becomes a
//! pose-graph edge ([`graph`]) weighted by its information matrix: consecutive pairs are odometry edges, the
//! others loop closures. A robust optimisation with line processes ([`optimize`]) switches wrong loop closures
//! off, and the optimised poses form the [`Trajectory`] (world = the first scan's frame). [`evaluate`] compares a
//! trajectory with ground truth.
//!
//! Edge roles: an odometry edge whose registration the verdict trusts is certain (always counts in full, as in
//! Choi et al. and Open3D); an untrusted odometry edge and every trusted loop closure are uncertain (a line
//! process may switch them off); untrusted loop closures do not enter the graph. The initial poses come from a
//! maximum spanning tree over the graph's edges (certain edges first, then by inlier count), so one failed
//! odometry pair does not break the chain when a loop closure bridges it.

pub mod evaluate;
pub mod graph;
pub mod optimize;
pub mod pair;
pub mod pairs;
pub mod trajectory;

use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::pipeline::{Registrar, ScanFeatures};
use crate::settings::RegistrationSettings;
use graph::{GraphEdge, PoseGraph, information_at_source, spanning_tree_poses};
pub use optimize::GlobalOptimizationOption;
pub use pair::{InformationSettings, PairResult};
pub use pairs::PairSelection;
use serde::{Deserialize, Serialize};
pub use trajectory::Trajectory;

/// Everything that shapes a multiway registration.
#[derive(Clone, Debug)]
pub struct MultiwaySettings {
    /// The pairwise registration (keypoints, estimator, verdict, seed...).
    pub registration: RegistrationSettings,
    /// Which pairs to register.
    pub pairs: PairSelection,
    /// At most this many pairs (consecutive pairs first), if set.
    pub max_pairs: Option<usize>,
    /// Correspondence distance of the edge information matrices (cloud units); default: the inlier threshold.
    pub information_distance: Option<f64>,
    /// Largest correspondence set of an information matrix.
    pub max_information_points: usize,
    /// Line-process weight preference (larger keeps more loop closures).
    pub preference_loop_closure: f64,
    /// Loop closures whose line process ends below this are pruned.
    pub edge_prune_threshold: f64,
}

impl Default for MultiwaySettings {
    fn default() -> Self {
        let open3d = GlobalOptimizationOption::default();
        MultiwaySettings {
            registration: RegistrationSettings::default(),
            pairs: PairSelection::ConsecutiveAndRetrieval { k: 5 },
            max_pairs: None,
            information_distance: None,
            max_information_points: 5000,
            preference_loop_closure: open3d.preference_loop_closure,
            edge_prune_threshold: open3d.edge_prune_threshold,
        }
    }
}

/// Whether an edge links consecutive scans or closes a loop.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum EdgeKind {
    /// Scans k and k + 1.
    Odometry,
    /// Any other pair.
    Loop,
}

/// One registered pair and what the pose graph made of it (a record of `edges.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EdgeRecord {
    /// The registration.
    #[serde(flatten)]
    pub pair: PairResult,
    /// Odometry or loop closure.
    pub kind: EdgeKind,
    /// Whether the edge entered the pose graph (untrusted loop closures do not).
    pub in_graph: bool,
    /// Whether a line process could switch it off.
    pub uncertain: bool,
    /// Its final line process (1 for certain edges, 0 outside the graph).
    pub line_process: f64,
    /// In the graph and not pruned: the edge shaped the trajectory.
    pub survived: bool,
}

/// Everything a multiway registration produced.
#[derive(Clone, Debug)]
pub struct MultiwayResult {
    /// world_from_scan for every scan (world = scan 0's frame).
    pub trajectory: Trajectory,
    /// Every registered pair, in registration order.
    pub edges: Vec<EdgeRecord>,
    /// Scans connected to scan 0 by surviving edges; the others could not be placed (identity, or their
    /// spanning-tree pose when only pruned edges reach them).
    pub connected: Vec<bool>,
    /// μ of the line processes.
    pub line_process_weight: f64,
    /// Scans described in this run (fewer than all when a store supplied every pair they were needed for).
    pub described: usize,
    /// Pairs taken from the store instead of registered.
    pub reused_pairs: usize,
    /// The patch radius every scan was described at and how it was chosen (`None` from
    /// [`optimize_pairs`] alone).
    pub scale: Option<crate::scale::ScaleReport>,
}

/// Where pair results (and pooled codewords) are kept between runs, so an interrupted run resumes; see the
/// CLI's folder store. Implementations decide whether a stored result still matches the settings.
pub trait PairStore {
    /// A stored result of pair (i, j), if one matches.
    fn load_pair(&mut self, i: usize, j: usize) -> Result<Option<PairResult>>;
    /// Stores a finished pair (atomically: a crash leaves the old state or the new one).
    fn save_pair(&mut self, result: &PairResult) -> Result<()>;
    /// A stored pooled codeword of scan k, if one matches.
    fn load_pooled(&mut self, _k: usize) -> Result<Option<Vec<f32>>> {
        Ok(None)
    }
    /// Stores the pooled codeword of scan k.
    fn save_pooled(&mut self, _k: usize, _pooled: &[f32]) -> Result<()> {
        Ok(())
    }
}

/// A store that keeps nothing.
pub struct NoStore;

impl PairStore for NoStore {
    fn load_pair(&mut self, _i: usize, _j: usize) -> Result<Option<PairResult>> {
        Ok(None)
    }
    fn save_pair(&mut self, _result: &PairResult) -> Result<()> {
        Ok(())
    }
}

/// Progress of a run, reported as it happens.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Progress {
    /// Scan `k` was described.
    Described {
        /// The scan.
        k: usize,
    },
    /// The pairs were chosen.
    Selected {
        /// How many.
        pairs: usize,
    },
    /// Pair `(i, j)` is done (`reused`: taken from the store).
    Pair {
        /// Target scan.
        i: usize,
        /// Source scan.
        j: usize,
        /// Taken from the store.
        reused: bool,
    },
}

/// [`multiway_detailed`] without a store or progress, returning the trajectory only.
pub fn multiway(scans: &[PointCloud], settings: &MultiwaySettings) -> Result<Trajectory> {
    let registrar = Registrar::new(&settings.registration)?;
    Ok(multiway_detailed(&registrar, scans, settings, &mut NoStore, &|_| {})?.trajectory)
}

/// Registers `scans` (at least two) into one trajectory with `registrar` (whose settings must be
/// `settings.registration`); pairs found in `store` are reused, new ones saved to it as they finish.
pub fn multiway_detailed(
    registrar: &Registrar,
    scans: &[PointCloud],
    settings: &MultiwaySettings,
    store: &mut dyn PairStore,
    progress: &dyn Fn(Progress),
) -> Result<MultiwayResult> {
    let n = scans.len();
    if n < 2 {
        return Err(Error::invalid(format!("multiway registration needs at least 2 scans, got {n}")));
    }
    if settings.max_information_points == 0 {
        return Err(Error::invalid("the information matrices need at least one point"));
    }
    // One radius for every scan: chosen from all of them when the settings give none.
    let names: Vec<String> = (0..n).map(|k| format!("scan {k}")).collect();
    let clouds: Vec<(&PointCloud, &str)> = scans.iter().zip(&names).map(|(c, name)| (c, name.as_str())).collect();
    let registrar = &registrar.at_scale_of(&clouds)?;
    let information = InformationSettings {
        distance: settings.information_distance.unwrap_or(f64::from(registrar.inlier_threshold())),
        max_points: settings.max_information_points,
        seed: settings.registration.seed,
    };
    let option = GlobalOptimizationOption {
        max_correspondence_distance: information.distance,
        edge_prune_threshold: settings.edge_prune_threshold,
        preference_loop_closure: settings.preference_loop_closure,
        ..GlobalOptimizationOption::default()
    };
    option.validate()?;
    let mut described: Vec<Option<(ScanFeatures, crate::eval::groundtruth::PreparedFragment)>> =
        (0..n).map(|_| None).collect();
    let describe = |k: usize, described: &mut Vec<Option<_>>| -> Result<()> {
        if described[k].is_none() {
            let f = registrar.describe(&scans[k], k as u64).map_err(|e| scan_error(k, e))?;
            let prepared = pair::prepare_for_information(&f, information.distance);
            described[k] = Some((f, prepared));
            progress(Progress::Described { k });
        }
        Ok(())
    };
    let pooled = match settings.pairs {
        PairSelection::All => None,
        PairSelection::ConsecutiveAndRetrieval { .. } => {
            let dim = registrar.backend().model().config.codeword();
            let mut pooled = Vec::with_capacity(n);
            for k in 0..n {
                let p = match store.load_pooled(k)? {
                    Some(p) if p.len() == dim => p,
                    _ => {
                        describe(k, &mut described)?;
                        let f = &described[k].as_ref().expect("described").0;
                        let p = pairs::pooled_codeword(&f.read_codewords()?, dim);
                        store.save_pooled(k, &p)?;
                        p
                    }
                };
                pooled.push(p);
            }
            Some(pooled)
        }
    };
    let selected = pairs::select_pairs(n, settings.pairs, pooled.as_deref(), settings.max_pairs);
    progress(Progress::Selected { pairs: selected.len() });
    let mut results = Vec::with_capacity(selected.len());
    let mut reused = 0;
    for &(i, j) in &selected {
        if let Some(r) = store.load_pair(i, j)?.filter(|r| r.i == i && r.j == j) {
            reused += 1;
            results.push(r);
            progress(Progress::Pair { i, j, reused: true });
            continue;
        }
        describe(i, &mut described)?;
        describe(j, &mut described)?;
        let (fi, pi) = described[i].as_ref().expect("described");
        let (fj, pj) = described[j].as_ref().expect("described");
        let r = pair::register_pair(registrar, (i, j), fi, fj, pi, pj, &information);
        store.save_pair(&r)?;
        results.push(r);
        progress(Progress::Pair { i, j, reused: false });
    }
    let described_count = described.iter().filter(|d| d.is_some()).count();
    drop(described);
    let mut result = optimize_pairs(n, &results, &option)?;
    result.described = described_count;
    result.reused_pairs = reused;
    result.scale = Some(registrar.scale_report());
    Ok(result)
}

fn scan_error(k: usize, e: Error) -> Error {
    match e {
        Error::InvalidInput(m) => Error::InvalidInput(format!("scan {k}: {m}")),
        other => other,
    }
}

/// Builds the pose graph of `results` (see the module docs for edge roles), initialises it with a maximum
/// spanning tree and optimises it robustly.
pub fn optimize_pairs(n: usize, results: &[PairResult], option: &GlobalOptimizationOption) -> Result<MultiwayResult> {
    let mut edges = Vec::new();
    let mut strength = Vec::new();
    let mut edge_of_result = Vec::with_capacity(results.len());
    for r in results {
        let odometry = r.j == r.i + 1;
        if !odometry && !r.trusted {
            edge_of_result.push(None);
            continue;
        }
        edge_of_result.push(Some(edges.len()));
        let certain = odometry && r.trusted;
        strength.push(if certain { 1e12 } else { 0.0 } + if r.trusted { 1e9 } else { 0.0 } + r.inliers as f64);
        edges.push(graph_edge(r, !certain));
    }
    let (initial, _) = spanning_tree_poses(n, &edges, &strength);
    let graph = PoseGraph { world_from_node: initial, edges };
    let report = optimize::optimize(&graph, option)?;
    let records = results
        .iter()
        .zip(&edge_of_result)
        .map(|(r, e)| {
            let kind = if r.j == r.i + 1 { EdgeKind::Odometry } else { EdgeKind::Loop };
            match e {
                Some(k) => EdgeRecord {
                    pair: r.clone(),
                    kind,
                    in_graph: true,
                    uncertain: graph.edges[*k].uncertain,
                    line_process: report.line_process[*k],
                    survived: report.survived[*k],
                },
                None => EdgeRecord {
                    pair: r.clone(),
                    kind,
                    in_graph: false,
                    uncertain: true,
                    line_process: 0.0,
                    survived: false,
                },
            }
        })
        .collect();
    // Node 0 stays at its initial pose, the identity: the world is scan 0's frame.
    Ok(MultiwayResult {
        trajectory: Trajectory { world_from_scan: report.world_from_node },
        edges: records,
        connected: report.connected,
        line_process_weight: report.line_process_weight,
        described: 0,
        reused_pairs: 0,
        scale: None,
    })
}

/// The pose-graph edge of a registered pair (its information moved to the graph's convention).
fn graph_edge(r: &PairResult, uncertain: bool) -> GraphEdge {
    let i_from_j = r.transform();
    let information = information_at_source(&r.information_matrix(), &i_from_j);
    GraphEdge { i: r.i, j: r.j, i_from_j, information, uncertain }
}

impl MultiwayResult {
    /// The optimised pose graph (the trajectory and the edges that entered the graph) and each edge's final
    /// weight (its line process; 0 when pruned).
    pub fn pose_graph(&self) -> (PoseGraph, Vec<f64>) {
        let in_graph: Vec<&EdgeRecord> = self.edges.iter().filter(|e| e.in_graph).collect();
        let edges = in_graph.iter().map(|e| graph_edge(&e.pair, e.uncertain)).collect();
        let weights = in_graph.iter().map(|e| if e.survived { e.line_process } else { 0.0 }).collect();
        (PoseGraph { world_from_node: self.trajectory.world_from_scan.clone(), edges }, weights)
    }

    /// Writes [`Self::pose_graph`] to `path` as g2o (vertex ids = scan numbers; weights as comments), atomically.
    pub fn write_g2o(&self, path: &std::path::Path) -> Result<()> {
        let (graph, weights) = self.pose_graph();
        let ids: Vec<u64> = (0..graph.world_from_node.len() as u64).collect();
        crate::pose_graph::write_g2o(path, &graph, &ids, Some(&weights))
    }
}

/// All scans in the world frame of `trajectory`, merged and voxel-downsampled (one point per `voxel` cell).
pub fn fuse(scans: &[PointCloud], trajectory: &Trajectory, voxel: f32) -> Result<PointCloud> {
    if scans.len() != trajectory.len() {
        return Err(Error::invalid(format!("{} scans but {} trajectory poses", scans.len(), trajectory.len())));
    }
    let mut merged = PointCloud { points: Vec::new(), normals: Some(Vec::new()) };
    for (scan, pose) in scans.iter().zip(&trajectory.world_from_scan) {
        let moved = scan.transformed(pose);
        merged.points.extend(moved.points);
        match (merged.normals.as_mut(), moved.normals) {
            (Some(all), Some(ns)) => all.extend(ns),
            _ => merged.normals = None,
        }
    }
    crate::preprocess::voxel_downsample(&merged, voxel)
}
