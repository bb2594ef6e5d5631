//! Pose graphs at scale: a sparse SE(3) Levenberg-Marquardt ([`lm`]) over normal equations factored by faer's
//! sparse Cholesky ([`sparse`]), a chordal initialisation ([`chordal`]) and g2o files in and out ([`g2o`]). The
//! robust (line-process / Geman-McClure) scheme for uncertain edges lives in [`crate::multiway::optimize`] and runs
//! on this solver; `dpr-gpu pose-graph` and `multiway` both use it.
//!
//! Conventions: a graph is a [`PoseGraph`] (x_world = world_from_node[k] x_k) of [`GraphEdge`]s measuring
//! i_from_j = world_from_i⁻¹ world_from_j; an edge's error is e = Log(i_from_j⁻¹ world_from_i⁻¹ world_from_j)
//! = [ρ; φ] (translation first, as g2o orders its information matrices), which is GTSAM's `BetweenFactor<Pose3>`
//! error with its halves swapped, so F = ½ Σ eᵀΩe ([`lm::cost`]) is the value GTSAM's `graph.error` reports.

pub mod chordal;
pub mod g2o;
pub mod lm;
pub mod se3;
pub use crate::pose::so3;
pub mod solve;
pub mod sparse;

pub use crate::multiway::graph::{GraphEdge, PoseGraph};
pub use g2o::{G2oGraph, read_g2o, write_g2o};
pub use solve::{Init, Kernel, Solution, SolveOptions, solve};
