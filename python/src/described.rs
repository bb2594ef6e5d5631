//! Described scans and registered pairs as values that travel between processes (pickle): a `DescribedScan`
//! (one scan described once, by `Registrar.describe` for the step-by-step pipeline or `Registrar.describe_scan`
//! for a collection) and a `PairResult` (one registered pair). They let a scheduler such as
//! `dpr_gpu.distributed` run the describe and pair stages of `Registrar.multiway` anywhere and feed the results
//! to the same pose graph ([`crate::multiway`]).

use crate::arrays::{cloud_from_arrays, matrix, positions, vectors};
use crate::errors::{to_py_err, value_error};
use crate::result::timings_dict;
use crate::state::{Reader, Writer, flat, triples};
use dpr_gpu::backend::{ContextRows, HostRows, HostScanRows, ScanRows, check_restored};
use dpr_gpu::eval::groundtruth::PreparedFragment;
use dpr_gpu::io::{LoadOptions, OriginShift};
use dpr_gpu::multiway::pair::{InformationSettings, prepare_for_information, register_pair};
use dpr_gpu::multiway::pairs::pooled_codeword;
use dpr_gpu::multiway::{MultiwaySettings, PairResult as RustPairResult};
use dpr_gpu::pipeline::{PoseRows, ScanFeatures, weights_file};
use dpr_gpu::{Error, PointCloud, RegistrationSettings, StageTime};
use numpy::{IntoPyArray, PyArray1, PyArray2};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyTuple};
use std::sync::{Arc, OnceLock};

/// Magic tags of the pickled states.
const SCAN_MAGIC: &[u8] = b"dpr-gpu/DescribedScan/4\0";
const PAIR_MAGIC: &[u8] = b"dpr-gpu/PairResult/1\0";

/// A fingerprint of the settings and weights a scan was described with: only a registrar with the same key may
/// register it (in any process), as the descriptors of different settings or weights do not match.
pub(crate) fn description_key(settings: &RegistrationSettings) -> u64 {
    let text = format!(
        "{}|{}",
        serde_json::to_string(settings).unwrap_or_default(),
        weights_file(settings).map_or_else(|| "built-in".to_string(), |p| p.display().to_string())
    );
    // FNV-1a: stable across processes and machines (std's hasher is seeded per process).
    text.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3))
}

/// One described scan (``Registrar.describe`` or ``Registrar.describe_scan``): its preprocessed points,
/// keypoints, their normals and learned descriptors (kept opaque), and its random stream (its index in a
/// collection). Picklable (bit for bit), so it can be described in one process and used in another by a
/// ``Registrar`` with the same settings and weights.
#[pyclass(frozen, module = "dpr_gpu")]
pub struct DescribedScan {
    /// The library's description (points in the collection's shifted frame).
    pub(crate) features: Arc<ScanFeatures>,
    /// The scan's random stream: its index in a collection.
    pub(crate) index: usize,
    /// The whole-unit origin subtracted from the scan (the collection's, from scan 0).
    pub(crate) origin: [i64; 3],
    /// [`description_key`] of the describing registrar.
    pub(crate) key: u64,
    /// The pooled codeword used by retrieval, computed on first use.
    pooled: OnceLock<Vec<f32>>,
    /// The points indexed for the information matrices, built on first use in this process.
    prepared: OnceLock<(f64, Arc<PreparedFragment>)>,
}

impl DescribedScan {
    pub(crate) fn new(features: ScanFeatures, index: usize, origin: [i64; 3], key: u64) -> DescribedScan {
        DescribedScan {
            features: Arc::new(features),
            index,
            origin,
            key,
            pooled: OnceLock::new(),
            prepared: OnceLock::new(),
        }
    }

    /// The unit-length mean of the keypoints' unit codewords (read back once).
    pub(crate) fn pooled(&self) -> PyResult<&[f32]> {
        if let Some(p) = self.pooled.get() {
            return Ok(p);
        }
        let codewords = self.features.read_codewords().map_err(to_py_err)?;
        let pooled = pooled_codeword(&codewords, self.features.rows.codeword());
        Ok(self.pooled.get_or_init(|| pooled))
    }

    /// Refuses a scan described with other settings or weights than `registrar`'s (`what` names the argument):
    /// their descriptors do not match.
    pub(crate) fn check_described_by(&self, registrar: &dpr_gpu::Registrar, what: &str) -> PyResult<()> {
        if self.key != description_key(&registrar.settings) {
            return Err(value_error(format!(
                "{what} (scan {}) was described with other settings or weights than this Registrar's",
                self.index
            )));
        }
        Ok(())
    }

