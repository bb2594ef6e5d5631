//! The extension module `dpr_gpu._dpr_gpu`: Python bindings of the dpr-gpu library (numpy arrays in and out).
//! The public Python API is re-exported by `python/dpr_gpu/__init__.py`; the type stubs are in
//! `python/dpr_gpu/_dpr_gpu.pyi`.

mod arrays;
mod described;
mod errors;
mod multiway;
mod pose_graph;
mod registrar;
mod result;
mod settings;
mod state;

use arrays::{positions, vectors};
use dpr_gpu::io::{LoadOptions, OriginShift, XyzColumns, ZeroPoints};
use errors::to_py_err;
use numpy::PyArray2;
use pyo3::prelude::*;
use std::path::PathBuf;

/// An (N, 3) float64 array.
type Points<'py> = Bound<'py, PyArray2<f64>>;

/// Reads a point cloud file (.ply, .pcd, .xyz/.txt/.pts) with the command line's reader.
///
/// Returns ``(points, normals)``: an (N, 3) float64 array of positions and an (N, 3) float64 array of the
/// file's normals, or None when the file has none. Points with a NaN or infinite coordinate (or normal) are
/// dropped; points exactly at (0, 0, 0) are dropped when there are two or more (sensor no-returns; one
/// alone is kept), every one with ``drop_zero_points=True``, none with ``False``. ``xyz_columns`` names the columns of text files (e.g.
/// ``"x,y,z,nx,ny,nz"``); by default columns 4-6 are normals when every row has unit length there. Values pass
/// through float32 as in the library; large (georeferenced) coordinates are read relative to a whole-unit
/// origin and returned with it added back in float64.
///
/// Raises ``OSError`` (``FileNotFoundError``...) when the file cannot be read and ``ValueError`` when its
/// contents or extension are not understood.
#[pyfunction]
#[pyo3(signature = (path, *, drop_zero_points = None, xyz_columns = None))]
fn read_cloud<'py>(
    py: Python<'py>,
    path: PathBuf,
    drop_zero_points: Option<bool>,
    xyz_columns: Option<String>,
) -> PyResult<(Points<'py>, Option<Points<'py>>)> {
    if path.is_dir() {
        return Err(pyo3::exceptions::PyIsADirectoryError::new_err(format!("{}: is a directory", path.display())));
    }
    let xyz_columns = xyz_columns.as_deref().map(XyzColumns::parse).transpose().map_err(to_py_err)?;
    let options =
        LoadOptions { zero_points: ZeroPoints::from_flag(drop_zero_points), xyz_columns, origin: OriginShift::Auto };
    let (cloud, report) = py.detach(|| dpr_gpu::io::read_cloud(&path, &options)).map_err(to_py_err)?;
    let normals = cloud.normals.as_deref().map(|n| vectors(py, n));
    Ok((positions(py, &cloud.points, report.origin), normals))
}

/// dpr-gpu: learned pairwise point-cloud registration (RelativeNet / PPF-FoldNet), numpy in and out.
#[pymodule]
fn _dpr_gpu(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<registrar::Registrar>()?;
    m.add_class::<result::RegistrationResult>()?;
    m.add_class::<result::PoseEstimate>()?;
    m.add_class::<described::DescribedScan>()?;
    // The name `Registrar.describe`'s scans had before they became `DescribedScan`s.
    m.add("Features", m.getattr("DescribedScan")?)?;
    m.add_class::<described::PairResult>()?;
    m.add_class::<multiway::MultiwayResult>()?;
    m.add_function(wrap_pyfunction!(read_cloud, m)?)?;
    m.add_function(wrap_pyfunction!(multiway::multiway_origin, m)?)?;
    m.add_function(wrap_pyfunction!(multiway::select_pairs, m)?)?;
    m.add_function(wrap_pyfunction!(multiway::scan_size, m)?)?;
    m.add_function(wrap_pyfunction!(multiway::choose_radius, m)?)?;
    m.add_function(wrap_pyfunction!(multiway::optimize_pairs, m)?)?;
    m.add_function(wrap_pyfunction!(pose_graph::pose_graph, m)?)?;
    m.add_function(wrap_pyfunction!(described::_described_scan_from_state, m)?)?;
    m.add_function(wrap_pyfunction!(described::_pair_result_from_state, m)?)?;
    m.add_function(wrap_pyfunction!(settings::_library_defaults, m)?)?;
    Ok(())
}
