//! Body regions of an image, drawn from perception's 33 image landmarks and cut to the person
//! mask, the same way on a photo and on a render of the avatar.
//!
//! Lengths scale with the torso length `s` (the distance between the shoulders' and the hips'
//! midpoints, in pixels; the landmark model places hidden and out-of-frame landmarks too, so
//! `s` is always defined). Each region is a union of parts, each part a union of shapes:
//!
//! | region | parts (each needs its landmarks seen) | shape |
//! | --- | --- | --- |
//! | torso | shoulders and hips | the quadrilateral shoulder–shoulder–hip–hip shrunk to 85 % about its centre, and a band 0.12 s wide on each side of the shoulder-midpoint → hip-midpoint line (10-90 % of it), so side views keep a torso; less the forearm bands (elbow → 120 % of elbow–wrist, 0.10 s) |
//! | upper arms | left, right: shoulder and elbow | band 0.10 s around shoulder → elbow, 15-85 % |
//! | thighs | left, right: hip and knee | band 0.14 s around hip → knee, 10-85 % |
//! | shins | left, right: knee and ankle | band 0.09 s around knee → ankle, 15-85 % |
//! | feet | left, right: ankle, heel and toe | triangle ankle–heel–toe and a band 0.05 s around heel → toe |
//! | head | nose and an ear | disc of radius 0.18 s about the mean of nose and ears |
//!
//! A landmark is seen when its visibility and presence are both at least
//! [`RegionConfig::min_visibility`] and it lies inside the image. Left and right are pooled: a
//! region's colour is taken over the pixels of every part the photo shows. Where shapes
//! overlap, a pixel belongs to the first region of head, upper arms, feet, shins, thighs, torso.
//! Only mask pixels (≥ [`RegionConfig::mask_threshold`]) count.

use crate::perception::{Landmark, LandmarkId, BODY_LANDMARKS};
use glam::Vec2;
use image::GrayImage;
use serde::Serialize;

/// The body regions compared, in table order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Region {
    /// Chest and belly, between shoulders and hips.
    Torso,
    /// Both upper arms, shoulder to elbow.
    UpperArms,
    /// Both thighs, hip to knee.
    Thighs,
    /// Both shins, knee to ankle.
    Shins,
    /// Both feet (shoes).
    Feet,
    /// Face and hair.
    Head,
}

impl Region {
    /// Every region, in table order.
    pub const ALL: [Region; 6] = [
        Region::Torso,
        Region::UpperArms,
        Region::Thighs,
        Region::Shins,
        Region::Feet,
        Region::Head,
    ];

    /// Index in [`Region::ALL`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// Name in tables.
    pub fn name(self) -> &'static str {
        match self {
            Region::Torso => "torso",
            Region::UpperArms => "upper arms",
            Region::Thighs => "thighs",
            Region::Shins => "shins",
            Region::Feet => "feet",
            Region::Head => "head",
        }
    }

    /// The colour the region is drawn in on pictures.
    pub fn tint(self) -> [u8; 3] {
        match self {
            Region::Torso => [235, 50, 50],
            Region::UpperArms => [255, 165, 0],
            Region::Thighs => [40, 100, 255],
            Region::Shins => [0, 210, 230],
            Region::Feet => [225, 40, 225],
            Region::Head => [50, 205, 50],
        }
    }
}

/// Thresholds of the region extraction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RegionConfig {
    /// Visibility and presence a landmark needs to be seen.
    pub min_visibility: f32,
    /// Mask values at or above this are the person.
    pub mask_threshold: u8,
    /// Pixels a region needs for its colour to be taken.
    pub min_pixels: usize,
}

impl Default for RegionConfig {
    fn default() -> Self {
        Self {
            min_visibility: 0.5,
            mask_threshold: 128,
            min_pixels: 40,
        }
    }
}

/// The left/right parts of the regions: which ones a photo shows.
pub type Sides = [[bool; 2]; 6];

