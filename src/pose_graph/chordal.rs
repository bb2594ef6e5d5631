//! Chordal initialisation (Martinec and Pajdla 2007; Carlone et al., "Initialization techniques for 3D SLAM",
//! ICRA 2015; GTSAM's `InitializePose3`): a start for Levenberg-Marquardt that does not depend on how far the
//! odometry drifted, so LM does not stop in the local minimum the drift leads to.
//!
//! 1. Rotations: minimise Σ w_r ‖R_j − R_i Z_R‖²_F over unconstrained 3 x 3 matrices (linear least squares; the
//!    three rows of every R decouple into three right-hand sides of one sparse system), then project each
//!    solution onto SO(3).
//! 2. Translations: with the rotations fixed, minimise Σ w_t ‖t_j − t_i − R_i z_t‖² (again linear).
//!
//! w_r and w_t are the mean diagonal entries of the edge's rotation and translation information. Node 0 keeps its
//! pose; nodes the edges do not connect to it keep theirs. Both systems are solved with faer's sparse Cholesky.

use super::se3::parts;
use super::sparse::BlockPattern;
use crate::error::{Error, Result};
use crate::multiway::graph::{GraphEdge, reachable_from_reference};
use crate::pose::{matrix_from_parts, nearest_rotation};
use nalgebra::{Matrix3, Matrix4, Vector3};

/// Poses from the chordal relaxation of the `active` edges (see the module docs); `world_from_node` supplies
/// node 0's pose and the poses of unconnected nodes.
pub fn chordal_poses(
    world_from_node: &[Matrix4<f64>],
    edges: &[GraphEdge],
    active: &[bool],
) -> Result<Vec<Matrix4<f64>>> {
    let n = world_from_node.len();
    let weights: Vec<(f64, f64)> = edges.iter().map(|e| (mean_diagonal(e, 3), mean_diagonal(e, 0))).collect();
    let usable: Vec<bool> = edges
        .iter()
        .zip(active)
        .zip(&weights)
        .map(|((e, a), (wr, wt))| *a && e.i < n && e.j < n && *wr > 0.0 && *wt > 0.0)
        .collect();
    let weighted: Vec<(&GraphEdge, f64, f64)> =
        edges.iter().zip(&weights).zip(&usable).filter(|(_, u)| **u).map(|((e, w), _)| (e, w.0, w.1)).collect();
    let reachable = reachable_from_reference(n, edges, &usable);
    let mut next = 0;
    let block: Vec<Option<usize>> = reachable
        .iter()
        .enumerate()
        .map(|(k, &r)| {
            let free = r && k != 0;
            next += usize::from(free);
            free.then(|| next - 1)
        })
        .collect();
    let mut poses = world_from_node.to_vec();
    if next == 0 {
        return Ok(poses);
    }
    let rotations = solve_rotations(&poses, &weighted, &block, next)?;
    for (k, b) in block.iter().enumerate() {
        if let Some(b) = b {
            let x = Matrix3::from_fn(|r, c| rotations[c * 3 * next + 3 * b + r]);
            poses[k] = matrix_from_parts(&nearest_rotation(&x.transpose()), &Vector3::zeros());
        }
    }
    let translations = solve_translations(&poses, &weighted, &block, next)?;
    for (k, b) in block.iter().enumerate() {
        if let Some(b) = b {
            poses[k].fixed_view_mut::<3, 1>(0, 3).copy_from_slice(&translations[3 * b..3 * b + 3]);
        }
    }
    Ok(poses)
}

/// Mean of the information diagonal from `offset` (0: translation, 3: rotation).
fn mean_diagonal(e: &GraphEdge, offset: usize) -> f64 {
    let w = (0..3).map(|k| e.information[(offset + k, offset + k)]).sum::<f64>() / 3.0;
    if w.is_finite() { w } else { 0.0 }
}

/// A linear system of 3 x 3 blocks over the free nodes, assembled edge by edge.
struct Linear<'a> {
    block: &'a [Option<usize>],
    free: usize,
    diagonal: Vec<f64>,
    off: Vec<(usize, usize, Matrix3<f64>)>,
    /// `columns` right-hand sides of length 3 x free, one after another.
    rhs: Vec<f64>,
    columns: usize,
}

