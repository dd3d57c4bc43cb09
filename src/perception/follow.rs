//! Which person one camera follows when several are in view (one-person mode): the person
//! already followed, found again where they were last seen; when nobody is followed, the most
//! prominent one (the largest box, then the nearest the frame's centre).

use super::landmark::{Landmark, BODY_LANDMARKS};
use glam::Vec2;

/// Boxes whose area is at least this share of the largest box's count as large as it: among
/// them the one nearest the frame's centre comes first.
const AS_LARGE: f32 = 0.8;
/// A box is the followed person found again when its centre lies within this many of the
/// last box's heights from the last box's centre ...
const MAX_CENTRE_SHIFT: f32 = 0.5;
/// ... and this many more for each second since (they walk on while hidden), ...
const SHIFT_PER_SECOND: f32 = 1.5;
/// ... up to this many;
const MAX_SHIFT: f32 = 2.0;
/// ... and its height is within this factor of the last box's height (either way).
const MAX_HEIGHT_RATIO: f32 = 2.0;
/// Landmark visibility from which a landmark bounds the followed person's box.
const MIN_BOX_VISIBILITY: f32 = 0.5;

/// An axis-aligned box in frame pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelBox {
    /// Top-left corner.
    pub min: Vec2,
    /// Bottom-right corner.
    pub max: Vec2,
}

impl PixelBox {
    /// The box from `min` to `max`.
    pub fn new(min: Vec2, max: Vec2) -> Self {
        Self { min, max }
    }

    /// The box around a person's image landmarks: those visible at least
    /// [`MIN_BOX_VISIBILITY`], or all 33 when fewer than four are.
    pub fn around_landmarks(landmarks: &[Landmark; BODY_LANDMARKS]) -> Self {
        let seen: Vec<Vec2> = landmarks
            .iter()
            .filter(|l| l.visibility >= MIN_BOX_VISIBILITY)
            .map(|l| l.position.truncate())
            .collect();
        let points: Vec<Vec2> = if seen.len() >= 4 {
            seen
        } else {
            landmarks.iter().map(|l| l.position.truncate()).collect()
        };
        let min = points
            .iter()
            .copied()
            .fold(Vec2::splat(f32::MAX), Vec2::min);
        let max = points
            .iter()
            .copied()
            .fold(Vec2::splat(f32::MIN), Vec2::max);
        Self { min, max }
    }

    /// Width × height (0 for an empty box).
    pub fn area(&self) -> f32 {
        let d = (self.max - self.min).max(Vec2::ZERO);
        d.x * d.y
    }

    /// Height in pixels.
    pub fn height(&self) -> f32 {
        (self.max.y - self.min.y).max(0.0)
    }

    /// The centre.
    pub fn centre(&self) -> Vec2 {
        0.5 * (self.min + self.max)
    }

    /// Intersection over union with `other` (0 when either is empty).
    pub fn iou(&self, other: &PixelBox) -> f32 {
        let inter = PixelBox::new(self.min.max(other.min), self.max.min(other.max)).area();
        let union = self.area() + other.area() - inter;
        if union > 0.0 {
            inter / union
        } else {
            0.0
        }
    }
}

/// The order in which to try the people of a frame when nobody is followed: the largest box
/// first, where boxes nearly as large as the largest (within [`AS_LARGE`] of its area) go by
/// their distance to the frame's centre; the rest follow by area.
pub fn by_prominence(boxes: &[PixelBox], width: u32, height: u32) -> Vec<usize> {
    let centre = Vec2::new(width as f32, height as f32) / 2.0;
    let largest = boxes.iter().map(PixelBox::area).fold(0.0f32, f32::max);
    let mut order: Vec<usize> = (0..boxes.len()).collect();
    order.sort_by(|&a, &b| {
        let (ba, bb) = (&boxes[a], &boxes[b]);
        let large = |b: &PixelBox| b.area() >= AS_LARGE * largest;
        match (large(ba), large(bb)) {
            (true, true) => ba
                .centre()
                .distance(centre)
                .total_cmp(&bb.centre().distance(centre)),
            (true, false) => std::cmp::Ordering::Less,
            (false, true) => std::cmp::Ordering::Greater,
            (false, false) => bb.area().total_cmp(&ba.area()),
        }
    });
    order
}

