//! How big the head is on an uncalibrated photo: hair and caps stand well beyond the
//! template's skull, so the skull's Gaussians, sampling the photo where the skull projects,
//! take the hairline's and the neck's colours rather than the hair's or the cap's.
//!
//! [`HeadWarp`] scales the head's sampling points about the head joint (moved with the face
//! landmarks) so that the skull's top reaches the top of the person's mask there. Each
//! Gaussian moves by its skinning weight on the head (the neck stays, the skull moves fully),
//! so the sampling stays continuous. The points come in already moved by the landmark misses
//! ([`super::landmark_warp`]).

use crate::avatar::Avatar;
use crate::body::BodyTemplate;
use crate::perception::BODY_LANDMARKS;
use glam::Vec2;
use image::GrayImage;

/// Face landmarks (nose, eyes, ears, mouth): the first eleven of the body landmarks.
const FACE_LANDMARKS: usize = 11;

/// Range of the head's scale on the photo (hair and caps only add; a mask may fall short of
/// the head, so it may shrink a little).
const SCALE_RANGE: (f32, f32) = (0.9, 1.4);

/// Mask value (0–255) that counts as the person when looking for the head's top.
const MASK_ON: u8 = 128;

/// Gaussians counted as the skull (head weight at least this) when measuring the head's top.
const SKULL_WEIGHT: f32 = 0.9;

/// A 2-D scaling of the head's points on one photo, `p ↦ pivot + scale · (p − pivot)`,
/// blended by each point's head weight.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadWarp {
    /// The head joint's pixel.
    pub pivot: Vec2,
    /// Scale of the head about the pivot.
    pub scale: f32,
}

impl HeadWarp {
    /// The move that changes nothing.
    pub const IDENTITY: Self = Self {
        pivot: Vec2::ZERO,
        scale: 1.0,
    };

    /// Where the pixel `p` of a point with head weight `weight` samples the photo.
    pub fn apply(&self, p: Vec2, weight: f32) -> Vec2 {
        if weight <= 0.0 {
            return p;
        }
        let moved = self.pivot + (p - self.pivot) * self.scale;
        p + (moved - p) * weight
    }
}

/// Each Gaussian's skinning weight on the template's head bone and the bones below it (jaw,
/// eyes); all zero when the template has no bone named `head`.
pub fn head_weights(avatar: &Avatar, template: &BodyTemplate) -> Vec<f32> {
    let n = avatar.canonical.len();
    let Some(head) = template.skeleton.bone_index("head") else {
        return vec![0.0; n];
    };
    let in_head = template.skeleton.subtree_mask(head);
    (0..n)
        .map(|i| {
            let (bones, weights) = (&avatar.skin.bones[i], &avatar.skin.weights[i]);
            bones
                .iter()
                .zip(weights)
                .filter(|(b, _)| in_head.get(**b as usize).copied().unwrap_or(false))
                .map(|(_, w)| *w)
                .sum()
        })
        .collect()
}

/// What [`fit_head_warp`] looks at on one photo.
pub struct HeadEvidence<'a> {
    /// Each landmark's miss on the photo, where usable
    /// ([`super::landmark_warp::landmark_misses`]).
    pub misses: &'a [Option<Vec2>; BODY_LANDMARKS],
    /// The person's mask on the photo.
    pub mask: &'a GrayImage,
    /// The posed head joint, projected (before the landmark misses move it).
    pub pivot: Vec2,
    /// The person's height on the photo, pixels.
    pub height: f32,
}

/// The head's scaling on one photo (see the module doc), from the pixels where the Gaussians
/// sample it (`None` where not projected) and their head weights.
pub fn fit_head_warp(
    evidence: &HeadEvidence<'_>,
    pixels: &[Option<Vec2>],
    weights: &[f32],
) -> HeadWarp {
    let pivot = evidence.pivot + landmark_shift(evidence);
    let unscaled = HeadWarp { pivot, scale: 1.0 };
    let skull: Vec<Vec2> = pixels
        .iter()
        .zip(weights)
        .filter(|(_, w)| **w >= SKULL_WEIGHT)
        .filter_map(|(p, _)| *p)
        .collect();
    if skull.len() < 8 {
        return unscaled;
    }
    let centre = skull.iter().copied().sum::<Vec2>() / skull.len() as f32;
    let up = (centre - pivot).normalize_or_zero();
    if up == Vec2::ZERO {
        return unscaled;
    }
    // The skull's reach along three directions around "up" against the mask's.
    let mut ratios: Vec<f32> = [-0.35f32, 0.0, 0.35]
        .iter()
        .filter_map(|&angle| {
            let dir = Vec2::from_angle(angle).rotate(up);
            let reach = skull
                .iter()
                .map(|p| (*p - pivot).dot(dir))
                .fold(f32::MIN, f32::max);
            let mask_reach = mask_extent(evidence.mask, pivot, dir, evidence.height)?;
            (reach > 1.0).then(|| mask_reach / reach)
        })
        .collect();
    ratios.sort_by(f32::total_cmp);
    let scale = ratios
        .get(ratios.len() / 2)
        .copied()
        .unwrap_or(1.0)
        .clamp(SCALE_RANGE.0, SCALE_RANGE.1);
    HeadWarp { pivot, scale }
}

