//! The pose solver: world landmarks (camera axes) → local bone rotations of a skeleton.
//!
//! Everything works with directions between landmarks, never with their distances, so a
//! person whose proportions differ from the template's is posed all the same. Rotations are
//! solved top-down; each bone gets a target orientation (its rotation from rest, in world
//! axes), its local rotation is that target relative to its parent's actual orientation,
//! clamped to [`super::limits`], so children are always solved against the clamped parent.
//!
//! * Root: the hip line (right → left hip) and the torso's up (hips' midpoint → shoulders'
//!   midpoint) against the same vectors at rest. Forward lean of the whole torso is taken by
//!   the root (the hips alone cannot tell pelvis tilt from spine flexion).
//! * Spine: the shoulder line with the same up vector, relative to the root: the torso's
//!   twist and side bend, shared over three spine bones ([`super::skeleton_map`]).
//! * Neck and head: the head's orientation from a left–right pair (ears, else outer eye
//!   corners, eyes or mouth corners) and the mean of the visible face points (nose, eyes,
//!   mouth corners); the neck swings so that the head's centre lies where the landmarks put
//!   it (measured from the shoulders, scaled by shoulder width) and takes half the head's
//!   twist; the head bone the rest.
//! * Arms and legs: the upper arm (thigh) swings onto shoulder → elbow (hip → knee); its
//!   twist puts the elbow's (knee's) hinge axis on the observed bend plane, trusted in full
//!   from a bend of about 24° down to none below about 9°, where the twist comes instead from
//!   the hand (foot) orientation (half of it for the arm, the rest left to the forearm twist,
//!   all of it for the leg). The forearm (shin) swings onto elbow → wrist (knee → ankle).
//!   The hand's orientation comes from wrist → knuckles and the across-palm direction
//!   (little finger → index, plus little finger → thumb when the thumb is seen); its twist
//!   about the forearm goes to the forearm twist bone where there is one. The foot's comes
//!   from heel → toe and heel → ankle.
//!
//! A segment whose landmarks are not all visible keeps the rotation the caller passes as a
//! fallback ([`PoseSolver::solve`]); [`landmarks_to_pose`] passes the rest pose, and
//! [`super::PoseEstimator`] the last good rotation easing back to rest.

use super::correspondence::LandmarkRig;
use super::limits::{self, BoneLimit, LimbAxes};
use super::rotation::{align, angle_about, arc, smoothstep, twist_angle, wrap};
use super::skeleton_map::BoneMap;
use super::PoseSolveError;
use crate::body::{BodyTemplate, Pose};
use crate::perception::{Landmark, LandmarkId, BODY_LANDMARKS};
use glam::{Quat, Vec3};

/// Below this sine of the elbow or knee bend (about 9°) the bend plane gives no twist.
const BEND_UNTRUSTED: f32 = 0.15;
/// From this sine (about 24°) on, the bend plane gives all of the twist.
const BEND_TRUSTED: f32 = 0.40;
/// A rest limb bent by less than this sine counts as straight: its hinge axis comes from
/// the skeleton map instead.
const REST_BENT: f32 = 0.25;

/// The groups of bones solved (and held) together, each from its own landmarks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Segment {
    /// Root rotation (hips, shoulders).
    Root,
    /// Spine bones (hips, shoulders).
    Spine,
    /// Neck and head (a left–right face pair, a face point, shoulders).
    Head,
    /// Left upper arm (shoulder, elbow).
    LeftUpperArm,
    /// Right upper arm.
    RightUpperArm,
    /// Left forearm (elbow, wrist).
    LeftForearm,
    /// Right forearm.
    RightForearm,
    /// Left hand and forearm twist (wrist, index and little-finger knuckles).
    LeftHand,
    /// Right hand.
    RightHand,
    /// Left thigh (hip, knee).
    LeftThigh,
    /// Right thigh.
    RightThigh,
    /// Left shin (knee, ankle).
    LeftShin,
    /// Right shin.
    RightShin,
    /// Left foot (ankle, heel, foot index).
    LeftFoot,
    /// Right foot.
    RightFoot,
}

