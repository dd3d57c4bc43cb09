//! Arms and legs (see [`super::ik`] for the method).

use super::ik::{PoseSolver, Work};
use super::rotation::{align, angle_about, arc, smoothstep, twist_angle, wrap};
use crate::perception::{LandmarkId, BODY_LANDMARKS};
use glam::{Quat, Vec3};

/// Below this sine of the elbow or knee bend (about 9°) the bend plane gives no twist.
const BEND_UNTRUSTED: f32 = 0.15;
/// From this sine (about 24°) on, the bend plane gives all of the twist.
const BEND_TRUSTED: f32 = 0.40;
/// A rest limb bent by less than this sine counts as straight: its hinge axis comes from
/// the skeleton map instead.
const REST_BENT: f32 = 0.25;

/// Share of the hand's twist the upper arm takes when the elbow is straight.
const ARM_DISTAL_TWIST_SHARE: f32 = 0.5;
/// Share of the foot's twist the thigh takes when the knee is straight.
const LEG_DISTAL_TWIST_SHARE: f32 = 1.0;

/// Rest geometry of one side's limbs.
#[derive(Debug, Clone, Copy)]
pub(super) struct LimbRest {
    pub(super) arm: TwoSegmentRest,
    pub(super) leg: TwoSegmentRest,
}

/// Rest vectors of a two-segment limb (arm or leg).
#[derive(Debug, Clone, Copy)]
pub(super) struct TwoSegmentRest {
    /// Proximal segment (shoulder → elbow, hip → knee).
    pub(super) upper: Vec3,
    /// Distal segment (elbow → wrist, knee → ankle).
    pub(super) lower: Vec3,
    /// Hinge axis, flexion positive.
    pub(super) hinge: Vec3,
    /// Rest bend, degrees.
    pub(super) bend_deg: f32,
}

impl TwoSegmentRest {
    pub(super) fn new(upper: Vec3, lower: Vec3, fallback_hinge: Vec3) -> Self {
        let normal = upper.cross(lower);
        let sine = normal.length() / (upper.length() * lower.length()).max(1e-9);
        let hinge = if sine > REST_BENT {
            normal.normalize()
        } else {
            fallback_hinge
        };
        Self {
            upper,
            lower,
            hinge,
            bend_deg: upper.angle_between(lower).to_degrees(),
        }
    }
}

/// The landmarks of one side, in the order the limb solvers use.
pub(super) struct SideIds {
    pub(super) shoulder: LandmarkId,
    pub(super) elbow: LandmarkId,
    pub(super) wrist: LandmarkId,
    pub(super) index: LandmarkId,
    pub(super) pinky: LandmarkId,
    pub(super) thumb: LandmarkId,
    pub(super) hip: LandmarkId,
    pub(super) knee: LandmarkId,
    pub(super) ankle: LandmarkId,
    pub(super) heel: LandmarkId,
    pub(super) toe: LandmarkId,
}

pub(super) const SIDES: [SideIds; 2] = {
    use LandmarkId::*;
    [
        SideIds {
            shoulder: LeftShoulder,
            elbow: LeftElbow,
            wrist: LeftWrist,
            index: LeftIndex,
            pinky: LeftPinky,
            thumb: LeftThumb,
            hip: LeftHip,
            knee: LeftKnee,
            ankle: LeftAnkle,
            heel: LeftHeel,
            toe: LeftFootIndex,
        },
        SideIds {
            shoulder: RightShoulder,
            elbow: RightElbow,
            wrist: RightWrist,
            index: RightIndex,
            pinky: RightPinky,
            thumb: RightThumb,
            hip: RightHip,
            knee: RightKnee,
            ankle: RightAnkle,
            heel: RightHeel,
            toe: RightFootIndex,
        },
    ]
};

