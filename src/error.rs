//! The crate's error type: every failure names what went wrong and where.

use std::path::PathBuf;

/// Everything that can go wrong in dpr-gpu. Each variant's message is one line that names the problem.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file involved.
        path: PathBuf,
        /// The underlying I/O error.
        #[source]
        source: std::io::Error,
    },
    /// A file's contents are malformed; `location` is a line (text) or byte offset (binary).
    #[error("{path}: {location}: {message}")]
    Parse {
        /// The file being parsed.
        path: PathBuf,
        /// Where in the file ("line 12", "byte 4096", "header").
        location: String,
        /// What is wrong.
        message: String,
    },
    /// A weights file does not match the expected model (every mismatch is listed).
    #[error("weights {path}: {}", problems.join("; "))]
    Weights {
        /// The weights file (or "<memory>").
        path: String,
        /// One entry per problem: missing, unexpected, wrong dtype or wrong shape tensors.
        problems: Vec<String>,
    },
    /// An argument or input that cannot be processed (empty cloud, bad setting...).
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// The GPU path failed: no adapter, a missing limit or feature, or a device error.
    #[error("GPU: {0}")]
    Gpu(String),
}

/// Shorthand result type.
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// An [`Error::Io`] for `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io { path: path.into(), source }
    }

    /// An [`Error::Parse`] for `path` at `location`.
    pub fn parse(path: impl Into<PathBuf>, location: impl Into<String>, message: impl Into<String>) -> Self {
        Error::Parse { path: path.into(), location: location.into(), message: message.into() }
    }

    /// An [`Error::InvalidInput`].
    pub fn invalid(message: impl Into<String>) -> Self {
        Error::InvalidInput(message.into())
    }
}
