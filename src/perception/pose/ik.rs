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
//!   all of it for the leg). A bend plane that would twist the limb past its limit is read
//!   the other way round (a knee seen bending forwards is a straight knee, clamped by its
//!   hinge). The forearm (shin) swings onto elbow → wrist (knee → ankle).
//!   The hand's orientation comes from wrist → knuckles and the across-palm direction
//!   (little finger → index, plus little finger → thumb when the thumb is seen); its twist
//!   about the forearm goes to the forearm twist bone where there is one. The foot's comes
//!   from heel → toe and heel → ankle.
//!
//! A segment whose landmarks are not all visible keeps the rotation the caller passes as a
//! fallback ([`PoseSolver::solve`]); [`landmarks_to_pose`] passes the rest pose, and
//! [`super::PoseEstimator`] the last good rotation easing back to rest.

use super::correspondence::LandmarkRig;
use super::limbs::{Limb, LimbRest, TwoSegmentRest, SIDES};
use super::limits::{self, BoneLimit, LimbAxes};
use super::segment::{BoneRotations, Segment, SolvedPose};
use super::skeleton_map::BoneMap;
use super::PoseSolveError;
use crate::body::{BodyTemplate, Pose};
use crate::perception::{Landmark, LandmarkId, BODY_LANDMARKS};
use glam::{Quat, Vec3};

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

/// Solves poses of one skeleton from world landmarks.
#[derive(Debug, Clone)]
pub struct PoseSolver {
    pub(super) bone_names: Vec<String>,
    pub(super) parents: Vec<Option<usize>>,
    pub(super) joints: Vec<Vec3>,
    pub(super) map: BoneMap,
    pub(super) rest: [Vec3; BODY_LANDMARKS],
    pub(super) limbs: [LimbRest; 2],
    pub(super) limits: Vec<Option<BoneLimit>>,
    pub(super) segment_bones: [Vec<usize>; Segment::COUNT],
    pub(super) config: SolverConfig,
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

    pub(super) fn global(&self, w: &Work, bone: usize) -> Quat {
        let mut q = w.rotations.locals[bone];
        let mut b = bone;
        while let Some(p) = self.parents[b] {
            q = w.rotations.locals[p] * q;
            b = p;
        }
        w.rotations.root * q
    }

    pub(super) fn parent_global(&self, w: &Work, bone: usize) -> Quat {
        match self.parents[bone] {
            Some(p) => self.global(w, p),
            None => w.rotations.root,
        }
    }

    pub(super) fn set_local(&self, w: &mut Work, bone: usize, local: Quat) {
        let local = local.normalize();
        w.rotations.locals[bone] = match (self.config.apply_limits, &self.limits[bone]) {
            (true, Some(limit)) => limit.clamp(local),
            _ => local,
        };
    }

    /// How far (radians) a twist of `twist` about the rest axis lies outside `bone`'s twist
    /// range; 0 inside it or when limits are off.
    pub(super) fn twist_excess(&self, bone: usize, twist: f32) -> f32 {
        match (self.config.apply_limits, &self.limits[bone]) {
            (true, Some(limit)) => limit.twist_excess(twist),
            _ => 0.0,
        }
    }

    pub(super) fn set_global(&self, w: &mut Work, bone: usize, target: Quat) {
        let local = self.parent_global(w, bone).inverse() * target;
        self.set_local(w, bone, local);
    }
}

/// One frame being solved.
pub(super) struct Work {
    /// Landmarks in the canonical frame.
    pub(super) p: [Vec3; BODY_LANDMARKS],
    pub(super) visible: [bool; BODY_LANDMARKS],
    pub(super) rotations: BoneRotations,
    pub(super) solved: [bool; Segment::COUNT],
}

impl Work {
    /// `Some` when every landmark in `ids` is visible.
    pub(super) fn seen(&self, ids: &[LandmarkId]) -> Option<()> {
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
