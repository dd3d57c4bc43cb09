//! Debug pictures of what perception saw: the frame with the person mask tinted and the
//! landmark skeleton drawn on top (`lhmpp perceive`, the README's pictures).

use super::landmark::{Landmark, LandmarkId, BODY_LANDMARKS, SKELETON_EDGES};
use glam::Vec2;
use image::{GrayImage, Rgb, RgbImage};

/// Tint of the mask.
const MASK_TINT: [f32; 3] = [40.0, 200.0, 255.0];
/// How strongly a full mask pixel takes the tint.
const MASK_ALPHA: f32 = 0.45;
/// Colours of the body's left side, right side and centre line.
const LEFT: Rgb<u8> = Rgb([255, 140, 0]);
const RIGHT: Rgb<u8> = Rgb([0, 200, 80]);
const CENTRE: Rgb<u8> = Rgb([255, 255, 255]);

/// `image` with `mask` tinted and the landmarks at least `min_visibility` visible joined by
/// the skeleton's bones; line width scales with the frame.
pub fn draw_overlay(
    image: &RgbImage,
    mask: Option<&GrayImage>,
    landmarks: Option<&[Landmark; BODY_LANDMARKS]>,
    min_visibility: f32,
) -> RgbImage {
    let mut out = image.clone();
    if let Some(mask) = mask.filter(|m| m.dimensions() == image.dimensions()) {
        for (p, m) in out.pixels_mut().zip(mask.pixels()) {
            let a = MASK_ALPHA * f32::from(m.0[0]) / 255.0;
            for (channel, tint) in p.0.iter_mut().zip(MASK_TINT) {
                *channel = (f32::from(*channel) * (1.0 - a) + tint * a).round() as u8;
            }
        }
    }
    let Some(landmarks) = landmarks else {
        return out;
    };
    let width = (image.width().max(image.height()) as f32 / 250.0).max(1.5);
    let seen = |id: LandmarkId| {
        let l = landmarks[id.index()];
        (l.visibility >= min_visibility).then(|| l.position.truncate())
    };
    for (a, b) in SKELETON_EDGES {
        if let (Some(pa), Some(pb)) = (seen(a), seen(b)) {
            draw_line(&mut out, pa, pb, width, side_colour(a, b));
        }
    }
    for id in LandmarkId::ALL {
        if let Some(p) = seen(id) {
            draw_disc(&mut out, p, width * 1.6, side_colour(id, id));
        }
    }
    out
}

/// Left-side bones orange, right-side green, the rest white.
fn side_colour(a: LandmarkId, b: LandmarkId) -> Rgb<u8> {
    let left = |id: LandmarkId| id.name().starts_with("left") || id.name().ends_with("left");
    let right = |id: LandmarkId| id.name().starts_with("right") || id.name().ends_with("right");
    if left(a) && left(b) {
        LEFT
    } else if right(a) && right(b) {
        RIGHT
    } else {
        CENTRE
    }
}

/// A line of the given width from `a` to `b` (a disc stamped along it).
pub fn draw_line(image: &mut RgbImage, a: Vec2, b: Vec2, width: f32, colour: Rgb<u8>) {
    let steps = (a.distance(b) / (width * 0.5).max(0.5)).ceil().max(1.0) as usize;
    for i in 0..=steps {
        draw_disc(
            image,
            a.lerp(b, i as f32 / steps as f32),
            width / 2.0,
            colour,
        );
    }
}

/// A filled disc of `radius` pixels centred at `c`.
pub fn draw_disc(image: &mut RgbImage, c: Vec2, radius: f32, colour: Rgb<u8>) {
    let (w, h) = (image.width() as i64, image.height() as i64);
    let r = radius.max(0.5);
    let (x0, x1) = ((c.x - r).floor() as i64, (c.x + r).ceil() as i64);
    let (y0, y1) = ((c.y - r).floor() as i64, (c.y + r).ceil() as i64);
    for y in y0.max(0)..=y1.min(h - 1) {
        for x in x0.max(0)..=x1.min(w - 1) {
            if Vec2::new(x as f32, y as f32).distance(c) <= r {
                image.put_pixel(x as u32, y as u32, colour);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn the_mask_is_tinted_and_visible_bones_are_drawn() {
        let image = RgbImage::from_pixel(100, 100, Rgb([0, 0, 0]));
        let mut mask = GrayImage::new(100, 100);
        mask.put_pixel(5, 5, image::Luma([255]));
        let mut landmarks = [Landmark::default(); BODY_LANDMARKS];
        let mut place = |id: LandmarkId, x: f32, y: f32, v: f32| {
            landmarks[id.index()] = Landmark {
                position: Vec3::new(x, y, 0.0),
                visibility: v,
                presence: 1.0,
            }
        };
        place(LandmarkId::LeftShoulder, 50.0, 20.0, 0.9);
        place(LandmarkId::LeftElbow, 50.0, 60.0, 0.9);
        place(LandmarkId::RightShoulder, 80.0, 20.0, 0.1);
        let out = draw_overlay(&image, Some(&mask), Some(&landmarks), 0.5);
        assert_ne!(out.get_pixel(5, 5), &Rgb([0, 0, 0]), "mask tinted");
        assert_eq!(
            out.get_pixel(6, 50),
            &Rgb([0, 0, 0]),
            "background untouched"
        );
        assert_eq!(out.get_pixel(50, 40), &LEFT, "left upper arm drawn");
        assert_eq!(
            out.get_pixel(80, 20),
            &Rgb([0, 0, 0]),
            "invisible landmark not drawn"
        );
    }
}
