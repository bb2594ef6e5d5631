//! g2o pose-graph files: `VERTEX_SE3:QUAT id x y z qx qy qz qw` and `EDGE_SE3:QUAT i j x y z qx qy qz qw`
//! followed by the 21 upper-triangular entries of the 6 x 6 information matrix (row by row, translation first).
//! Blank lines and `#` comments are skipped; anything else is refused with the file, line and token. The edge
//! measures i_from_j = x_i⁻¹ x_j, as [`GraphEdge`] does.
//!
//! Nodes are ordered by vertex id, so node 0 (the fixed one) is the lowest id. An edge between consecutive ids is
//! odometry (certain); any other is a loop closure (uncertain: a robust kernel may switch it off).
//!
//! Writing gives every number 17 significant digits (a double read back is the same double) and, when weights
//! are given, a `# EDGE_WEIGHT i j w` comment after each edge (g2o and GTSAM skip `#` lines).

use super::se3::parts;
use crate::error::{Error, Result};
use crate::multiway::graph::{GraphEdge, PoseGraph};
use crate::pose::{matrix_from_parts, quaternion_from_matrix};
use nalgebra::{Matrix4, Matrix6, Quaternion, UnitQuaternion, Vector3};
use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::Path;

/// Largest g2o file read, in bytes (2 GiB: tens of millions of edges).
pub const MAX_G2O_BYTES: u64 = 2 << 30;
/// The vertex tag read and written.
pub const VERTEX_TAG: &str = "VERTEX_SE3:QUAT";
/// The edge tag read and written.
pub const EDGE_TAG: &str = "EDGE_SE3:QUAT";

/// A pose graph with the vertex id of each node.
#[derive(Clone, Debug, PartialEq)]
pub struct G2oGraph {
    /// Vertex id of node k (ascending).
    pub ids: Vec<u64>,
    /// Nodes (in id order) and edges (in file order).
    pub graph: PoseGraph,
}

/// Reads a g2o file (at most [`MAX_G2O_BYTES`]).
pub fn read_g2o(path: &Path) -> Result<G2oGraph> {
    let bytes = crate::io::read_file_bounded(path, MAX_G2O_BYTES)?;
    parse_g2o(path, &bytes)
}

/// An edge as read, before its vertex ids are resolved.
struct RawEdge {
    line: usize,
    ids: (u64, u64),
    i_from_j: Matrix4<f64>,
    information: Matrix6<f64>,
}

/// Parses g2o text; errors name `path`, the line and the token.
pub fn parse_g2o(path: &Path, bytes: &[u8]) -> Result<G2oGraph> {
    let mut vertices: Vec<(u64, Matrix4<f64>, usize)> = Vec::new();
    let mut edges: Vec<RawEdge> = Vec::new();
    for (index, raw) in bytes.split(|&b| b == b'\n').enumerate() {
        let line = index + 1;
        let at = |message: String| Error::parse(path, format!("line {line}"), message);
        let text = std::str::from_utf8(raw).map_err(|_| at("not UTF-8 text".into()))?;
        let mut tokens = text.split_ascii_whitespace();
        let Some(tag) = tokens.next() else { continue };
        if tag.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = tokens.collect();
        match tag {
            VERTEX_TAG => {
                let (id, pose) = parse_vertex(&fields).map_err(at)?;
                vertices.push((id, pose, line));
            }
            EDGE_TAG => {
                let (ids, i_from_j, information) = parse_edge(&fields).map_err(at)?;
                edges.push(RawEdge { line, ids, i_from_j, information });
            }
            other => {
                return Err(at(format!("unsupported element '{}' (only {VERTEX_TAG} and {EDGE_TAG})", clip(other))));
            }
        }
    }
    assemble(path, vertices, edges)
}

/// Orders the vertices by id and resolves the edges' ids to nodes.
fn assemble(path: &Path, mut vertices: Vec<(u64, Matrix4<f64>, usize)>, edges: Vec<RawEdge>) -> Result<G2oGraph> {
    vertices.sort_by_key(|v| (v.0, v.2));
    if let Some(w) = vertices.windows(2).find(|w| w[0].0 == w[1].0) {
        let message = format!("vertex {} defined again (first on line {})", w[1].0, w[0].2);
        return Err(Error::parse(path, format!("line {}", w[1].2), message));
    }
    if vertices.is_empty() {
        return Err(Error::parse(path, "end of file", format!("no {VERTEX_TAG} vertex")));
    }
    let node: HashMap<u64, usize> = vertices.iter().enumerate().map(|(k, v)| (v.0, k)).collect();
    let mut graph_edges = Vec::with_capacity(edges.len());
    for e in edges {
        let find = |id: u64| {
            node.get(&id).copied().ok_or_else(|| {
                Error::parse(
                    path,
                    format!("line {}", e.line),
                    format!("edge names vertex {id}, which no {VERTEX_TAG} line defines"),
                )
            })
        };
        let (i, j) = (find(e.ids.0)?, find(e.ids.1)?);
        if i == j {
            return Err(Error::parse(
                path,
                format!("line {}", e.line),
                format!("edge joins vertex {} to itself", e.ids.0),
            ));
        }
        let uncertain = e.ids.0.abs_diff(e.ids.1) != 1;
        graph_edges.push(GraphEdge { i, j, i_from_j: e.i_from_j, information: e.information, uncertain });
    }
    Ok(G2oGraph {
        ids: vertices.iter().map(|v| v.0).collect(),
        graph: PoseGraph { world_from_node: vertices.into_iter().map(|v| v.1).collect(), edges: graph_edges },
    })
}

