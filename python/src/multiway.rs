//! `Registrar.multiway`: many scans into one trajectory with the library's robust pose graph.

use crate::arrays::{cloud_from_arrays, matrix};
use crate::errors::{to_py_err, value_error};
use dpr_gpu::io::{LoadOptions, OriginShift};
use dpr_gpu::multiway::{EdgeKind, MultiwaySettings, NoStore, PairSelection, multiway_detailed};
use dpr_gpu::pose::unshift_pose;
use numpy::ndarray::Array3;
use numpy::{IntoPyArray, PyArray2};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

/// The multiway options of `Registrar.multiway`, as Python gave them.
pub(crate) struct MultiwayArgs {
    pub pairs: String,
    pub retrieval_k: i64,
    pub max_pairs: Option<i64>,
    pub information_distance: Option<f64>,
    pub loop_preference: f64,
}

/// Registers `scans` (a sequence of (N, 3) arrays, optional `normals` alike) with `registrar`; returns the dict
/// documented on `Registrar.multiway`.
pub(crate) fn run<'py>(
    py: Python<'py>,
    registrar: &dpr_gpu::Registrar,
    load: LoadOptions,
    scans: &Bound<'py, PyAny>,
    normals: Option<&Bound<'py, PyAny>>,
    args: MultiwayArgs,
) -> PyResult<Bound<'py, PyDict>> {
    let scans: Vec<Bound<'py, PyAny>> = scans.try_iter()?.collect::<PyResult<_>>()?;
    let normals: Option<Vec<Bound<'py, PyAny>>> =
        normals.map(|n| n.try_iter()?.collect::<PyResult<_>>()).transpose()?;
    if let Some(n) = &normals
        && n.len() != scans.len()
    {
        return Err(value_error(format!("{} normal arrays for {} scans", n.len(), scans.len())));
    }
    let pairs = match args.pairs.as_str() {
        "all" => PairSelection::All,
        "consecutive+retrieval" => PairSelection::ConsecutiveAndRetrieval {
            k: usize::try_from(args.retrieval_k)
                .map_err(|_| value_error(format!("retrieval_k must not be negative, got {}", args.retrieval_k)))?,
        },
        other => {
            return Err(value_error(format!("unknown pairs '{other}' (expected 'all' or 'consecutive+retrieval')")));
        }
    };
    let max_pairs = args
        .max_pairs
        .map(|m| usize::try_from(m).map_err(|_| value_error(format!("max_pairs must not be negative, got {m}"))))
        .transpose()?;
    // Georeferenced scans: all shifted by one origin (from the first scan) before the float32 conversion.
    let mut clouds = Vec::with_capacity(scans.len());
    let mut origin = [0i64; 3];
    for (k, scan) in scans.iter().enumerate() {
        let shift = if k == 0 { OriginShift::Auto } else { OriginShift::At(origin) };
        let n = normals.as_ref().map(|n| &n[k]);
        let (cloud, report) = cloud_from_arrays(scan, n, &format!("scan {k}"), &LoadOptions { origin: shift, ..load })?;
        if k == 0 {
            origin = report.origin;
        }
        clouds.push(cloud);
    }
    let settings = MultiwaySettings {
        registration: registrar.settings.clone(),
        pairs,
        max_pairs,
        information_distance: args.information_distance,
        preference_loop_closure: args.loop_preference,
        ..MultiwaySettings::default()
    };
    let result =
        py.detach(|| multiway_detailed(registrar, &clouds, &settings, &mut NoStore, &|_| {})).map_err(to_py_err)?;
    let poses: Vec<_> = result.trajectory.world_from_scan.iter().map(|w| unshift_pose(w, origin)).collect();
    let world_from_scan = Array3::from_shape_fn((poses.len(), 4, 4), |(k, r, c)| poses[k][(r, c)]).into_pyarray(py);
    let edges = PyList::empty(py);
    for e in &result.edges {
        let p = &e.pair;
        let d = PyDict::new(py);
        d.set_item("i", p.i)?;
        d.set_item("j", p.j)?;
        d.set_item("i_from_j", matrix(py, &p.transform()))?;
        d.set_item("correspondences", p.correspondences)?;
        d.set_item("inliers", p.inliers)?;
        d.set_item("fitness", p.fitness)?;
        d.set_item("inlier_rmse", p.inlier_rmse)?;
        d.set_item("trusted", p.trusted)?;
        d.set_item("reason", p.reason.as_deref())?;
        let info = p.information_matrix();
        d.set_item(
            "information",
            PyArray2::from_vec2(
                py,
                &(0..6).map(|r| (0..6).map(|c| info[(r, c)]).collect()).collect::<Vec<Vec<f64>>>(),
            )?,
        )?;
        d.set_item("kind", if e.kind == EdgeKind::Odometry { "odometry" } else { "loop" })?;
        d.set_item("in_graph", e.in_graph)?;
        d.set_item("uncertain", e.uncertain)?;
        d.set_item("line_process", e.line_process)?;
        d.set_item("survived", e.survived)?;
        edges.append(d)?;
    }
    let out = PyDict::new(py);
    out.set_item("world_from_scan", world_from_scan)?;
    out.set_item("edges", edges)?;
    out.set_item("connected", result.connected.clone())?;
    out.set_item("line_process_weight", result.line_process_weight)?;
    Ok(out)
}