/// The median miss of the usable face landmarks: where the head joint moves.
fn landmark_shift(evidence: &HeadEvidence<'_>) -> Vec2 {
    let misses: Vec<Vec2> = evidence.misses[..FACE_LANDMARKS]
        .iter()
        .flatten()
        .copied()
        .collect();
    if misses.is_empty() {
        return Vec2::ZERO;
    }
    let median = |f: fn(&Vec2) -> f32| {
        let mut v: Vec<f32> = misses.iter().map(f).collect();
        v.sort_by(f32::total_cmp);
        v[v.len() / 2]
    };
    Vec2::new(median(|m| m.x), median(|m| m.y))
}

/// How far from `from` along unit `dir` the mask goes on (pixels) before three pixels in a row
/// are off it; `None` when `from` is off the mask or the mask runs past half the person's
/// height (a raised arm, not the head).
fn mask_extent(mask: &GrayImage, from: Vec2, dir: Vec2, height: f32) -> Option<f32> {
    let on = |p: Vec2| {
        p.x >= 0.0
            && p.y >= 0.0
            && (p.x as u32) < mask.width()
            && (p.y as u32) < mask.height()
            && mask.get_pixel(p.x as u32, p.y as u32).0[0] >= MASK_ON
    };
    if !on(from) {
        return None;
    }
    let mut off = 0;
    let limit = (0.5 * height).ceil() as usize;
    for step in 1..=limit {
        if on(from + dir * step as f32) {
            off = 0;
        } else {
            off += 1;
            if off == 3 {
                return Some(step as f32 - 3.0);
            }
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A disc of mask (the head, radius `r` about `c`) over a body below it.
    fn head_mask(c: Vec2, r: f32) -> GrayImage {
        GrayImage::from_fn(200, 400, |x, y| {
            let p = Vec2::new(x as f32, y as f32);
            let body = y as f32 > c.y + r * 0.8 && (x as f32 - c.x).abs() < 40.0;
            image::Luma([if p.distance(c) <= r || body { 255 } else { 0 }])
        })
    }

    /// The warp of a skull sampled at `pixels` (all head weight 1), its joint at (100, 100),
    /// with the face landmarks missing by `face_miss` on a person `mask`.
    fn warp_of(pixels: &[Option<Vec2>], face_miss: Vec2, mask: &GrayImage) -> HeadWarp {
        let misses: [Option<Vec2>; BODY_LANDMARKS] =
            std::array::from_fn(|i| (i < FACE_LANDMARKS).then_some(face_miss));
        fit_head_warp(
            &HeadEvidence {
                misses: &misses,
                mask,
                pivot: Vec2::new(100.0, 100.0),
                height: 300.0,
            },
            pixels,
            &vec![1.0; pixels.len()],
        )
    }

    #[test]
    fn the_head_grows_to_the_masks_top_about_the_joint_the_face_landmarks_place() {
        // Template skull: a disc of radius 20, its joint 20 px below its centre; face
        // landmarks 10 px right of and 10 px above the template's, and the skull's sampling
        // points already moved with them to about (110, 70). The person's head (hair): a
        // disc of radius 30 about (110, 70).
        let skull_c = Vec2::new(110.0, 70.0);
        let pixels: Vec<Option<Vec2>> = (0..200)
            .map(|k| {
                let a = k as f32 * 0.0314;
                let r = 20.0 * ((k % 10) as f32 / 9.0);
                Some(skull_c + Vec2::from_angle(a) * r)
            })
            .collect();
        let warp = warp_of(&pixels, Vec2::new(10.0, -10.0), &head_mask(skull_c, 30.0));
        assert!(
            warp.pivot.distance(Vec2::new(110.0, 90.0)) < 0.5,
            "{warp:?}"
        );
        // Skull top 40 px above the joint; the mask's top 50 px above it.
        assert!((warp.scale - 1.25).abs() < 0.1, "{warp:?}");
        let top = warp.apply(Vec2::new(110.0, 50.0), 1.0);
        assert!(top.distance(Vec2::new(110.0, 40.0)) < 5.0, "{top}");
        // A point with no head weight (the neck, the body) stays where it was.
        assert_eq!(
            warp.apply(Vec2::new(100.0, 120.0), 0.0),
            Vec2::new(100.0, 120.0)
        );
    }

    #[test]
    fn a_head_that_fits_its_mask_and_landmarks_stays() {
        let skull_c = Vec2::new(100.0, 80.0);
        let pixels: Vec<Option<Vec2>> = (0..100)
            .map(|k| Some(skull_c + Vec2::from_angle(k as f32 * 0.0628) * 20.0))
            .collect();
        let warp = warp_of(&pixels, Vec2::ZERO, &head_mask(skull_c, 20.0));
        assert_eq!(warp.pivot, Vec2::new(100.0, 100.0));
        assert!((warp.scale - 1.0).abs() < 0.08, "{warp:?}");
    }
}