/// `id x y z qx qy qz qw`.
fn parse_vertex(fields: &[&str]) -> std::result::Result<(u64, Matrix4<f64>), String> {
    expect_count(VERTEX_TAG, fields, 8)?;
    let id = parse_id(fields[0], "id")?;
    Ok((id, parse_pose(&fields[1..8])?))
}

/// Vertex ids, i_from_j and information of an edge line.
type ParsedEdge = ((u64, u64), Matrix4<f64>, Matrix6<f64>);

/// `i j x y z qx qy qz qw` and 21 information entries.
fn parse_edge(fields: &[&str]) -> std::result::Result<ParsedEdge, String> {
    expect_count(EDGE_TAG, fields, 30)?;
    let ids = (parse_id(fields[0], "first vertex id")?, parse_id(fields[1], "second vertex id")?);
    let pose = parse_pose(&fields[2..9])?;
    let mut information = Matrix6::zeros();
    let mut k = 9;
    for r in 0..6 {
        for c in r..6 {
            let v = parse_number(fields[k], &format!("information ({r}, {c})"))?;
            information[(r, c)] = v;
            information[(c, r)] = v;
            k += 1;
        }
    }
    // Positive semi-definite within rounding: Ω + 1e-9 max|Ω| I has a Cholesky factor (cheaper than eigenvalues).
    let shifted = information + Matrix6::identity() * (1e-9 * information.abs().max()).max(f64::MIN_POSITIVE);
    if shifted.cholesky().is_none() {
        let smallest = information.symmetric_eigenvalues().min();
        return Err(format!("information matrix is not positive semi-definite (eigenvalue {smallest:e})"));
    }
    Ok((ids, pose, information))
}

fn expect_count(tag: &str, fields: &[&str], count: usize) -> std::result::Result<(), String> {
    match fields.len() {
        n if n < count => Err(format!("{tag} needs {count} values after the tag, found {n}")),
        n if n > count => Err(format!("unexpected token '{}' after the {count} values of {tag}", clip(fields[count]))),
        _ => Ok(()),
    }
}

/// `x y z qx qy qz qw` as a rigid transform; the quaternion must have unit norm within 1 %.
fn parse_pose(fields: &[&str]) -> std::result::Result<Matrix4<f64>, String> {
    let names = ["x", "y", "z", "qx", "qy", "qz", "qw"];
    let mut v = [0.0; 7];
    for (k, name) in names.iter().enumerate() {
        v[k] = parse_number(fields[k], name)?;
    }
    let q = Quaternion::new(v[6], v[3], v[4], v[5]);
    if (q.norm() - 1.0).abs() > 1e-2 {
        return Err(format!(
            "quaternion ({}, {}, {}, {}) does not have unit norm ({})",
            v[3],
            v[4],
            v[5],
            v[6],
            q.norm()
        ));
    }
    let r = UnitQuaternion::from_quaternion(q).to_rotation_matrix().into_inner();
    Ok(matrix_from_parts(&r, &Vector3::new(v[0], v[1], v[2])))
}

fn parse_id(token: &str, what: &str) -> std::result::Result<u64, String> {
    token.parse::<u64>().map_err(|_| format!("{what} '{}' is not a non-negative integer", clip(token)))
}

fn parse_number(token: &str, what: &str) -> std::result::Result<f64, String> {
    match token.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(format!("{what} '{}' is not a finite number", clip(token))),
    }
}

/// A token cut to 40 characters for messages.
fn clip(token: &str) -> String {
    let mut out: String = token.chars().take(40).collect();
    if out.len() < token.len() {
        out.push_str("...");
    }
    out
}

/// The g2o text of `graph` with vertex ids `ids` and, if given, one weight per edge as a comment line.
pub fn encode_g2o(graph: &PoseGraph, ids: &[u64], weights: Option<&[f64]>) -> String {
    let mut out = String::with_capacity(120 * graph.world_from_node.len() + 420 * graph.edges.len());
    for (id, pose) in ids.iter().zip(&graph.world_from_node) {
        let _ = write!(out, "{VERTEX_TAG} {id}");
        push_pose(&mut out, pose);
        out.push('\n');
    }
    for (k, e) in graph.edges.iter().enumerate() {
        let _ = write!(out, "{EDGE_TAG} {} {}", ids[e.i], ids[e.j]);
        push_pose(&mut out, &e.i_from_j);
        for r in 0..6 {
            for c in r..6 {
                let _ = write!(out, " {:.16e}", 0.5 * (e.information[(r, c)] + e.information[(c, r)]));
            }
        }
        out.push('\n');
        if let Some(w) = weights {
            let _ = writeln!(out, "# EDGE_WEIGHT {} {} {:.16e}", ids[e.i], ids[e.j], w[k]);
        }
    }
    out
}

