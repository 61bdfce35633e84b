//! The error type of scene IO: every variant names the file and, where there is one, the field.

use std::path::PathBuf;

/// What went wrong while reading or writing a scene.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// A file or directory could not be read or written.
    #[error("{path}: {error}")]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// The underlying error (shown in the message, not repeated as a source).
        error: std::io::Error,
    },
    /// A JSON or TOML file is malformed or lacks a field (the message names the field).
    #[error("{path}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// The parser's message, which names the missing or malformed field.
        message: String,
    },
    /// A field is present but holds an unusable value, or a required field is missing.
    #[error("{path}: field `{field}`: {expected}")]
    Field {
        /// The file.
        path: PathBuf,
        /// The field (dotted path, e.g. `frames[3].particle_path`).
        field: String,
        /// What was expected instead.
        expected: String,
    },
    /// A `.npz` archive could not be read or written (the message names the array).
    #[error("{path}: {message}")]
    Npz {
        /// The archive.
        path: PathBuf,
        /// The npz reader's or writer's message.
        message: String,
    },
    /// A PNG could not be decoded or encoded.
    #[error("{path}: {message}")]
    Image {
        /// The image file.
        path: PathBuf,
        /// What failed.
        message: String,
    },
    /// The scene asks for something it does not have (an unknown view, a frame out of range).
    #[error("{0}")]
    Lookup(String),
}

impl SceneError {
    /// An I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, error: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            error,
        }
    }

    /// A bad or missing field in `path`.
    pub fn field(
        path: impl Into<PathBuf>,
        field: impl Into<String>,
        expected: impl Into<String>,
    ) -> Self {
        Self::Field {
            path: path.into(),
            field: field.into(),
            expected: expected.into(),
        }
    }
}

/// Result alias of scene IO.
pub type Result<T> = std::result::Result<T, SceneError>;
