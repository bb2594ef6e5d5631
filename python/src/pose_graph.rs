//! `dpr_gpu.pose_graph`: the sparse pose-graph optimiser of `dpr-gpu pose-graph` on a g2o file or on edges given
//! as arrays.

use crate::arrays::matrices;
use crate::errors::{to_py_err, value_error};
use dpr_gpu::io::check_outputs;
use dpr_gpu::pose_graph::{GraphEdge, Init, PoseGraph, Solution, SolveOptions, read_g2o, solve, write_g2o};
use nalgebra::{Matrix4, Matrix6};
use numpy::{PyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyString};
use std::path::PathBuf;

/// Most nodes a graph given as edges may name (its largest index + 1), checked before allocating.
const MAX_NODES: usize = 10_000_000;

/// A `rows` x `cols` float64 matrix from a numpy array (or anything `numpy.asarray` takes) named `what`.
fn fixed_matrix<const R: usize, const C: usize>(value: &Bound<'_, PyAny>, what: &str) -> PyResult<[[f64; C]; R]> {
    let numpy = value.py().import("numpy")?;
    let array = numpy.call_method1("asarray", (value, "float64"))?;
    let array: PyReadonlyArray2<f64> =
        array.extract().map_err(|_| value_error(format!("{what}: expected a {R}x{C} array of numbers")))?;
    if array.shape() != [R, C] {
        return Err(value_error(format!("{what}: expected a {R}x{C} array, got shape {:?}", array.shape())));
    }
    let view = array.as_array();
    let mut out = [[0.0; C]; R];
    for (r, row) in out.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = view[(r, c)];
        }
    }
    Ok(out)
}

/// A graph given as `edges` (`(i, j, i_from_j, information)` tuples) and optional starting `poses`.
fn graph_from_edges(edges: &Bound<'_, PyAny>, poses: Option<&Bound<'_, PyAny>>) -> PyResult<PoseGraph> {
    let mut graph_edges = Vec::new();
    for (k, item) in edges.try_iter()?.enumerate() {
        let item = item?;
        let (i, j, i_from_j, information): (i64, i64, Bound<'_, PyAny>, Bound<'_, PyAny>) = item
            .extract()
            .map_err(|_| value_error(format!("edges[{k}]: expected a tuple (i, j, i_from_j, information)")))?;
        let index = |v: i64, name: &str| {
            usize::try_from(v)
                .ok()
                .filter(|&n| n < MAX_NODES)
                .ok_or_else(|| value_error(format!("edges[{k}]: {name} = {v} is not a node index in [0, {MAX_NODES})")))
        };
        let (i, j) = (index(i, "i")?, index(j, "j")?);
        let t = fixed_matrix::<4, 4>(&i_from_j, &format!("edges[{k}] i_from_j"))?;
        let w = fixed_matrix::<6, 6>(&information, &format!("edges[{k}] information"))?;
        graph_edges.push(GraphEdge {
            i,
            j,
            i_from_j: Matrix4::from_fn(|r, c| t[r][c]),
            information: Matrix6::from_fn(|r, c| w[r][c]),
            uncertain: i.abs_diff(j) != 1,
        });
    }
    let n = graph_edges.iter().map(|e| e.i.max(e.j) + 1).max().unwrap_or(0);
    let world_from_node = match poses {
        None => vec![Matrix4::identity(); n],
        Some(poses) => {
            let mut out = Vec::new();
            for (k, pose) in poses.try_iter()?.enumerate() {
                if k >= MAX_NODES {
                    return Err(value_error(format!("poses: more than {MAX_NODES} poses")));
                }
                let m = fixed_matrix::<4, 4>(&pose?, &format!("poses[{k}]"))?;
                out.push(Matrix4::from_fn(|r, c| m[r][c]));
            }
            if out.len() < n {
                return Err(value_error(format!("{} poses, but the edges name node {}", out.len(), n - 1)));
            }
            out
        }
    };
    let graph = PoseGraph { world_from_node, edges: graph_edges };
    graph.validate().map_err(to_py_err)?;
    Ok(graph)
}