impl PoseSolver {
    /// Upper arm or thigh: swing onto the segment, twist from the bend plane or the distal end.
    pub(super) fn solve_upper(&self, w: &mut Work, side: usize, limb: Limb) -> Option<()> {
        let ids = &SIDES[side];
        let (rest, bone, [top, mid, end], share) = match limb {
            Limb::Arm => (
                &self.limbs[side].arm,
                self.map.upper_arm[side],
                [ids.shoulder, ids.elbow, ids.wrist],
                ARM_DISTAL_TWIST_SHARE,
            ),
            Limb::Leg => (
                &self.limbs[side].leg,
                self.map.thigh[side],
                [ids.hip, ids.knee, ids.ankle],
                LEG_DISTAL_TWIST_SHARE,
            ),
        };
        w.seen(&[top, mid])?;
        let upper = w.p[mid.index()] - w.p[top.index()];
        let axis = upper.try_normalize()?;
        let parent = self.parent_global(w, bone);
        let untwisted = arc(parent * rest.upper, upper)? * parent;
        let lower = w.seen(&[end]).map(|_| w.p[end.index()] - w.p[mid.index()]);
        let bend = lower.and_then(|lower| {
            let normal = upper.cross(lower);
            let sine = normal.length() / (upper.length() * lower.length()).max(1e-9);
            let trust = smoothstep((sine - BEND_UNTRUSTED) / (BEND_TRUSTED - BEND_UNTRUSTED));
            let angle = angle_about(axis, untwisted * rest.hinge, normal)?;
            Some((angle, trust))
        });
        let distal = lower.and_then(|lower| {
            let target = match limb {
                Limb::Arm => self.hand_target(w, side),
                Limb::Leg => self.foot_target(w, side),
            }?;
            let lower_untwisted = arc(untwisted * rest.lower, lower)? * untwisted;
            Some(share * twist_angle(target * lower_untwisted.inverse(), axis))
        });
        let blend = |bend: Option<(f32, f32)>| match (bend, distal) {
            (Some((b, trust)), Some(d)) => d + trust * wrap(b - d),
            (Some((b, trust)), None) => trust * b,
            (None, Some(d)) => d,
            (None, None) => 0.0,
        };
        // A bend plane read the wrong way round (a knee or elbow seen bending backwards)
        // asks for a twist of about half a turn; the flipped plane is then the plausible
        // reading (the hinge limit straightens the joint instead).
        let twist = blend(bend);
        let flipped = blend(bend.map(|(b, trust)| (wrap(b + std::f32::consts::PI), trust)));
        let twist = if self.twist_excess(bone, flipped) < self.twist_excess(bone, twist) {
            flipped
        } else {
            twist
        };
        self.set_global(w, bone, Quat::from_axis_angle(axis, twist) * untwisted);
        Some(())
    }

    /// Forearm or shin: swing onto the segment from the solved upper segment.
    pub(super) fn solve_lower(&self, w: &mut Work, side: usize, limb: Limb) -> Option<()> {
        let ids = &SIDES[side];
        let (rest, bone, [top, end]) = match limb {
            Limb::Arm => (
                &self.limbs[side].arm,
                self.map.forearm[side],
                [ids.elbow, ids.wrist],
            ),
            Limb::Leg => (
                &self.limbs[side].leg,
                self.map.shin[side],
                [ids.knee, ids.ankle],
            ),
        };
        w.seen(&[top, end])?;
        let lower = w.p[end.index()] - w.p[top.index()];
        let parent = self.parent_global(w, bone);
        self.set_global(w, bone, arc(parent * rest.lower, lower)? * parent);
        Some(())
    }

    /// The hand's orientation from wrist, knuckles and (when seen) thumb.
    pub(super) fn hand_target(&self, w: &Work, side: usize) -> Option<Quat> {
        let ids = &SIDES[side];
        w.seen(&[ids.wrist, ids.index, ids.pinky])?;
        let thumb = w.visible[ids.thumb.index()];
        let frame = |x: &[Vec3; BODY_LANDMARKS]| {
            let at = |id: LandmarkId| x[id.index()];
            let knuckles = 0.5 * (at(ids.index) + at(ids.pinky));
            let mut across = at(ids.index) - at(ids.pinky);
            if thumb {
                across += at(ids.thumb) - at(ids.pinky);
            }
            (knuckles - at(ids.wrist), across)
        };
        let (rest_forward, rest_across) = frame(&self.rest);
        let (forward, across) = frame(&w.p);
        align(rest_forward, rest_across, forward, across)
    }

    /// The foot's orientation from heel, toe and ankle.
    pub(super) fn foot_target(&self, w: &Work, side: usize) -> Option<Quat> {
        let ids = &SIDES[side];
        w.seen(&[ids.ankle, ids.heel, ids.toe])?;
        let frame = |x: &[Vec3; BODY_LANDMARKS]| {
            let at = |id: LandmarkId| x[id.index()];
            (at(ids.toe) - at(ids.heel), at(ids.ankle) - at(ids.heel))
        };
        let (rest_forward, rest_up) = frame(&self.rest);
        let (forward, up) = frame(&w.p);
        align(rest_forward, rest_up, forward, up)
    }

    pub(super) fn solve_hand(&self, w: &mut Work, side: usize) -> Option<()> {
        let target = self.hand_target(w, side)?;
        if let Some(twist_bone) = self.map.forearm_twist[side] {
            let axis = self.limbs[side].arm.lower.normalize();
            let relative = self.parent_global(w, twist_bone).inverse() * target;
            let twist = twist_angle(relative, axis);
            self.set_local(w, twist_bone, Quat::from_axis_angle(axis, twist));
        }
        self.set_global(w, self.map.hand[side], target);
        Some(())
    }

    pub(super) fn solve_foot(&self, w: &mut Work, side: usize) -> Option<()> {
        let target = self.foot_target(w, side)?;
        self.set_global(w, self.map.foot[side], target);
        Some(())
    }
}

#[derive(Debug, Clone, Copy)]
pub(super) enum Limb {
    Arm,
    Leg,
}
