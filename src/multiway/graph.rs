//! The pose graph: one node per scan (world_from_node), one edge per registered pair with its measured
//! relative pose and information matrix, and the initial poses from a maximum spanning tree of the edges.

use crate::error::{Error, Result};
use crate::pose::inverse;
use nalgebra::{Matrix4, Matrix6};
use std::collections::{BTreeSet, VecDeque};

/// One measured relative pose.
#[derive(Clone, Debug, PartialEq)]
pub struct GraphEdge {
    /// The target node (its frame holds the information matrix's points).
    pub i: usize,
    /// The source node.
    pub j: usize,
    /// The measurement x_i = T x_j.
    pub i_from_j: Matrix4<f64>,
    /// 6x6 information matrix of the edge error e = Log(i_from_j⁻¹ world_from_i⁻¹ world_from_j) = [ρ; φ]
    /// (translation first, as g2o's; see [`crate::pose_graph`]). A registration's information matrix, which
    /// acts on the error of world_from_i⁻¹ world_from_j i_from_j⁻¹ in frame i, is moved here by
    /// [`information_at_source`].
    pub information: Matrix6<f64>,
    /// Whether a line process may switch the edge off (loop closures); certain edges (trusted odometry) always
    /// count in full.
    pub uncertain: bool,
}

/// Nodes and edges.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseGraph {
    /// x_world = world_from_node[k] x_k; node 0 is the reference and stays where it is.
    pub world_from_node: Vec<Matrix4<f64>>,
    /// The measurements.
    pub edges: Vec<GraphEdge>,
}

impl PoseGraph {
    /// Checks node indices and finiteness; the error names the edge.
    pub fn validate(&self) -> Result<()> {
        let n = self.world_from_node.len();
        for (k, e) in self.edges.iter().enumerate() {
            if e.i >= n || e.j >= n || e.i == e.j {
                return Err(Error::invalid(format!(
                    "pose graph edge {k} joins nodes {} and {}, but the graph has {n} nodes (and no self-loops)",
                    e.i, e.j
                )));
            }
            if !(e.i_from_j.iter().all(|v| v.is_finite()) && e.information.iter().all(|v| v.is_finite())) {
                return Err(Error::invalid(format!("pose graph edge {k} ({}, {}) has non-finite entries", e.i, e.j)));
            }
        }
        if let Some(k) = self.world_from_node.iter().position(|w| !w.iter().all(|v| v.is_finite())) {
            return Err(Error::invalid(format!("pose graph node {k} has a non-finite pose")));
        }
        Ok(())
    }
}

/// The information matrix of an edge's error in frame j (the pose graph's convention) from `at_target`, the
/// information of the error [t; ω] of E_i = world_from_i⁻¹ world_from_j i_from_j⁻¹ in frame i (the gt.info and
/// registration convention). E_i = Z E_j Z⁻¹, so e_i = Ad(Z) e_j to first order and Ω_j = Ad(Z)ᵀ Ω_i Ad(Z).
pub fn information_at_source(at_target: &Matrix6<f64>, i_from_j: &Matrix4<f64>) -> Matrix6<f64> {
    let ad = crate::pose_graph::se3::adjoint(i_from_j);
    ad.transpose() * at_target * ad
}

/// Nodes reachable from node 0 over the edges whose `active` flag is set (breadth-first over adjacency lists:
/// O(nodes + edges)).
pub fn reachable_from_reference(n: usize, edges: &[GraphEdge], active: &[bool]) -> Vec<bool> {
    let mut seen = vec![false; n];
    if n == 0 {
        return seen;
    }
    let incident = incident_edges(n, edges, |k| active.get(k).copied().unwrap_or(false));
    seen[0] = true;
    let mut queue = VecDeque::from([0usize]);
    while let Some(node) = queue.pop_front() {
        for &k in &incident[node] {
            let other = edges[k].i + edges[k].j - node;
            if !seen[other] {
                seen[other] = true;
                queue.push_back(other);
            }
        }
    }
    seen
}

/// The indices of the edges (those `keep` accepts, joining nodes below `n`) at each node.
fn incident_edges(n: usize, edges: &[GraphEdge], keep: impl Fn(usize) -> bool) -> Vec<Vec<usize>> {
    let mut incident: Vec<Vec<usize>> = vec![Vec::new(); n];
    for (k, e) in edges.iter().enumerate().filter(|(k, e)| keep(*k) && e.i < n && e.j < n) {
        incident[e.i].push(k);
        incident[e.j].push(k);
    }
    incident
}