impl Segment {
    /// Number of segments.
    pub const COUNT: usize = 15;

    /// Every segment, in solving order.
    pub const ALL: [Segment; Self::COUNT] = [
        Self::Root,
        Self::Spine,
        Self::Head,
        Self::LeftUpperArm,
        Self::RightUpperArm,
        Self::LeftForearm,
        Self::RightForearm,
        Self::LeftHand,
        Self::RightHand,
        Self::LeftThigh,
        Self::RightThigh,
        Self::LeftShin,
        Self::RightShin,
        Self::LeftFoot,
        Self::RightFoot,
    ];

    /// Position in [`Segment::ALL`].
    pub fn index(self) -> usize {
        self as usize
    }
}

/// Solver settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolverConfig {
    /// Rotation from the camera's axes (x right, y down, z forward) into the canonical
    /// frame; by default the half turn about x (see the module doc of [`super`]).
    pub canonical_from_camera: Quat,
    /// Root translation of every solved pose (world landmarks are hip-centred and carry no
    /// position; metres).
    pub root_translation: Vec3,
    /// Landmarks whose visibility is below this are not used.
    pub min_visibility: f32,
    /// Clamp local rotations to [`super::limits`].
    pub apply_limits: bool,
}

impl Default for SolverConfig {
    fn default() -> Self {
        Self {
            canonical_from_camera: Quat::from_rotation_x(std::f32::consts::PI),
            root_translation: Vec3::ZERO,
            min_visibility: 0.5,
            apply_limits: true,
        }
    }
}

/// Root rotation and per-bone local rotations (indexed like the skeleton's bones).
#[derive(Debug, Clone, PartialEq)]
pub struct BoneRotations {
    /// Root rotation (world axes).
    pub root: Quat,
    /// Local rotation per bone.
    pub locals: Vec<Quat>,
}

impl BoneRotations {
    /// The rest pose of a skeleton with `bones` bones.
    pub fn rest(bones: usize) -> Self {
        Self {
            root: Quat::IDENTITY,
            locals: vec![Quat::IDENTITY; bones],
        }
    }
}

/// A solved frame.
#[derive(Debug, Clone, PartialEq)]
pub struct SolvedPose {
    /// The rotations (fallback rotations for unsolved segments).
    pub rotations: BoneRotations,
    /// Per segment ([`Segment::index`]): whether its landmarks were seen and it was solved.
    pub solved: [bool; Segment::COUNT],
}

/// Rest geometry of one side's limbs.
#[derive(Debug, Clone, Copy)]
struct LimbRest {
    arm: TwoSegmentRest,
    leg: TwoSegmentRest,
}

/// Rest vectors of a two-segment limb (arm or leg).
#[derive(Debug, Clone, Copy)]
struct TwoSegmentRest {
    /// Proximal segment (shoulder → elbow, hip → knee).
    upper: Vec3,
    /// Distal segment (elbow → wrist, knee → ankle).
    lower: Vec3,
    /// Hinge axis, flexion positive.
    hinge: Vec3,
    /// Rest bend, degrees.
    bend_deg: f32,
}

