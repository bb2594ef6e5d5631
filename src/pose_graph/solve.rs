//! One call from a pose graph to optimised poses: initialisation (the given poses or [`super::chordal`]), then
//! the sparse Levenberg-Marquardt, plain or under the line-process / Geman-McClure kernel of
//! [`crate::multiway::optimize`]. Used by `dpr-gpu pose-graph`, `dpr-gpu bench --pose-graph` and Python.

use super::chordal::chordal_poses;
use super::lm::cost;
use crate::error::{Error, Result};
use crate::multiway::graph::PoseGraph;
use crate::multiway::optimize::{GlobalOptimizationOption, optimize_with_weight};
use nalgebra::Matrix4;

/// Where the optimisation starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Init {
    /// The graph's own poses (a g2o file's vertices, usually chained odometry).
    File,
    /// Chordal relaxation of the rotations, then the translations; the graph's own poses instead where the
    /// relaxation fails (a singular system) or starts at a higher error than they do (poses already near an
    /// optimum). [`Solution::start`] says which was used.
    Chordal,
}

/// How edges are weighted.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Kernel {
    /// Every edge counts in full (least squares).
    None,
    /// Uncertain edges (loop closures) carry a line process: weight (μ / (μ + eᵀΩe))², i.e. the Geman-McClure
    /// kernel of scale μ (GTSAM's `GemanMcClure(c)` with c² = μ); edges whose weight ends below the prune
    /// threshold are dropped and the graph solved again.
    GemanMcClure {
        /// μ, in units of eᵀΩe.
        scale: f64,
        /// Prune threshold on the final weight.
        prune_below: f64,
    },
}

/// Settings of [`solve`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolveOptions {
    /// Where to start.
    pub init: Init,
    /// Edge weighting.
    pub kernel: Kernel,
    /// Most reweighting passes (robust kernel only).
    pub max_reweightings: usize,
}

impl Default for SolveOptions {
    fn default() -> Self {
        SolveOptions { init: Init::Chordal, kernel: Kernel::None, max_reweightings: 100 }
    }
}

impl SolveOptions {
    /// The options named as `dpr-gpu pose-graph` and Python's `pose_graph` name them: `robust` is `none` or
    /// `geman-mcclure` (with its `scale` μ > 0 and `prune_below` in [0, 1]); `init` is `chordal` or `file`, by
    /// default chordal without a kernel and file with one (wrong loop closures mislead the relaxation).
    pub fn from_names(robust: &str, scale: f64, prune_below: f64, init: Option<&str>) -> Result<Self> {
        let kernel = match robust {
            "none" => Kernel::None,
            "geman-mcclure" => {
                if !(scale.is_finite() && scale > 0.0) {
                    return Err(Error::invalid(format!("the robust scale must be positive, got {scale}")));
                }
                if !(0.0..=1.0).contains(&prune_below) {
                    return Err(Error::invalid(format!("the prune threshold must be in [0, 1], got {prune_below}")));
                }
                Kernel::GemanMcClure { scale, prune_below }
            }
            other => {
                return Err(Error::invalid(format!(
                    "unknown robust kernel '{other}' (expected none or geman-mcclure)"
                )));
            }
        };
        let init = match (init, kernel) {
            (Some("chordal"), _) | (None, Kernel::None) => Init::Chordal,
            (Some("file"), _) | (None, Kernel::GemanMcClure { .. }) => Init::File,
            (Some(other), _) => {
                return Err(Error::invalid(format!("unknown initialisation '{other}' (expected chordal or file)")));
            }
        };
        Ok(SolveOptions { init, kernel, ..SolveOptions::default() })
    }
}

/// What [`solve`] found.
#[derive(Clone, Debug, PartialEq)]
pub struct Solution {
    /// Optimised world_from_node (node 0 unchanged).
    pub world_from_node: Vec<Matrix4<f64>>,
    /// Final weight of each edge: 1 for certain edges (all of them without a kernel), the line process of kept
    /// uncertain edges, 0 for pruned edges and edges without information.
    pub weights: Vec<f64>,
    /// ½ Σ eᵀΩe over all edges at the given poses, after the initialisation, and at the end (GTSAM's
    /// `graph.error`, every edge at full weight).
    pub given_error: f64,
    /// See `given_error`.
    pub initial_error: f64,
    /// See `given_error`.
    pub final_error: f64,
    /// Levenberg-Marquardt steps tried (all passes).
    pub iterations: usize,
    /// The start used: [`Init::File`] also when [`Init::Chordal`] was asked for and fell back (see `start_note`).
    pub start: Init,
    /// Why a chordal start fell back to the graph's poses.
    pub start_note: Option<String>,
}

/// Initialises and optimises `graph` (node 0 fixed).
pub fn solve(graph: &PoseGraph, options: &SolveOptions) -> Result<Solution> {
    graph.validate()?;
    if graph.world_from_node.is_empty() {
        return Err(Error::invalid("the pose graph has no nodes"));
    }
    let given_error = cost(&graph.edges, &graph.world_from_node);
    let (start, start_used, start_note) = start_poses(graph, options.init, given_error);
    let initial_error = cost(&graph.edges, &start);
    let (mu, prune, robust) = match options.kernel {
        Kernel::None => (1.0, 0.0, false),
        Kernel::GemanMcClure { scale, prune_below } => (scale, prune_below, true),
    };
    let mut edges = graph.edges.clone();
    for e in &mut edges {
        e.uncertain &= robust;
    }
    let started = PoseGraph { world_from_node: start, edges };
    let option = GlobalOptimizationOption {
        edge_prune_threshold: prune,
        max_iterations: options.max_reweightings,
        ..GlobalOptimizationOption::default()
    };
    let report = optimize_with_weight(&started, mu, &option)?;
    let weights = report.line_process.iter().zip(&report.survived).map(|(l, s)| if *s { *l } else { 0.0 }).collect();
    Ok(Solution {
        final_error: cost(&graph.edges, &report.world_from_node),
        world_from_node: report.world_from_node,
        weights,
        given_error,
        initial_error,
        iterations: report.lm_iterations,
        start: start_used,
        start_note,
    })
}

/// The starting poses for `init`, the start used and why a chordal start fell back to the graph's poses.
fn start_poses(graph: &PoseGraph, init: Init, given_error: f64) -> (Vec<Matrix4<f64>>, Init, Option<String>) {
    if init == Init::File {
        return (graph.world_from_node.clone(), Init::File, None);
    }
    match chordal_poses(&graph.world_from_node, &graph.edges, &vec![true; graph.edges.len()]) {
        Err(e) => (graph.world_from_node.clone(), Init::File, Some(format!("the chordal relaxation failed: {e}"))),
        Ok(poses) => {
            let chordal_error = cost(&graph.edges, &poses);
            if chordal_error.is_finite() && chordal_error <= given_error {
                (poses, Init::Chordal, None)
            } else {
                let note = format!(
                    "the graph's poses start lower ({given_error:.6}) than the chordal ones ({chordal_error:.6})"
                );
                (graph.world_from_node.clone(), Init::File, Some(note))
            }
        }
    }
}
