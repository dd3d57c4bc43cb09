//! Where each Gaussian samples an uncalibrated photo, corrected by the landmarks the camera fit
//! misses: the affine camera is fitted to all landmarks at once, and the solved pose never
//! bends quite as the person does, so a thigh may land a few centimetres above the photo's
//! thigh (and sample the coat's hem) or an arm beside the photo's arm.
//!
//! Each Gaussian is tied to the landmarks nearest to it on the canonical body (at most
//! [`ANCHORS`], weighted by inverse squared distance); on a photo it moves by the blend of
//! those landmarks' misses (perception's pixel minus the posed template's), each miss capped
//! at [`MAX_MISS`] of the person's height. Distances are taken on the canonical body, where
//! the arms stand off the torso, so a wrist's miss does not move the hip's Gaussians even
//! where the hand rests on the hip in the photo.

use crate::avatar::Avatar;
use crate::body::{BodyTemplate, Pose};
use crate::perception::pose::template_landmarks;
use crate::perception::{Landmark, BODY_LANDMARKS};
use glam::{Vec2, Vec3};

/// Landmarks each Gaussian is tied to.
pub const ANCHORS: usize = 2;

/// Largest landmark miss taken, as a share of the person's height (beyond it perception, not
/// the pose, is wrong).
pub const MAX_MISS: f32 = 0.1;

/// Softening of the inverse squared distance (metres²): a Gaussian on a landmark still
/// takes some of its neighbours' misses.
const SOFTENING: f32 = 0.03 * 0.03;

/// Per Gaussian, its [`ANCHORS`] landmarks and their weights (summing to 1).
#[derive(Debug, Clone, Default)]
pub struct LandmarkTies {
    ties: Vec<[(u8, f32); ANCHORS]>,
}

impl LandmarkTies {
    /// The ties of `avatar`'s Gaussians to the landmarks of `template` in its rest pose (none
    /// when the template's landmarks cannot be placed).
    pub fn new(avatar: &Avatar, template: &BodyTemplate) -> Self {
        let Ok(landmarks) = template_landmarks(template, &Pose::identity()) else {
            return Self::default();
        };
        let ties = avatar
            .canonical
            .positions
            .iter()
            .map(|p| nearest_landmarks(*p, &landmarks))
            .collect();
        Self { ties }
    }

    /// Each Gaussian's shift (pixels) on a photo from the landmark misses there (`None` for a
    /// landmark not to be used); zero for every Gaussian when there are no ties.
    pub fn shifts(&self, misses: &[Option<Vec2>; BODY_LANDMARKS], n: usize) -> Vec<Vec2> {
        if self.ties.len() != n {
            return vec![Vec2::ZERO; n];
        }
        self.ties
            .iter()
            .map(|tie| {
                let (mut sum, mut weight) = (Vec2::ZERO, 0.0);
                for &(k, w) in tie {
                    if let Some(miss) = misses[k as usize] {
                        sum += miss * w;
                        weight += w;
                    }
                }
                if weight > 0.0 {
                    sum / weight
                } else {
                    Vec2::ZERO
                }
            })
            .collect()
    }
}

/// The [`ANCHORS`] landmarks nearest to `p` and their normalised inverse-square weights.
fn nearest_landmarks(p: Vec3, landmarks: &[Vec3; BODY_LANDMARKS]) -> [(u8, f32); ANCHORS] {
    let mut by_distance: Vec<(u8, f32)> = landmarks
        .iter()
        .enumerate()
        .map(|(k, l)| (k as u8, p.distance_squared(*l)))
        .collect();
    by_distance.sort_by(|a, b| a.1.total_cmp(&b.1));
    let mut out = [(0u8, 0.0f32); ANCHORS];
    for (slot, (k, d2)) in out.iter_mut().zip(&by_distance) {
        *slot = (*k, 1.0 / (d2 + SOFTENING));
    }
    let total: f32 = out.iter().map(|(_, w)| w).sum();
    for (_, w) in &mut out {
        *w /= total;
    }
    out
}

/// Each landmark's miss on a photo: perception's pixel minus the posed template's projected
/// one, for landmarks at least `min_visibility` visible whose miss is within [`MAX_MISS`] of
/// the person's `height` (pixels).
pub fn landmark_misses(
    landmarks: &[Landmark; BODY_LANDMARKS],
    projected: &[Option<Vec2>; BODY_LANDMARKS],
    min_visibility: f32,
    height: f32,
) -> [Option<Vec2>; BODY_LANDMARKS] {
    std::array::from_fn(|k| {
        let template = projected[k]?;
        let l = &landmarks[k];
        let miss = l.position.truncate() - template;
        (l.visibility >= min_visibility && miss.is_finite() && miss.length() <= MAX_MISS * height)
            .then_some(miss)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_gaussian_moves_with_the_landmarks_nearest_to_it() {
        let mut landmarks = [Vec3::splat(100.0); BODY_LANDMARKS];
        landmarks[0] = Vec3::new(0.0, 1.0, 0.0);
        landmarks[1] = Vec3::new(0.0, 0.5, 0.0);
        landmarks[2] = Vec3::new(0.5, 0.5, 0.0);
        let ties = LandmarkTies {
            ties: vec![
                nearest_landmarks(Vec3::new(0.0, 0.99, 0.0), &landmarks),
                nearest_landmarks(Vec3::new(0.0, 0.75, 0.0), &landmarks),
            ],
        };
        let mut misses = [None; BODY_LANDMARKS];
        misses[0] = Some(Vec2::new(10.0, 0.0));
        misses[1] = Some(Vec2::new(0.0, 10.0));
        let shifts = ties.shifts(&misses, 2);
        // On landmark 0: nearly all of its miss.
        assert!(shifts[0].distance(Vec2::new(10.0, 0.0)) < 0.5, "{shifts:?}");
        // Halfway between 0 and 1 (2 further): half of each.
        assert!(shifts[1].distance(Vec2::new(5.0, 5.0)) < 1.5, "{shifts:?}");
        // No usable miss: no shift.
        let none = ties.shifts(&[None; BODY_LANDMARKS], 2);
        assert!(none.iter().all(|s| *s == Vec2::ZERO));
    }

    #[test]
    fn misses_of_hidden_or_far_off_landmarks_are_not_used() {
        let at = |x: f32, visibility: f32| Landmark {
            position: Vec3::new(x, 0.0, 0.0),
            visibility,
            presence: 1.0,
        };
        let mut landmarks = [at(0.0, 1.0); BODY_LANDMARKS];
        landmarks[1] = at(5.0, 0.2);
        landmarks[2] = at(50.0, 1.0);
        let projected = [Some(Vec2::ZERO); BODY_LANDMARKS];
        let misses = landmark_misses(&landmarks, &projected, 0.5, 100.0);
        assert_eq!(misses[0], Some(Vec2::ZERO));
        assert_eq!(misses[1], None, "hidden");
        assert_eq!(misses[2], None, "half the person's height off");
    }
}
