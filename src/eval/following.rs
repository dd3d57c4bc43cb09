//! One-person perception scored on crowd bags (`lhmpp eval-tracking --one-person`): each
//! camera's frames go, in time order, through a [`PersonTracker`] of their own, as the node's
//! one-person mode runs them, and each frame is scored against the bag's id maps.
//!
//! The measures, per frame:
//! - **visible**: the true persons with at least [`MIN_PERSON_PIXELS`] pixels in the id map;
//!   the frame's class is the height of the tallest of them (their id-map pixels' box) as a
//!   share of the frame's height;
//! - **found**: the person perception read is a visible true person: the one under most of
//!   their torso landmarks (shoulders, hips and their midpoints; at least [`MIN_TORSO_VOTES`]),
//!   else the one holding half of perception's mask ([`covered_person`]); a find on nobody is
//!   a **false** find, and a mask mostly on another true person than the torso's a **mixed
//!   mask**;
//! - **switches**: per camera, following passing to another person while the one followed is
//!   still in view, for at least [`LASTING_FINDS`] finds in a row (a lasting flip); shorter
//!   runs, and each find of another person while the one followed is in view, count as
//!   **finds of another** (a person hidden behind another reads as the one in front);
//! - **time**: the tracker's time for the frame (networks, mask), split into frames where the
//!   person was followed from the previous frame's landmarks and frames that ran the detector.
//!
//! On bags without id maps (real video, [`follow_frames`] alone) the found person's box gives
//! the switches instead: a jump of the box centre by more than [`JUMP_HEIGHTS`] box heights
//! between consecutive finds (with or without frames between them in which nobody was found).

use super::tracking::{covered_person, CrowdImage};
use crate::perception::follow::PixelBox;
use crate::perception::{LandmarkId, Perceived, PerceptionError, PersonTracker};
use glam::Vec2;
use image::GrayImage;
use std::collections::BTreeMap;

/// Id-map pixels from which a true person counts as visible in a frame.
pub const MIN_PERSON_PIXELS: usize = 50;
/// Torso points (of 6) that must lie on one true person for the torso to name them.
pub const MIN_TORSO_VOTES: usize = 3;
/// Finds in a row of another person, the one followed still in view, that make a switch.
pub const LASTING_FINDS: usize = 3;
/// Box-centre jump, in box heights, from which consecutive finds count as a switch on bags
/// without truth.
pub const JUMP_HEIGHTS: f32 = 0.5;

/// Height classes of a frame's tallest visible person: lower bound (share of the frame's
/// height) and label.
pub const HEIGHT_CLASSES: [(f64, &str); 7] = [
    (0.0, "under 1/10"),
    (0.1, "1/10 – 1/8"),
    (0.125, "1/8 – 1/6"),
    (1.0 / 6.0, "1/6 – 1/4"),
    (0.25, "1/4 – 1/3"),
    (1.0 / 3.0, "1/3 – 1/2"),
    (0.5, "1/2 and more"),
];

/// The class of a height share.
pub fn height_class(share: f64) -> usize {
    HEIGHT_CLASSES
        .iter()
        .rposition(|(low, _)| share >= *low)
        .unwrap_or(0)
}

/// What the tracker gave for one frame.
#[derive(Debug, Clone)]
pub struct FollowedFrame {
    /// Index of the image in the bag's order.
    pub image: usize,
    /// The camera.
    pub camera: String,
    /// What was found of the person, if anyone.
    pub found: Option<Found>,
    /// The detector ran in this frame (nobody was followed, or the person was lost).
    pub ran_detector: bool,
    /// The tracker's time for the frame, milliseconds.
    pub ms: f64,
}

/// What one frame showed of the person followed.
#[derive(Debug, Clone)]
pub struct Found {
    /// Their mask (mono8, as the node thresholds it).
    pub mask: GrayImage,
    /// Their landmarks' box.
    pub bbox: PixelBox,
    /// Their shoulders, hips and the midpoints of each pair, frame pixels.
    pub torso: [Vec2; 6],
}

