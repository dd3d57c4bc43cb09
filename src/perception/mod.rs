//! Camera-only perception: finds the person in a frame, segments them and reads their 33 body
//! landmarks, with MediaPipe's BlazePose networks (Apache-2.0, converted once into
//! `assets/perception/`) run on the crate's CPU kernels.
//!
//! Per camera (one person): a detector runs only while no person is tracked (MoveNet
//! MultiPose by default, choosing whom to follow by [`follow`]; or BlazePose's own); a tracked
//! person's region of interest comes from the previous frame's landmarks. The landmark model
//! reads a rotated square crop around the person and gives image landmarks, world landmarks
//! (metres, hip-centred) and a segmentation mask, which are mapped back into the frame.
//!
//! Several people at once: [`multipose`] runs MoveNet MultiPose Lightning (Apache-2.0), which
//! splits a frame into up to six person instances with 17 keypoints each; [`people`] reads
//! each of them with the landmark model (landmarks and a mask per person).
//!
//! Perception imports the CPU kernels and the body template, never the avatar network
//! (`tests/module_layers.rs`).

pub mod crop;
pub mod detection;
mod error;
pub mod follow;
pub mod landmark;
pub mod landmarks;
pub mod looks;
pub mod multipose;
pub mod network;
pub mod nobody;
pub mod overlay;
pub mod people;
pub mod pose;
pub mod pose_networks;
pub mod roi;
pub mod segmentation;
pub mod shape;
pub mod tracker;
pub mod weights;

pub use error::PerceptionError;
pub use landmark::{Landmark, LandmarkId, BODY_LANDMARKS};
pub use multipose::{MultiPoseDetector, PersonInstance};
pub use network::{Network, NetworkOutputs};
pub use people::{FoundPerson, PeopleConfig, PeopleFinder};
pub use pose_networks::PoseNetworks;
pub use tracker::{Detected, Perceived, PersonDetector, PersonTracker, TrackerConfig};
pub use weights::LandmarkModel;
