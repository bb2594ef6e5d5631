//! Robust pose-graph optimisation with line processes (Choi, Zhou, Koltun, "Robust Reconstruction of Indoor
//! Scenes", CVPR 2015, section 4; the scheme of Open3D's `GlobalOptimization`).
//!
//! The objective over the node poses W and one line process l ∈ [0, 1] per uncertain edge is
//!
//! ```text
//! E(W, l) = Σ_certain eᵀΛe + Σ_uncertain l eᵀΛe + μ Σ_uncertain (√l - 1)²
//! ```
//!
//! with e = Log(Z_ij⁻¹ W_i⁻¹ W_j) the edge error of [`crate::pose_graph`] (Z the measured i_from_j) and Λ the
//! edge's information matrix. For fixed poses the best l is (μ / (μ + eᵀΛe))², so alternating the two steps is
//! iteratively reweighted least squares with the Geman-McClure kernel ρ(s) = μ s / (μ + s): a wrong loop closure,
//! whose residual stays large, gets a weight near zero. The weight μ follows Open3D: `preference_loop_closure` x
//! `max_correspondence_distance`² x the mean correspondence count (Λ(0,0)) of the edges. After convergence the
//! uncertain edges with l below `edge_prune_threshold` are pruned and the graph is optimised again without them.
//!
//! The weighted least-squares step is the sparse SE(3) Levenberg-Marquardt of [`crate::pose_graph::lm`]; one
//! symbolic factorisation serves every reweighting of a pass. [`optimize_with_weight`] takes μ directly (the
//! `pose-graph` command's Geman-McClure scale).

use super::graph::{PoseGraph, reachable_from_reference};
use crate::error::{Error, Result};
use crate::pose_graph::lm::{LmOptions, Problem, edge_chi2};
use nalgebra::Matrix4;

/// The knobs of the robust optimisation (names and defaults after Open3D's `GlobalOptimizationOption`).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GlobalOptimizationOption {
    /// The distance (cloud units) the edges' information matrices were built with; it scales μ.
    pub max_correspondence_distance: f64,
    /// Uncertain edges whose line process ends below this are pruned (Open3D: 0.25).
    pub edge_prune_threshold: f64,
    /// Larger values keep more loop closures (Open3D: 1.0).
    pub preference_loop_closure: f64,
    /// Most line-process (reweighting) iterations per optimisation.
    pub max_iterations: usize,
}

impl Default for GlobalOptimizationOption {
    fn default() -> Self {
        GlobalOptimizationOption {
            max_correspondence_distance: 0.075,
            edge_prune_threshold: 0.25,
            preference_loop_closure: 1.0,
            max_iterations: 100,
        }
    }
}

impl GlobalOptimizationOption {
    /// Checks the values; the error names the setting.
    pub fn validate(&self) -> Result<()> {
        let positive = |name: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(Error::invalid(format!("{name} must be positive, got {v}")))
            }
        };
        positive("max correspondence distance", self.max_correspondence_distance)?;
        positive("loop closure preference", self.preference_loop_closure)?;
        if !(0.0..=1.0).contains(&self.edge_prune_threshold) {
            return Err(Error::invalid(format!(
                "edge prune threshold must be in [0, 1], got {}",
                self.edge_prune_threshold
            )));
        }
        if self.max_iterations == 0 {
            return Err(Error::invalid("the optimisation needs at least one iteration"));
        }
        Ok(())
    }
}

/// What the optimisation did.
#[derive(Clone, Debug, PartialEq)]
pub struct OptimizationReport {
    /// The optimised x_world = world_from_node[k] x_k (node 0 unchanged).
    pub world_from_node: Vec<Matrix4<f64>>,
    /// Final line process per edge (1 for certain edges; pruned edges keep the value that pruned them).
    pub line_process: Vec<f64>,
    /// Whether each edge is still in the graph after pruning (edges without information never are).
    pub survived: Vec<bool>,
    /// Nodes connected to node 0 by surviving edges; the others keep their initial poses.
    pub connected: Vec<bool>,
    /// μ of the line processes.
    pub line_process_weight: f64,
    /// Reweighting iterations run (both passes).
    pub iterations: usize,
    /// Levenberg-Marquardt steps tried over all reweightings.
    pub lm_iterations: usize,
}

