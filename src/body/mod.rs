//! Body prior: the free CC0 MakeHuman template (mesh, 163-bone rig, skinning weights, part
//! labels), anchor-point sampling, poses and linear blend skinning, and an optional SMPL-X loader.

mod pose;
mod skin;

pub use pose::Pose;
pub use skin::{SkinWeights, MAX_INFLUENCES};
