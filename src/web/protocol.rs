//! The live page's WebSocket messages.
//!
//! - An avatar is one binary frame: `LHAV`, a little-endian u32 header length, the JSON header
//!   ([`AvatarHeader`]: person, revision, skeleton, blob sizes), then the compact avatar's
//!   Gaussians blob and its skin blob (`msg/msg/CompactAvatar.msg` describes both).
//! - A pose is a JSON text frame: `{"type":"pose","person","stamp_ns","bones":[names],
//!   "rotations":[[x,y,z,w]],"root_translation":[x,y,z],"root_rotation":[x,y,z,w]}` (local
//!   rotations about each joint in canonical axes, the root transform last about the first
//!   joint, as `lhmpp_msgs/BodyPose`).
//! - A status is a JSON text frame: `{"type":"status","person","revision","views_held",
//!   "state","message","latency_ms"}`.
//!
//! The page sends `drawn` (a text frame) after each frame it draws; poses are sent to it only
//! after that, each person's newest (avatars and statuses go as they come).

use crate::msgs::{BodyPose, ReconstructionStatus};
use serde::Serialize;

/// Magic of an avatar frame.
pub const AVATAR_MAGIC: &[u8; 4] = b"LHAV";

/// The JSON header of an avatar frame.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AvatarHeader {
    /// Person id.
    pub person: String,
    /// Avatar revision.
    pub revision: u64,
    /// Views it was made from.
    pub views_used: usize,
    /// Body model of the skeleton.
    pub body_model: String,
    /// Whether the colours are colours to display.
    pub rgb_display_ready: bool,
    /// Skeleton bone names (the skin's bone indices index them).
    pub bone_names: Vec<String>,
    /// Parent of each bone, -1 for a root.
    pub bone_parents: Vec<i32>,
    /// Rest joint positions, `x y z` per bone.
    pub bone_rest: Vec<f32>,
    /// Bytes of the Gaussians blob after the header.
    pub gaussians_bytes: usize,
    /// Bytes of the skin blob after it.
    pub skin_bytes: usize,
}

/// The binary frame of an avatar.
pub fn avatar_frame(header: &AvatarHeader, gaussians: &[u8], skin: &[u8]) -> Vec<u8> {
    let json = serde_json::to_vec(header).expect("a header serialises");
    let mut frame = Vec::with_capacity(8 + json.len() + gaussians.len() + skin.len());
    frame.extend_from_slice(AVATAR_MAGIC);
    frame.extend_from_slice(&(json.len() as u32).to_le_bytes());
    frame.extend_from_slice(&json);
    frame.extend_from_slice(gaussians);
    frame.extend_from_slice(skin);
    frame
}

/// The JSON of `person`'s pose.
pub fn pose_json(person: &str, pose: &BodyPose) -> String {
    let q = |q: &crate::msgs::Quaternion| [q.x, q.y, q.z, q.w];
    let t = pose.root.translation;
    serde_json::json!({
        "type": "pose",
        "person": person,
        "stamp_ns": pose.header.stamp.as_nanos(),
        "bones": pose.bone_names,
        "rotations": pose.rotations.iter().map(q).collect::<Vec<_>>(),
        "root_translation": [t.x, t.y, t.z],
        "root_rotation": q(&pose.root.rotation),
    })
    .to_string()
}

/// The JSON of a status.
pub fn status_json(status: &ReconstructionStatus) -> String {
    serde_json::json!({
        "type": "status",
        "person": status.person_id,
        "revision": status.revision,
        "views_held": status.views_held,
        "state": status.state,
        "message": status.message,
        "latency_ms": status.last_latency_ms,
    })
    .to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_avatar_frame_is_magic_length_header_then_the_blobs() {
        let header = AvatarHeader {
            person: "p".into(),
            revision: 2,
            views_used: 3,
            body_model: "m".into(),
            rgb_display_ready: true,
            bone_names: vec!["root".into()],
            bone_parents: vec![-1],
            bone_rest: vec![0.0, 1.0, 0.0],
            gaussians_bytes: 2,
            skin_bytes: 1,
        };
        let frame = avatar_frame(&header, &[7, 8], &[9]);
        assert_eq!(&frame[..4], b"LHAV");
        let len = u32::from_le_bytes(frame[4..8].try_into().unwrap()) as usize;
        let json: serde_json::Value = serde_json::from_slice(&frame[8..8 + len]).unwrap();
        assert_eq!(json["person"], "p");
        assert_eq!(json["bone_rest"][1], 1.0);
        assert_eq!(&frame[8 + len..], &[7, 8, 9]);
    }

    #[test]
    fn a_pose_lists_bones_with_xyzw_rotations() {
        let mut pose = BodyPose {
            person_id: "p".into(),
            bone_names: vec!["spine".into()],
            rotations: vec![crate::msgs::Quaternion {
                x: 0.0,
                y: 0.0,
                z: 0.6,
                w: 0.8,
            }],
            ..Default::default()
        };
        pose.root.translation.x = 1.5;
        let json: serde_json::Value = serde_json::from_str(&pose_json("p", &pose)).unwrap();
        assert_eq!(json["bones"][0], "spine");
        assert_eq!(json["rotations"][0][2], 0.6);
        assert_eq!(json["root_translation"][0], 1.5);
        assert_eq!(json["root_rotation"][3], 1.0, "the identity by default");
    }
}
