//! `geometry_msgs`: vectors, points, quaternions, poses and transforms (float64), with
//! conversions to and from `glam`.

use super::message::ros_message;
use super::Header;
use glam::{DQuat, DVec3, Quat, Vec3};
use serde::{Deserialize, Serialize};

/// `geometry_msgs/msg/Vector3`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Vector3 {
    /// X component.
    pub x: f64,
    /// Y component.
    pub y: f64,
    /// Z component.
    pub z: f64,
}
ros_message!(
    Vector3,
    "geometry_msgs",
    "Vector3",
    include_str!("defs/geometry_msgs/Vector3.msg")
);

/// `geometry_msgs/msg/Point`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Point {
    /// X coordinate.
    pub x: f64,
    /// Y coordinate.
    pub y: f64,
    /// Z coordinate.
    pub z: f64,
}
ros_message!(
    Point,
    "geometry_msgs",
    "Point",
    include_str!("defs/geometry_msgs/Point.msg")
);

/// `geometry_msgs/msg/Quaternion`; the default is the identity, as in the `.msg` (w = 1).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    /// X component.
    pub x: f64,
    /// Y component.
    pub y: f64,
    /// Z component.
    pub z: f64,
    /// W (scalar) component.
    pub w: f64,
}
ros_message!(
    Quaternion,
    "geometry_msgs",
    "Quaternion",
    include_str!("defs/geometry_msgs/Quaternion.msg")
);

impl Default for Quaternion {
    fn default() -> Self {
        Self {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }
    }
}

/// `geometry_msgs/msg/Pose` (named apart from the body pose, [`crate::body::Pose`]; serde
/// keeps the message's name).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(rename = "Pose")]
pub struct GeometryPose {
    /// Position.
    pub position: Point,
    /// Orientation.
    pub orientation: Quaternion,
}
ros_message!(
    GeometryPose,
    "geometry_msgs",
    "Pose",
    include_str!("defs/geometry_msgs/Pose.msg")
);

/// `geometry_msgs/msg/Transform`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Transform {
    /// Translation.
    pub translation: Vector3,
    /// Rotation.
    pub rotation: Quaternion,
}
ros_message!(
    Transform,
    "geometry_msgs",
    "Transform",
    include_str!("defs/geometry_msgs/Transform.msg")
);

/// `geometry_msgs/msg/TransformStamped`: the pose of `child_frame_id` in `header.frame_id`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct TransformStamped {
    /// Stamp and parent frame.
    pub header: Header,
    /// Frame the transform points to.
    pub child_frame_id: String,
    /// Child frame in the parent frame.
    pub transform: Transform,
}
ros_message!(
    TransformStamped,
    "geometry_msgs",
    "TransformStamped",
    include_str!("defs/geometry_msgs/TransformStamped.msg")
);

impl From<Vec3> for Vector3 {
    fn from(v: Vec3) -> Self {
        Self {
            x: v.x as f64,
            y: v.y as f64,
            z: v.z as f64,
        }
    }
}

impl From<Vector3> for Vec3 {
    fn from(v: Vector3) -> Self {
        DVec3::new(v.x, v.y, v.z).as_vec3()
    }
}

impl From<Vec3> for Point {
    fn from(v: Vec3) -> Self {
        Self {
            x: v.x as f64,
            y: v.y as f64,
            z: v.z as f64,
        }
    }
}

impl From<Point> for Vec3 {
    fn from(p: Point) -> Self {
        DVec3::new(p.x, p.y, p.z).as_vec3()
    }
}

impl From<Quat> for Quaternion {
    fn from(q: Quat) -> Self {
        Self {
            x: q.x as f64,
            y: q.y as f64,
            z: q.z as f64,
            w: q.w as f64,
        }
    }
}

impl From<Quaternion> for Quat {
    fn from(q: Quaternion) -> Self {
        DQuat::from_xyzw(q.x, q.y, q.z, q.w).as_quat()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_quaternion_is_identity_like_the_msg_default() {
        assert_eq!(Quat::from(Quaternion::default()), Quat::IDENTITY);
    }

    #[test]
    fn glam_quaternion_components_keep_their_names() {
        let q = Quat::from_xyzw(0.1, 0.2, 0.3, 0.9);
        let m = Quaternion::from(q);
        assert_eq!(
            (m.x as f32, m.y as f32, m.z as f32, m.w as f32),
            (0.1, 0.2, 0.3, 0.9)
        );
    }
}
