//! Sparse on-manifold Levenberg-Marquardt for SE(3) pose graphs.
//!
//! The cost is F = ½ Σ w eᵀΩe over the edges, e = Log(Z⁻¹ T_i⁻¹ T_j) (see [`edge_error`]) and w the edge's
//! weight (1, or a line process). Poses move by right perturbations T ← T Exp(δ), δ = [ρ; φ]; each step solves
//! (H + λD) δ = −g with H = Σ Jᵀ wΩ J and g = Σ Jᵀ wΩ e assembled per edge into 6 x 6 blocks and factored by
//! faer's sparse Cholesky ([`super::sparse`]): memory follows the edges, not nodes². D = diag(H) clamped as
//! Ceres does; λ starts near Gauss-Newton and follows Nielsen's gain-ratio rule (shrinking at most tenfold a step). The analytic Jacobians ([`edge_jacobians`]) are exact, so
//! the fixed point is the exact stationary point of F (the tests check them against finite differences).

use super::se3;
use super::sparse::{BlockPattern, Factor};
use crate::error::{Error, Result};
use crate::multiway::graph::GraphEdge;
use crate::pose::rigid_inverse;
use nalgebra::{Matrix4, Matrix6, Vector6};
use rayon::prelude::*;

/// λ of the first step, relative to diag(H): nearly Gauss-Newton, since pose-graph steps from a reasonable start
/// are good ones (on generated helix graphs of 2,000 poses, 1e-10 took 4-6 steps where 1e-5 took 5-8).
const INITIAL_DAMPING: f64 = 1e-10;

/// Stopping rules.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LmOptions {
    /// Most linearisations (accepted and rejected steps together).
    pub max_iterations: usize,
    /// Stop once an accepted step lowers the cost by less than this fraction.
    pub relative_decrease: f64,
}

impl Default for LmOptions {
    fn default() -> Self {
        LmOptions { max_iterations: 100, relative_decrease: 1e-10 }
    }
}

/// What a minimisation did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LmReport {
    /// Steps tried (accepted and rejected).
    pub iterations: usize,
    /// F at the start.
    pub initial_cost: f64,
    /// F at the end.
    pub final_cost: f64,
}

/// The edge error e = Log(Z⁻¹ T_i⁻¹ T_j) = [ρ; φ] of measurement `z` = i_from_j between world_from_i `wi` and
/// world_from_j `wj`: GTSAM's `BetweenFactor<Pose3>` error with its two halves swapped (translation first).
pub fn edge_error(wi: &Matrix4<f64>, wj: &Matrix4<f64>, z: &Matrix4<f64>) -> Vector6<f64> {
    se3::log(&(rigid_inverse(z) * rigid_inverse(wi) * wj))
}

/// d e / d δ_i and d e / d δ_j for right perturbations T ← T Exp(δ), at error `e` = [`edge_error`]:
/// −J_r(e)⁻¹ Ad(T_j⁻¹ T_i) and J_r(e)⁻¹.
pub fn edge_jacobians(wi: &Matrix4<f64>, wj: &Matrix4<f64>, e: &Vector6<f64>) -> (Matrix6<f64>, Matrix6<f64>) {
    let jr_inv = se3::right_jacobian_inverse(e);
    (-(jr_inv * se3::adjoint(&(rigid_inverse(wj) * wi))), jr_inv)
}

/// eᵀΩe of an edge at the given poses (Ω symmetrised).
pub fn edge_chi2(edge: &GraphEdge, poses: &[Matrix4<f64>]) -> f64 {
    let e = edge_error(&poses[edge.i], &poses[edge.j], &edge.i_from_j);
    e.dot(&(symmetric(&edge.information) * e))
}

/// F = ½ Σ eᵀΩe over all edges (GTSAM's `graph.error` of the same graph).
pub fn cost(edges: &[GraphEdge], poses: &[Matrix4<f64>]) -> f64 {
    0.5 * edges.iter().map(|e| edge_chi2(e, poses)).sum::<f64>()
}

fn symmetric(m: &Matrix6<f64>) -> Matrix6<f64> {
    (m + m.transpose()) * 0.5
}

/// A pose graph's normal-equation structure for a fixed set of free nodes and edges: built once, minimised for
/// any edge weights (the line-process passes reuse one symbolic factorisation).
pub struct Problem<'a> {
    edges: &'a [GraphEdge],
    /// Variable block of each node; `None` for fixed nodes.
    block: Vec<Option<usize>>,
    /// Edges that touch a free node, with their off-diagonal pair index when both ends are free.
    used: Vec<(usize, Option<usize>)>,
    /// Edges between two fixed nodes: constant cost.
    fixed: Vec<usize>,
    pattern: BlockPattern,
}

/// One edge's contribution to H and g.
struct EdgeTerms {
    cost: f64,
    hii: Matrix6<f64>,
    hjj: Matrix6<f64>,
    hij: Matrix6<f64>,
    gi: Vector6<f64>,
    gj: Vector6<f64>,
}