impl Found {
    /// The mask `mask` and the landmarks of `p`.
    pub fn new(p: &Perceived, mask: GrayImage) -> Self {
        let at = |id: LandmarkId| p.landmarks.image[id.index()].position.truncate();
        let (ls, rs) = (at(LandmarkId::LeftShoulder), at(LandmarkId::RightShoulder));
        let (lh, rh) = (at(LandmarkId::LeftHip), at(LandmarkId::RightHip));
        Self {
            mask,
            bbox: PixelBox::around_landmarks(&p.landmarks.image),
            torso: [ls, rs, lh, rh, (ls + rs) / 2.0, (lh + rh) / 2.0],
        }
    }

    /// The true person under most of the torso points (at least [`MIN_TORSO_VOTES`]).
    pub fn torso_person(&self, ids: &GrayImage) -> Option<usize> {
        let mut votes = [0usize; 256];
        for p in self.torso {
            let (x, y) = (p.x.round(), p.y.round());
            if x >= 0.0 && y >= 0.0 && (x as u32) < ids.width() && (y as u32) < ids.height() {
                votes[usize::from(ids.get_pixel(x as u32, y as u32).0[0])] += 1;
            }
        }
        let (k, n) = votes
            .iter()
            .enumerate()
            .skip(1)
            .max_by_key(|(k, n)| (**n, std::cmp::Reverse(*k)))?;
        (*n >= MIN_TORSO_VOTES).then(|| k - 1)
    }
}

/// Runs `images` (time order) through one fresh tracker per camera made by `tracker`;
/// `each(index, image, perceived)` sees every frame's result.
pub fn follow_frames(
    images: &[CrowdImage],
    mut tracker: impl FnMut() -> PersonTracker,
    mask: impl Fn(&Perceived) -> GrayImage,
    mut each: impl FnMut(usize, &CrowdImage, Option<&Perceived>),
) -> Result<Vec<FollowedFrame>, PerceptionError> {
    let mut trackers: BTreeMap<String, PersonTracker> = BTreeMap::new();
    let mut out = Vec::with_capacity(images.len());
    for (index, image) in images.iter().enumerate() {
        let t = trackers
            .entry(image.camera.clone())
            .or_insert_with(&mut tracker);
        let _frame = tracing::trace_span!("frame", index, camera = %image.camera).entered();
        let started = std::time::Instant::now();
        let perceived = t.perceive_at(&image.rgb, image.stamp_ns as f64 * 1e-9)?;
        let found = perceived.as_ref().map(|p| Found::new(p, mask(p)));
        let ms = started.elapsed().as_secs_f64() * 1e3;
        each(index, image, perceived.as_ref());
        out.push(FollowedFrame {
            image: index,
            camera: image.camera.clone(),
            found,
            ran_detector: t.ran_detector(),
            ms,
        });
    }
    Ok(out)
}

/// True persons visible in an id map with their heights as a share of the frame's height,
/// `(k, share)` for `person_k`.
pub fn visible_heights(ids: &GrayImage) -> Vec<(usize, f64)> {
    let mut rows: BTreeMap<u8, (u32, u32, usize)> = BTreeMap::new();
    for (_, y, p) in ids.enumerate_pixels() {
        let k = p.0[0];
        if k == 0 {
            continue;
        }
        let r = rows.entry(k).or_insert((y, y, 0));
        r.0 = r.0.min(y);
        r.1 = r.1.max(y);
        r.2 += 1;
    }
    rows.into_iter()
        .filter(|(_, (_, _, n))| *n >= MIN_PERSON_PIXELS)
        .map(|(k, (top, bottom, _))| {
            let share = f64::from(bottom - top + 1) / f64::from(ids.height().max(1));
            (usize::from(k) - 1, share)
        })
        .collect()
}

/// Frames and finds of one height class.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ClassCount {
    /// Frames whose tallest visible person is in the class.
    pub frames: usize,
    /// Of those, frames in which a visible person was found.
    pub found: usize,
}