/// The solution as the dict documented on `pose_graph`.
fn solution_dict<'py>(py: Python<'py>, solution: Solution, ids: Vec<u64>) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("world_from_node", matrices(py, &solution.world_from_node))?;
    d.set_item("ids", ids)?;
    d.set_item("weights", PyArray1::from_vec(py, solution.weights))?;
    d.set_item("given_error", solution.given_error)?;
    d.set_item("initial_error", solution.initial_error)?;
    d.set_item("final_error", solution.final_error)?;
    d.set_item("iterations", solution.iterations)?;
    d.set_item("start", if solution.start == Init::Chordal { "chordal" } else { "file" })?;
    d.set_item("start_note", solution.start_note)?;
    Ok(d)
}

/// Optimises a pose graph with the sparse Levenberg-Marquardt of ``dpr-gpu pose-graph`` (node 0 fixed).
///
/// ``graph`` is a g2o file's path (``VERTEX_SE3:QUAT`` and ``EDGE_SE3:QUAT`` lines) or a sequence of edges
/// ``(i, j, i_from_j, information)``: node indices, the 4x4 measurement x_i = i_from_j x_j and its 6x6
/// information matrix (translation first, as g2o's). Edges between consecutive nodes (ids) are odometry, any
/// other is a loop closure that ``robust="geman-mcclure"`` may down-weight (scale ``robust_scale``) or prune (final
/// weight below ``prune_below``). ``poses`` (edges only): the starting world_from_node, (N, 4, 4); without it the
/// start is chordal. ``init``: ``"chordal"`` or ``"file"`` (the given poses); by default chordal without a kernel
/// and the given poses with one. ``out``: a g2o file to write the optimised graph to (atomically, never onto the
/// input), as ``dpr-gpu pose-graph --out`` writes it.
///
/// Returns a dict: ``world_from_node`` (N, 4, 4), ``ids`` (the vertex id of each node), ``weights`` (each edge's
/// final weight; 0 for pruned edges), ``given_error``, ``initial_error`` and ``final_error`` (GTSAM's
/// 0.5 sum e^T Omega e at the given poses, after the initialisation, and at the end), ``iterations``, ``start``
/// (``"chordal"`` or ``"file"``: a chordal start falls back to the given poses when the relaxation fails or starts
/// higher than they do) and ``start_note`` (why it fell back, or None).
#[pyfunction]
#[pyo3(signature = (graph, *, poses = None, robust = "none".to_string(), robust_scale = 1.0, prune_below = 0.25,
    init = None, out = None),
    text_signature = "(graph, *, poses=None, robust='none', robust_scale=1.0, prune_below=0.25, init=None, out=None)")]
#[allow(clippy::too_many_arguments)]
pub(crate) fn pose_graph<'py>(
    py: Python<'py>,
    graph: &Bound<'py, PyAny>,
    poses: Option<&Bound<'py, PyAny>>,
    robust: String,
    robust_scale: f64,
    prune_below: f64,
    init: Option<String>,
    out: Option<PathBuf>,
) -> PyResult<Bound<'py, PyDict>> {
    let mut options =
        SolveOptions::from_names(&robust, robust_scale, prune_below, init.as_deref()).map_err(to_py_err)?;
    let path: Option<PathBuf> =
        if graph.is_instance_of::<PyString>() || graph.hasattr("__fspath__")? { Some(graph.extract()?) } else { None };
    let (graph, ids) = match &path {
        Some(path) => {
            if poses.is_some() {
                return Err(value_error("poses is for a graph given as edges; a g2o file holds its own"));
            }
            let read = py.detach(|| read_g2o(path)).map_err(to_py_err)?;
            (read.graph, read.ids)
        }
        None => {
            if poses.is_none() {
                if init.as_deref() == Some("file") {
                    return Err(value_error("init='file' needs the starting poses"));
                }
                options.init = Init::Chordal;
            }
            let graph = graph_from_edges(graph, poses)?;
            let ids = (0..graph.world_from_node.len() as u64).collect();
            (graph, ids)
        }
    };
    if let Some(out) = &out {
        let inputs: Vec<&std::path::Path> = path.iter().map(PathBuf::as_path).collect();
        check_outputs(&inputs, &[("out", out)]).map_err(to_py_err)?;
    }
    let solution = py
        .detach(|| {
            let solution = solve(&graph, &options)?;
            if let Some(out) = &out {
                let solved =
                    PoseGraph { world_from_node: solution.world_from_node.clone(), edges: graph.edges.clone() };
                write_g2o(out, &solved, &ids, Some(&solution.weights))?;
            }
            Ok::<_, dpr_gpu::Error>(solution)
        })
        .map_err(to_py_err)?;
    solution_dict(py, solution, ids)
}
