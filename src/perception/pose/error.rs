//! Errors of the pose solver's set-up.

use crate::body::BodyError;

/// Why a pose solver could not be built for a template.
#[derive(Debug, thiserror::Error)]
pub enum PoseSolveError {
    /// The skeleton is neither the MakeHuman rig nor SMPL-X.
    #[error(
        "skeleton is neither the MakeHuman rig (no bone `upperarm01.L`) nor SMPL-X (no joint `left_shoulder`)"
    )]
    UnknownSkeleton,
    /// A bone the skeleton family needs is missing.
    #[error("{skeleton} skeleton lacks bone `{bone}`")]
    MissingBone {
        /// Skeleton family.
        skeleton: &'static str,
        /// The missing bone.
        bone: String,
    },
    /// No template vertex matches the rule placing a landmark.
    #[error("no template vertex for landmark `{landmark}`: {reason}")]
    NoVertices {
        /// The landmark's name.
        landmark: &'static str,
        /// What was looked for.
        reason: String,
    },
    /// The reference MakeHuman template could not be loaded.
    #[error(transparent)]
    Body(#[from] BodyError),
}