    /// The description with its rows on `registrar`'s backend: pickled scans hold host rows and a scan described
    /// by another registrar holds that one's, so the backend takes them over (kept as they are when it
    /// described them itself).
    pub(crate) fn adopted_by(&self, registrar: &dpr_gpu::Registrar) -> Result<ScanFeatures, Error> {
        registrar.adopt(&self.features)
    }

    /// The scan's points indexed for information matrices at `distance` (cached for the first distance asked).
    fn prepared(&self, distance: f64) -> Arc<PreparedFragment> {
        let (d, p) =
            self.prepared.get_or_init(|| (distance, Arc::new(prepare_for_information(&self.features, distance))));
        if *d == distance { Arc::clone(p) } else { Arc::new(prepare_for_information(&self.features, distance)) }
    }

    fn state(&self) -> PyResult<Vec<u8>> {
        let f = &self.features;
        // The rows live with the backend that described them (device buffers for a GPU): read back once here.
        let mut w = Writer::new(SCAN_MAGIC);
        w.u64(self.key);
        w.u64(self.index as u64);
        for c in self.origin {
            w.i64(c);
        }
        w.f32s(&flat(&f.cloud.points));
        w.f32s(&f.viewpoint);
        w.u64(u64::from(f.cloud.normals.is_some()));
        w.f32s(&f.cloud.normals.as_deref().map(flat).unwrap_or_default());
        w.f32s(&flat(&f.keypoints));
        w.f32s(&flat(&f.keypoint_normals));
        w.u64(f.empty_patches as u64);
        w.u32s(&f.keypoint_ranks);
        w.u64(f.candidates as u64);
        write_rows(&mut w, f.rows.as_ref())?;
        w.u64(f.context.len() as u64);
        for c in &f.context {
            w.f64(f64::from(c.radius));
            w.f64(f64::from(c.weight));
            write_rows(&mut w, c.rows.as_ref())?;
        }
        w.f32s(self.pooled()?);
        w.u64(f.timings.len() as u64);
        for t in &f.timings {
            w.str(&t.stage);
            w.f64(t.seconds);
        }
        Ok(w.bytes)
    }

    fn from_state(bytes: &[u8]) -> PyResult<DescribedScan> {
        const WHAT: &str = "DescribedScan";
        let mut r = Reader::new(bytes, SCAN_MAGIC, WHAT)?;
        let key = r.u64()?;
        let index = r.usize()?;
        let origin = [r.i64()?, r.i64()?, r.i64()?];
        let points = triples(r.f32s()?, WHAT)?;
        let viewpoint: [f32; 3] = match triples(r.f32s()?, WHAT)?.as_slice() {
            [v] if v.iter().all(|c| c.is_finite()) => *v,
            _ => return Err(value_error("DescribedScan: the pickled viewpoint is not one finite point")),
        };
        let has_normals = r.u64()? != 0;
        let normals = triples(r.f32s()?, WHAT)?;
        let keypoints = triples(r.f32s()?, WHAT)?;
        let keypoint_normals = triples(r.f32s()?, WHAT)?;
        let empty_patches = r.usize()?;
        let keypoint_ranks = r.u32s()?;
        let candidates = r.usize()?;
        let main = read_rows(&mut r)?;
        let context_radii = r.usize()?;
        if context_radii > dpr_gpu::settings::MAX_CONTEXT_RADII {
            return Err(value_error(format!(
                "DescribedScan: {context_radii} context radii (at most {})",
                dpr_gpu::settings::MAX_CONTEXT_RADII
            )));
        }
        let mut context = Vec::with_capacity(context_radii);
        for _ in 0..context_radii {
            let (radius, weight) = (r.f64()? as f32, r.f64()? as f32);
            context.push((radius, weight, read_rows(&mut r)?));
        }
        let pooled = r.f32s()?;
        let stages = r.usize()?;
        let mut timings = Vec::new();
        for _ in 0..stages {
            timings.push(StageTime { stage: r.str()?, seconds: r.f64()? });
        }
        r.finish()?;
        let consistent = (!has_normals || normals.len() == points.len())
            && keypoint_normals.len() == keypoints.len()
            && keypoint_ranks.len() == keypoints.len()
            && keypoint_ranks.windows(2).all(|w| w[0] < w[1])
            && keypoint_ranks.last().is_none_or(|&r| (r as usize) < candidates)
            && (keypoints.is_empty() || main.codewords.len() % keypoints.len() == 0);
        if !consistent {
            return Err(value_error("DescribedScan: the pickled arrays do not fit together"));
        }
        let codeword = main.codewords.len() / keypoints.len().max(1);
        // Host rows; `Registrar.register_described` moves them to its backend (`Registrar::adopt`).
        let restore = |rows: HostRows| -> PyResult<Arc<dyn ScanRows>> {
            check_restored(&rows.codewords, &rows.pose, keypoints.len(), codeword)
                .map_err(|e| value_error(format!("DescribedScan: {e}")))?;
            Ok(Arc::new(HostScanRows::with_rows(codeword, rows)))
        };
        let rows = restore(main)?;
        let context = context
            .into_iter()
            .map(|(radius, weight, rows)| Ok(ContextRows { radius, weight, rows: restore(rows)? }))
            .collect::<PyResult<Vec<_>>>()?;
        let features = ScanFeatures {
            cloud: PointCloud { points, normals: has_normals.then_some(normals) },
            viewpoint,
            keypoints,
            keypoint_normals,
            keypoint_ranks,
            candidates,
            empty_patches,
            rows,
            context,
            held_points: None,
            // Restored normals are taken as given (ICP estimates its own).
            estimated_normals: None,
            timings,
        };
        let scan = DescribedScan::new(features, index, origin, key);
        scan.pooled.get_or_init(|| pooled);
        Ok(scan)
    }
}

