//! `lhmpp_msgs/msg/GaussianAvatar`: an animatable Gaussian avatar (canonical Gaussians in a
//! PointCloud2 plus the skeleton its skinning fields refer to).

use super::message::ros_message;
use super::{Header, Point, PointCloud2};
use serde::{Deserialize, Serialize};

/// `lhmpp_msgs/msg/GaussianAvatar`. The `gaussians` layout is documented in
/// `msg/msg/GaussianAvatar.msg` and built by [`super::GaussianCloud`].
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct GaussianAvatar {
    /// Stamp of the newest view used; canonical frame of the avatar.
    pub header: Header,
    /// Tracked person.
    pub person_id: String,
    /// Rebuild counter, 1 for the first avatar of a person.
    pub revision: u32,
    /// Number of views the reconstruction used.
    pub views_used: u32,
    /// Body model, e.g. `makehuman-cc0` or `smplx`.
    pub body_model: String,
    /// Body shape coefficients of the body model.
    pub shape_params: Vec<f32>,
    /// Spherical-harmonics degree of the colours (0: plain `r g b`).
    pub sh_degree: u8,
    /// Whether the `r g b` fields are colours to display (false: a latent intermediate that
    /// the neural renderer named by `neural_renderer` decodes).
    pub rgb_display_ready: bool,
    /// `<official neural_renderer.type>@<checkpoint>` when the RGB is not display-ready,
    /// else empty.
    pub neural_renderer: String,
    /// Skeleton bone names, indexed by the `bone_*` point fields.
    pub bone_names: Vec<String>,
    /// Parent index of each bone, -1 for the root.
    pub bone_parents: Vec<i32>,
    /// Rest-pose joint position of each bone (metres, canonical frame).
    pub bone_rest_positions: Vec<Point>,
    /// The Gaussians.
    pub gaussians: PointCloud2,
}
ros_message!(
    GaussianAvatar,
    "lhmpp_msgs",
    "GaussianAvatar",
    include_str!("../../msg/msg/GaussianAvatar.msg")
);