/// Initial world_from_node for `n` nodes: node 0 at the identity, then a maximum spanning tree over the edges by
/// `strength` (e.g. trusted first, then by inlier count; Prim's algorithm, ties to the lower edge index), each
/// node placed by composing its tree edge. Nodes no edge reaches stay at the identity; the second value marks the
/// nodes that were placed.
pub fn spanning_tree_poses(n: usize, edges: &[GraphEdge], strength: &[f64]) -> (Vec<Matrix4<f64>>, Vec<bool>) {
    let mut poses = vec![Matrix4::identity(); n];
    let mut placed = vec![false; n];
    if n == 0 {
        return (poses, placed);
    }
    placed[0] = true;
    // Candidate edges touching the tree, best first: (strength as ordered key, -index) in a set.
    let key = |k: usize| (ordered(strength.get(k).copied().unwrap_or(0.0)), std::cmp::Reverse(k));
    let mut frontier: BTreeSet<(i64, std::cmp::Reverse<usize>)> = BTreeSet::new();
    let incident = incident_edges(n, edges, |_| true);
    let touching = |node: usize, frontier: &mut BTreeSet<_>| {
        for &k in &incident[node] {
            frontier.insert(key(k));
        }
    };
    touching(0, &mut frontier);
    while let Some(best) = frontier.pop_last() {
        let k = best.1.0;
        let e = &edges[k];
        let (new, pose) = match (placed[e.i], placed[e.j]) {
            // world_from_j = world_from_i * i_from_j, and back.
            (true, false) => (e.j, poses[e.i] * e.i_from_j),
            (false, true) => (e.i, poses[e.j] * inverse(&e.i_from_j)),
            _ => continue,
        };
        poses[new] = pose;
        placed[new] = true;
        touching(new, &mut frontier);
    }
    (poses, placed)
}

/// A float as a totally ordered integer key (for the frontier set).
fn ordered(x: f64) -> i64 {
    let bits = x.to_bits() as i64;
    if bits < 0 { bits ^ i64::MAX } else { bits }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn translation(x: f64) -> Matrix4<f64> {
        Matrix4::new_translation(&nalgebra::Vector3::new(x, 0.0, 0.0))
    }

    fn edge(i: usize, j: usize, x: f64) -> GraphEdge {
        GraphEdge { i, j, i_from_j: translation(x), information: Matrix6::identity(), uncertain: false }
    }

    #[test]
    fn spanning_tree_prefers_strong_edges_and_composes_both_directions() {
        // 0 -1- 1 -1- 2, and a strong but wrong shortcut 0 - 2 claiming x = 5.
        let edges = [edge(0, 1, 1.0), edge(1, 2, 1.0), edge(0, 2, 5.0), edge(3, 2, -1.0)];
        let (poses, placed) = spanning_tree_poses(5, &edges, &[2.0, 2.0, 1.0, 1.0]);
        assert_eq!(placed, [true, true, true, true, false]);
        assert!((poses[2][(0, 3)] - 2.0).abs() < 1e-12);
        // x_3 = T x_2 with T = translate(-1)... edge (3, 2): world_from_3 = world_from_2 * inverse(3_from_2).
        assert!((poses[3][(0, 3)] - 3.0).abs() < 1e-12);
        let (poses, _) = spanning_tree_poses(3, &edges[..3], &[1.0, 1.0, 3.0]);
        assert!((poses[2][(0, 3)] - 5.0).abs() < 1e-12);
        assert!(ordered(-1.0) < ordered(0.0) && ordered(0.0) < ordered(0.5) && ordered(0.5) < ordered(2.0));
    }

    #[test]
    fn reachability_follows_active_edges_only() {
        let edges = [edge(0, 1, 1.0), edge(1, 2, 1.0), edge(2, 3, 1.0)];
        assert_eq!(reachable_from_reference(4, &edges, &[true, false, true]), [true, true, false, false]);
        let bad = PoseGraph { world_from_node: vec![Matrix4::identity(); 2], edges: vec![edge(0, 2, 1.0)] };
        assert!(bad.validate().unwrap_err().to_string().contains("edge 0"));
    }
}
