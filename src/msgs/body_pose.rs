//! `lhmpp_msgs/msg/BodyPose`: bone rotations by name plus a root transform, and conversion to
//! and from the crate's [`crate::body::Pose`].

use super::message::ros_message;
use super::{Header, Quaternion, Transform};
use crate::body;
use glam::Quat;
use serde::{Deserialize, Serialize};

/// How far a rotation's squared norm may be from 1: tf2's
/// `QUATERNION_NORMALIZATION_TOLERANCE` (`10e-3`), which tf2 applies to every transform it is
/// given.
pub const UNIT_QUATERNION_TOLERANCE: f64 = 10e-3;

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

    /// The pose this message describes. Fails when names and rotations differ in number, when
    /// a value is not finite (NaN, infinite, or beyond `f32`), or when a rotation is not a unit
    /// quaternion: its squared norm must be within [`UNIT_QUATERNION_TOLERANCE`] of 1, as tf2
    /// requires of transforms. The error names the person, the bone and the values.
    pub fn to_pose(&self) -> Result<body::Pose, super::MsgError> {
        let bad = |what: String| {
            super::MsgError::Inconsistent(format!("BodyPose of `{}`: {what}", self.person_id))
        };
        if self.bone_names.len() != self.rotations.len() {
            return Err(bad(format!(
                "{} bone names but {} rotations",
                self.bone_names.len(),
                self.rotations.len()
            )));
        }
        let rotations = self
            .bone_names
            .iter()
            .map(|n| format!("rotation of bone `{n}`"))
            .zip(&self.rotations)
            .chain(std::iter::once((
                "root rotation".to_string(),
                &self.root.rotation,
            )));
        for (what, q) in rotations {
            let (x, y, z, w) = (q.x, q.y, q.z, q.w);
            let finite = [x, y, z, w].iter().all(|v| (*v as f32).is_finite());
            if !finite {
                return Err(bad(format!(
                    "{what} (x {x}, y {y}, z {z}, w {w}) is not finite"
                )));
            }
            let norm2 = x * x + y * y + z * z + w * w;
            if (norm2 - 1.0).abs() > UNIT_QUATERNION_TOLERANCE {
                return Err(bad(format!(
                    "{what} (x {x}, y {y}, z {z}, w {w}) is not a unit quaternion: squared \
                     norm {norm2} is not within {UNIT_QUATERNION_TOLERANCE} of 1"
                )));
            }
        }
        let t = self.root.translation;
        if ![t.x, t.y, t.z].iter().all(|v| (*v as f32).is_finite()) {
            return Err(bad(format!(
                "root translation (x {}, y {}, z {}) is not finite",
                t.x, t.y, t.z
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

    #[test]
    fn nan_infinite_and_non_unit_values_are_rejected_naming_the_bone_and_values() {
        let pose = |q: Quaternion| BodyPose {
            person_id: "p1".into(),
            bone_names: vec!["spine".into()],
            rotations: vec![q],
            ..Default::default()
        };
        let q = |x, y, z, w| Quaternion { x, y, z, w };
        let e = pose(q(f64::NAN, 0.0, 0.0, 1.0)).to_pose().unwrap_err();
        let e = e.to_string();
        assert!(
            e.contains("`p1`") && e.contains("bone `spine`") && e.contains("NaN"),
            "{e}"
        );
        assert!(e.contains("not finite"), "{e}");
        let e = pose(q(0.0, 0.0, 0.0, 2.0))
            .to_pose()
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("bone `spine`") && e.contains("squared norm 4") && e.contains("unit"),
            "{e}"
        );
        let e = pose(q(0.0, 0.0, 0.0, 0.0))
            .to_pose()
            .unwrap_err()
            .to_string();
        assert!(e.contains("squared norm 0"), "{e}");
        // Beyond f32: infinite once converted.
        let e = pose(q(1e300, 0.0, 0.0, 1.0))
            .to_pose()
            .unwrap_err()
            .to_string();
        assert!(e.contains("not finite"), "{e}");
        // Within tf2's tolerance: accepted as it is.
        assert!(pose(q(0.0, 0.0, 0.0, 1.004)).to_pose().is_ok());
        let mut root = pose(Quaternion::default());
        root.root.rotation = q(0.0, 0.0, 0.5, 0.5);
        let e = root.to_pose().unwrap_err().to_string();
        assert!(e.contains("root rotation") && e.contains("0.5"), "{e}");
        let mut moved = pose(Quaternion::default());
        moved.root.translation.y = f64::INFINITY;
        let e = moved.to_pose().unwrap_err().to_string();
        assert!(e.contains("root translation") && e.contains("inf"), "{e}");
    }
}
