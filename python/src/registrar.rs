//! `Registrar`: the pipeline with its model and backend loaded once, and the scan features it describes.

use crate::arrays::{cloud_from_arrays, index_pairs};
use crate::described::{DescribedScan, PairResult, description_key};
use crate::errors::{to_py_err, value_error};
use crate::result::{PoseEstimate, RegistrationResult, SnapshotInputs};
use crate::settings::{ESTIMATORS, SettingsArgs, default_context_radii, settings_dict};
use dpr_gpu::io::{LoadOptions, OriginShift};
use dpr_gpu::pipeline::{ScanFeatures, load_weights, weights_file};
use dpr_gpu::pose::unshift_pose;
use dpr_gpu::{Correspondence, RegistrationSettings};
use numpy::{PyArray2, PyArrayMethods, PyUntypedArray, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;
use std::sync::Arc;

/// The registration pipeline with its weights, model and compute backend loaded once: reuse one ``Registrar``
/// for many pairs.
///
/// Keyword arguments are the library's ``RegistrationSettings`` (distances in the clouds' units, metres by
/// default):
///
/// - ``weights``: weights file (safetensors); None uses the weights built into the package (or the file named
///   by the ``DPR_GPU_WEIGHTS`` environment variable).
/// - ``radius``: patch radius; None takes twice the radius the weights were trained with (0.60 m).
/// - ``voxel``: voxel size for downsampling before normals and keypoints; 0 keeps every point; None (default):
///   radius / 24 for a cloud without normals, the density the weights were trained at (2.5 cm at 0.60 m), and
///   every point of a cloud with normals.
/// - ``keypoints``: keypoints per scan. ``keypoint_mode``: ``"random"`` or ``"uniform"`` (farthest-point).
/// - ``first_keypoints``: the progressive schedule: ``register`` describes this many keypoints per scan first
///   and doubles them, up to ``keypoints``, only while the result is not trusted; None describes ``keypoints``
///   at once. A pair that needs every round ends with exactly the result of None.
/// - ``normal_neighbors``: neighbours for PCA normals (scans without normals). ``viewpoint``: normals are
///   flipped to face this point (each scan's own frame).
/// - ``matching``: ``"mutual"`` (mutual ``mutual_k`` nearest neighbours, 1..4) or ``"closest"``.
/// - ``estimator``: ``"relativenet"`` (one hypothesis per correspondence) or ``"ransac"``.
/// - ``inlier_threshold``: None uses radius / 6. ``ransac_iterations``, ``ransac_confidence``: RANSAC criteria.
/// - ``icp``: refine with point-to-plane ICP (on by default; about 0.2 s a pair);
///   ``icp_max_correspondence_distance`` (None: radius / 12) and ``icp_max_iterations``.
/// - ``drop_zero_points``: rows exactly at (0, 0, 0) (sensor no-returns): None (the default) drops them when
///   there are two or more and keeps one alone, True drops every one, False keeps them.
/// - ``seed``: seed for every random choice (same inputs and seed, same result).
/// - ``backend``: ``"auto"`` (a GPU when one exists, else the CPU with a warning), ``"cpu"`` or ``"gpu"``.
/// - ``min_inliers``, ``min_inlier_ratio``, ``min_spread_over_threshold``: thresholds of the success verdict.
///   ``free_space_check``: the verdict also distrusts a pose that puts more points in space the other scan saw
///   empty from ``viewpoint`` than the scans' own views leave unexplained (False for clouds in a shared world
///   frame).
/// - ``context_radii``: ``(factor, weight)`` pairs: each keypoint is also described with a patch ``factor``
///   times the radius (1..8), and matching reads the unit codewords of every radius side by side, this one's
///   weighted by ``weight`` (the main radius's by 1); ``[]`` for the main radius alone. ``context_when``:
///   ``"untrusted"`` (only a last round on all keypoints, when the main radius gave no trusted result) or
///   ``"always"``.
/// - ``pose_candidates``: how many of the estimator's best distinct poses compete: the one with most inliers
///   stays when the verdict trusts it, or unless another with at least half its inliers puts clearly fewer
///   points in space the other scan saw empty from ``viewpoint`` (in each scan's frame); 1 keeps the pose with
///   most inliers (clouds in a shared world frame).
///
/// Raises ``ValueError`` for bad settings or weights that do not fit, ``OSError`` when the weights file cannot be
/// read, ``RuntimeError`` when ``backend="gpu"`` finds no usable GPU.
#[pyclass(frozen, module = "dpr_gpu")]
pub struct Registrar {
    /// The library's pipeline.
    inner: Arc<dpr_gpu::Registrar>,
}

impl Registrar {
    /// `scan`'s description on this registrar's backend, checked to fit its settings and weights.
    fn own(&self, py: Python<'_>, scan: &Bound<'_, DescribedScan>, what: &str) -> PyResult<ScanFeatures> {
        let scan = scan.get();
        scan.check_described_by(&self.inner, what)?;
        py.detach(|| scan.adopted_by(&self.inner)).map_err(to_py_err)
    }

    /// The load options for arrays given to this registrar.
    fn load_options(&self, origin: OriginShift) -> LoadOptions {
        LoadOptions { zero_points: self.inner.settings.zero_points, origin, ..LoadOptions::default() }
    }
}

#[pymethods]
impl Registrar {
    #[new]
    #[pyo3(signature = (
        *,
        weights = None,
        radius = None,
        voxel = None,
        keypoints = 2500,
        first_keypoints = Some(250),
        keypoint_mode = "random".to_string(),
        normal_neighbors = 30,
        viewpoint = [0.0, 0.0, 0.0],
        matching = "mutual".to_string(),
        mutual_k = 1,
        estimator = "relativenet".to_string(),
        inlier_threshold = None,
        ransac_iterations = 100_000,
        ransac_confidence = 0.999,
        icp = true,
        icp_max_correspondence_distance = None,
        icp_max_iterations = 30,
        drop_zero_points = None,
        seed = 0,
        backend = "auto".to_string(),
        min_inliers = 12,
        min_inlier_ratio = 0.055,
        min_spread_over_threshold = 2.0,
        free_space_check = true,
        context_radii = default_context_radii(),
        context_when = "untrusted".to_string(),
        pose_candidates = 16,
    ),
    text_signature = "(*, weights=None, radius=None, voxel=None, keypoints=2500, first_keypoints=250, \
        keypoint_mode='random', \
        normal_neighbors=30, viewpoint=(0.0, 0.0, 0.0), matching='mutual', mutual_k=1, estimator='relativenet', \
        inlier_threshold=None, ransac_iterations=100000, ransac_confidence=0.999, icp=True, \
        icp_max_correspondence_distance=None, icp_max_iterations=30, drop_zero_points=None, seed=0, \
        backend='auto', min_inliers=12, min_inlier_ratio=0.055, min_spread_over_threshold=2.0, \
        free_space_check=True, context_radii=[(2.0, 1.0)], context_when='untrusted', pose_candidates=16)")]
    #[expect(clippy::too_many_arguments, reason = "one keyword argument per setting, as Python callers expect")]
    fn new(
        py: Python<'_>,
        weights: Option<PathBuf>,
        radius: Option<f32>,
        voxel: Option<f32>,
        keypoints: i64,
        first_keypoints: Option<i64>,
        keypoint_mode: String,
        normal_neighbors: i64,
        viewpoint: [f32; 3],
        matching: String,
        mutual_k: i64,
        estimator: String,
        inlier_threshold: Option<f32>,
        ransac_iterations: i64,
        ransac_confidence: f64,
        icp: bool,
        icp_max_correspondence_distance: Option<f32>,
        icp_max_iterations: i64,
        drop_zero_points: Option<bool>,
        seed: i128,
        backend: String,
        min_inliers: i64,
        min_inlier_ratio: f64,
        min_spread_over_threshold: f64,
        free_space_check: bool,
        context_radii: Vec<(f32, f32)>,
        context_when: String,
        pose_candidates: i64,
    ) -> PyResult<Registrar> {
        let args = SettingsArgs {
            weights,
            radius,
            voxel,
            keypoints,
            first_keypoints,
            keypoint_mode,
            normal_neighbors,
            viewpoint,
            matching,
            mutual_k,
            estimator,
            inlier_threshold,
            ransac_iterations,
            ransac_confidence,
            icp,
            icp_max_correspondence_distance,
            icp_max_iterations,
            drop_zero_points,
            seed,
            backend,
            min_inliers,
            min_inlier_ratio,
            min_spread_over_threshold,
            free_space_check,
            context_radii,
            context_when,
            pose_candidates,
        };
        let probe = RegistrationSettings { weights: args.weights.clone(), ..RegistrationSettings::default() };
        // A weights file is read (and its errors reported) before the other arguments are checked; the built-in
        // weights are read in place by `Registrar::new`.
        let loaded = match weights_file(&probe) {
            Some(_) => Some(py.detach(|| load_weights(&probe)).map_err(to_py_err)?),
            None => None,
        };
        let settings = args.to_settings()?;
        let inner = py
            .detach(|| match &loaded {
                Some(weights) => dpr_gpu::Registrar::with_weights(&settings, weights),
                None => dpr_gpu::Registrar::new(&settings),
            })
            .map_err(to_py_err)?;
        Ok(Registrar { inner: Arc::new(inner) })
    }

    /// The settings in effect, as a dict of the keyword arguments (defaults resolved where the library resolves
    /// them at construction, e.g. the ICP distance).
    #[getter]
    fn settings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = settings_dict(py, &self.inner.settings)?;
        // The ICP distance as resolved against the radius in use.
        d.set_item("icp_max_correspondence_distance", self.inner.icp_max_distance())?;
        Ok(d)
    }

    /// The backend (and adapter) that runs the learned stages, e.g. ``"cpu"``.
    #[getter]
    fn backend(&self) -> String {
        self.inner.backend_name()
    }

    /// The patch radius the steps (``describe``, ``estimate``) use (cloud units): the one given, else the default.
    /// ``register`` with no radius given chooses its own from the two clouds: see ``RegistrationResult.scale``.
    #[getter]
    fn radius(&self) -> f32 {
        self.inner.radius()
    }

    /// The inlier threshold the steps use (cloud units): the one given, else radius / 6. ``register`` with no
    /// radius given derives its own from the scale it chose: see ``RegistrationResult.scale``.
    #[getter]
    fn inlier_threshold(&self) -> f32 {
        self.inner.inlier_threshold()
    }

    /// Describes one scan: preprocessing, normals (from ``normals`` when given, else estimated), keypoints and
    /// their learned descriptors.
    ///
    /// ``points`` (and ``normals``) are (N, 3) float32 or float64 arrays in any memory order; rows with a NaN or
    /// infinite value are dropped, as the file readers do. Coordinates are converted to float32 as given:
    /// subtract an origin from georeferenced coordinates first (``register`` does this itself). ``stream``
    /// separates the random choices of different scans under one seed; ``register`` describes the source with
    /// stream 0 and the target with stream 1. Raises ``ValueError`` for bad arrays or too few points.
    #[pyo3(signature = (points, normals = None, *, stream = 0))]
    fn describe(
        &self,
        py: Python<'_>,
        points: &Bound<'_, PyAny>,
        normals: Option<&Bound<'_, PyAny>>,
        stream: usize,
    ) -> PyResult<DescribedScan> {
        let (cloud, _) = cloud_from_arrays(points, normals, "points", &self.load_options(OriginShift::None))?;
        let inner = &self.inner;
        let features = py.detach(|| inner.describe(&cloud, stream as u64)).map_err(to_py_err)?;
        Ok(DescribedScan::new(features, stream, [0; 3], description_key(&inner.settings)))
    }

    /// Correspondences between two described scans (matching rule from the settings), as a (K, 2) int64 array
    /// of keypoint indices: column 0 indexes ``source.keypoints``, column 1 ``target.keypoints``.
    fn correspond<'py>(
        &self,
        py: Python<'py>,
        source: &Bound<'py, DescribedScan>,
        target: &Bound<'py, DescribedScan>,
    ) -> PyResult<Bound<'py, PyArray2<i64>>> {
        let (s, t) = (self.own(py, source, "source")?, self.own(py, target, "target")?);
        let inner = &self.inner;
        let found = py.detach(|| inner.correspond(&s, &t)).map_err(to_py_err)?;
        Ok(index_pairs(py, found.iter().map(|c| [c.source_index, c.target_index])))
    }

    /// Estimates target_from_source from correspondences ((K, 2) integer keypoint indices, as from
    /// ``correspond``, possibly filtered), then refines it with ICP when enabled. ``estimator`` overrides the
    /// setting (``"relativenet"`` or ``"ransac"``). Raises ``ValueError`` for indices out of range or fewer
    /// than 3 correspondences.
    #[pyo3(signature = (source, target, correspondences, *, estimator = None))]
    fn estimate(
        &self,
        py: Python<'_>,
        source: &Bound<'_, DescribedScan>,
        target: &Bound<'_, DescribedScan>,
        correspondences: &Bound<'_, PyAny>,
        estimator: Option<String>,
    ) -> PyResult<PoseEstimate> {
        let (s, t) = (self.own(py, source, "source")?, self.own(py, target, "target")?);
        let estimator = match estimator {
            Some(name) => crate::settings::choose("estimator", &name, ESTIMATORS)?,
            None => self.inner.settings.estimator,
        };
        let pairs = index_rows(correspondences)?;
        let list = correspondences_between(&s, &t, &pairs)?;
        let inner = &self.inner;
        let estimate = py.detach(|| inner.estimate(&s, &t, &list, estimator)).map_err(to_py_err)?;
        Ok(PoseEstimate { estimate })
    }

    /// Registers ``source`` onto ``target``: the whole pipeline. Returns a ``RegistrationResult`` whose
    /// ``target_from_source`` maps source points into the target frame.
    ///
    /// ``source``, ``target`` (and the optional normals) are (N, 3) float32 or float64 arrays in any memory
    /// order, copied only into the library's own point type. Rows with a NaN or infinite value are dropped as
    /// the command line drops them from files, and large (georeferenced) coordinates are shifted by one origin
    /// before the float32 conversion, as the command line does. Raises ``ValueError`` for bad arrays or too few
    /// points, ``RuntimeError`` for GPU failures.
    #[pyo3(signature = (source, target, *, source_normals = None, target_normals = None))]
    fn register(
        &self,
        py: Python<'_>,
        source: &Bound<'_, PyAny>,
        target: &Bound<'_, PyAny>,
        source_normals: Option<&Bound<'_, PyAny>>,
        target_normals: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<RegistrationResult> {
        let (source, source_report) =
            cloud_from_arrays(source, source_normals, "source", &self.load_options(OriginShift::Auto))?;
        let origin = source_report.origin;
        let (target, target_report) =
            cloud_from_arrays(target, target_normals, "target", &self.load_options(OriginShift::At(origin)))?;
        let inner = &self.inner;
        let registration = py.detach(|| inner.register_detailed(&source, &target)).map_err(to_py_err)?;
        let mut result = registration.result;
        let shifted = result.estimate.target_from_source;
        result.estimate.target_from_source = unshift_pose(&shifted, origin);
        let dropped = [source_report, target_report].iter().map(|r| r.dropped_non_finite + r.dropped_zero).sum();
        let inlier_threshold = result.scale.inlier_threshold;
        Ok(RegistrationResult {
            result,
            correspondences: registration.correspondences,
            source_keypoints: registration.source.keypoints,
            target_keypoints: registration.target.keypoints,
            origin,
            dropped_points: dropped,
            snapshot: SnapshotInputs { source, target, shifted_target_from_source: shifted, inlier_threshold },
        })
    }

    /// Registers a collection of scans into one trajectory: every scan is described once, candidate pairs are
    /// registered, and a robust pose graph (line processes, as in Choi et al. 2015) switches wrong loop
    /// closures off.
    ///
    /// ``scans`` is a sequence of (N, 3) float arrays (``normals``: an optional sequence of the same shapes).
    /// ``pairs``: ``"all"`` or ``"consecutive+retrieval"`` (consecutive scans plus each scan's ``retrieval_k``
    /// most similar scans by pooled codewords); ``max_pairs`` caps the count (consecutive pairs first).
    /// ``information_distance`` (None: the inlier threshold) builds the edge information matrices;
    /// ``loop_preference`` (larger keeps more loop closures) scales the line processes.
    ///
    /// Returns a dict: ``world_from_scan`` ((N, 4, 4) float64, world = the first scan's frame), ``edges`` (one
    /// dict per registered pair: ``i``, ``j``, ``i_from_j`` (x_i = T x_j), ``correspondences``, ``inliers``,
    /// ``fitness``, ``inlier_rmse``, ``trusted``, ``reason``, ``information`` (6x6), ``kind`` (``"odometry"`` or
    /// ``"loop"``), ``in_graph``, ``uncertain``, ``line_process``, ``survived``), ``connected`` (per scan: linked
    /// to scan 0 by surviving edges) and ``line_process_weight``. Raises ``ValueError`` for fewer than 2 scans or
    /// bad arrays or options.
    #[pyo3(signature = (
        scans, normals = None, *, pairs = "consecutive+retrieval".to_string(), retrieval_k = 5, max_pairs = None,
        information_distance = None, loop_preference = 1.0
    ),
    text_signature = "($self, scans, normals=None, *, pairs='consecutive+retrieval', retrieval_k=5, max_pairs=None, \
        information_distance=None, loop_preference=1.0)")]
    #[expect(clippy::too_many_arguments, reason = "one keyword argument per option, as Python callers expect")]
    fn multiway<'py>(
        &self,
        py: Python<'py>,
        scans: &Bound<'py, PyAny>,
        normals: Option<&Bound<'py, PyAny>>,
        pairs: String,
        retrieval_k: i64,
        max_pairs: Option<i64>,
        information_distance: Option<f64>,
        loop_preference: f64,
    ) -> PyResult<Bound<'py, PyDict>> {
        let args =
            crate::multiway::MultiwayArgs { pairs, retrieval_k, max_pairs, information_distance, loop_preference };
        crate::multiway::run(py, &self.inner, self.load_options(OriginShift::None), scans, normals, args)
    }

    /// Describes scan ``index`` of a collection exactly as ``Registrar.multiway`` describes it (random stream
    /// ``index``, coordinates shifted by the collection's ``origin`` from ``multiway_origin(scans[0])``), and
    /// returns a picklable ``DescribedScan``: the describe stage of a multiway run, for schedulers that spread it
    /// over processes or machines (``dpr_gpu.distributed``). Raises ``ValueError`` for bad arrays or too few
    /// points (the message names the scan).
    #[pyo3(signature = (points, normals = None, *, index, origin = (0, 0, 0)),
        text_signature = "($self, points, normals=None, *, index, origin=(0, 0, 0))")]
    fn describe_scan(
        &self,
        py: Python<'_>,
        points: &Bound<'_, PyAny>,
        normals: Option<&Bound<'_, PyAny>>,
        index: usize,
        origin: (i64, i64, i64),
    ) -> PyResult<DescribedScan> {
        let load = self.load_options(OriginShift::None);
        crate::described::describe_scan(py, &self.inner, load, (points, normals), index, [origin.0, origin.1, origin.2])
    }

    /// Registers ``source`` (scan j) onto ``target`` (scan i), i < j, as ``Registrar.multiway`` registers a
    /// candidate pair: correspondences, the estimator, the verdict and the edge information matrix at
    /// ``information_distance`` (None: the inlier threshold). Both scans must come from ``describe_scan`` of a
    /// registrar with the same settings and weights (any process). Returns a picklable ``PairResult``; a pair
    /// without enough correspondences comes back untrusted with the reason, not as an error.
    #[pyo3(signature = (target, source, *, information_distance = None))]
    fn register_described(
        &self,
        py: Python<'_>,
        target: &Bound<'_, DescribedScan>,
        source: &Bound<'_, DescribedScan>,
        information_distance: Option<f64>,
    ) -> PyResult<PairResult> {
        let (t, s) = (crate::described::scan_of(target), crate::described::scan_of(source));
        crate::described::register_described(py, &self.inner, t, s, information_distance)
    }

    fn __repr__(&self) -> String {
        let s = &self.inner.settings;
        format!(
            "Registrar(backend='{}', keypoints={}, estimator='{}', radius={})",
            self.inner.backend_name(),
            s.keypoints,
            crate::settings::name_of(s.estimator, ESTIMATORS),
            self.inner.radius()
        )
    }
}

