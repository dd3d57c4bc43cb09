//! Anatomical joint limits the solver clamps each bone's local rotation to.
//!
//! Limits are written per body segment and resolved per skeleton from its rest geometry
//! (bone directions, the elbow's rest bend), so one table serves the MakeHuman A-pose and the
//! SMPL-X zero pose. Ball joints (shoulders, hips, neck, head, wrists, ankles) limit the
//! twist about the rest bone direction and the swing away from it; hinges (elbows, knees)
//! limit the bend about the hinge axis and how far the bone may leave the hinge plane; the
//! spine bones limit canonical-axis Euler angles. The ranges are wider than the natural
//! ranges of `crate::synth::random_pose` (which random poses sample), so the solver never
//! clamps a pose those produce, and stop at what a body can do: no knee or elbow bending
//! backwards beyond 10°, no head turned past 70°, no thigh twisted past 50°.

use super::rotation::{limit_angle, swing_twist};
use glam::{EulerRot, Quat, Vec3};

/// One bone's allowed local rotations.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BoneLimit {
    /// Twist about `axis` (the rest bone direction) within `twist` (degrees), swing away from
    /// it at most `max_swing` degrees.
    Ball {
        /// Rest bone direction (unit, canonical axes).
        axis: Vec3,
        /// Twist range, degrees.
        twist: [f32; 2],
        /// Largest swing, degrees.
        max_swing: f32,
    },
    /// Bend about `axis` within `range` (degrees, positive = flexion), at most `off_axis`
    /// degrees of rotation out of the hinge.
    Hinge {
        /// Hinge axis (unit, canonical axes).
        axis: Vec3,
        /// Bend range, degrees.
        range: [f32; 2],
        /// Largest rotation about other axes, degrees.
        off_axis: f32,
    },
    /// Euler angles about canonical X, Y, Z (`Rz · Ry · Rx`) within ranges (degrees).
    Euler {
        /// Range about X (flexion: positive bends an upright segment forward).
        x: [f32; 2],
        /// Range about Y (twist).
        y: [f32; 2],
        /// Range about Z (side bend).
        z: [f32; 2],
    },
}

fn clamp_deg(angle: f32, [lo, hi]: [f32; 2]) -> f32 {
    angle.clamp(lo.to_radians(), hi.to_radians())
}

impl BoneLimit {
    /// `q` moved to the nearest rotation (in this limit's parameters) inside the limit.
    pub fn clamp(&self, q: Quat) -> Quat {
        match *self {
            Self::Ball {
                axis,
                twist,
                max_swing,
            } => {
                let (swing, angle) = swing_twist(q, axis);
                limit_angle(swing, max_swing.to_radians())
                    * Quat::from_axis_angle(axis, clamp_deg(angle, twist))
            }
            Self::Hinge {
                axis,
                range,
                off_axis,
            } => {
                let (off, angle) = swing_twist(q, axis);
                limit_angle(off, off_axis.to_radians())
                    * Quat::from_axis_angle(axis, clamp_deg(angle, range))
            }
            Self::Euler { x, y, z } => {
                let (az, ay, ax) = q.to_euler(EulerRot::ZYX);
                Quat::from_euler(
                    EulerRot::ZYX,
                    clamp_deg(az, z),
                    clamp_deg(ay, y),
                    clamp_deg(ax, x),
                )
            }
        }
        .normalize()
    }
}

impl BoneLimit {
    /// How far (radians) a twist of `twist` radians about the rest bone axis lies outside a
    /// ball joint's twist range; 0 inside it, and for other limits.
    pub fn twist_excess(&self, twist: f32) -> f32 {
        match *self {
            Self::Ball {
                twist: [lo, hi], ..
            } => (lo.to_radians() - twist)
                .max(twist - hi.to_radians())
                .max(0.0),
            _ => 0.0,
        }
    }
}

/// Rest geometry of one side's limbs the limits are resolved from (unit vectors, canonical
/// rest axes).
#[derive(Debug, Clone, Copy)]
pub struct LimbAxes {
    /// Shoulder → elbow.
    pub upper_arm: Vec3,
    /// Elbow → wrist.
    pub forearm: Vec3,
    /// Elbow hinge axis (flexion positive).
    pub elbow_hinge: Vec3,
    /// The elbow's bend at rest, degrees.
    pub elbow_rest_bend: f32,
    /// Wrist → middle of the index and little-finger knuckles.
    pub hand: Vec3,
    /// Whether a forearm twist bone takes the pronation (else the wrist does).
    pub has_forearm_twist: bool,
    /// Hip → knee.
    pub thigh: Vec3,
    /// Knee hinge axis.
    pub knee_hinge: Vec3,
    /// The knee's bend at rest, degrees.
    pub knee_rest_bend: f32,
    /// Heel → foot index.
    pub foot: Vec3,
}