#[pymethods]
impl DescribedScan {
    /// The scan's index in the collection (and its random stream).
    #[getter]
    fn index(&self) -> usize {
        self.index
    }

    /// The random stream the scan was described with: its index (``register`` uses 0 for the source, 1 for the
    /// target).
    #[getter]
    fn stream(&self) -> usize {
        self.index
    }

    /// Keypoints dropped because no other point lay within the patch radius.
    #[getter]
    fn empty_patches(&self) -> usize {
        self.features.empty_patches
    }

    /// The whole-unit origin subtracted from the scan's coordinates before the float32 conversion (zeros unless
    /// the collection is georeferenced).
    #[getter]
    fn origin(&self) -> (i64, i64, i64) {
        (self.origin[0], self.origin[1], self.origin[2])
    }

    /// Keypoint positions (scan frame, origin added back) as a (K, 3) float64 array.
    #[getter]
    fn keypoints<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        positions(py, &self.features.keypoints, self.origin)
    }

    /// Unit normals at the keypoints as a (K, 3) float64 array.
    #[getter]
    fn keypoint_normals<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        vectors(py, &self.features.keypoint_normals)
    }

    /// Points left after preprocessing (the ones the information matrices use).
    #[getter]
    fn points(&self) -> usize {
        self.features.cloud.len()
    }

    /// The unit-length mean of the keypoints' unit PPF-FoldNet codewords, a (D,) float32 array: retrieval ranks
    /// scan pairs by the dot product of these.
    #[getter]
    fn pooled_codeword<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<f32>>> {
        Ok(self.pooled()?.to_vec().into_pyarray(py))
    }

    /// Wall time per description stage in seconds (dict, in pipeline order).
    #[getter]
    fn timings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        timings_dict(py, &self.features.timings)
    }

    /// Number of keypoints.
    fn __len__(&self) -> usize {
        self.features.keypoints.len()
    }

    fn __repr__(&self) -> String {
        format!(
            "DescribedScan(index={}, keypoints={}, points={})",
            self.index,
            self.features.keypoints.len(),
            self.features.cloud.len()
        )
    }

    /// Pickling: the state as bytes, restored bit for bit by ``dpr_gpu._dpr_gpu._described_scan_from_state``.
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        let restore = py.import("dpr_gpu._dpr_gpu")?.getattr("_described_scan_from_state")?;
        let state = PyBytes::new(py, &self.state()?);
        PyTuple::new(py, [restore, PyTuple::new(py, [state])?.into_any()])
    }
}

/// Writes described rows (read back from the backend that holds them): codewords, then the pose rows.
fn write_rows(w: &mut Writer, rows: &dyn ScanRows) -> PyResult<()> {
    let codewords = dpr_gpu::block_on(rows.read_codewords()).map_err(to_py_err)?;
    let pose = dpr_gpu::block_on(rows.read_pose_rows()).map_err(to_py_err)?;
    w.f32s(&codewords);
    w.f32s(&pose.input);
    w.f32s(&pose.features);
    w.u32s(&pose.ready.iter().map(|&r| u32::from(r)).collect::<Vec<u32>>());
    Ok(())
}

