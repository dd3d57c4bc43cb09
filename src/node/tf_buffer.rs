//! The newest transform of every TF frame (`/tf` and `/tf_static`), looked up along the frame
//! tree: where each camera's optical frame is in the world frame, for reading the body shape
//! from calibrated views. No interpolation in time: the newest transform of each frame counts
//! (cameras of a calibrated rig are static or slow).

use crate::msgs::TransformStamped;
use glam::{Affine3A, Quat, Vec3};
use std::collections::HashMap;

/// Frames a lookup climbs through at most (a guard against cycles in bad trees).
const MAX_DEPTH: usize = 32;
/// Frames kept at most; a new frame beyond it is ignored (memory stays bounded).
const MAX_FRAMES: usize = 1024;

/// The newest transform of each child frame to its parent.
#[derive(Debug, Default, Clone)]
pub struct TfBuffer {
    /// child frame → (parent frame, parent_from_child).
    frames: HashMap<String, (String, Affine3A)>,
}

impl TfBuffer {
    /// Records transforms (newer ones replace older ones of the same child frame). Transforms
    /// that are not finite are ignored.
    pub fn insert(&mut self, transforms: &[TransformStamped]) {
        for t in transforms {
            let q: Quat = t.transform.rotation.into();
            let p: Vec3 = t.transform.translation.into();
            if !(q.is_finite() && p.is_finite()) || q.length_squared() < 1e-12 {
                continue;
            }
            let child = t.child_frame_id.trim_start_matches('/').to_owned();
            if !self.frames.contains_key(&child) && self.frames.len() >= MAX_FRAMES {
                continue;
            }
            let parent = t.header.frame_id.trim_start_matches('/').to_owned();
            self.frames.insert(
                child,
                (
                    parent,
                    Affine3A::from_rotation_translation(q.normalize(), p),
                ),
            );
        }
    }

    /// `target_from_source`: where frame `source` is in frame `target`, when both are on one
    /// branch of the tree with `target` above `source` (or equal).
    pub fn lookup(&self, target: &str, source: &str) -> Option<Affine3A> {
        let target = target.trim_start_matches('/');
        let mut frame = source.trim_start_matches('/');
        let mut acc = Affine3A::IDENTITY;
        for _ in 0..MAX_DEPTH {
            if frame == target {
                return Some(acc);
            }
            let (parent, parent_from_child) = self.frames.get(frame)?;
            acc = *parent_from_child * acc;
            frame = parent;
        }
        None
    }

    /// Frames known.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Whether no frame is known.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::{Header, Quaternion, Time, Transform, Vector3};

    fn t(parent: &str, child: &str, x: f64, yaw: f64) -> TransformStamped {
        let (s, c) = (yaw / 2.0).sin_cos();
        TransformStamped {
            header: Header::new(Time::from_nanos(0), parent),
            child_frame_id: child.into(),
            transform: Transform {
                translation: Vector3 { x, y: 0.0, z: 0.0 },
                rotation: Quaternion {
                    x: 0.0,
                    y: 0.0,
                    z: s,
                    w: c,
                },
            },
        }
    }

    #[test]
    fn lookups_compose_along_the_tree() {
        let mut tf = TfBuffer::default();
        tf.insert(&[
            t("world", "rig", 1.0, std::f64::consts::FRAC_PI_2),
            t("rig", "cam0_optical_frame", 2.0, 0.0),
        ]);
        let world_from_cam = tf.lookup("world", "cam0_optical_frame").unwrap();
        // 2 m along the rig's x, which is the world's y, from the rig at x = 1.
        let origin = world_from_cam.transform_point3(Vec3::ZERO);
        assert!(
            origin.abs_diff_eq(Vec3::new(1.0, 2.0, 0.0), 1e-6),
            "{origin}"
        );
        assert!(tf.lookup("world", "/world").is_some());
        assert!(tf.lookup("world", "nowhere").is_none());
        assert!(tf.lookup("cam0_optical_frame", "world").is_none());
    }

    #[test]
    fn newer_transforms_replace_older_ones_and_cycles_end() {
        let mut tf = TfBuffer::default();
        tf.insert(&[t("world", "a", 1.0, 0.0)]);
        tf.insert(&[t("world", "a", 5.0, 0.0)]);
        let p = tf
            .lookup("world", "a")
            .unwrap()
            .transform_point3(Vec3::ZERO);
        assert!((p.x - 5.0).abs() < 1e-6);
        tf.insert(&[t("b", "c", 0.0, 0.0), t("c", "b", 0.0, 0.0)]);
        assert!(tf.lookup("world", "b").is_none());
        assert_eq!(tf.len(), 3);
    }
}