/// Alternates line-process updates and weighted solves over the `active` edges until the weights settle.
fn line_process_pass(
    graph: &PoseGraph,
    poses: &mut Vec<Matrix4<f64>>,
    active: &[bool],
    mu: f64,
    option: &GlobalOptimizationOption,
    line_process: &mut [f64],
) -> Result<(usize, usize)> {
    let free: Vec<bool> = reachable_from_reference(poses.len(), &graph.edges, active)
        .into_iter()
        .enumerate()
        .map(|(k, r)| r && k != 0)
        .collect();
    let problem = Problem::new(&graph.edges, active, &free)?;
    let (mut iterations, mut lm_iterations) = (0, 0);
    for _ in 0..option.max_iterations {
        iterations += 1;
        let mut change: f64 = 0.0;
        for (k, e) in graph.edges.iter().enumerate() {
            if active[k] && e.uncertain {
                let l = (mu / (mu + edge_chi2(e, poses))).powi(2);
                change = change.max((l - line_process[k]).abs());
                line_process[k] = l;
            }
        }
        if iterations > 1 && change < 1e-6 {
            break;
        }
        let weights: Vec<f64> = graph
            .edges
            .iter()
            .zip(active)
            .zip(line_process.iter())
            .map(|((e, &a), &l)| {
                if !a {
                    0.0
                } else if e.uncertain {
                    l
                } else {
                    1.0
                }
            })
            .collect();
        let (solved, report) = problem.minimize(poses, &weights, &LmOptions::default())?;
        *poses = solved;
        lm_iterations += report.iterations;
    }
    Ok((iterations, lm_iterations))
}

/// Optimises `graph` robustly (see the module docs), starting from its node poses; node 0 stays fixed.
pub fn optimize(graph: &PoseGraph, option: &GlobalOptimizationOption) -> Result<OptimizationReport> {
    option.validate()?;
    let counts: Vec<f64> = graph.edges.iter().map(|e| e.information[(0, 0)]).filter(|&c| c > 0.0).collect();
    let mean_points = if counts.is_empty() { 1.0 } else { counts.iter().sum::<f64>() / counts.len() as f64 };
    let mu = option.preference_loop_closure * option.max_correspondence_distance.powi(2) * mean_points.max(1e-12);
    optimize_with_weight(graph, mu, option)
}

/// [`optimize`] with the line-process weight μ given (the Geman-McClure scale: an uncertain edge's weight is
/// (μ / (μ + eᵀΛe))²); `option`'s correspondence distance and preference are not used.
pub fn optimize_with_weight(
    graph: &PoseGraph,
    mu: f64,
    option: &GlobalOptimizationOption,
) -> Result<OptimizationReport> {
    graph.validate()?;
    option.validate()?;
    if !(mu.is_finite() && mu > 0.0) {
        return Err(Error::invalid(format!("the line-process weight must be positive, got {mu}")));
    }
    let mut poses = graph.world_from_node.clone();
    // An edge without information (no point of the pair within the correspondence distance) constrains
    // nothing: it stays out, so it cannot make a scan look connected.
    let mut active: Vec<bool> = graph.edges.iter().map(|e| e.information.iter().any(|&v| v != 0.0)).collect();
    let mut line_process: Vec<f64> = active.iter().map(|&a| if a { 1.0 } else { 0.0 }).collect();
    let (mut iterations, mut lm_iterations) =
        line_process_pass(graph, &mut poses, &active, mu, option, &mut line_process)?;
    let mut pruned = false;
    for (k, e) in graph.edges.iter().enumerate() {
        if active[k] && e.uncertain && line_process[k] < option.edge_prune_threshold {
            active[k] = false;
            pruned = true;
        }
    }
    if pruned {
        let (more, more_lm) = line_process_pass(graph, &mut poses, &active, mu, option, &mut line_process)?;
        iterations += more;
        lm_iterations += more_lm;
    }
    let connected = reachable_from_reference(poses.len(), &graph.edges, &active);
    Ok(OptimizationReport {
        world_from_node: poses,
        line_process,
        survived: active,
        connected,
        line_process_weight: mu,
        iterations,
        lm_iterations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::multiway::graph::GraphEdge;
    use nalgebra::{Matrix6, Vector3};

    #[test]
    fn edges_without_information_stay_out_and_leave_their_scan_unconnected() {
        let info = crate::eval::metrics::information_matrix(&[[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
        let shift = Matrix4::new_translation(&Vector3::new(1.0, 0.0, 0.0));
        let edge = |i, j, information| GraphEdge { i, j, i_from_j: shift, information, uncertain: false };
        let graph = PoseGraph {
            world_from_node: vec![Matrix4::identity(); 3],
            edges: vec![edge(0, 1, info), edge(1, 2, Matrix6::zeros())],
        };
        let report = optimize(&graph, &GlobalOptimizationOption::default()).unwrap();
        assert_eq!(report.survived, [true, false]);
        assert_eq!(report.connected, [true, true, false]);
        assert!((report.world_from_node[1] - shift).abs().max() < 1e-9);
        assert_eq!(report.world_from_node[2], Matrix4::identity());
    }
}
