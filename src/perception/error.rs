//! Errors of the perception networks and their inputs.

use std::path::PathBuf;

/// Why a perception network could not be loaded or run.
#[derive(Debug, thiserror::Error)]
pub enum PerceptionError {
    /// A weights file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A weights file or graph is malformed; `origin` names it.
    #[error("{origin}: {reason}")]
    Format {
        /// File or embedded asset name.
        origin: String,
        /// What is wrong.
        reason: String,
    },
    /// Weights that are not shipped with the binary and have not been produced yet.
    #[error("{what}: no weights file at {path}; produce it with: {command}")]
    MissingWeights {
        /// The network.
        what: String,
        /// Where the file was looked for.
        path: PathBuf,
        /// The commands that produce it.
        command: String,
    },
    /// An input has the wrong size.
    #[error("{what}: expected {expected}, got {got}")]
    Input {
        /// The input.
        what: String,
        /// Expected size or shape.
        expected: String,
        /// Given size or shape.
        got: String,
    },
}

impl PerceptionError {
    /// A format error for `origin`.
    pub fn format(origin: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::Format {
            origin: origin.into(),
            reason: reason.into(),
        }
    }
}
