//! Robust pose-graph optimisation with line processes (Choi, Zhou, Koltun, "Robust Reconstruction of Indoor
//! Scenes", CVPR 2015, section 4; the scheme of Open3D's `GlobalOptimization`).
//!
//! The objective over the node poses W and one line process l ∈ [0, 1] per uncertain edge is
//!
//! ```text
//! E(W, l) = Σ_certain eᵀΛe + Σ_uncertain l eᵀΛe + μ Σ_uncertain (√l - 1)²
//! ```
//!
//! with e = [t; ω] the error of E = W_i⁻¹ W_j Z_ij⁻¹ (Z the measured i_from_j, ω = log of its rotation) and Λ the
//! edge's information matrix. For fixed poses the best l is (μ / (μ + eᵀΛe))², so alternating the two steps is
//! iteratively reweighted least squares with the Geman-McClure kernel ρ(s) = μ s / (μ + s): a wrong loop closure,
//! whose residual stays large, gets a weight near zero. The weight μ follows Open3D: `preference_loop_closure` x
//! `max_correspondence_distance`² x the mean correspondence count (Λ(0,0)) of the edges. After convergence the
//! uncertain edges with l below `edge_prune_threshold` are pruned and the graph is optimised again without them.
//!
//! The weighted least-squares step uses the `levenberg-marquardt` crate (a MINPACK port): this module supplies the
//! residuals √w S e (S = Λ^½) and their analytic Jacobians (checked against finite differences in the tests).
//! The crate is dense, so the step costs O(edges · nodes²): fine for hundreds of scans, not for many thousands.

use super::graph::{GraphEdge, PoseGraph, reachable_from_reference};
use crate::error::{Error, Result};
use crate::pose::skew;
use crate::pose::so3;
use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{Matrix3, Matrix4, Matrix6, SMatrix, Vector3, Vector6};
use nalgebra_lm::{DMatrix as LmMatrix, DVector as LmVector, Dyn, Owned};

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
}

/// The error e = [t; ω] of edge `z` (x_i = z x_j) between poses `wi` and `wj`.
pub fn edge_error(wi: &Matrix4<f64>, wj: &Matrix4<f64>, z: &Matrix4<f64>) -> Vector6<f64> {
    let (ri, ti) = parts(wi);
    let (rj, tj) = parts(wj);
    let (rz, tz) = parts(z);
    let c = -(rz.transpose() * tz);
    let t = ri.transpose() * (rj * c + tj - ti);
    let w = so3::log(&(ri.transpose() * rj * rz.transpose()));
    Vector6::new(t.x, t.y, t.z, w.x, w.y, w.z)
}

/// eᵀΛe of an edge at the given poses.
pub fn edge_chi2(edge: &GraphEdge, poses: &[Matrix4<f64>]) -> f64 {
    let e = edge_error(&poses[edge.i], &poses[edge.j], &edge.i_from_j);
    (e.transpose() * edge.information * e)[(0, 0)]
}

fn parts(m: &Matrix4<f64>) -> (Matrix3<f64>, Vector3<f64>) {
    (m.fixed_view::<3, 3>(0, 0).into_owned(), m.fixed_view::<3, 1>(0, 3).into_owned())
}

/// The symmetric square root of a (positive semi-definite) information matrix, negative eigenvalues clamped.
pub fn information_sqrt(information: &Matrix6<f64>) -> Matrix6<f64> {
    let sym = (information + information.transpose()) * 0.5;
    let eig = sym.symmetric_eigen();
    let d = eig.eigenvalues.map(|v| v.max(0.0).sqrt());
    eig.eigenvectors * Matrix6::from_diagonal(&d) * eig.eigenvectors.transpose()
}

/// Parameters of a node around its linearisation point: R = exp(φ) R0, t = t0 + ρ.
fn perturbed(base: &Matrix4<f64>, phi: &Vector3<f64>, rho: &Vector3<f64>) -> Matrix4<f64> {
    let (r0, t0) = parts(base);
    crate::pose::matrix_from_parts(&(so3::exp(phi) * r0), &(t0 + rho))
}

