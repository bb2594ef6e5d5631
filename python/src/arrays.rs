//! numpy arrays in and out: (N, 3) float arrays become point clouds through the library's own loader rules,
//! results become numpy arrays.

use crate::errors::value_error;
use dpr_gpu::PointCloud;
use dpr_gpu::io::{LoadOptions, LoadReport, cloud_from_rows};
use numpy::ndarray::{Array2, Array3};
use numpy::{
    Element, IntoPyArray, PyArray1, PyArray2, PyArray3, PyArrayMethods, PyUntypedArray, PyUntypedArrayMethods,
};
use pyo3::prelude::*;

/// The rows of an (N, 3) float array as `f64` (exact for float32 and float64 input), read through the array's
/// strides: C- or F-ordered and strided arrays are read in place, never copied to a contiguous buffer first.
fn rows_of<T: Element + Copy + Into<f64>>(array: &Bound<'_, PyArray2<T>>, what: &str) -> PyResult<Vec<[f64; 3]>> {
    let readonly = array.try_readonly().map_err(|e| value_error(format!("{what}: cannot read the array: {e}")))?;
    let view = readonly.as_array();
    Ok(view.rows().into_iter().map(|r| [r[0].into(), r[1].into(), r[2].into()]).collect())
}

/// `object` as an (N, 3) float32 or float64 numpy array. Other array-likes (lists, integer arrays) are converted
/// with `numpy.asarray(object, dtype=float64)`; float32 and float64 arrays are used as they are. `what` names the
/// argument in errors.
fn xyz_rows(object: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<[f64; 3]>> {
    let py = object.py();
    let array = if object.cast::<PyArray2<f32>>().is_ok() || object.cast::<PyArray2<f64>>().is_ok() {
        object.clone()
    } else {
        let numpy = py.import("numpy")?;
        let float64 = numpy.getattr("float64")?;
        let kwargs = pyo3::types::PyDict::new(py);
        kwargs.set_item("dtype", float64)?;
        numpy
            .call_method("asarray", (object,), Some(&kwargs))
            .map_err(|e| value_error(format!("{what}: not an array of numbers: {e}")))?
    };
    let untyped = array.cast::<PyUntypedArray>().map_err(|_| value_error(format!("{what}: not a numpy array")))?;
    let shape = untyped.shape().to_vec();
    if shape.len() != 2 || shape[1] != 3 {
        let shape = shape.iter().map(|d| d.to_string()).collect::<Vec<_>>().join(", ");
        return Err(value_error(format!("{what}: expected an array of shape (N, 3), got shape ({shape})")));
    }
    if shape[0] == 0 {
        return Err(value_error(format!("{what}: the array is empty (shape (0, 3))")));
    }
    if let Ok(a) = array.cast::<PyArray2<f32>>() {
        rows_of(a, what)
    } else if let Ok(a) = array.cast::<PyArray2<f64>>() {
        rows_of(a, what)
    } else {
        let dtype = untyped.dtype();
        Err(value_error(format!("{what}: expected float32 or float64 values, got {dtype}")))
    }
}

/// A point cloud from a points array and an optional normals array of the same shape, filtered exactly as the
/// file readers filter a file's points ([`cloud_from_rows`]): rows with a NaN or infinite coordinate (or normal)
/// are dropped, exact zeros as `options.zero_points` says, and `options.origin` is subtracted in `f64`.
pub(crate) fn cloud_from_arrays(
    points: &Bound<'_, PyAny>,
    normals: Option<&Bound<'_, PyAny>>,
    what: &str,
    options: &LoadOptions,
) -> PyResult<(PointCloud, LoadReport)> {
    let points = xyz_rows(points, what)?;
    let normals = normals.map(|n| xyz_rows(n, &format!("{what} normals"))).transpose()?;
    if let Some(n) = &normals
        && n.len() != points.len()
    {
        return Err(value_error(format!("{what}: {} normals for {} points", n.len(), points.len())));
    }
    let with_normals = normals.is_some();
    let rows = points.iter().enumerate().map(|(i, p)| {
        let n = normals.as_ref().map_or([0.0; 3], |n| n[i]);
        [p[0], p[1], p[2], n[0], n[1], n[2]]
    });
    Ok(cloud_from_rows(rows, with_normals, options))
}

/// Positions as an (N, 3) float64 array, with `origin` (a shift subtracted before the computation) added back.
pub(crate) fn positions<'py>(py: Python<'py>, points: &[[f32; 3]], origin: [i64; 3]) -> Bound<'py, PyArray2<f64>> {
    let o = origin.map(|c| c as f64);
    let flat: Vec<f64> = points.iter().flat_map(|p| [0, 1, 2].map(|i| f64::from(p[i]) + o[i])).collect();
    Array2::from_shape_vec((points.len(), 3), flat).expect("3 values per point").into_pyarray(py)
}

/// Unit vectors (normals) as an (N, 3) float64 array.
pub(crate) fn vectors<'py>(py: Python<'py>, vectors: &[[f32; 3]]) -> Bound<'py, PyArray2<f64>> {
    positions(py, vectors, [0; 3])
}

/// A 4x4 matrix as a (4, 4) float64 array.
pub(crate) fn matrix<'py>(py: Python<'py>, m: &nalgebra::Matrix4<f64>) -> Bound<'py, PyArray2<f64>> {
    Array2::from_shape_fn((4, 4), |(r, c)| m[(r, c)]).into_pyarray(py)
}

/// 4x4 poses as an (N, 4, 4) float64 array.
pub(crate) fn matrices<'py>(py: Python<'py>, poses: &[nalgebra::Matrix4<f64>]) -> Bound<'py, PyArray3<f64>> {
    Array3::from_shape_fn((poses.len(), 4, 4), |(k, r, c)| poses[k][(r, c)]).into_pyarray(py)
}

/// Index pairs as a (K, 2) int64 array.
pub(crate) fn index_pairs<'py>(
    py: Python<'py>,
    pairs: impl ExactSizeIterator<Item = [u32; 2]>,
) -> Bound<'py, PyArray2<i64>> {
    let k = pairs.len();
    let flat: Vec<i64> = pairs.flat_map(|p| p.map(i64::from)).collect();
    Array2::from_shape_vec((k, 2), flat).expect("2 values per pair").into_pyarray(py)
}

/// Values as a 1-D float32 array.
pub(crate) fn values<'py>(py: Python<'py>, values: Vec<f32>) -> Bound<'py, PyArray1<f32>> {
    values.into_pyarray(py)
}
