//! The synchronous "frames → avatar" API, independent of ROS: decode camera images
//! ([`image_decode`]), crop and resize them around the person ([`preprocess`]), check body
//! shapes against the body model ([`shape`]) and turn a set of views into an animatable
//! [`Avatar`](crate::avatar::Avatar) with the network ([`Reconstructor`]).
//!
//! The node (`crate::node`), the held-out evaluation (`crate::eval`), the synthetic data sets
//! and the official-checkpoint tests all reconstruct through this module. [`part_rules`]
//! applies the official decoder's per-part rules to avatars made on the SMPL-X prior.
//! [`photos`] is the photos → masked views → avatar → front render path of `lhmpp avatar` and
//! `lhmpp eval-photos` (camera-only perception for the masks and poses).

pub mod delight;
pub mod head_fit;
pub mod image_decode;
pub mod landmark_warp;
pub mod part_rules;
pub mod photo_camera;
pub mod photo_colours;
pub mod photos;
pub mod preprocess;
pub mod reconstructor;
pub mod shape;
pub mod surface;

pub use part_rules::apply_part_rules;
pub use reconstructor::{select_device, ReconstructError, Reconstructor};