/// d e / d (φ_i, ρ_i) and d e / d (φ_j, ρ_j) at the poses `wi = exp(φ_i) R0_i ...` (J_l(φ) maps the parameter
/// step to the left perturbation).
pub fn edge_jacobians(
    wi: &Matrix4<f64>,
    wj: &Matrix4<f64>,
    z: &Matrix4<f64>,
    phi_i: &Vector3<f64>,
    phi_j: &Vector3<f64>,
) -> (SMatrix<f64, 6, 6>, SMatrix<f64, 6, 6>) {
    let (ri, ti) = parts(wi);
    let (rj, tj) = parts(wj);
    let (rz, tz) = parts(z);
    let c = -(rz.transpose() * tz);
    let v = rj * c + tj - ti;
    let rit = ri.transpose();
    let jinv = so3::left_jacobian_inverse(&so3::log(&(rit * rj * rz.transpose())));
    let (jl_i, jl_j) = (so3::left_jacobian(phi_i), so3::left_jacobian(phi_j));
    let mut a = SMatrix::<f64, 6, 6>::zeros();
    let mut b = SMatrix::<f64, 6, 6>::zeros();
    // Rows 0..3: translation error; rows 3..6: rotation error. Columns: φ then ρ.
    a.fixed_view_mut::<3, 3>(0, 0).copy_from(&(rit * skew(&v) * jl_i));
    a.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-rit));
    a.fixed_view_mut::<3, 3>(3, 0).copy_from(&(-(jinv * rit) * jl_i));
    b.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-(rit * skew(&(rj * c))) * jl_j));
    b.fixed_view_mut::<3, 3>(0, 3).copy_from(&rit);
    b.fixed_view_mut::<3, 3>(3, 0).copy_from(&(jinv * rit * jl_j));
    (a, b)
}

/// The weighted least-squares problem of one reweighting step, in the solver's types.
struct Problem<'a> {
    base: &'a [Matrix4<f64>],
    /// Column offset of each node's six parameters; `None` for fixed nodes.
    column: Vec<Option<usize>>,
    /// (edge, √w S).
    edges: Vec<(&'a GraphEdge, Matrix6<f64>)>,
    params: LmVector<f64>,
}

impl Problem<'_> {
    fn node(&self, k: usize) -> (Vector3<f64>, Vector3<f64>) {
        match self.column[k] {
            Some(c) => (
                Vector3::new(self.params[c], self.params[c + 1], self.params[c + 2]),
                Vector3::new(self.params[c + 3], self.params[c + 4], self.params[c + 5]),
            ),
            None => (Vector3::zeros(), Vector3::zeros()),
        }
    }

    fn pose(&self, k: usize) -> Matrix4<f64> {
        let (phi, rho) = self.node(k);
        perturbed(&self.base[k], &phi, &rho)
    }

    fn poses(&self) -> Vec<Matrix4<f64>> {
        (0..self.base.len()).map(|k| self.pose(k)).collect()
    }
}

impl LeastSquaresProblem<f64, Dyn, Dyn> for Problem<'_> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;

    fn set_params(&mut self, x: &LmVector<f64>) {
        self.params.copy_from(x);
    }

    fn params(&self) -> LmVector<f64> {
        self.params.clone()
    }

    fn residuals(&self) -> Option<LmVector<f64>> {
        let mut r = LmVector::zeros(6 * self.edges.len());
        for (k, (e, s)) in self.edges.iter().enumerate() {
            let res = s * edge_error(&self.pose(e.i), &self.pose(e.j), &e.i_from_j);
            for row in 0..6 {
                r[6 * k + row] = res[row];
            }
        }
        Some(r)
    }

    fn jacobian(&self) -> Option<LmMatrix<f64>> {
        let mut jac = LmMatrix::zeros(6 * self.edges.len(), self.params.len());
        for (k, (e, s)) in self.edges.iter().enumerate() {
            let ((phi_i, _), (phi_j, _)) = (self.node(e.i), self.node(e.j));
            let (a, b) = edge_jacobians(&self.pose(e.i), &self.pose(e.j), &e.i_from_j, &phi_i, &phi_j);
            for (node, block) in [(e.i, s * a), (e.j, s * b)] {
                let Some(c) = self.column[node] else { continue };
                for row in 0..6 {
                    for col in 0..6 {
                        jac[(6 * k + row, c + col)] = block[(row, col)];
                    }
                }
            }
        }
        Some(jac)
    }
}