/// The boxes that can be the person last seen in `last`, `seconds` before, nearest first:
/// centre within [`MAX_CENTRE_SHIFT`] of `last`'s height (plus [`SHIFT_PER_SECOND`] a second
/// since, at most [`MAX_SHIFT`]) and a height within [`MAX_HEIGHT_RATIO`] of it.
pub fn near_followed(boxes: &[PixelBox], last: &PixelBox, seconds: f64) -> Vec<usize> {
    let shift = (MAX_CENTRE_SHIFT + SHIFT_PER_SECOND * seconds.max(0.0) as f32).min(MAX_SHIFT);
    let reach = shift * last.height().max(1.0);
    let distance = |b: &PixelBox| b.centre().distance(last.centre());
    let mut near: Vec<usize> = (0..boxes.len())
        .filter(|&i| {
            let b = &boxes[i];
            let ratio = b.height().max(1.0) / last.height().max(1.0);
            distance(b) <= reach && (1.0 / MAX_HEIGHT_RATIO..=MAX_HEIGHT_RATIO).contains(&ratio)
        })
        .collect();
    near.sort_by(|&a, &b| distance(&boxes[a]).total_cmp(&distance(&boxes[b])));
    near
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    fn at(x: f32, y: f32, w: f32, h: f32) -> PixelBox {
        PixelBox::new(Vec2::new(x, y), Vec2::new(x + w, y + h))
    }

    #[test]
    fn the_largest_person_comes_first_and_near_ties_go_to_the_one_nearest_the_centre() {
        // 640×480: a large person at the edge, a slightly smaller one in the middle, a small
        // one in the middle.
        let boxes = [
            at(10.0, 100.0, 60.0, 200.0),
            at(290.0, 120.0, 58.0, 190.0),
            at(300.0, 200.0, 20.0, 60.0),
        ];
        assert_eq!(by_prominence(&boxes, 640, 480), vec![1, 0, 2]);
        // Clearly larger wins over nearer the centre.
        let boxes = [at(10.0, 100.0, 100.0, 300.0), at(300.0, 200.0, 30.0, 90.0)];
        assert_eq!(by_prominence(&boxes, 640, 480), vec![0, 1]);
        assert!(by_prominence(&[], 640, 480).is_empty());
    }

    #[test]
    fn the_followed_person_is_the_box_where_they_were_not_a_larger_one_elsewhere() {
        let last = at(100.0, 100.0, 30.0, 90.0);
        let boxes = [
            at(400.0, 50.0, 120.0, 360.0),  // someone else, larger
            at(110.0, 105.0, 32.0, 92.0),   // the followed person, moved a little
            at(100.0, 100.0, 120.0, 360.0), // at the same place but four times as tall
        ];
        assert_eq!(near_followed(&boxes, &last, 0.0), vec![1]);
        assert!(near_followed(&boxes[..1], &last, 0.0).is_empty());
        // 90 px to the right: too far the next frame, near enough a second on.
        let walked = [at(190.0, 100.0, 30.0, 90.0)];
        assert!(near_followed(&walked, &last, 1.0 / 30.0).is_empty());
        assert_eq!(near_followed(&walked, &last, 1.0), vec![0]);
    }

    #[test]
    fn the_landmark_box_spans_the_visible_landmarks() {
        let mut l = [Landmark {
            position: Vec3::new(50.0, 50.0, 0.0),
            visibility: 0.9,
            presence: 0.9,
        }; BODY_LANDMARKS];
        l[0].position = Vec3::new(40.0, 10.0, 0.0);
        l[1].position = Vec3::new(70.0, 90.0, 0.0);
        l[2].position = Vec3::new(500.0, 500.0, 0.0);
        l[2].visibility = 0.1;
        let b = PixelBox::around_landmarks(&l);
        assert_eq!(
            (b.min, b.max),
            (Vec2::new(40.0, 10.0), Vec2::new(70.0, 90.0))
        );
    }

    #[test]
    fn overlap_is_intersection_over_union() {
        let a = at(0.0, 0.0, 10.0, 10.0);
        assert!((a.iou(&a) - 1.0).abs() < 1e-6);
        assert!((a.iou(&at(5.0, 0.0, 10.0, 10.0)) - 50.0 / 150.0).abs() < 1e-6);
        assert_eq!(a.iou(&at(20.0, 0.0, 10.0, 10.0)), 0.0);
    }
}
