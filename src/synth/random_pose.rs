//! Seeded random body poses within joint limits (`lhmpp synth --pose random`): each limited
//! bone gets independent uniform angles about the canonical X, Y and Z axes inside its range,
//! composed as `Rz · Ry · Rx` (glam's `EulerRot::ZYX`); other bones keep their rest pose.
//!
//! Angles follow the gait's conventions ([`crate::body::motion::gait`]): canonical axes (+Y up,
//! person facing +Z, their left at +X); flexing a hanging segment forward is a negative
//! rotation about +X; moving the left leg or arm outwards is a positive rotation about +Z.
//! Ranges stay well inside the human range of motion, so every pose looks natural.

use crate::body::{motion, BodyTemplate, Pose};
use glam::{EulerRot, Quat};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Allowed angles of one bone, degrees about the canonical X, Y and Z axes (`[min, max]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointLimit {
    /// Bone name in the template's skeleton.
    pub bone: &'static str,
    /// Range about X (flexion / extension).
    pub x: [f32; 2],
    /// Range about Y (twist).
    pub y: [f32; 2],
    /// Range about Z (abduction / side bend).
    pub z: [f32; 2],
}

const fn limit(bone: &'static str, x: [f32; 2], y: [f32; 2], z: [f32; 2]) -> JointLimit {
    JointLimit { bone, x, y, z }
}

/// The bones a random pose moves and their ranges (degrees).
pub const JOINT_LIMITS: &[JointLimit] = &[
    limit("spine03", [-10.0, 15.0], [-15.0, 15.0], [-8.0, 8.0]),
    limit("neck01", [-10.0, 15.0], [-20.0, 20.0], [-8.0, 8.0]),
    limit("head", [-10.0, 10.0], [-20.0, 20.0], [-8.0, 8.0]),
    limit("upperleg01.L", [-50.0, 15.0], [-15.0, 15.0], [-5.0, 25.0]),
    limit("upperleg01.R", [-50.0, 15.0], [-15.0, 15.0], [-25.0, 5.0]),
    limit("lowerleg01.L", [0.0, 70.0], [0.0, 0.0], [0.0, 0.0]),
    limit("lowerleg01.R", [0.0, 70.0], [0.0, 0.0], [0.0, 0.0]),
    limit("foot.L", [-15.0, 15.0], [0.0, 0.0], [0.0, 0.0]),
    limit("foot.R", [-15.0, 15.0], [0.0, 0.0], [0.0, 0.0]),
    limit("upperarm01.L", [-45.0, 45.0], [-20.0, 20.0], [-20.0, 30.0]),
    limit("upperarm01.R", [-45.0, 45.0], [-20.0, 20.0], [-30.0, 20.0]),
    limit("lowerarm01.L", [-70.0, 0.0], [0.0, 0.0], [0.0, 0.0]),
    limit("lowerarm01.R", [-70.0, 0.0], [0.0, 0.0], [0.0, 0.0]),
];

impl JointLimit {
    /// Whether `rotation` decomposes (ZYX) into angles inside this limit, allowing
    /// `tolerance_deg` for rounding.
    pub fn contains(&self, rotation: Quat, tolerance_deg: f32) -> bool {
        let (z, y, x) = rotation.to_euler(EulerRot::ZYX);
        let inside = |angle: f32, [lo, hi]: [f32; 2]| {
            let deg = angle.to_degrees();
            deg >= lo - tolerance_deg && deg <= hi + tolerance_deg
        };
        inside(x, self.x) && inside(y, self.y) && inside(z, self.z)
    }

    fn sample(&self, rng: &mut ChaCha8Rng) -> Quat {
        let mut angle = |[lo, hi]: [f32; 2]| {
            let deg = if hi > lo { rng.gen_range(lo..hi) } else { lo };
            deg.to_radians()
        };
        // Drawn in X, Y, Z order whatever the composition order.
        let (x, y, z) = (angle(self.x), angle(self.y), angle(self.z));
        Quat::from_euler(EulerRot::ZYX, z, y, x)
    }
}

/// The random pose of person `person` (0, 1, ...) under `seed`: every bone of
/// [`JOINT_LIMITS`] rotated within its range, identity root. The same seed and person always
/// give the same pose; different people under one seed get different poses.
pub fn random_pose(seed: u64, person: u32) -> Pose {
    let stream = seed ^ 0x706f_7365_0000_0000 ^ u64::from(person).rotate_left(17);
    let mut rng = ChaCha8Rng::seed_from_u64(stream);
    let mut pose = Pose::identity();
    for limit in JOINT_LIMITS {
        pose.rotations
            .insert(limit.bone.to_owned(), limit.sample(&mut rng));
    }
    pose
}

/// [`random_pose`] shifted vertically so the lowest foot vertex of `template` rests at y = 0.
pub fn grounded_random_pose(template: &BodyTemplate, seed: u64, person: u32) -> Pose {
    let feet = motion::foot_vertices(template);
    motion::ground(template, &feet, random_pose(seed, person))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_limited_bone_exists_in_the_template() {
        let template = BodyTemplate::load_default().unwrap();
        for limit in JOINT_LIMITS {
            assert!(
                template.skeleton.bone_index(limit.bone).is_some(),
                "{}",
                limit.bone
            );
        }
    }

    #[test]
    fn limits_reject_a_rotation_outside_them() {
        let knee = JOINT_LIMITS
            .iter()
            .find(|l| l.bone == "lowerleg01.L")
            .unwrap();
        assert!(knee.contains(Quat::from_rotation_x(1.0), 0.01));
        assert!(!knee.contains(Quat::from_rotation_x(-0.3), 0.01));
        assert!(!knee.contains(Quat::from_rotation_y(0.3), 0.01));
    }
}
