//! `Registrar.multiway`: many scans into one trajectory with the library's robust pose graph; and its stages as
//! separate calls for schedulers (`dpr_gpu.distributed`): `multiway_origin`, `select_pairs` and
//! `optimize_pairs`, whose `MultiwayResult` is the single-process result, written as `dpr-gpu multiway` writes it.

use crate::arrays::{cloud_from_arrays, matrices, matrix};
use crate::errors::{to_py_err, value_error};
use dpr_gpu::io::{LoadOptions, OriginShift, ZeroPoints, write_atomic};
use dpr_gpu::multiway::pairs::select_pairs as library_select_pairs;
use dpr_gpu::multiway::{
    EdgeKind, EdgeRecord, GlobalOptimizationOption, MultiwayResult as RustMultiwayResult, MultiwaySettings, NoStore,
    PairSelection, Trajectory, multiway_detailed, optimize_pairs as library_optimize_pairs,
};
use dpr_gpu::pose::unshift_pose;
use numpy::{PyArray2, PyArray3, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use serde::Serialize;
use std::path::PathBuf;

/// The multiway options of `Registrar.multiway`, as Python gave them.
pub(crate) struct MultiwayArgs {
    pub pairs: String,
    pub retrieval_k: i64,
    pub max_pairs: Option<i64>,
    pub information_distance: Option<f64>,
    pub loop_preference: f64,
}

/// The pair selection named `pairs` (`"all"` or `"consecutive+retrieval"` with `retrieval_k`).
fn pair_selection(pairs: &str, retrieval_k: i64) -> PyResult<PairSelection> {
    match pairs {
        "all" => Ok(PairSelection::All),
        "consecutive+retrieval" => Ok(PairSelection::ConsecutiveAndRetrieval {
            k: usize::try_from(retrieval_k)
                .map_err(|_| value_error(format!("retrieval_k must not be negative, got {retrieval_k}")))?,
        }),
        other => Err(value_error(format!("unknown pairs '{other}' (expected 'all' or 'consecutive+retrieval')"))),
    }
}

/// `max_pairs` as a count.
fn pair_cap(max_pairs: Option<i64>) -> PyResult<Option<usize>> {
    max_pairs
        .map(|m| usize::try_from(m).map_err(|_| value_error(format!("max_pairs must not be negative, got {m}"))))
        .transpose()
}

/// The pose-graph options of `Registrar.multiway` for information distance `distance` (checked).
fn graph_option(distance: f64, loop_preference: f64) -> PyResult<GlobalOptimizationOption> {
    let defaults = MultiwaySettings::default();
    let option = GlobalOptimizationOption {
        max_correspondence_distance: distance,
        edge_prune_threshold: defaults.edge_prune_threshold,
        preference_loop_closure: loop_preference,
        ..GlobalOptimizationOption::default()
    };
    option.validate().map_err(to_py_err)?;
    Ok(option)
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
    let pairs = pair_selection(&args.pairs, args.retrieval_k)?;
    let max_pairs = pair_cap(args.max_pairs)?;
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
    MultiwayResult { result, origin }.to_dict(py)
}

/// The size of one scan of a collection (the median distance of its points from its centre, the coordinate-wise median, after the
/// collection's ``origin`` is subtracted and, points exactly at (0, 0, 0) dropped as ``read_cloud`` drops them), as
/// ``Registrar.multiway`` measures it to choose the patch radius: ``choose_radius`` of every scan's size gives
/// the radius ``Registrar.multiway`` uses when none is set.
#[pyfunction]
#[pyo3(signature = (points, *, origin = (0, 0, 0), drop_zero_points = None))]
pub(crate) fn scan_size(
    points: &Bound<'_, PyAny>,
    origin: (i64, i64, i64),
    drop_zero_points: Option<bool>,
) -> PyResult<f64> {
    let options = LoadOptions {
        origin: OriginShift::At([origin.0, origin.1, origin.2]),
        zero_points: ZeroPoints::from_flag(drop_zero_points),
        ..LoadOptions::default()
    };
    let (cloud, _) = cloud_from_arrays(points, None, "points", &options)?;
    dpr_gpu::scale::scan_size(&cloud, "points").map_err(to_py_err)
}

/// The patch radius chosen for scans of these sizes (``scan_size`` of each): 0.6 times their median.
#[pyfunction]
pub(crate) fn choose_radius(sizes: Vec<f64>) -> PyResult<f32> {
    Ok(dpr_gpu::scale::choose(&sizes).map_err(to_py_err)?.radius)
}

/// The whole-unit origin that ``Registrar.multiway`` subtracts from every scan of a collection whose first scan
/// is ``points``: the first finite point rounded, when one of its coordinates has magnitude 1e4 or more (a
/// georeferenced scan), else ``(0, 0, 0)``. Pass it to ``Registrar.describe_scan`` for every scan.
#[pyfunction]
pub(crate) fn multiway_origin(points: &Bound<'_, PyAny>) -> PyResult<(i64, i64, i64)> {
    let options = LoadOptions { origin: OriginShift::Auto, ..LoadOptions::default() };
    let (_, report) = cloud_from_arrays(points, None, "scan 0", &options)?;
    let o = report.origin;
    Ok((o[0], o[1], o[2]))
}

/// The candidate pairs ``(i, j)``, i < j, of ``n`` scans in registration order, chosen as ``Registrar.multiway``
/// chooses them: consecutive pairs first, then (``pairs="all"``) every other pair by increasing j - i, or
/// (``"consecutive+retrieval"``) each scan's ``retrieval_k`` most similar scans by ``pooled`` codewords (one
/// ``DescribedScan.pooled_codeword`` per scan, needed only for retrieval), cut to ``max_pairs`` when given.
#[pyfunction]
#[pyo3(signature = (n, pooled = None, *, pairs = "consecutive+retrieval".to_string(), retrieval_k = 5, max_pairs = None),
    text_signature = "(n, pooled=None, *, pairs='consecutive+retrieval', retrieval_k=5, max_pairs=None)")]