impl<'a> Linear<'a> {
    fn new(block: &'a [Option<usize>], free: usize, columns: usize) -> Self {
        Linear {
            block,
            free,
            diagonal: vec![0.0; free * 9],
            off: Vec::new(),
            rhs: vec![0.0; 3 * free * columns],
            columns,
        }
    }

    /// Adds the term w ‖x_j − Mᵀ x_i − c‖² (x, c: 3 x columns) where `known_i`/`known_j` give fixed nodes' values.
    fn add(
        &mut self,
        (i, j): (usize, usize),
        w: f64,
        m: &Matrix3<f64>,
        c: &[Vector3<f64>],
        known: (&[Vector3<f64>], &[Vector3<f64>]),
    ) {
        let (bi, bj) = (self.block[i], self.block[j]);
        // Rows of the residual's Jacobian: J_i = −Mᵀ, J_j = I.
        for (col, offset) in c.iter().enumerate() {
            // The constant part of the residual: fixed ends and the offset.
            let mut constant = -offset;
            if bi.is_none() {
                constant -= m.transpose() * known.0[col];
            }
            if bj.is_none() {
                constant += known.1[col];
            }
            if let Some(b) = bi {
                self.add_rhs(b, col, &(m * constant * w));
            }
            if let Some(b) = bj {
                self.add_rhs(b, col, &(-constant * w));
            }
        }
        if let Some(b) = bi {
            self.add_diagonal(b, &(m * m.transpose() * w));
        }
        if let Some(b) = bj {
            self.add_diagonal(b, &(Matrix3::identity() * w));
        }
        if let (Some(a), Some(b)) = (bi, bj) {
            self.off.push((a, b, -m * w));
        }
    }

    fn add_diagonal(&mut self, b: usize, h: &Matrix3<f64>) {
        for r in 0..3 {
            for c in 0..3 {
                self.diagonal[9 * b + 3 * r + c] += h[(r, c)];
            }
        }
    }

    fn add_rhs(&mut self, b: usize, col: usize, v: &Vector3<f64>) {
        for r in 0..3 {
            self.rhs[col * 3 * self.free + 3 * b + r] += v[r];
        }
    }

    /// The solution, column after column.
    fn solve(self) -> Result<Vec<f64>> {
        let pairs: Vec<(usize, usize)> = self.off.iter().map(|(a, b, _)| (*a, *b)).collect();
        let pattern = BlockPattern::new(3, self.free, &pairs)?;
        let mut off = Vec::with_capacity(self.off.len() * 9);
        for (a, b, h) in &self.off {
            // The pattern stores the block of rows min(a, b).
            let h = if a < b { *h } else { h.transpose() };
            off.extend((0..9).map(|k| h[(k / 3, k % 3)]));
        }
        let factor = pattern.factor(&self.diagonal, &vec![0.0; 3 * self.free], &off)?.ok_or_else(|| {
            Error::invalid("chordal initialisation: the linear system is singular (edges without information?)")
        })?;
        Ok(factor.solve(&self.rhs, self.columns))
    }
}

/// Row c of every free R (as column c of Rᵀ): R_j − R_i Z = 0 reads x_j − Zᵀ x_i = 0 for the rows x of R.
fn solve_rotations(
    poses: &[Matrix4<f64>],
    edges: &[(&GraphEdge, f64, f64)],
    block: &[Option<usize>],
    free: usize,
) -> Result<Vec<f64>> {
    let mut linear = Linear::new(block, free, 3);
    let rows = |k: usize| {
        let r = parts(&poses[k]).0;
        [0, 1, 2].map(|c| r.row(c).transpose())
    };
    let zero = [Vector3::zeros(); 3];
    for (e, wr, _) in edges {
        let z = parts(&e.i_from_j).0;
        linear.add((e.i, e.j), *wr, &z, &zero, (&rows(e.i), &rows(e.j)));
    }
    linear.solve()
}

