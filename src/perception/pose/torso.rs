//! Root, spine, neck and head (see [`super::ik`] for the method).

use super::ik::{PoseSolver, Work};
use super::rotation::{align, arc, twist_angle};
use crate::perception::{LandmarkId, BODY_LANDMARKS};
use glam::{Quat, Vec3};

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

impl PoseSolver {
    pub(super) fn torso_vectors(&self, w: &Work) -> Option<[(Vec3, Vec3); 3]> {
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

    pub(super) fn solve_root(&self, w: &mut Work) -> Option<()> {
        let [(rest_hips, hips), _, (rest_up, up)] = self.torso_vectors(w)?;
        w.rotations.root = align(rest_hips, rest_up, hips, up)?;
        Some(())
    }

    pub(super) fn solve_spine(&self, w: &mut Work) -> Option<()> {
        let [_, (rest_line, line), (rest_up, up)] = self.torso_vectors(w)?;
        let chest = align(rest_line, rest_up, line, up)?;
        let first = self.map.spine.first()?.0;
        let bend = self.parent_global(w, first).inverse() * chest;
        for &(bone, share) in &self.map.spine {
            self.set_local(w, bone, Quat::IDENTITY.slerp(bend, share));
        }
        Some(())
    }

    pub(super) fn solve_head(&self, w: &mut Work) -> Option<()> {
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
}