pub(crate) fn select_pairs(
    n: usize,
    pooled: Option<Vec<Bound<'_, PyAny>>>,
    pairs: String,
    retrieval_k: i64,
    max_pairs: Option<i64>,
) -> PyResult<Vec<(usize, usize)>> {
    let selection = pair_selection(&pairs, retrieval_k)?;
    let max_pairs = pair_cap(max_pairs)?;
    let pooled = match (selection, pooled) {
        (PairSelection::All, _) => None,
        (PairSelection::ConsecutiveAndRetrieval { .. }, None) => {
            return Err(value_error("pairs='consecutive+retrieval' needs the pooled codeword of every scan"));
        }
        (PairSelection::ConsecutiveAndRetrieval { .. }, Some(p)) => {
            if p.len() != n {
                return Err(value_error(format!("{} pooled codewords for {n} scans", p.len())));
            }
            let mut vectors = Vec::with_capacity(n);
            for (k, v) in p.iter().enumerate() {
                let array = v
                    .cast::<numpy::PyArray1<f32>>()
                    .map_err(|_| value_error(format!("pooled[{k}]: expected a 1-D float32 array")))?;
                let values = array.to_vec().map_err(|e| value_error(format!("pooled[{k}]: {e}")))?;
                if k > 0 && values.len() != vectors.first().map_or(0, Vec::len) {
                    return Err(value_error(format!(
                        "pooled[{k}] has {} values, pooled[0] {}",
                        array.len(),
                        vectors[0].len()
                    )));
                }
                vectors.push(values);
            }
            Some(vectors)
        }
    };
    Ok(library_select_pairs(n, selection, pooled.as_deref(), max_pairs))
}

/// Builds the pose graph of ``pair_results`` (``PairResult`` values, in the order of ``select_pairs``) over
/// ``n`` scans and optimises it robustly, exactly as ``Registrar.multiway`` does after registering the pairs.
/// ``information_distance`` is the distance the pairs' information matrices were computed at (the
/// ``information_distance`` of the run, or the registrar's ``inlier_threshold``); ``origin`` the collection's
/// (``multiway_origin``), added back to the poses. Returns a ``MultiwayResult``.
#[pyfunction]
#[pyo3(signature = (n, pair_results, *, information_distance, loop_preference = 1.0, origin = (0, 0, 0)),
    text_signature = "(n, pair_results, *, information_distance, loop_preference=1.0, origin=(0, 0, 0))")]
pub(crate) fn optimize_pairs(
    py: Python<'_>,
    n: usize,
    pair_results: Vec<Bound<'_, PyAny>>,
    information_distance: f64,
    loop_preference: f64,
    origin: (i64, i64, i64),
) -> PyResult<MultiwayResult> {
    if n < 2 {
        return Err(value_error(format!("multiway registration needs at least 2 scans, got {n}")));
    }
    let option = graph_option(information_distance, loop_preference)?;
    let mut results = Vec::with_capacity(pair_results.len());
    for (k, p) in pair_results.iter().enumerate() {
        let r = crate::described::pair_of(p, k)?;
        if !(r.i < r.j && r.j < n) {
            return Err(value_error(format!("pair_results[{k}]: pair ({}, {}) is not i < j < {n}", r.i, r.j)));
        }
        results.push(r);
    }
    let result = py.detach(|| library_optimize_pairs(n, &results, &option)).map_err(to_py_err)?;
    Ok(MultiwayResult { result, origin: [origin.0, origin.1, origin.2] })
}