/// Every free t given the rotations: t_j − t_i − R_i z_t = 0.
fn solve_translations(
    poses: &[Matrix4<f64>],
    edges: &[(&GraphEdge, f64, f64)],
    block: &[Option<usize>],
    free: usize,
) -> Result<Vec<f64>> {
    let mut linear = Linear::new(block, free, 1);
    for (e, _, wt) in edges {
        let (ri, _) = parts(&poses[e.i]);
        let offset = ri * parts(&e.i_from_j).1;
        let (ti, tj) = (parts(&poses[e.i]).1, parts(&poses[e.j]).1);
        linear.add((e.i, e.j), *wt, &Matrix3::identity(), &[offset], (&[ti], &[tj]));
    }
    linear.solve()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pose::{rigid_inverse, rotation_error_deg, translation_error};
    use crate::rng::Rng;
    use nalgebra::Matrix6;

    fn random_pose(rng: &mut Rng, angle: f64, reach: f64) -> Matrix4<f64> {
        let phi = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize() * angle;
        let t = Vector3::new(rng.uniform(-reach, reach), rng.uniform(-reach, reach), rng.uniform(-reach, reach));
        matrix_from_parts(&super::super::so3::exp(&phi), &t)
    }

    #[test]
    fn exact_measurements_give_back_the_known_poses_from_any_start() {
        let mut rng = Rng::new(11);
        let n = 30;
        let truth: Vec<Matrix4<f64>> =
            (0..n).map(|k| if k == 0 { Matrix4::identity() } else { random_pose(&mut rng, 3.0, 10.0) }).collect();
        let mut edges = Vec::new();
        for k in 0..n - 1 {
            edges.push((k, k + 1));
            edges.push((k, (k * 7 + 3) % n));
        }
        let information = Matrix6::from_diagonal(&nalgebra::Vector6::new(1.0, 2.0, 1.5, 10.0, 8.0, 9.0));
        let edges: Vec<GraphEdge> = edges
            .into_iter()
            .filter(|(i, j)| i != j)
            .map(|(i, j)| GraphEdge {
                i,
                j,
                i_from_j: rigid_inverse(&truth[i]) * truth[j],
                information,
                uncertain: false,
            })
            .collect();
        // The start is the identity everywhere but node 0: nothing of the answer is in it.
        let start = vec![Matrix4::identity(); n];
        let poses = chordal_poses(&start, &edges, &vec![true; edges.len()]).unwrap();
        for k in 0..n {
            let (t, r) = (translation_error(&poses[k], &truth[k]), rotation_error_deg(&poses[k], &truth[k]));
            assert!(t < 1e-8 && r < 1e-6, "node {k}: {t} m, {r} deg");
        }
    }

    #[test]
    fn noisy_measurements_land_near_the_truth_and_unconnected_nodes_stay() {
        let mut rng = Rng::new(12);
        let n = 40;
        let truth: Vec<Matrix4<f64>> = (0..n)
            .map(|k| {
                let a = std::f64::consts::TAU * k as f64 / n as f64;
                matrix_from_parts(
                    &super::super::so3::exp(&Vector3::new(0.0, 0.0, a)),
                    &Vector3::new(5.0 * a.cos(), 5.0 * a.sin(), 0.0),
                )
            })
            .collect();
        let mut edges = Vec::new();
        for k in 0..n - 1 {
            for j in [k + 1, (k + n / 2) % n] {
                if j != k && j < n - 1 {
                    let noise = random_pose(&mut rng, 0.01, 0.01);
                    let i_from_j = rigid_inverse(&truth[k]) * truth[j] * noise;
                    edges.push(GraphEdge { i: k, j, i_from_j, information: Matrix6::identity(), uncertain: false });
                }
            }
        }
        // Node n - 1 has no edge: it keeps its start pose. Node 0 is the anchor.
        let mut start = vec![Matrix4::identity(); n];
        start[n - 1] = truth[3];
        start[0] = truth[0];
        let poses = chordal_poses(&start, &edges, &vec![true; edges.len()]).unwrap();
        assert_eq!(poses[n - 1], truth[3]);
        for k in 0..n - 1 {
            let (t, r) = (translation_error(&poses[k], &truth[k]), rotation_error_deg(&poses[k], &truth[k]));
            // Budget: the noise of ~20 chained edges (0.01 rad, 1 cm each) at a 5 m lever arm is ~0.25 m, 2.6 deg.
            assert!(t < 0.3 && r < 3.0, "node {k}: {t} m, {r} deg");
        }
    }
}