/// Minimises Σ w eᵀΛe over the nodes in `free` (others fixed), starting at `poses`.
fn solve_weighted(poses: &[Matrix4<f64>], edges: &[(&GraphEdge, f64)], free: &[bool]) -> Result<Vec<Matrix4<f64>>> {
    let mut column = Vec::with_capacity(poses.len());
    let mut next = 0;
    for &f in free {
        column.push(f.then(|| {
            next += 6;
            next - 6
        }));
    }
    let used: Vec<(&GraphEdge, Matrix6<f64>)> = edges
        .iter()
        .filter(|(e, w)| *w > 0.0 && (free[e.i] || free[e.j]))
        .map(|(e, w)| (*e, information_sqrt(&e.information) * w.sqrt()))
        .collect();
    if next == 0 || used.is_empty() {
        return Ok(poses.to_vec());
    }
    let problem = Problem { base: poses, column, edges: used, params: LmVector::zeros(next) };
    let (problem, report) = LevenbergMarquardt::new().minimize(problem);
    if report.termination.was_usage_issue()
        || matches!(report.termination, levenberg_marquardt::TerminationReason::Numerical(_))
    {
        return Err(Error::invalid(format!("pose graph optimisation failed: {:?}", report.termination)));
    }
    Ok(problem.poses())
}

/// Alternates line-process updates and weighted solves over the `active` edges until the weights settle.
fn line_process_pass(
    graph: &PoseGraph,
    poses: &mut Vec<Matrix4<f64>>,
    active: &[bool],
    mu: f64,
    option: &GlobalOptimizationOption,
    line_process: &mut [f64],
) -> Result<usize> {
    let free: Vec<bool> = reachable_from_reference(poses.len(), &graph.edges, active)
        .into_iter()
        .enumerate()
        .map(|(k, r)| r && k != 0)
        .collect();
    let mut iterations = 0;
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
        let weighted: Vec<(&GraphEdge, f64)> = graph
            .edges
            .iter()
            .zip(active)
            .zip(line_process.iter())
            .filter(|((_, a), _)| **a)
            .map(|((e, _), &l)| (e, if e.uncertain { l } else { 1.0 }))
            .collect();
        *poses = solve_weighted(poses, &weighted, &free)?;
    }
    Ok(iterations)
}

