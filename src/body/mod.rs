//! Body prior: the free CC0 MakeHuman template (mesh, 163-bone rig, skinning weights, part
//! labels), anchor-point sampling, poses and linear blend skinning, and an optional SMPL-X loader.
//!
//! # Canonical frame
//! Every position in this module is in the *canonical frame*: metres, +Y up, the person facing
//! +Z (their left hand towards +X), the origin on the ground plane (y = 0 at the soles) and
//! centred between the feet in x and z (centre of the bounding box of the vertices labelled
//! `foot.L`/`foot.R`).
//!
//! # Canonical pose
//! The template's rest state is the MakeHuman rest **A-pose** (arms down about 45° from the
//! horizontal, legs slightly apart, palms facing the thighs): rest vertices and rest joints are
//! that pose, and a [`Pose`] rotates bones relative to it (`Pose::identity()` is the A-pose).
//! The T-pose is available as the pose spec `tpose` ([`motion::parse_pose_spec`]).
//!
//! The embedded asset `assets/body/makehuman.safetensors` is built by
//! `lhmpp body convert` ([`convert`]); the runtime never reads the MakeHuman source folder.

mod anchors;
pub mod convert;
mod error;
pub mod garment;
mod geometry;
pub mod motion;
mod nearest;
pub mod official;
mod ply;
mod pose;
pub mod raycast;
mod shape;
mod skeleton;
mod skin;
mod smplx;
mod template;

pub use anchors::AnchorPoints;
pub use error::BodyError;
pub use garment::{Garment, GarmentKind, GarmentLibrary, GarmentRegion};
pub use geometry::{generalized_winding_number, point_triangle_distance, vertex_normals};
pub use nearest::PointGrid;
pub use ply::{write_point_ply, PlyScalar};
pub use pose::Pose;
pub use shape::{MakeHumanShape, MAKEHUMAN_SHAPE_RANGE};
pub use skeleton::Skeleton;
pub use skin::{SkinWeights, MAX_INFLUENCES};
pub use smplx::{load_smplx, SMPLX_JOINT_NAMES};
pub use template::{BodyTemplate, DEFAULT_ASSET};

/// Body-model id of avatars bound to the embedded MakeHuman template (PLY comments, messages).
pub const MAKEHUMAN_MODEL_ID: &str = "makehuman-cc0";
