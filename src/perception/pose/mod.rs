//! From BlazePose's 33 world landmarks to a [`Pose`](crate::body::Pose) of the avatar's
//! skeleton: the live pose of a person seen by a camera.
//!
//! * [`correspondence`]: where each landmark sits on the template (a rig joint, or a small set
//!   of mesh vertices), and [`template_landmarks`], the landmarks of a posed template (ground
//!   truth for synthetic checks, and the rest positions the solver aims with).
//! * [`skeleton_map`]: which bones carry which body segment, for the MakeHuman rig and for
//!   the SMPL-X joints, so the same motion drives either skeleton.
//! * [`ik`]: the solver. Root orientation from hips and shoulders, spine from the shoulder
//!   line, neck and head from ears, eyes, nose and mouth, and per limb the swing of each
//!   segment towards its landmark direction with the twist the data gives (elbow or knee
//!   bend plane, hand plane, foot).
//! * [`limits`]: anatomical joint limits the solver clamps to.
//! * [`one_euro`]: the One-Euro filter (Casiez et al. 2012) on landmark positions.
//! * [`estimator`]: [`PoseEstimator`], the per-person state: filtering, holding the last good
//!   rotation of segments whose landmarks are hidden and easing them back to rest.
//!
//! # Axes
//! World landmarks come in the camera's axes (x right, y down, z away from the camera,
//! metres, origin between the hips). The solver maps them into the canonical frame of
//! [`crate::body`] (+Y up, the person facing +Z, their left at +X) with
//! [`SolverConfig::canonical_from_camera`], by default the half turn about x
//! (`(x, y, z) → (x, −y, −z)`). A person facing the camera therefore gets the identity root
//! rotation: the avatar faces +Z, towards a virtual camera placed on +Z looking back at it
//! (the front view of the synthetic rigs), and their left hand appears on the image's right
//! as in the real camera. A person with their back to the camera gets a half turn about +Y.
//! A tilted camera tilts the avatar unless `canonical_from_camera` includes the tilt.

pub mod correspondence;
mod error;
pub mod estimator;
pub mod ik;
mod limbs;
pub mod limits;
pub mod one_euro;
mod rotation;
mod segment;
pub mod skeleton_map;
mod torso;

pub use correspondence::{template_landmarks, LandmarkAnchor, LandmarkRig};
pub use error::PoseSolveError;
pub use estimator::{PoseEstimator, PoseEstimatorConfig};
pub use ik::{landmarks_to_pose, PoseSolver, SolverConfig};
pub use one_euro::{OneEuroConfig, OneEuroFilter};
pub use segment::{BoneRotations, Segment, SolvedPose};
pub use skeleton_map::{BoneMap, SkeletonKind};