/// Reads rows written by [`write_rows`] (checked by the caller).
fn read_rows(r: &mut Reader<'_>) -> PyResult<HostRows> {
    let codewords = r.f32s()?;
    let (input, features, ready) = (r.f32s()?, r.f32s()?, r.u32s()?);
    Ok(HostRows { codewords, pose: PoseRows { input, features, ready: ready.iter().map(|&r| r != 0).collect() } })
}

/// Rebuilds a pickled `DescribedScan`.
#[pyfunction]
pub(crate) fn _described_scan_from_state(state: &[u8]) -> PyResult<DescribedScan> {
    DescribedScan::from_state(state)
}

/// The registration of scan ``j`` (source) onto scan ``i`` (target), i < j: one candidate edge of the pose graph
/// (``Registrar.register_described``). Picklable (bit for bit); ``optimize_pairs`` takes a list of them.
#[pyclass(frozen, module = "dpr_gpu")]
pub struct PairResult {
    /// The library's pair result.
    pub(crate) result: RustPairResult,
}

#[pymethods]
impl PairResult {
    /// Target scan index.
    #[getter]
    fn i(&self) -> usize {
        self.result.i
    }

    /// Source scan index.
    #[getter]
    fn j(&self) -> usize {
        self.result.j
    }

    /// The 4x4 estimate x_i = T x_j (float64, in the collection's shifted frame).
    #[getter]
    fn i_from_j<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        matrix(py, &self.result.transform())
    }

    /// Keypoint correspondences fed to the estimator.
    #[getter]
    fn correspondences(&self) -> usize {
        self.result.correspondences
    }

    /// Correspondences within the inlier threshold under the estimate.
    #[getter]
    fn inliers(&self) -> usize {
        self.result.inliers
    }

    /// Inliers / correspondences.
    #[getter]
    fn fitness(&self) -> f64 {
        self.result.fitness
    }

    /// RMS residual of the inliers (cloud units).
    #[getter]
    fn inlier_rmse(&self) -> f64 {
        self.result.inlier_rmse
    }

    /// Whether the verdict trusts the estimate.
    #[getter]
    fn trusted(&self) -> bool {
        self.result.trusted
    }

    /// Why not; None when trusted.
    #[getter]
    fn reason(&self) -> Option<&str> {
        self.result.reason.as_deref()
    }

    /// The 6x6 edge information matrix (translation first), float64.
    #[getter]
    fn information<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let rows: Vec<Vec<f64>> = self.result.information.iter().map(|r| r.to_vec()).collect();
        PyArray2::from_vec2(py, &rows).map_err(|e| value_error(e.to_string()))
    }

    /// Seconds spent registering the pair.
    #[getter]
    fn seconds(&self) -> f64 {
        self.result.seconds
    }

    fn __repr__(&self) -> String {
        let r = &self.result;
        format!(
            "PairResult(i={}, j={}, trusted={}, inliers={}, correspondences={})",
            r.i,
            r.j,
            if r.trusted { "True" } else { "False" },
            r.inliers,
            r.correspondences
        )
    }

    /// Pickling: the state as bytes, restored bit for bit by ``dpr_gpu._dpr_gpu._pair_result_from_state``.
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        let r = &self.result;
        let mut w = Writer::new(PAIR_MAGIC);
        w.u64(r.i as u64);
        w.u64(r.j as u64);
        w.f64s(r.i_from_j.as_flattened());
        w.u64(r.correspondences as u64);
        w.u64(r.inliers as u64);
        w.f64(r.fitness);
        w.f64(r.inlier_rmse);
        w.u64(u64::from(r.trusted));
        w.opt_str(r.reason.as_deref());
        w.f64s(r.information.as_flattened());
        w.f64(r.seconds);
        let restore = py.import("dpr_gpu._dpr_gpu")?.getattr("_pair_result_from_state")?;
        let state = PyBytes::new(py, &w.bytes);
        PyTuple::new(py, [restore, PyTuple::new(py, [state])?.into_any()])
    }
}