/// The edges file of `dpr-gpu multiway`: every registered pair and its fate in the pose graph.
#[derive(Serialize)]
struct EdgesFile<'a> {
    scans: usize,
    line_process_weight: f64,
    connected: &'a [bool],
    edges: &'a [EdgeRecord],
}

/// A multiway registration's outcome (``optimize_pairs``): the trajectory and every registered pair with its
/// fate in the robust pose graph.
#[pyclass(frozen, module = "dpr_gpu")]
pub struct MultiwayResult {
    /// The library's result (poses in the shifted frame).
    result: RustMultiwayResult,
    /// The collection's origin.
    origin: [i64; 3],
}

impl MultiwayResult {
    /// world_from_scan with the origin added back.
    fn trajectory(&self) -> Trajectory {
        Trajectory {
            world_from_scan: self
                .result
                .trajectory
                .world_from_scan
                .iter()
                .map(|w| unshift_pose(w, self.origin))
                .collect(),
        }
    }

    fn world_array<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray3<f64>> {
        matrices(py, &self.trajectory().world_from_scan)
    }

    fn edge_list<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let edges = PyList::empty(py);
        for e in &self.result.edges {
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
        Ok(edges)
    }
}

#[pymethods]
impl MultiwayResult {
    /// world_from_scan per scan, an (N, 4, 4) float64 array (world = the first scan's frame).
    #[getter]
    fn world_from_scan<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray3<f64>> {
        self.world_array(py)
    }

    /// One dict per registered pair (the ``edges`` of ``Registrar.multiway``).
    #[getter]
    fn edges<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        self.edge_list(py)
    }

    /// Per scan: linked to scan 0 by surviving edges.
    #[getter]
    fn connected(&self) -> Vec<bool> {
        self.result.connected.clone()
    }

    /// μ of the line processes.
    #[getter]
    fn line_process_weight(&self) -> f64 {
        self.result.line_process_weight
    }

    /// The dict ``Registrar.multiway`` returns: ``world_from_scan``, ``edges``, ``connected``,
    /// ``line_process_weight``.
    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let out = PyDict::new(py);
        out.set_item("world_from_scan", self.world_array(py))?;
        out.set_item("edges", self.edge_list(py)?)?;
        out.set_item("connected", self.result.connected.clone())?;
        out.set_item("line_process_weight", self.result.line_process_weight)?;
        Ok(out)
    }

    /// Writes ``out/trajectory.log`` and ``out/edges.json`` as ``dpr-gpu multiway`` writes them (atomically;
    /// the folder is created if missing), and ``out/scans.txt`` (one path per line) when ``scans`` is given.
    #[pyo3(signature = (out, scans = None))]
    fn write(&self, py: Python<'_>, out: PathBuf, scans: Option<Vec<PathBuf>>) -> PyResult<()> {
        let n = self.result.trajectory.world_from_scan.len();
        if let Some(s) = &scans
            && s.len() != n
        {
            return Err(value_error(format!("{} scan paths for {n} scans", s.len())));
        }
        if out.is_file() {
            return Err(pyo3::exceptions::PyNotADirectoryError::new_err(format!(
                "{} is a file; it must be a folder",
                out.display()
            )));
        }
        let edges = EdgesFile {
            scans: n,
            line_process_weight: self.result.line_process_weight,
            connected: &self.result.connected,
            edges: &self.result.edges,
        };
        let text = serde_json::to_string_pretty(&edges).map_err(|e| value_error(format!("edges.json: {e}")))?;
        let trajectory = self.trajectory();
        py.detach(|| -> dpr_gpu::Result<()> {
            std::fs::create_dir_all(&out).map_err(|e| dpr_gpu::Error::io(&out, e))?;
            trajectory.write_log(&out.join("trajectory.log"))?;
            write_atomic(&out.join("edges.json"), format!("{text}\n").as_bytes())?;
            if let Some(scans) = &scans {
                let list: String = scans.iter().map(|p| format!("{}\n", p.display())).collect();
                write_atomic(&out.join("scans.txt"), list.as_bytes())?;
            }
            Ok(())
        })
        .map_err(to_py_err)
    }

    fn __repr__(&self) -> String {
        let r = &self.result;
        format!(
            "MultiwayResult(scans={}, edges={}, survived={})",
            r.trajectory.world_from_scan.len(),
            r.edges.len(),
            r.edges.iter().filter(|e| e.survived).count()
        )
    }
}