/// `object` as (K, 2) integer index pairs.
fn index_rows(object: &Bound<'_, PyAny>) -> PyResult<Vec<[i64; 2]>> {
    let numpy = object.py().import("numpy")?;
    let array = numpy.call_method1("asarray", (object,))?;
    let untyped = array.cast::<PyUntypedArray>()?;
    let kind: String = array.getattr("dtype")?.getattr("kind")?.extract()?;
    let shape = untyped.shape().to_vec();
    if shape.len() != 2 || shape[1] != 2 || !(kind == "i" || kind == "u") {
        let shape = shape.iter().map(|d| d.to_string()).collect::<Vec<_>>().join(", ");
        return Err(value_error(format!(
            "correspondences: expected a (K, 2) array of integer keypoint indices, got shape ({shape}) of dtype {}",
            untyped.dtype()
        )));
    }
    let as_i64 = array.call_method1("astype", ("int64",))?;
    let typed = as_i64.cast::<PyArray2<i64>>()?;
    let readonly = typed.try_readonly().map_err(|e| value_error(format!("correspondences: {e}")))?;
    Ok(readonly.as_array().rows().into_iter().map(|r| [r[0], r[1]]).collect())
}

/// The library's correspondences for index `pairs` between two described scans (positions from the keypoints,
/// feature distance between the codewords); indices out of range are refused.
fn correspondences_between(
    source: &ScanFeatures,
    target: &ScanFeatures,
    pairs: &[[i64; 2]],
) -> PyResult<Vec<Correspondence>> {
    let (source_codewords, target_codewords) =
        (source.read_codewords().map_err(to_py_err)?, target.read_codewords().map_err(to_py_err)?);
    let dim = source_codewords.len() / source.keypoints.len().max(1);
    let check = |i: i64, n: usize, what: &str, row: usize| {
        usize::try_from(i)
            .ok()
            .filter(|&i| i < n)
            .ok_or_else(|| value_error(format!("correspondences row {row}: {what} index {i} is out of range (0..{n})")))
    };
    pairs
        .iter()
        .enumerate()
        .map(|(row, &[s, t])| {
            let s = check(s, source.keypoints.len(), "source", row)?;
            let t = check(t, target.keypoints.len(), "target", row)?;
            let (a, b) = (&source_codewords[s * dim..(s + 1) * dim], &target_codewords[t * dim..(t + 1) * dim]);
            let distance = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f32>().sqrt();
            Ok(Correspondence {
                source_index: s as u32,
                target_index: t as u32,
                source_point: source.keypoints[s],
                target_point: target.keypoints[t],
                feature_distance: distance,
            })
        })
        .collect()
}