/// Optimises `graph` robustly (see the module docs), starting from its node poses; node 0 stays fixed.
pub fn optimize(graph: &PoseGraph, option: &GlobalOptimizationOption) -> Result<OptimizationReport> {
    graph.validate()?;
    option.validate()?;
    let counts: Vec<f64> = graph.edges.iter().map(|e| e.information[(0, 0)]).filter(|&c| c > 0.0).collect();
    let mean_points = if counts.is_empty() { 1.0 } else { counts.iter().sum::<f64>() / counts.len() as f64 };
    let mu = option.preference_loop_closure * option.max_correspondence_distance.powi(2) * mean_points.max(1e-12);
    let mut poses = graph.world_from_node.clone();
    // An edge without information (no point of the pair within the correspondence distance) constrains
    // nothing: it stays out, so it cannot make a scan look connected.
    let mut active: Vec<bool> = graph.edges.iter().map(|e| e.information[(0, 0)] > 0.0).collect();
    let mut line_process: Vec<f64> = active.iter().map(|&a| if a { 1.0 } else { 0.0 }).collect();
    let mut iterations = line_process_pass(graph, &mut poses, &active, mu, option, &mut line_process)?;
    let mut pruned = false;
    for (k, e) in graph.edges.iter().enumerate() {
        if active[k] && e.uncertain && line_process[k] < option.edge_prune_threshold {
            active[k] = false;
            pruned = true;
        }
    }
    if pruned {
        iterations += line_process_pass(graph, &mut poses, &active, mu, option, &mut line_process)?;
    }
    let connected = reachable_from_reference(poses.len(), &graph.edges, &active);
    Ok(OptimizationReport {
        world_from_node: poses,
        line_process,
        survived: active,
        connected,
        line_process_weight: mu,
        iterations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn random_pose(rng: &mut Rng, angle: f64, reach: f64) -> Matrix4<f64> {
        let phi = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize() * angle * rng.unit_f64();
        let t = Vector3::new(rng.uniform(-reach, reach), rng.uniform(-reach, reach), rng.uniform(-reach, reach));
        crate::pose::matrix_from_parts(&so3::exp(&phi), &t)
    }

    #[test]
    fn analytic_jacobians_match_central_differences() {
        let mut rng = Rng::new(5);
        let h = 1e-6;
        for _ in 0..10 {
            let (bi, bj, z) =
                (random_pose(&mut rng, 3.0, 2.0), random_pose(&mut rng, 3.0, 2.0), random_pose(&mut rng, 1.0, 1.0));
            let phi_i = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.3;
            let phi_j = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.3;
            let (rho_i, rho_j) = (Vector3::new(0.1, -0.2, 0.3), Vector3::new(-0.3, 0.0, 0.2));
            let at = |pi: Vector3<f64>, ri: Vector3<f64>, pj: Vector3<f64>, rj: Vector3<f64>| {
                edge_error(&perturbed(&bi, &pi, &ri), &perturbed(&bj, &pj, &rj), &z)
            };
            let (wi, wj) = (perturbed(&bi, &phi_i, &rho_i), perturbed(&bj, &phi_j, &rho_j));
            let (a, b) = edge_jacobians(&wi, &wj, &z, &phi_i, &phi_j);
            for col in 0..6 {
                let mut d = Vector3::zeros();
                d[col % 3] = h;
                let (numeric_i, numeric_j) = if col < 3 {
                    (
                        (at(phi_i + d, rho_i, phi_j, rho_j) - at(phi_i - d, rho_i, phi_j, rho_j)) / (2.0 * h),
                        (at(phi_i, rho_i, phi_j + d, rho_j) - at(phi_i, rho_i, phi_j - d, rho_j)) / (2.0 * h),
                    )
                } else {
                    (
                        (at(phi_i, rho_i + d, phi_j, rho_j) - at(phi_i, rho_i - d, phi_j, rho_j)) / (2.0 * h),
                        (at(phi_i, rho_i, phi_j, rho_j + d) - at(phi_i, rho_i, phi_j, rho_j - d)) / (2.0 * h),
                    )
                };
                assert!((numeric_i - a.column(col)).norm() < 1e-6, "i col {col}: {numeric_i} vs {}", a.column(col));
                assert!((numeric_j - b.column(col)).norm() < 1e-6, "j col {col}: {numeric_j} vs {}", b.column(col));
            }
        }
    }

    #[test]
    fn information_sqrt_squares_back() {
        let pts: Vec<[f64; 3]> =
            (0..20).map(|k| [k as f64 * 0.1, (k % 3) as f64, 1.0 + (k % 5) as f64 * 0.2]).collect();
        let info = crate::eval::metrics::information_matrix(&pts);
        let s = information_sqrt(&info);
        assert!((s * s - info).abs().max() < 1e-9 * info.abs().max());
        // A rank-deficient (planar) information matrix still has a real square root.
        let plane: Vec<[f64; 3]> = (0..20).map(|k| [k as f64 * 0.1, (k % 4) as f64 * 0.3, 0.0]).collect();
        let info = crate::eval::metrics::information_matrix(&plane);
        let s = information_sqrt(&info);
        assert!((s * s - info).abs().max() < 1e-9 * info.abs().max());
    }

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
