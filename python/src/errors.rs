//! Library errors as Python exceptions: the exception class says what kind of failure it is, the message is the
//! library's own.

use dpr_gpu::Error;
use pyo3::PyErr;
use pyo3::exceptions::{
    PyFileNotFoundError, PyIsADirectoryError, PyOSError, PyPermissionError, PyRuntimeError, PyValueError,
};
use std::io::ErrorKind;

/// `OSError` (or its subclass for the I/O error kind) for files that cannot be read, `ValueError` for bad input
/// (malformed files, weights that do not fit, bad settings or arrays), `RuntimeError` for the GPU.
pub(crate) fn to_py_err(e: Error) -> PyErr {
    let message = e.to_string();
    match &e {
        Error::Io { source, .. } => match source.kind() {
            ErrorKind::NotFound => PyFileNotFoundError::new_err(message),
            ErrorKind::PermissionDenied => PyPermissionError::new_err(message),
            ErrorKind::IsADirectory => PyIsADirectoryError::new_err(message),
            _ => PyOSError::new_err(message),
        },
        Error::Parse { .. } | Error::Weights { .. } | Error::InvalidInput(_) => PyValueError::new_err(message),
        Error::Gpu(_) => PyRuntimeError::new_err(message),
    }
}

/// A `ValueError` with `message`.
pub(crate) fn value_error(message: impl Into<String>) -> PyErr {
    PyValueError::new_err(message.into())
}