/// Per-frame times, milliseconds.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FrameTimes {
    /// Every frame.
    pub all: Vec<f64>,
    /// Frames where the person was followed from the previous frame's landmarks.
    pub followed: Vec<f64>,
    /// Frames that ran the detector.
    pub detector: Vec<f64>,
}

impl FrameTimes {
    fn push(&mut self, f: &FollowedFrame) {
        self.all.push(f.ms);
        if f.ran_detector {
            self.detector.push(f.ms);
        } else {
            self.followed.push(f.ms);
        }
    }

    /// Appends another's times.
    pub fn extend(&mut self, other: &FrameTimes) {
        self.all.extend_from_slice(&other.all);
        self.followed.extend_from_slice(&other.followed);
        self.detector.extend_from_slice(&other.detector);
    }
}

/// The `q` quantile (0..=1) of `values` (nearest rank), `None` when empty.
pub fn quantile(values: &[f64], q: f64) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let rank = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len());
    Some(v[rank - 1])
}

/// What one-person perception scored on a crowd bag.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FollowingScore {
    /// Frames.
    pub frames: usize,
    /// By [`HEIGHT_CLASSES`]: frames with someone visible, and found.
    pub classes: [ClassCount; HEIGHT_CLASSES.len()],
    /// Frames with nobody visible in which a person was found anyway.
    pub found_in_empty: usize,
    /// Finds of no true person (with someone visible or not).
    pub false_finds: usize,
    /// Finds whose mask is mostly another true person's than the one their torso is on.
    pub mixed_masks: usize,
    /// Lasting switches to another person while the one followed is in view.
    pub switches: usize,
    /// Finds of another person than the one followed while that one is in view.
    pub finds_of_another: usize,
    /// Per-frame times.
    pub times: FrameTimes,
}

impl FollowingScore {
    /// Frames with someone visible whose tallest visible person is at least `share` of the
    /// frame's height (a class bound), and of those found.
    pub fn at_least(&self, share: f64) -> ClassCount {
        let first = height_class(share);
        self.classes[first..]
            .iter()
            .fold(ClassCount::default(), |a, c| ClassCount {
                frames: a.frames + c.frames,
                found: a.found + c.found,
            })
    }

    /// Adds another bag's score.
    pub fn add(&mut self, other: &FollowingScore) {
        self.frames += other.frames;
        for (a, b) in self.classes.iter_mut().zip(&other.classes) {
            a.frames += b.frames;
            a.found += b.found;
        }
        self.found_in_empty += other.found_in_empty;
        self.false_finds += other.false_finds;
        self.mixed_masks += other.mixed_masks;
        self.switches += other.switches;
        self.finds_of_another += other.finds_of_another;
        self.times.extend(&other.times);
    }
}

/// One camera's person followed (`k` of `person_k`), and a run of finds of another one
/// (`(k, finds in a row)`).
type Followed = (usize, Option<(usize, usize)>);

/// Scores the tracker's frames against the id maps of `images`.
pub fn score_following(images: &[CrowdImage], frames: &[FollowedFrame]) -> FollowingScore {
    let mut score = FollowingScore {
        frames: frames.len(),
        ..FollowingScore::default()
    };
    let mut followed: BTreeMap<&str, Followed> = BTreeMap::new();
    for f in frames {
        score.times.push(f);
        let image = &images[f.image];
        let visible = visible_heights(&image.ids);
        let person = f.found.as_ref().map(|found| {
            let masked = covered_person(&found.mask, &image.ids);
            let torso = found.torso_person(&image.ids);
            if let (Some(m), Some(t)) = (masked, torso) {
                score.mixed_masks += usize::from(m != t);
            }
            torso.or(masked)
        });
        let tallest = visible
            .iter()
            .map(|(_, h)| *h)
            .fold(None, |a: Option<f64>, h| Some(a.map_or(h, |a| a.max(h))));
        let found_visible = match person {
            Some(Some(k)) => visible.iter().any(|(v, _)| *v == k).then_some(k),
            _ => None,
        };
        if let Some(t) = tallest {
            let class = &mut score.classes[height_class(t)];
            class.frames += 1;
            class.found += usize::from(found_visible.is_some());
        } else if f.found.is_some() {
            score.found_in_empty += 1;
        }
        if matches!(person, Some(None)) {
            score.false_finds += 1;
        }
        let Some(k) = found_visible else {
            continue;
        };
        let (current, run) = followed.entry(&f.camera).or_insert((k, None));
        if k == *current {
            *run = None;
        } else if !visible.iter().any(|(v, _)| v == current) {
            // The one followed left the view: taking up another is no switch.
            (*current, *run) = (k, None);
        } else {
            score.finds_of_another += 1;
            let n = match *run {
                Some((other, n)) if other == k => n + 1,
                _ => 1,
            };
            *run = Some((k, n));
            if n >= LASTING_FINDS {
                score.switches += 1;
                (*current, *run) = (k, None);
            }
        }
    }
    score
}