/// Which parts the landmarks show: per region, `[left, right]` (torso and head use the first).
pub fn seen_parts(landmarks: &[Landmark; BODY_LANDMARKS], config: &RegionConfig) -> Sides {
    let seen = |ids: &[LandmarkId]| ids.iter().all(|id| visible(&landmarks[id.index()], config));
    use LandmarkId::*;
    let mut sides = [[false; 2]; 6];
    sides[Region::Torso.index()][0] = seen(&[LeftShoulder, RightShoulder, LeftHip, RightHip]);
    sides[Region::Head.index()][0] = seen(&[Nose]) && (seen(&[LeftEar]) || seen(&[RightEar]));
    for (side, [shoulder, elbow, hip, knee, ankle, heel, toe]) in [
        [
            LeftShoulder,
            LeftElbow,
            LeftHip,
            LeftKnee,
            LeftAnkle,
            LeftHeel,
            LeftFootIndex,
        ],
        [
            RightShoulder,
            RightElbow,
            RightHip,
            RightKnee,
            RightAnkle,
            RightHeel,
            RightFootIndex,
        ],
    ]
    .into_iter()
    .enumerate()
    {
        sides[Region::UpperArms.index()][side] = seen(&[shoulder, elbow]);
        sides[Region::Thighs.index()][side] = seen(&[hip, knee]);
        sides[Region::Shins.index()][side] = seen(&[knee, ankle]);
        sides[Region::Feet.index()][side] = seen(&[ankle, heel, toe]);
    }
    sides
}

fn visible(l: &Landmark, config: &RegionConfig) -> bool {
    l.visibility >= config.min_visibility
        && l.presence >= config.min_visibility
        && l.position.is_finite()
        && l.position.x >= 0.0
        && l.position.y >= 0.0
}

/// One image's regions: a label per pixel (0 = none, `1 + region index`).
#[derive(Debug, Clone, PartialEq)]
pub struct RegionMap {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// The parts drawn.
    pub sides: Sides,
    labels: Vec<u8>,
}

impl RegionMap {
    /// The region of pixel `(x, y)`, if any.
    pub fn at(&self, x: u32, y: u32) -> Option<Region> {
        let label = self.labels[(y * self.width + x) as usize];
        (label > 0).then(|| Region::ALL[usize::from(label) - 1])
    }

    /// Pixels of each region.
    pub fn pixel_counts(&self) -> [usize; 6] {
        let mut counts = [0; 6];
        for &l in &self.labels {
            if l > 0 {
                counts[usize::from(l) - 1] += 1;
            }
        }
        counts
    }
}

/// A band around a segment: points within `radius` of `a + t·(b − a)`, `t` in `t0..=t1`.
#[derive(Debug, Clone, Copy)]
struct Band {
    a: Vec2,
    b: Vec2,
    radius: f32,
    t0: f32,
    t1: f32,
}

impl Band {
    fn contains(&self, p: Vec2) -> bool {
        let d = self.b - self.a;
        let len2 = d.length_squared();
        if len2 < 1e-6 {
            return false;
        }
        let t = (p - self.a).dot(d) / len2;
        if t < self.t0 || t > self.t1 {
            return false;
        }
        (self.a + t * d).distance_squared(p) <= self.radius * self.radius
    }

    fn bounds(&self) -> (Vec2, Vec2) {
        let (p, q) = (self.a.lerp(self.b, self.t0), self.a.lerp(self.b, self.t1));
        (p.min(q) - self.radius, p.max(q) + self.radius)
    }
}

/// A shape of a part.
#[derive(Debug, Clone)]
enum Shape {
    Band(Band),
    /// A convex polygon (any winding).
    Polygon(Vec<Vec2>),
    Disc(Vec2, f32),
}

impl Shape {
    fn contains(&self, p: Vec2) -> bool {
        match self {
            Shape::Band(b) => b.contains(p),
            Shape::Polygon(v) => {
                let mut sign = 0.0f32;
                for i in 0..v.len() {
                    let (a, b) = (v[i], v[(i + 1) % v.len()]);
                    let c = (b - a).perp_dot(p - a);
                    if c != 0.0 {
                        if sign != 0.0 && c.signum() != sign {
                            return false;
                        }
                        sign = c.signum();
                    }
                }
                v.len() >= 3
            }
            Shape::Disc(c, r) => c.distance_squared(p) <= r * r,
        }
    }

    fn bounds(&self) -> (Vec2, Vec2) {
        match self {
            Shape::Band(b) => b.bounds(),
            Shape::Polygon(v) => v.iter().fold(
                (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY)),
                |(lo, hi), p| (lo.min(*p), hi.max(*p)),
            ),
            Shape::Disc(c, r) => (*c - *r, *c + *r),
        }
    }
}