/// Limits of the spine bones (each; the spine's bend is shared by three).
pub const SPINE: BoneLimit = BoneLimit::Euler {
    x: [-25.0, 45.0],
    y: [-30.0, 30.0],
    z: [-25.0, 25.0],
};

/// Neck limit for a neck whose rest direction is `axis`.
pub fn neck(axis: Vec3) -> BoneLimit {
    BoneLimit::Ball {
        axis,
        twist: [-70.0, 70.0],
        max_swing: 60.0,
    }
}

/// Head limit (relative to the neck) for a neck whose rest direction is `axis`.
pub fn head(axis: Vec3) -> BoneLimit {
    BoneLimit::Ball {
        axis,
        twist: [-70.0, 70.0],
        max_swing: 50.0,
    }
}

/// Limits of one side's limb bones: upper arm, forearm, forearm twist, hand, thigh, shin,
/// foot.
pub fn limb(axes: &LimbAxes) -> [BoneLimit; 7] {
    let hinge = |axis: Vec3, rest_bend: f32, max: f32, off_axis: f32| BoneLimit::Hinge {
        axis,
        range: [-10.0 - rest_bend, max - rest_bend],
        off_axis,
    };
    // Pronation/supination: ±100° about the forearm, on the twist bone or else the wrist.
    let (twist_bone, wrist_twist) = if axes.has_forearm_twist {
        (100.0, 25.0)
    } else {
        (0.0, 100.0)
    };
    [
        BoneLimit::Ball {
            axis: axes.upper_arm,
            twist: [-95.0, 95.0],
            max_swing: 180.0,
        },
        hinge(axes.elbow_hinge, axes.elbow_rest_bend, 155.0, 30.0),
        BoneLimit::Ball {
            axis: axes.forearm,
            twist: [-twist_bone, twist_bone],
            max_swing: 0.0,
        },
        BoneLimit::Ball {
            axis: axes.hand,
            twist: [-wrist_twist, wrist_twist],
            max_swing: 85.0,
        },
        BoneLimit::Ball {
            axis: axes.thigh,
            twist: [-50.0, 50.0],
            max_swing: 150.0,
        },
        hinge(axes.knee_hinge, axes.knee_rest_bend, 155.0, 15.0),
        BoneLimit::Ball {
            axis: axes.foot,
            twist: [-35.0, 35.0],
            max_swing: 60.0,
        },
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hinge_clamps_backward_bend_and_keeps_allowed_bends() {
        let knee = limb(&LimbAxes {
            upper_arm: -Vec3::Y,
            forearm: -Vec3::Y,
            elbow_hinge: -Vec3::X,
            elbow_rest_bend: 0.0,
            hand: -Vec3::Y,
            has_forearm_twist: false,
            thigh: -Vec3::Y,
            knee_hinge: Vec3::X,
            knee_rest_bend: 0.0,
            foot: Vec3::Z,
        })[5];
        let bent = Quat::from_rotation_x(1.2);
        assert!(knee.clamp(bent).abs_diff_eq(bent, 1e-6));
        let back = knee.clamp(Quat::from_rotation_x(-0.8));
        assert!(back.abs_diff_eq(Quat::from_rotation_x(-10f32.to_radians()), 1e-5));
        let sideways = knee.clamp(Quat::from_rotation_z(0.5));
        assert!((sideways.angle_between(Quat::IDENTITY) - 15f32.to_radians()).abs() < 1e-4);
    }

    #[test]
    fn ball_clamps_twist_only_as_far_as_needed() {
        let limit = neck(Vec3::Y);
        let q = Quat::from_rotation_x(0.3) * Quat::from_rotation_y(1.6);
        let c = limit.clamp(q);
        let expected = Quat::from_rotation_x(0.3) * Quat::from_rotation_y(70f32.to_radians());
        assert!(c.abs_diff_eq(expected, 1e-5), "{c} {expected}");
        let inside = Quat::from_rotation_z(0.4) * Quat::from_rotation_y(-0.5);
        assert!(limit.clamp(inside).abs_diff_eq(inside, 1e-6));
    }
}
