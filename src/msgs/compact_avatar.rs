//! `lhmpp_msgs/msg/CompactAvatar`: an avatar as a Gaussians blob (SPZ's quantisation) plus a
//! skin blob (built by
//! [`crate::compact::CompactAvatar`]) with the skeleton its bone indices refer to.

use super::message::ros_message;
use super::Header;
use serde::{Deserialize, Serialize};

/// `lhmpp_msgs/msg/CompactAvatar`. The blobs' layouts are documented in
/// `msg/msg/CompactAvatar.msg`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct CompactAvatar {
    /// Stamp of the newest view used; canonical frame of the avatar.
    pub header: Header,
    /// Tracked person.
    pub person_id: String,
    /// Revision of the GaussianAvatar this is the compact form of.
    pub revision: u32,
    /// Number of views the reconstruction used.
    pub views_used: u32,
    /// Body model, e.g. `makehuman-cc0` or `smplx`.
    pub body_model: String,
    /// Body shape coefficients of the body model.
    pub shape_params: Vec<f32>,
    /// Whether the Gaussians' colours are colours to display.
    pub rgb_display_ready: bool,
    /// The neural renderer of a latent-RGB avatar, else empty.
    pub neural_renderer: String,
    /// Skeleton bone names, indexed by the skin blob.
    pub bone_names: Vec<String>,
    /// Parent index of each bone, -1 for the root.
    pub bone_parents: Vec<i32>,
    /// Rest-pose joint position of each bone (metres, canonical frame), `x y z` per bone.
    pub bone_rest_positions: Vec<f32>,
    /// The canonical Gaussians (gzip `LHCA` blob).
    #[serde(with = "serde_bytes")]
    pub gaussians: Vec<u8>,
    /// Bones and weights of each Gaussian (gzip `LHSK` blob).
    #[serde(with = "serde_bytes")]
    pub skin: Vec<u8>,
}
ros_message!(
    CompactAvatar,
    "lhmpp_msgs",
    "CompactAvatar",
    include_str!("../../msg/msg/CompactAvatar.msg")
);