/// The regions of an image whose person has `landmarks` (image landmarks, pixels) and `mask`,
/// drawing the parts `sides` names (a photo's: [`seen_parts`] of its landmarks; a render's:
/// the photo's, so both sides compare the same parts).
pub fn region_map(
    landmarks: &[Landmark; BODY_LANDMARKS],
    mask: &GrayImage,
    sides: Sides,
    config: &RegionConfig,
) -> RegionMap {
    use LandmarkId::*;
    let p = |id: LandmarkId| landmarks[id.index()].position.truncate();
    let band = |a: LandmarkId, b: LandmarkId, radius: f32, t0: f32, t1: f32| {
        Shape::Band(Band {
            a: p(a),
            b: p(b),
            radius,
            t0,
            t1,
        })
    };
    let shoulders = 0.5 * (p(LeftShoulder) + p(RightShoulder));
    let hips = 0.5 * (p(LeftHip) + p(RightHip));
    let s = shoulders.distance(hips).max(1.0);

    // Parts in label priority order; each: region, shapes.
    let mut parts: Vec<(Region, Vec<Shape>)> = Vec::new();
    if sides[Region::Head.index()][0] {
        let centre = (p(Nose) + p(LeftEar) + p(RightEar)) / 3.0;
        parts.push((Region::Head, vec![Shape::Disc(centre, 0.18 * s)]));
    }
    let limbs = [
        [
            LeftShoulder,
            LeftElbow,
            LeftHip,
            LeftKnee,
            LeftAnkle,
            LeftHeel,
            LeftFootIndex,
        ],
        [
            RightShoulder,
            RightElbow,
            RightHip,
            RightKnee,
            RightAnkle,
            RightHeel,
            RightFootIndex,
        ],
    ];
    for (side, [shoulder, elbow, ..]) in limbs.iter().enumerate() {
        if sides[Region::UpperArms.index()][side] {
            parts.push((
                Region::UpperArms,
                vec![band(*shoulder, *elbow, 0.10 * s, 0.15, 0.85)],
            ));
        }
    }
    for (side, [.., ankle, heel, toe]) in limbs.iter().enumerate() {
        if sides[Region::Feet.index()][side] {
            parts.push((
                Region::Feet,
                vec![
                    Shape::Polygon(vec![p(*ankle), p(*heel), p(*toe)]),
                    band(*heel, *toe, 0.05 * s, 0.0, 1.0),
                ],
            ));
        }
    }
    for (side, [_, _, _, knee, ankle, ..]) in limbs.iter().enumerate() {
        if sides[Region::Shins.index()][side] {
            parts.push((
                Region::Shins,
                vec![band(*knee, *ankle, 0.09 * s, 0.15, 0.85)],
            ));
        }
    }
    for (side, [_, _, hip, knee, ..]) in limbs.iter().enumerate() {
        if sides[Region::Thighs.index()][side] {
            parts.push((
                Region::Thighs,
                vec![band(*hip, *knee, 0.14 * s, 0.10, 0.85)],
            ));
        }
    }
    let forearms = [
        band(LeftElbow, LeftWrist, 0.10 * s, 0.0, 1.2),
        band(RightElbow, RightWrist, 0.10 * s, 0.0, 1.2),
    ];
    if sides[Region::Torso.index()][0] {
        let quad = [LeftShoulder, RightShoulder, RightHip, LeftHip].map(p);
        let centre = quad.iter().copied().sum::<Vec2>() / 4.0;
        let shrunk = quad.iter().map(|q| centre + 0.85 * (*q - centre)).collect();
        parts.push((
            Region::Torso,
            vec![
                Shape::Polygon(shrunk),
                Shape::Band(Band {
                    a: shoulders,
                    b: hips,
                    radius: 0.12 * s,
                    t0: 0.1,
                    t1: 0.9,
                }),
            ],
        ));
    }

    let (w, h) = mask.dimensions();
    let mut labels = vec![0u8; (w * h) as usize];
    for (region, shapes) in &parts {
        let label = region.index() as u8 + 1;
        for shape in shapes {
            let (lo, hi) = shape.bounds();
            if !(lo.is_finite() && hi.is_finite()) {
                continue;
            }
            let x0 = lo.x.floor().max(0.0) as u32;
            let y0 = lo.y.floor().max(0.0) as u32;
            let x1 = (hi.x.ceil().max(0.0) as u32).min(w);
            let y1 = (hi.y.ceil().max(0.0) as u32).min(h);
            for y in y0..y1 {
                for x in x0..x1 {
                    let i = (y * w + x) as usize;
                    if labels[i] != 0 || mask.get_pixel(x, y).0[0] < config.mask_threshold {
                        continue;
                    }
                    let q = Vec2::new(x as f32, y as f32);
                    if !shape.contains(q) {
                        continue;
                    }
                    if *region == Region::Torso && forearms.iter().any(|f| f.contains(q)) {
                        continue;
                    }
                    labels[i] = label;
                }
            }
        }
    }
    RegionMap {
        width: w,
        height: h,
        sides,
        labels,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// A frontal stick figure, 100 px torso, everything seen.
    fn figure() -> [Landmark; BODY_LANDMARKS] {
        use LandmarkId::*;
        let mut l = [Landmark::default(); BODY_LANDMARKS];
        let mut set = |id: LandmarkId, x: f32, y: f32| {
            l[id.index()] = Landmark {
                position: Vec3::new(x, y, 0.0),
                visibility: 0.9,
                presence: 0.9,
            }
        };
        // The person's left on the image's right.
        set(Nose, 100.0, 40.0);
        set(LeftEar, 115.0, 38.0);
        set(RightEar, 85.0, 38.0);
        set(LeftShoulder, 130.0, 80.0);
        set(RightShoulder, 70.0, 80.0);
        set(LeftElbow, 150.0, 130.0);
        set(RightElbow, 50.0, 130.0);
        set(LeftWrist, 160.0, 180.0);
        set(RightWrist, 40.0, 180.0);
        set(LeftHip, 120.0, 180.0);
        set(RightHip, 80.0, 180.0);
        set(LeftKnee, 122.0, 260.0);
        set(RightKnee, 78.0, 260.0);
        set(LeftAnkle, 124.0, 340.0);
        set(RightAnkle, 76.0, 340.0);
        set(LeftHeel, 122.0, 350.0);
        set(RightHeel, 78.0, 350.0);
        set(LeftFootIndex, 134.0, 358.0);
        set(RightFootIndex, 66.0, 358.0);
        l
    }

    #[test]
    fn regions_land_on_their_limbs_and_need_their_landmarks() {
        let config = RegionConfig::default();
        let l = figure();
        let mask = GrayImage::from_pixel(200, 380, image::Luma([255]));
        let sides = seen_parts(&l, &config);
        assert!(sides.iter().all(|s| s[0]), "{sides:?}");
        let map = region_map(&l, &mask, sides, &config);
        assert_eq!(map.at(100, 130), Some(Region::Torso));
        assert_eq!(map.at(140, 105), Some(Region::UpperArms));
        assert_eq!(map.at(60, 105), Some(Region::UpperArms));
        assert_eq!(map.at(121, 220), Some(Region::Thighs));
        assert_eq!(map.at(77, 300), Some(Region::Shins));
        assert_eq!(map.at(128, 354), Some(Region::Feet));
        assert_eq!(map.at(100, 38), Some(Region::Head));
        assert_eq!(map.at(5, 5), None);
        // Forearms belong to no region.
        assert_eq!(map.at(155, 155), None);
        let counts = map.pixel_counts();
        assert!(counts.iter().all(|c| *c >= config.min_pixels), "{counts:?}");

        // Outside the mask nothing is labelled.
        let empty = region_map(&l, &GrayImage::new(200, 380), sides, &config);
        assert_eq!(empty.pixel_counts(), [0; 6]);

        // A hidden left knee takes the left thigh and shin away, not the right ones.
        let mut hidden = l;
        hidden[LandmarkId::LeftKnee.index()].visibility = 0.1;
        let sides = seen_parts(&hidden, &config);
        assert_eq!(sides[Region::Thighs.index()], [false, true]);
        assert_eq!(sides[Region::Shins.index()], [false, true]);
        let map = region_map(&hidden, &mask, sides, &config);
        assert_eq!(map.at(121, 220), None);
        assert_eq!(map.at(79, 220), Some(Region::Thighs));
        // Landmarks off the frame (negative pixels) are not seen.
        let mut off = l;
        off[LandmarkId::Nose.index()].position.y = -5.0;
        assert!(!seen_parts(&off, &config)[Region::Head.index()][0]);
    }
}