/// Rebuilds a pickled `PairResult`.
#[pyfunction]
pub(crate) fn _pair_result_from_state(state: &[u8]) -> PyResult<PairResult> {
    const WHAT: &str = "PairResult";
    let mut r = Reader::new(state, PAIR_MAGIC, WHAT)?;
    let (i, j) = (r.usize()?, r.usize()?);
    let t = r.f64s()?;
    let (correspondences, inliers, fitness, inlier_rmse) = (r.usize()?, r.usize()?, r.f64()?, r.f64()?);
    let trusted = r.u64()? != 0;
    let reason = r.opt_str()?;
    let info = r.f64s()?;
    let seconds = r.f64()?;
    r.finish()?;
    if t.len() != 16 || info.len() != 36 {
        return Err(value_error("PairResult: the pickled matrices have the wrong sizes"));
    }
    Ok(PairResult {
        result: RustPairResult {
            i,
            j,
            i_from_j: std::array::from_fn(|row| std::array::from_fn(|c| t[4 * row + c])),
            correspondences,
            inliers,
            fitness,
            inlier_rmse,
            trusted,
            reason,
            information: std::array::from_fn(|row| std::array::from_fn(|c| info[6 * row + c])),
            seconds,
        },
    })
}

/// Adds "scan k: " to input errors, as the single-process multiway does.
fn scan_error(k: usize, e: Error) -> Error {
    match e {
        Error::InvalidInput(m) => Error::InvalidInput(format!("scan {k}: {m}")),
        other => other,
    }
}

/// `Registrar.describe_scan`: scan `index` of a collection, shifted by the collection's `origin`, described
/// with stream `index` as `Registrar.multiway` describes it.
pub(crate) fn describe_scan(
    py: Python<'_>,
    registrar: &dpr_gpu::Registrar,
    load: LoadOptions,
    (points, normals): (&Bound<'_, PyAny>, Option<&Bound<'_, PyAny>>),
    index: usize,
    origin: [i64; 3],
) -> PyResult<DescribedScan> {
    let options = LoadOptions { origin: OriginShift::At(origin), ..load };
    let (cloud, _) = cloud_from_arrays(points, normals, &format!("scan {index}"), &options)?;
    let features =
        py.detach(|| registrar.describe(&cloud, index as u64)).map_err(|e| to_py_err(scan_error(index, e)))?;
    Ok(DescribedScan::new(features, index, origin, description_key(&registrar.settings)))
}

/// `Registrar.register_described`: registers `source` (scan j) onto `target` (scan i), i < j, with the edge
/// information of `Registrar.multiway` at `information_distance` (None: the inlier threshold).
pub(crate) fn register_described(
    py: Python<'_>,
    registrar: &dpr_gpu::Registrar,
    target: &DescribedScan,
    source: &DescribedScan,
    information_distance: Option<f64>,
) -> PyResult<PairResult> {
    target.check_described_by(registrar, "target")?;
    source.check_described_by(registrar, "source")?;
    let (i, j) = (target.index, source.index);
    if i >= j {
        return Err(value_error(format!("the target's index must be below the source's, got target {i}, source {j}")));
    }
    if target.origin != source.origin {
        return Err(value_error(format!(
            "scans {i} and {j} were shifted by different origins ({:?} and {:?})",
            target.origin, source.origin
        )));
    }
    let distance = information_distance.unwrap_or(f64::from(registrar.inlier_threshold()));
    if !(distance.is_finite() && distance > 0.0) {
        return Err(value_error(format!("information_distance must be positive, got {distance}")));
    }
    let information = InformationSettings {
        distance,
        max_points: MultiwaySettings::default().max_information_points,
        seed: registrar.settings.seed,
    };
    let result = py
        .detach(|| {
            let (pt, ps) = (target.prepared(distance), source.prepared(distance));
            let (tf, sf) = (target.adopted_by(registrar)?, source.adopted_by(registrar)?);
            Ok::<_, Error>(register_pair(registrar, (i, j), &tf, &sf, &pt, &ps, &information))
        })
        .map_err(to_py_err)?;
    Ok(PairResult { result })
}

/// A `DescribedScan` argument as a plain reference.
pub(crate) fn scan_of<'a>(scan: &'a Bound<'_, DescribedScan>) -> &'a DescribedScan {
    scan.get()
}

/// A `PairResult` as the library's value.
pub(crate) fn pair_of(pair: &Bound<'_, PyAny>, k: usize) -> PyResult<RustPairResult> {
    let p = pair
        .cast::<PairResult>()
        .map_err(|_| value_error(format!("pair_results[{k}]: expected a PairResult, got {}", type_name(pair))))?;
    Ok(p.get().result.clone())
}

fn type_name(object: &Bound<'_, PyAny>) -> String {
    object.get_type().name().map(|n| n.to_string()).unwrap_or_else(|_| "?".to_string())
}
