//! Errors of the renderer and of the safetensors files it reads and writes (weights; the
//! reference cases of the developer tools).

use std::path::PathBuf;

/// Everything that can go wrong in this crate; messages name the file, the field and what was
/// expected.
#[derive(Debug, thiserror::Error)]
pub enum PhysNerfError {
    /// A file could not be read or written.
    #[error("{path}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A safetensors file is malformed.
    #[error("{path}: not a valid safetensors file: {message}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A tensor the reader needs is absent.
    #[error("{path}: tensor `{name}` is missing ({expected})")]
    Missing {
        /// The file.
        path: PathBuf,
        /// The tensor name.
        name: String,
        /// What was expected.
        expected: String,
    },
    /// A tensor has the wrong shape or dtype.
    #[error("{path}: tensor `{name}`: expected {expected}, found {found}")]
    Mismatch {
        /// The file.
        path: PathBuf,
        /// The tensor name.
        name: String,
        /// What was expected.
        expected: String,
        /// What the file holds.
        found: String,
    },
    /// A weight file holds tensors the network does not have.
    #[error("{path}: unexpected tensors {names:?} (the network has no such parameters)")]
    Unexpected {
        /// The file.
        path: PathBuf,
        /// The unknown names.
        names: Vec<String>,
    },
    /// A metadata entry is missing or malformed.
    #[error("{path}: metadata `{field}`: {message}")]
    Metadata {
        /// The file.
        path: PathBuf,
        /// The metadata key.
        field: String,
        /// What is wrong.
        message: String,
    },
    /// Invalid configuration or call arguments.
    #[error("invalid input: {0}")]
    Invalid(String),
    /// Reading a tensor back from the device failed.
    #[error("tensor read-back failed: {0}")]
    Readback(String),
    /// An image could not be written.
    #[error("{path}: cannot write the image: {message}")]
    Image {
        /// The file.
        path: PathBuf,
        /// The cause.
        message: String,
    },
}

impl PhysNerfError {
    /// An IO error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            source,
        }
    }
}

/// Result alias of this crate.
pub type Result<T> = std::result::Result<T, PhysNerfError>;