/// One camera's finds on a bag without truth.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CameraFollowing {
    /// The camera.
    pub camera: String,
    /// Frames.
    pub frames: usize,
    /// Frames in which a person was found.
    pub found: usize,
    /// Frames that ran the detector.
    pub detector_frames: usize,
    /// Consecutive finds (frames without one between them or not) whose box centres are more
    /// than [`JUMP_HEIGHTS`] box heights apart.
    pub jumps: usize,
    /// The largest such jump, in box heights.
    pub largest_jump: f32,
    /// Per-frame times.
    pub times: FrameTimes,
}

/// Per camera (in name order): finds, detector frames, box jumps and times.
pub fn camera_following(frames: &[FollowedFrame]) -> Vec<CameraFollowing> {
    let mut cameras: BTreeMap<&str, (CameraFollowing, Option<PixelBox>)> = BTreeMap::new();
    for f in frames {
        let (c, last) = cameras.entry(&f.camera).or_insert_with(|| {
            (
                CameraFollowing {
                    camera: f.camera.clone(),
                    ..CameraFollowing::default()
                },
                None,
            )
        });
        c.frames += 1;
        c.detector_frames += usize::from(f.ran_detector);
        c.times.push(f);
        // A jump across frames in which nobody was found counts too.
        if let Some(found) = &f.found {
            let b = found.bbox;
            c.found += 1;
            if let Some(prev) = last {
                let jump = b.centre().distance(prev.centre()) / prev.height().max(1.0);
                c.largest_jump = c.largest_jump.max(jump);
                c.jumps += usize::from(jump > JUMP_HEIGHTS);
            }
            *last = Some(b);
        }
    }
    cameras.into_values().map(|(c, _)| c).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::{Luma, RgbImage};

    /// A 100 × 100 frame: person 0 in rows 10..60 at x 10..20, person 1 in rows 20..40 at x
    /// 60..70.
    fn image(camera: &str) -> CrowdImage {
        let ids = GrayImage::from_fn(100, 100, |x, y| {
            Luma([match (x, y) {
                (10..20, 10..60) => 1,
                (60..70, 20..40) => 2,
                _ => 0,
            }])
        });
        CrowdImage {
            camera: camera.into(),
            stamp_ns: 0,
            rgb: RgbImage::new(100, 100),
            ids,
            camera_model: None,
            distortion: None,
        }
    }

    fn mask_over(x0: u32, x1: u32, y0: u32, y1: u32) -> GrayImage {
        GrayImage::from_fn(100, 100, |x, y| {
            Luma([if (x0..x1).contains(&x) && (y0..y1).contains(&y) {
                255
            } else {
                0
            }])
        })
    }

    /// A find whose mask is `mask`, whose torso points are all at `torso` and whose box spans
    /// `x` to `x + 10` and 0 to 40.
    fn found(mask: GrayImage, torso: Vec2, x: f32) -> Found {
        Found {
            mask,
            bbox: PixelBox::new(Vec2::new(x, 0.0), Vec2::new(x + 10.0, 40.0)),
            torso: [torso; 6],
        }
    }

    fn frame(i: usize, found: Option<Found>, detector: bool) -> FollowedFrame {
        FollowedFrame {
            image: i,
            camera: "cam0".into(),
            found,
            ran_detector: detector,
            ms: i as f64,
        }
    }

    #[test]
    fn heights_are_shares_of_the_frame() {
        let v = visible_heights(&image("cam0").ids);
        assert_eq!(v.len(), 2);
        assert_eq!(v[0].0, 0);
        assert!((v[0].1 - 0.5).abs() < 1e-9);
        assert!((v[1].1 - 0.2).abs() < 1e-9);
        assert_eq!(height_class(0.5), 6);
        assert_eq!(height_class(0.12), 1);
        assert_eq!(height_class(0.05), 0);
    }

    #[test]
    fn finds_switches_and_false_finds_are_counted() {
        let images: Vec<CrowdImage> = (0..6).map(|_| image("cam0")).collect();
        let person0 = mask_over(10, 20, 10, 60);
        let person1 = mask_over(60, 70, 20, 40);
        let nobody = mask_over(80, 90, 80, 90);
        let (on0, on1) = (Vec2::new(15.0, 30.0), Vec2::new(65.0, 30.0));
        let off = Vec2::splat(85.0);
        let frames = vec![
            frame(0, Some(found(person0.clone(), on0, 0.0)), true),
            frame(1, Some(found(person0.clone(), on0, 0.0)), false),
            // following flips to person 1 while person 0 is still in view
            frame(2, Some(found(person1.clone(), on1, 0.0)), false),
            frame(3, Some(found(nobody.clone(), off, 0.0)), true),
            // the torso is back on person 0, the mask on nobody: still a find of person 0
            frame(4, Some(found(nobody, on0, 0.0)), true),
            // the torso on person 0, the mask on person 1
            frame(5, Some(found(person1, on0, 0.0)), false),
        ];
        let s = score_following(&images, &frames);
        assert_eq!(s.frames, 6);
        let all = ClassCount {
            frames: 6,
            found: 5,
        };
        assert_eq!(s.classes[6], all);
        assert_eq!(s.at_least(0.125), all);
        assert_eq!(s.switches, 0, "one find of person 1: no lasting switch");
        assert_eq!(s.finds_of_another, 1);
        assert_eq!(s.false_finds, 1);
        assert_eq!(s.mixed_masks, 1);
        assert_eq!(s.times.detector, vec![0.0, 3.0, 4.0]);
        assert_eq!(s.times.followed, vec![1.0, 2.0, 5.0]);
        assert_eq!(quantile(&s.times.all, 0.5), Some(2.0));
        assert_eq!(quantile(&s.times.all, 0.95), Some(5.0));
    }

    #[test]
    fn a_lasting_run_of_another_person_in_view_is_a_switch() {
        let images: Vec<CrowdImage> = (0..7).map(|_| image("cam0")).collect();
        let (m0, m1) = (mask_over(10, 20, 10, 60), mask_over(60, 70, 20, 40));
        let (on0, on1) = (Vec2::new(15.0, 30.0), Vec2::new(65.0, 30.0));
        let on = |i, m: &GrayImage, p| frame(i, Some(found(m.clone(), p, 0.0)), false);
        let frames = vec![
            on(0, &m0, on0),
            on(1, &m1, on1),
            on(2, &m0, on0),
            on(3, &m1, on1),
            on(4, &m1, on1),
            on(5, &m1, on1),
            on(6, &m1, on1),
        ];
        let s = score_following(&images, &frames);
        assert_eq!((s.switches, s.finds_of_another), (1, 4));
    }

    #[test]
    fn a_box_that_jumps_counts_on_bags_without_truth() {
        let frames: Vec<FollowedFrame> = [0.0, 5.0, 60.0, 62.0]
            .iter()
            .enumerate()
            .map(|(i, &x)| frame(i, Some(found(GrayImage::new(1, 1), Vec2::ZERO, x)), false))
            .collect();
        let c = camera_following(&frames);
        assert_eq!(c.len(), 1);
        assert_eq!((c[0].frames, c[0].found, c[0].jumps), (4, 4, 1));
        assert!((c[0].largest_jump - 55.0 / 40.0).abs() < 1e-5);
    }
}
