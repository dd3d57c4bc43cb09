//! The one error type of the body module.

use std::path::PathBuf;

/// A body-template, pose or conversion problem; messages name the offending file, key or bone.
#[derive(Debug, thiserror::Error)]
pub enum BodyError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// File that failed.
        path: PathBuf,
        /// Underlying I/O error.
        source: std::io::Error,
    },
    /// A file's content is malformed (bad JSON, OBJ line, tensor shape, metadata...).
    #[error("{origin}: {message}")]
    Format {
        /// File (or embedded asset) that is malformed.
        origin: String,
        /// What is wrong with it.
        message: String,
    },
    /// A required key (tensor, metadata entry, JSON field) is missing.
    #[error("{origin}: missing key `{key}`")]
    MissingKey {
        /// File that lacks the key.
        origin: String,
        /// The key that is missing.
        key: String,
    },
    /// A pose names bones the skeleton does not have.
    #[error("pose names unknown bones: {}", .0.join(", "))]
    UnknownBones(Vec<String>),
    /// A pose spec string could not be parsed.
    #[error("pose spec `{spec}`: {message}")]
    PoseSpec {
        /// The spec as given.
        spec: String,
        /// What is wrong with it.
        message: String,
    },
}

impl BodyError {
    /// A [`BodyError::Format`] for `origin`.
    pub(crate) fn format(origin: impl std::fmt::Display, message: impl Into<String>) -> Self {
        Self::Format {
            origin: origin.to_string(),
            message: message.into(),
        }
    }

    /// A [`BodyError::MissingKey`] for `origin`.
    pub(crate) fn missing(origin: impl std::fmt::Display, key: impl Into<String>) -> Self {
        Self::MissingKey {
            origin: origin.to_string(),
            key: key.into(),
        }
    }

    /// A [`BodyError::Io`] for `path`.
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            source,
        }
    }
}
