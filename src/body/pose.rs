//! Body poses: per-bone local rotations by bone name plus a root transform.

use glam::{Quat, Vec3};
use std::collections::HashMap;

/// A body pose in SMPL convention: each rotation is about the bone's joint, expressed in the
/// canonical (rest) frame axes, applied relative to the rest pose; bones not named keep their
/// rest orientation. The root transform is applied last, in world space.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Pose {
    /// Local rotation per bone name.
    pub rotations: HashMap<String, Quat>,
    /// Rotation of the whole body about the root joint (world axes).
    pub root_rotation: Quat,
    /// Translation of the whole body (metres, world axes).
    pub root_translation: Vec3,
}

impl Pose {
    /// The rest pose: no bone rotated, identity root.
    pub fn identity() -> Self {
        Self {
            rotations: HashMap::new(),
            root_rotation: Quat::IDENTITY,
            root_translation: Vec3::ZERO,
        }
    }
}