impl TwoSegmentRest {
    fn new(upper: Vec3, lower: Vec3, fallback_hinge: Vec3) -> Self {
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
struct SideIds {
    shoulder: LandmarkId,
    elbow: LandmarkId,
    wrist: LandmarkId,
    index: LandmarkId,
    pinky: LandmarkId,
    thumb: LandmarkId,
    hip: LandmarkId,
    knee: LandmarkId,
    ankle: LandmarkId,
    heel: LandmarkId,
    toe: LandmarkId,
}

const SIDES: [SideIds; 2] = {
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

/// Left–right face pairs for the head's lateral axis, most trusted first.
const FACE_PAIRS: [(LandmarkId, LandmarkId); 4] = {
    use LandmarkId::*;
    [
        (LeftEar, RightEar),
        (LeftEyeOuter, RightEyeOuter),
        (LeftEye, RightEye),
        (MouthLeft, MouthRight),
    ]
};

/// Face points whose mean gives the head's forward direction.
const FACE_POINTS: [LandmarkId; 5] = {
    use LandmarkId::*;
    [Nose, LeftEye, RightEye, MouthLeft, MouthRight]
};

/// Share of the hand's twist the upper arm takes when the elbow is straight.
const ARM_DISTAL_TWIST_SHARE: f32 = 0.5;
/// Share of the foot's twist the thigh takes when the knee is straight.
const LEG_DISTAL_TWIST_SHARE: f32 = 1.0;

/// Solves poses of one skeleton from world landmarks.
#[derive(Debug, Clone)]
pub struct PoseSolver {
    bone_names: Vec<String>,
    parents: Vec<Option<usize>>,
    joints: Vec<Vec3>,
    map: BoneMap,
    rest: [Vec3; BODY_LANDMARKS],
    limbs: [LimbRest; 2],
    limits: Vec<Option<BoneLimit>>,
    segment_bones: [Vec<usize>; Segment::COUNT],
    config: SolverConfig,
}

impl PoseSolver {
    /// A solver for `template`'s skeleton (MakeHuman rig or SMPL-X joints), aiming with its
    /// landmarks ([`LandmarkRig`]).
    pub fn new(template: &BodyTemplate, config: SolverConfig) -> Result<Self, PoseSolveError> {
        let map = BoneMap::new(&template.skeleton)?;
        let rest = LandmarkRig::new(template)?.rest();
        let limbs = std::array::from_fn(|s| {
            let ids = &SIDES[s];
            let v = |from: LandmarkId, to: LandmarkId| rest[to.index()] - rest[from.index()];
            LimbRest {
                arm: TwoSegmentRest::new(
                    v(ids.shoulder, ids.elbow),
                    v(ids.elbow, ids.wrist),
                    map.elbow_hinge[s],
                ),
                leg: TwoSegmentRest::new(
                    v(ids.hip, ids.knee),
                    v(ids.knee, ids.ankle),
                    map.knee_hinge,
                ),
            }
        });
        let skeleton = &template.skeleton;
        let mut solver = Self {
            bone_names: skeleton.bone_names.clone(),
            parents: skeleton.parents.clone(),
            joints: skeleton.joints.clone(),
            map,
            rest,
            limbs,
            limits: vec![None; skeleton.len()],
            segment_bones: Default::default(),
            config,
        };
        solver.segment_bones = std::array::from_fn(|i| solver.bones_of(Segment::ALL[i]));
        solver.limits = solver.resolve_limits();
        Ok(solver)
    }

    /// The settings.
    pub fn config(&self) -> &SolverConfig {
        &self.config
    }

    /// The bone map in use.
    pub fn bone_map(&self) -> &BoneMap {
        &self.map
    }

    /// Number of bones of the skeleton.
    pub fn bone_count(&self) -> usize {
        self.bone_names.len()
    }

    /// The bones a segment writes.
    pub fn segment_bones(&self, segment: Segment) -> &[usize] {
        &self.segment_bones[segment.index()]
    }

    fn bones_of(&self, segment: Segment) -> Vec<usize> {
        let m = &self.map;
        match segment {
            Segment::Root => Vec::new(),
            Segment::Spine => m.spine.iter().map(|(b, _)| *b).collect(),
            Segment::Head => vec![m.neck, m.head],
            Segment::LeftUpperArm => vec![m.upper_arm[0]],
            Segment::RightUpperArm => vec![m.upper_arm[1]],
            Segment::LeftForearm => vec![m.forearm[0]],
            Segment::RightForearm => vec![m.forearm[1]],
            Segment::LeftHand => m.forearm_twist[0].into_iter().chain([m.hand[0]]).collect(),
            Segment::RightHand => m.forearm_twist[1].into_iter().chain([m.hand[1]]).collect(),
            Segment::LeftThigh => vec![m.thigh[0]],
            Segment::RightThigh => vec![m.thigh[1]],
            Segment::LeftShin => vec![m.shin[0]],
            Segment::RightShin => vec![m.shin[1]],
            Segment::LeftFoot => vec![m.foot[0]],
            Segment::RightFoot => vec![m.foot[1]],
        }
    }

    fn resolve_limits(&self) -> Vec<Option<BoneLimit>> {
        let mut out = vec![None; self.bone_names.len()];
        let m = &self.map;
        for (b, _) in &m.spine {
            out[*b] = Some(limits::SPINE);
        }
        let neck_axis = (self.joints[m.head] - self.joints[m.neck])
            .try_normalize()
            .unwrap_or(Vec3::Y);
        out[m.neck] = Some(limits::neck(neck_axis));
        out[m.head] = Some(limits::head(neck_axis));
        let r = &self.rest;
        for (s, ids) in SIDES.iter().enumerate() {
            let limb = &self.limbs[s];
            let knuckles = 0.5 * (r[ids.index.index()] + r[ids.pinky.index()]);
            let axes = LimbAxes {
                upper_arm: limb.arm.upper.normalize(),
                forearm: limb.arm.lower.normalize(),
                elbow_hinge: limb.arm.hinge,
                elbow_rest_bend: limb.arm.bend_deg,
                hand: (knuckles - r[ids.wrist.index()]).normalize(),
                has_forearm_twist: m.forearm_twist[s].is_some(),
                thigh: limb.leg.upper.normalize(),
                knee_hinge: limb.leg.hinge,
                knee_rest_bend: limb.leg.bend_deg,
                foot: (r[ids.toe.index()] - r[ids.heel.index()]).normalize(),
            };
            let [upper, fore, twist, hand, thigh, shin, foot] = limits::limb(&axes);
            out[m.upper_arm[s]] = Some(upper);
            out[m.forearm[s]] = Some(fore);
            if let Some(t) = m.forearm_twist[s] {
                out[t] = Some(twist);
            }
            out[m.hand[s]] = Some(hand);
            out[m.thigh[s]] = Some(thigh);
            out[m.shin[s]] = Some(shin);
            out[m.foot[s]] = Some(foot);
        }
        out
    }

    /// Solves one frame. `world`: landmark positions in the camera's axes (metres);
    /// `visible`: which landmarks to use; `fallback`: the rotations of segments whose
    /// landmarks are not all visible (or degenerate).
    pub fn solve(
        &self,
        world: &[Vec3; BODY_LANDMARKS],
        visible: &[bool; BODY_LANDMARKS],
        fallback: &BoneRotations,
    ) -> SolvedPose {
        let c = self.config.canonical_from_camera;
        let mut work = Work {
            p: std::array::from_fn(|i| c * world[i]),
            visible: std::array::from_fn(|i| visible[i] && world[i].is_finite()),
            rotations: BoneRotations::rest(self.bone_names.len()),
            solved: [false; Segment::COUNT],
        };
        for segment in Segment::ALL {
            let solved = match segment {
                Segment::Root => self.solve_root(&mut work),
                Segment::Spine => self.solve_spine(&mut work),
                Segment::Head => self.solve_head(&mut work),
                Segment::LeftUpperArm => self.solve_upper(&mut work, 0, Limb::Arm),
                Segment::RightUpperArm => self.solve_upper(&mut work, 1, Limb::Arm),
                Segment::LeftForearm => self.solve_lower(&mut work, 0, Limb::Arm),
                Segment::RightForearm => self.solve_lower(&mut work, 1, Limb::Arm),
                Segment::LeftHand => self.solve_hand(&mut work, 0),
                Segment::RightHand => self.solve_hand(&mut work, 1),
                Segment::LeftThigh => self.solve_upper(&mut work, 0, Limb::Leg),
                Segment::RightThigh => self.solve_upper(&mut work, 1, Limb::Leg),
                Segment::LeftShin => self.solve_lower(&mut work, 0, Limb::Leg),
                Segment::RightShin => self.solve_lower(&mut work, 1, Limb::Leg),
                Segment::LeftFoot => self.solve_foot(&mut work, 0),
                Segment::RightFoot => self.solve_foot(&mut work, 1),
            }
            .is_some();
            work.solved[segment.index()] = solved;
            if !solved {
                if segment == Segment::Root {
                    work.rotations.root = fallback.root;
                }
                for &b in &self.segment_bones[segment.index()] {
                    work.rotations.locals[b] = fallback.locals[b];
                }
            }
        }
        SolvedPose {
            rotations: work.rotations,
            solved: work.solved,
        }
    }

    /// The [`Pose`] of `rotations`: every bone a segment drives, by name, the root rotation
    /// and the configured root translation.
    pub fn to_pose(&self, rotations: &BoneRotations) -> Pose {
        let mut pose = Pose {
            root_rotation: rotations.root,
            root_translation: self.config.root_translation,
            ..Pose::identity()
        };
        for bones in &self.segment_bones {
            for &b in bones {
                pose.rotations
                    .insert(self.bone_names[b].clone(), rotations.locals[b]);
            }
        }
        pose
    }

    // --- forward kinematics over the frame being solved ---

    fn global(&self, w: &Work, bone: usize) -> Quat {
        let mut q = w.rotations.locals[bone];
        let mut b = bone;
        while let Some(p) = self.parents[b] {
            q = w.rotations.locals[p] * q;
            b = p;
        }
        w.rotations.root * q
    }

    fn parent_global(&self, w: &Work, bone: usize) -> Quat {
        match self.parents[bone] {
            Some(p) => self.global(w, p),
            None => w.rotations.root,
        }
    }

    fn set_local(&self, w: &mut Work, bone: usize, local: Quat) {
        let local = local.normalize();
        w.rotations.locals[bone] = match (self.config.apply_limits, &self.limits[bone]) {
            (true, Some(limit)) => limit.clamp(local),
            _ => local,
        };
    }

    fn set_global(&self, w: &mut Work, bone: usize, target: Quat) {
        let local = self.parent_global(w, bone).inverse() * target;
        self.set_local(w, bone, local);
    }

    // --- segments ---

    fn torso_vectors(&self, w: &Work) -> Option<[(Vec3, Vec3); 3]> {
        use LandmarkId::*;
        w.seen(&[LeftHip, RightHip, LeftShoulder, RightShoulder])?;
        let vectors = |x: &[Vec3; BODY_LANDMARKS]| {
            let at = |id: LandmarkId| x[id.index()];
            let hips = 0.5 * (at(LeftHip) + at(RightHip));
            let shoulders = 0.5 * (at(LeftShoulder) + at(RightShoulder));
            (
                at(LeftHip) - at(RightHip),
                at(LeftShoulder) - at(RightShoulder),
                shoulders - hips,
            )
        };
        let (rh, rs, ru) = vectors(&self.rest);
        let (h, s, u) = vectors(&w.p);
        Some([(rh, h), (rs, s), (ru, u)])
    }

    fn solve_root(&self, w: &mut Work) -> Option<()> {
        let [(rest_hips, hips), _, (rest_up, up)] = self.torso_vectors(w)?;
        w.rotations.root = align(rest_hips, rest_up, hips, up)?;
        Some(())
    }

    fn solve_spine(&self, w: &mut Work) -> Option<()> {
        let [_, (rest_line, line), (rest_up, up)] = self.torso_vectors(w)?;
        let chest = align(rest_line, rest_up, line, up)?;
        let first = self.map.spine.first()?.0;
        let bend = self.parent_global(w, first).inverse() * chest;
        for &(bone, share) in &self.map.spine {
            self.set_local(w, bone, Quat::IDENTITY.slerp(bend, share));
        }
        Some(())
    }

    fn solve_head(&self, w: &mut Work) -> Option<()> {
        use LandmarkId::{LeftShoulder, RightShoulder};
        w.seen(&[LeftShoulder, RightShoulder])?;
        let (left, right) = FACE_PAIRS
            .into_iter()
            .find(|(l, r)| w.seen(&[*l, *r]).is_some())?;
        let face: Vec<LandmarkId> = FACE_POINTS
            .into_iter()
            .filter(|id| w.visible[id.index()])
            .collect();
        if face.is_empty() {
            return None;
        }
        let r = &self.rest;
        let p = &w.p;
        let mean = |x: &[Vec3; BODY_LANDMARKS]| {
            face.iter().map(|id| x[id.index()]).sum::<Vec3>() / face.len() as f32
        };
        let mid = |x: &[Vec3; BODY_LANDMARKS], a: LandmarkId, b: LandmarkId| {
            0.5 * (x[a.index()] + x[b.index()])
        };
        let (rest_centre, centre) = (mid(r, left, right), mid(p, left, right));
        let head_target = align(
            r[left.index()] - r[right.index()],
            mean(r) - rest_centre,
            p[left.index()] - p[right.index()],
            mean(p) - centre,
        )?;
        let (ls, rs) = (LeftShoulder.index(), RightShoulder.index());
        let scale = (p[ls] - p[rs]).length() / (r[ls] - r[rs]).length();
        let (neck, head) = (self.map.neck, self.map.head);
        let chest = self.parent_global(w, neck);
        let neck_rest = self.joints[neck];
        let neck_seen = mid(p, LeftShoulder, RightShoulder)
            + chest * (neck_rest - mid(r, LeftShoulder, RightShoulder)) * scale;
        let rest_axis = (rest_centre - neck_rest).try_normalize()?;
        let swing = arc(chest * rest_axis, centre - neck_seen)?;
        let relative = (swing * chest).inverse() * head_target;
        let twist = twist_angle(relative, rest_axis);
        let neck_target = swing * chest * Quat::from_axis_angle(rest_axis, 0.5 * twist);
        self.set_global(w, neck, neck_target);
        self.set_global(w, head, head_target);
        Some(())
    }

    /// Upper arm or thigh: swing onto the segment, twist from the bend plane or the distal end.
    fn solve_upper(&self, w: &mut Work, side: usize, limb: Limb) -> Option<()> {
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
        let twist = match (bend, distal) {
            (Some((b, trust)), Some(d)) => d + trust * wrap(b - d),
            (Some((b, trust)), None) => trust * b,
            (None, Some(d)) => d,
            (None, None) => 0.0,
        };
        self.set_global(w, bone, Quat::from_axis_angle(axis, twist) * untwisted);
        Some(())
    }

    /// Forearm or shin: swing onto the segment from the solved upper segment.
    fn solve_lower(&self, w: &mut Work, side: usize, limb: Limb) -> Option<()> {
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
    fn hand_target(&self, w: &Work, side: usize) -> Option<Quat> {
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
    fn foot_target(&self, w: &Work, side: usize) -> Option<Quat> {
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

    fn solve_hand(&self, w: &mut Work, side: usize) -> Option<()> {
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

    fn solve_foot(&self, w: &mut Work, side: usize) -> Option<()> {
        let target = self.foot_target(w, side)?;
        self.set_global(w, self.map.foot[side], target);
        Some(())
    }
}

#[derive(Debug, Clone, Copy)]
enum Limb {
    Arm,
    Leg,
}

/// One frame being solved.
struct Work {
    /// Landmarks in the canonical frame.
    p: [Vec3; BODY_LANDMARKS],
    visible: [bool; BODY_LANDMARKS],
    rotations: BoneRotations,
    solved: [bool; Segment::COUNT],
}

impl Work {
    /// `Some` when every landmark in `ids` is visible.
    fn seen(&self, ids: &[LandmarkId]) -> Option<()> {
        ids.iter().all(|id| self.visible[id.index()]).then_some(())
    }
}

/// One frame of world landmarks to a pose, without state: landmarks below the solver's
/// `min_visibility` are ignored and their segments stay at rest. [`super::PoseEstimator`]
/// adds filtering and holds hidden segments.
pub fn landmarks_to_pose(solver: &PoseSolver, world: &[Landmark; BODY_LANDMARKS]) -> Pose {
    let positions = world.map(|l| l.position);
    let visible = world.map(|l| l.visibility >= solver.config.min_visibility);
    let rest = BoneRotations::rest(solver.bone_count());
    solver.to_pose(&solver.solve(&positions, &visible, &rest).rotations)
}