/// ` x y z qx qy qz qw` at 17 significant digits.
fn push_pose(out: &mut String, pose: &Matrix4<f64>) {
    let (r, t) = parts(pose);
    let q = quaternion_from_matrix(&r);
    for v in [t.x, t.y, t.z, q[1], q[2], q[3], q[0]] {
        let _ = write!(out, " {v:.16e}");
    }
}

/// Writes [`encode_g2o`] to `path` atomically.
pub fn write_g2o(path: &Path, graph: &PoseGraph, ids: &[u64], weights: Option<&[f64]>) -> Result<()> {
    crate::io::write_atomic(path, encode_g2o(graph, ids, weights).as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    const SAMPLE: &str = "# a comment\n\
        VERTEX_SE3:QUAT 5 1 2 3 0 0 0 1\n\
        VERTEX_SE3:QUAT 3 0 0 0 0 0 0.70710678118654757 0.70710678118654757\n\
        \n\
        EDGE_SE3:QUAT 3 5 1 2 3 0 0 0 1 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 4 0 0 4 0 4\n\
        EDGE_SE3:QUAT 5 3 0.5 0 0 0 0 0 1 2 0.1 0 0 0 0 2 0 0 0 0 2 0 0 0 3 0 0 3 0 3\n";

    #[test]
    fn reads_orders_by_id_and_writes_back_the_same_graph() {
        let path = Path::new("sample.g2o");
        let read = parse_g2o(path, SAMPLE.as_bytes()).unwrap();
        assert_eq!(read.ids, [3, 5]);
        let g = &read.graph;
        assert!((g.world_from_node[1][(2, 3)] - 3.0).abs() < 1e-15);
        // Vertex 3 is a quarter turn about z.
        assert!((g.world_from_node[0][(1, 0)] - 1.0).abs() < 1e-12);
        assert_eq!((g.edges[0].i, g.edges[0].j, g.edges[1].i, g.edges[1].j), (0, 1, 1, 0));
        // Ids 3 and 5 are not consecutive: both edges are loop closures.
        assert!(g.edges.iter().all(|e| e.uncertain), "{g:?}");
        assert_eq!(g.edges[1].information[(1, 0)], 0.1);
        assert_eq!(g.edges[1].information[(0, 1)], 0.1);
        let text = encode_g2o(g, &read.ids, Some(&[1.0, 0.25]));
        assert!(text.contains("# EDGE_WEIGHT 5 3 2.5000000000000000e-1"), "{text}");
        let again = parse_g2o(path, text.as_bytes()).unwrap();
        assert_eq!(again.ids, read.ids);
        for (a, b) in again.graph.world_from_node.iter().zip(&g.world_from_node) {
            assert!((a - b).abs().max() < 1e-15, "{a} vs {b}");
        }
        for (a, b) in again.graph.edges.iter().zip(&g.edges) {
            assert_eq!(a.information, b.information);
            assert!((a.i_from_j - b.i_from_j).abs().max() < 1e-15);
        }
    }

    #[test]
    fn bad_input_names_the_line_and_token() {
        let cases = [
            ("VERTEX_SE2 0 0 0 0\n", "line 1: unsupported element 'VERTEX_SE2'"),
            ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT x 0 0 0 0 0 0 1\n", "line 2: id 'x' is not"),
            ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1 7\n", "unexpected token '7'"),
            ("VERTEX_SE3:QUAT 0 0 0 nan 0 0 0 1\n", "z 'nan' is not a finite number"),
            ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 2\n", "unit norm"),
            ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n", "line 2: vertex 0 defined again"),
            (
                "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nEDGE_SE3:QUAT 0 9 0 0 0 0 0 0 1 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1\n",
                "line 2: edge names vertex 9",
            ),
            (
                "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 0 0 0 0 0 0 1\nEDGE_SE3:QUAT 0 1 0 0 0 0 0 0 1 -1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1\n",
                "line 3: information matrix is not positive semi-definite",
            ),
            ("EDGE_SE3:QUAT 0 1 0 0 0\n", "line 1: EDGE_SE3:QUAT needs 30 values after the tag, found 5"),
            ("# only a comment\n", "no VERTEX_SE3:QUAT vertex"),
        ];
        for (text, expected) in cases {
            let message = parse_g2o(Path::new("bad.g2o"), text.as_bytes()).unwrap_err().to_string();
            assert!(message.starts_with("bad.g2o: ") && message.contains(expected), "{text:?}: {message}");
        }
    }
}