/// The assembled normal equations at one linearisation point.
struct Normal {
    cost: f64,
    diagonal: Vec<f64>,
    off: Vec<f64>,
    gradient: Vec<f64>,
}

impl<'a> Problem<'a> {
    /// The structure for `edges` whose `active` flag is set, with nodes `free` (the others stay fixed).
    pub fn new(edges: &'a [GraphEdge], active: &[bool], free: &[bool]) -> Result<Problem<'a>> {
        let mut next = 0;
        let block: Vec<Option<usize>> = free
            .iter()
            .map(|&f| {
                next += usize::from(f);
                f.then(|| next - 1)
            })
            .collect();
        let mut pairs = Vec::new();
        let mut used = Vec::new();
        let mut fixed = Vec::new();
        for (k, e) in edges.iter().enumerate() {
            if !active[k] || e.i >= block.len() || e.j >= block.len() {
                continue;
            }
            match (block[e.i], block[e.j]) {
                (None, None) => fixed.push(k),
                (Some(a), Some(b)) => {
                    used.push((k, Some(pairs.len())));
                    pairs.push((a, b));
                }
                _ => used.push((k, None)),
            }
        }
        let pattern = BlockPattern::new(6, next, &pairs)?;
        Ok(Problem { edges, block, used, fixed, pattern })
    }

    /// Minimises ½ Σ w eᵀΩe (edge k weighted by `weights[k]`) from `poses`; returns the new poses.
    pub fn minimize(
        &self,
        poses: &[Matrix4<f64>],
        weights: &[f64],
        options: &LmOptions,
    ) -> Result<(Vec<Matrix4<f64>>, LmReport)> {
        let mut poses = poses.to_vec();
        let mut normal = self.linearize(&poses, weights);
        let initial_cost = normal.cost;
        let mut report = LmReport { iterations: 0, initial_cost, final_cost: initial_cost };
        if self.pattern.dim() == 0 || self.used.is_empty() {
            return Ok((poses, report));
        }
        let (mut lambda, mut nu) = (INITIAL_DAMPING, 2.0);
        while report.iterations < options.max_iterations {
            if normal.gradient.iter().all(|g| g.abs() <= 1e-12 * (1.0 + normal.cost)) || normal.cost == 0.0 {
                break;
            }
            report.iterations += 1;
            let damping: Vec<f64> = (0..normal.gradient.len())
                .map(|k| lambda * normal.diagonal[(k / 6) * 36 + (k % 6) * 7].clamp(1e-6, 1e32))
                .collect();
            let Some(factor) = self.pattern.factor(&normal.diagonal, &damping, &normal.off)? else {
                (lambda, nu) = (lambda * nu, nu * 2.0);
                continue;
            };
            let (delta, predicted) = step(&factor, &normal.gradient, &damping);
            let candidate = self.retract(&poses, &delta);
            let new_cost = self.cost(&candidate, weights);
            let gain = (normal.cost - new_cost) / predicted;
            if predicted > 0.0 && gain > 0.0 && new_cost.is_finite() {
                let relative = (normal.cost - new_cost) / normal.cost;
                poses = candidate;
                normal = self.linearize(&poses, weights);
                lambda *= (1.0 - (2.0 * gain - 1.0).powi(3)).max(0.1);
                nu = 2.0;
                if relative < options.relative_decrease {
                    break;
                }
            } else {
                (lambda, nu) = (lambda * nu, nu * 2.0);
                if lambda > 1e20 || !predicted.is_finite() {
                    break;
                }
            }
        }
        if !normal.cost.is_finite() {
            return Err(Error::invalid("pose graph optimisation diverged (non-finite cost)"));
        }
        report.final_cost = normal.cost;
        Ok((poses, report))
    }

    /// T_k Exp(δ_k) for every free node.
    fn retract(&self, poses: &[Matrix4<f64>], delta: &[f64]) -> Vec<Matrix4<f64>> {
        poses
            .iter()
            .zip(&self.block)
            .map(|(t, b)| match b {
                Some(b) => t * se3::exp(&Vector6::from_column_slice(&delta[6 * b..6 * b + 6])),
                None => *t,
            })
            .collect()
    }

    /// H (blocks) and g at `poses`.
    fn linearize(&self, poses: &[Matrix4<f64>], weights: &[f64]) -> Normal {
        let terms: Vec<EdgeTerms> =
            self.used.par_iter().map(|&(k, _)| edge_terms(&self.edges[k], weights[k].max(0.0), poses)).collect();
        let dim = self.pattern.dim();
        let mut normal = Normal {
            cost: 0.0,
            diagonal: vec![0.0; dim * 6],
            off: vec![0.0; self.pattern.pairs().len() * 36],
            gradient: vec![0.0; dim],
        };
        for (&(k, pair), t) in self.used.iter().zip(&terms) {
            let e = &self.edges[k];
            normal.cost += t.cost;
            for (node, h, g) in [(e.i, &t.hii, &t.gi), (e.j, &t.hjj, &t.gj)] {
                if let Some(b) = self.block[node] {
                    add_block(&mut normal.diagonal[36 * b..36 * b + 36], h);
                    for r in 0..6 {
                        normal.gradient[6 * b + r] += g[r];
                    }
                }
            }
            if let Some(p) = pair {
                // The pattern stores (min, max): the block of rows i and columns j, or its transpose.
                let (a, _) = self.pattern.pairs()[p];
                let h = if Some(a) == self.block[e.i] { t.hij } else { t.hij.transpose() };
                add_block(&mut normal.off[36 * p..36 * p + 36], &h);
            }
        }
        // Edges between two fixed nodes add cost but no terms.
        normal.cost +=
            self.fixed.iter().map(|&k| 0.5 * weights[k].max(0.0) * edge_chi2(&self.edges[k], poses)).sum::<f64>();
        normal
    }

    /// F over this problem's edges at `poses`.
    pub fn cost(&self, poses: &[Matrix4<f64>], weights: &[f64]) -> f64 {
        let half_chi2 = |k: usize| 0.5 * weights[k].max(0.0) * edge_chi2(&self.edges[k], poses);
        // Collected before summing, so the sum's order (and result) does not depend on the thread schedule.
        let terms: Vec<f64> = self.used.par_iter().map(|&(k, _)| half_chi2(k)).collect();
        terms.iter().sum::<f64>() + self.fixed.iter().map(|&k| half_chi2(k)).sum::<f64>()
    }
}

/// One edge's cost, H blocks and gradient blocks at `poses`, weighted by `w`.
fn edge_terms(edge: &GraphEdge, w: f64, poses: &[Matrix4<f64>]) -> EdgeTerms {
    let (wi, wj) = (&poses[edge.i], &poses[edge.j]);
    let e = edge_error(wi, wj, &edge.i_from_j);
    let omega = symmetric(&edge.information) * w;
    let (a, b) = edge_jacobians(wi, wj, &e);
    let (at_omega, bt_omega) = (a.transpose() * omega, b.transpose() * omega);
    EdgeTerms {
        cost: 0.5 * e.dot(&(omega * e)),
        hii: at_omega * a,
        hjj: bt_omega * b,
        hij: at_omega * b,
        gi: at_omega * e,
        gj: bt_omega * e,
    }
}

/// Adds a 6 x 6 block into a row-major slice.
fn add_block(target: &mut [f64], h: &Matrix6<f64>) {
    for r in 0..6 {
        for c in 0..6 {
            target[r * 6 + c] += h[(r, c)];
        }
    }
}

/// δ = −(H + λD)⁻¹ g and the reduction the linear model predicts, ½(−gᵀδ + δᵀ λD δ).
fn step(factor: &Factor, gradient: &[f64], damping: &[f64]) -> (Vec<f64>, f64) {
    let minus_g: Vec<f64> = gradient.iter().map(|g| -g).collect();
    let delta = factor.solve(&minus_g, 1);
    let predicted = 0.5 * delta.iter().zip(gradient).zip(damping).map(|((d, g), l)| -g * d + l * d * d).sum::<f64>();
    (delta, predicted)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn random_pose(rng: &mut Rng, angle: f64, reach: f64) -> Matrix4<f64> {
        let phi = nalgebra::Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize() * angle;
        let t =
            nalgebra::Vector3::new(rng.uniform(-reach, reach), rng.uniform(-reach, reach), rng.uniform(-reach, reach));
        crate::pose::matrix_from_parts(&super::super::so3::exp(&phi), &t)
    }

    #[test]
    fn analytic_jacobians_match_central_differences() {
        let mut rng = Rng::new(5);
        let h = 1e-6;
        for _ in 0..20 {
            let (wi, wj) = (random_pose(&mut rng, 2.5, 3.0), random_pose(&mut rng, 2.5, 3.0));
            // Measurements near and far from the poses' relative pose (large errors exercise J_r⁻¹ fully).
            let angle = rng.uniform(0.0, 2.0);
            let z = rigid_inverse(&wi) * wj * random_pose(&mut rng, angle, 0.5);
            let e = edge_error(&wi, &wj, &z);
            let (a, b) = edge_jacobians(&wi, &wj, &e);
            for c in 0..6 {
                let mut d = Vector6::zeros();
                d[c] = h;
                let (plus, minus) = (se3::exp(&d), se3::exp(&(-d)));
                let numeric_i = (edge_error(&(wi * plus), &wj, &z) - edge_error(&(wi * minus), &wj, &z)) / (2.0 * h);
                let numeric_j = (edge_error(&wi, &(wj * plus), &z) - edge_error(&wi, &(wj * minus), &z)) / (2.0 * h);
                assert!((numeric_i - a.column(c)).norm() < 1e-6, "i col {c}: {numeric_i} vs {}", a.column(c));
                assert!((numeric_j - b.column(c)).norm() < 1e-6, "j col {c}: {numeric_j} vs {}", b.column(c));
            }
        }
    }
}
