//! `lhmpp_msgs/msg/BodyPose`: bone rotations by name plus a root transform, and conversion to
//! and from the crate's [`crate::body::Pose`].

use super::message::ros_message;
use super::{Header, Quaternion, Transform};
use crate::body;
use glam::Quat;
use serde::{Deserialize, Serialize};

/// `lhmpp_msgs/msg/BodyPose`. `bone_names[i]` is rotated by `rotations[i]`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct BodyPose {
    /// Time the pose holds for; world frame of `root`.
    pub header: Header,
    /// Tracked person.
    pub person_id: String,
    /// Posed bones.
    pub bone_names: Vec<String>,
    /// Local rotation per bone, same order as `bone_names`.
    pub rotations: Vec<Quaternion>,
    /// Root rotation and translation in world axes.
    pub root: Transform,
}
ros_message!(
    BodyPose,
    "lhmpp_msgs",
    "BodyPose",
    include_str!("../../msg/msg/BodyPose.msg")
);

impl BodyPose {
    /// The message of a pose; bones are listed in name order so equal poses give equal bytes.
    pub fn from_pose(header: Header, person_id: impl Into<String>, pose: &body::Pose) -> Self {
        let mut bones: Vec<(&String, &Quat)> = pose.rotations.iter().collect();
        bones.sort_by(|a, b| a.0.cmp(b.0));
        Self {
            header,
            person_id: person_id.into(),
            bone_names: bones.iter().map(|(n, _)| (*n).clone()).collect(),
            rotations: bones.iter().map(|(_, q)| Quaternion::from(**q)).collect(),
            root: Transform {
                translation: pose.root_translation.into(),
                rotation: pose.root_rotation.into(),
            },
        }
    }

    /// The pose this message describes. Fails when names and rotations differ in number.
    pub fn to_pose(&self) -> Result<body::Pose, super::MsgError> {
        if self.bone_names.len() != self.rotations.len() {
            return Err(super::MsgError::Inconsistent(format!(
                "BodyPose of `{}`: {} bone names but {} rotations",
                self.person_id,
                self.bone_names.len(),
                self.rotations.len()
            )));
        }
        Ok(body::Pose {
            rotations: self
                .bone_names
                .iter()
                .cloned()
                .zip(self.rotations.iter().map(|q| Quat::from(*q)))
                .collect(),
            root_rotation: self.root.rotation.into(),
            root_translation: self.root.translation.into(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn pose_survives_the_message_round_trip() {
        let mut pose = body::Pose::identity();
        pose.rotations
            .insert("spine".into(), Quat::from_rotation_x(0.5));
        pose.rotations
            .insert("head".into(), Quat::from_rotation_y(-0.25));
        pose.root_translation = Vec3::new(1.0, 2.0, 3.0);
        pose.root_rotation = Quat::from_rotation_z(0.1);
        let msg = BodyPose::from_pose(Header::default(), "p1", &pose);
        assert_eq!(msg.bone_names, vec!["head", "spine"]);
        let back = msg.to_pose().unwrap();
        assert_eq!(back, pose);
    }

    #[test]
    fn mismatched_names_and_rotations_are_rejected() {
        let msg = BodyPose {
            bone_names: vec!["a".into()],
            ..Default::default()
        };
        assert!(msg.to_pose().is_err());
    }
}
