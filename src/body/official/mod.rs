//! The body prior of the official LHM++ checkpoints, loaded from the user's `LHMPP-Prior`
//! download (SMPL-X licence terms): the SMPL-X neutral model, the 160K canonical query points
//! (`dense_sample_points/1_160000.ply`) and the diffused skinning volume
//! (`voxel_grid/cano_1_volume.npz`).
//!
//! The official pipeline (reference §1.3(c), (g)): the query points are stored in the SMPL-X
//! zero pose; they are posed into the canonical "neutral" pose (hips ±π/9) with the skinning
//! weights of their nearest template vertex and fed to the network with the normals of that
//! vertex. Gaussians predicted in the neutral pose are taken back to the zero pose with the
//! weights of the diffused volume at their predicted positions (hands and head keep the
//! nearest-vertex weights; the 55 dense weights are reduced to the strongest 4) and then
//! posed by SMPL-X forward kinematics. Here the zero pose is the rest pose of the SMPL-X
//! [`BodyTemplate`](crate::body::BodyTemplate), so avatars bound to it animate with
//! [`Pose`](crate::body::Pose)s named by [`SMPLX_JOINT_NAMES`](crate::body::SMPLX_JOINT_NAMES).
//!
//! Differences from the official code, all for lack of files the prior does not need here:
//! hand and face points are those whose nearest vertex is dominated by a wrist/finger or a
//! head/jaw/eye joint (the official masks come from the MANO and FLAME vertex-id files);
//! skinning rows keep the strongest 4 of the 55 joints; betas and FLAME expressions are not
//! applied when posing (zero-shape template).
//!
//! The free MakeHuman template stays the default body for every other model.

mod ply_points;
mod prior;
mod volume;

pub use ply_points::read_ply_points;
pub use prior::{
    neutral_pose, OfficialPrior, PriorPaths, SkinRow, BODY_FACE_RATIO, NEUTRAL_HIP_ANGLE,
    POINTS_FILE, SMPLX_FILE, SMPLX_MODEL_ID, UPPER_BODY_JOINTS, VOLUME_FILE,
};
pub use volume::BlendWeightVolume;
