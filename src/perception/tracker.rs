//! One camera's person tracking, as MediaPipe's pose-landmark graph runs it: a detector only
//! while nobody is tracked, then each frame's crop from the previous frame's landmarks; the
//! landmark model's presence score decides whether the person is still there. The detector is
//! MoveNet MultiPose by default (it finds people who fill a small part of the frame; the person
//! taken up is chosen by [`super::follow`]), or BlazePose's own.
//!
//! Where two people cross, the crop can slide from the person followed onto the other. The
//! followed person's colours ([`Looks`]) are kept: a frame whose person looks too unlike them
//! runs the detector, and the person who looks most like them is followed, if anyone does.
//! Someone else is taken up only once the person followed has been gone [`HOLD_SECONDS`], or
//! right away when they were last seen at the frame's edge (they walked out of view).

use super::detection::{PersonDetection, DETECTOR_INPUT, MIN_DETECTION_SCORE};
use super::follow::{by_prominence, near_followed, PixelBox};
use super::landmarks::{PoseLandmarks, MIN_PRESENCE};
use super::looks::Looks;
use super::multipose::PersonInstance;
use super::people::{person_roi, PeopleConfig, PeopleFinder};
use super::pose_networks::PoseNetworks;
use super::roi::RotatedRect;
use super::segmentation::ProbabilityMap;
use super::PerceptionError;
use image::RgbImage;
use std::sync::Arc;

/// Share of the previous mask blended in where the new one is uncertain (MediaPipe's pose
/// graph uses 0.7).
const MASK_SMOOTHING: f32 = 0.7;

/// Which network finds the person a camera starts following (one-person mode).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PersonDetector {
    /// MoveNet MultiPose, the several-people finder ([`PeopleFinder`]): every person in the
    /// frame, at [`PeopleConfig::detector_side`]; the person followed is the one last seen
    /// there, else the most prominent ([`super::follow`]).
    #[default]
    MultiPose,
    /// BlazePose's own detector (the whole frame letterboxed into 224 × 224): made for a
    /// person filling much of the frame; its best detection is followed.
    BlazePose,
}

impl PersonDetector {
    /// The name configurations use (`movenet`, `blazepose`).
    pub fn name(self) -> &'static str {
        match self {
            Self::MultiPose => "movenet",
            Self::BlazePose => "blazepose",
        }
    }
}

/// Seconds after losing the followed person during which nobody else is taken up (they may be
/// hidden behind someone, or blurred, for a moment); the detector looks for them in each frame.
pub const HOLD_SECONDS: f64 = 1.0;
/// Frame period [`PersonTracker::perceive`] assumes (frames without a time).
pub const FRAME_SECONDS: f64 = 1.0 / 30.0;
/// People of one detector pass the landmark model reads at most.
const MAX_TRIES: usize = 3;
/// Likeness to the followed person's looks below which a frame's person is checked against the
/// others the detector finds.
pub const CHECK_BELOW: f32 = 0.85;
/// Likeness a person needs to be taken for the one followed, after a check or a loss (others
/// stayed at 0.69 and below on synthetic crowd scenes, [`Looks`]).
pub const SAME_FROM: f32 = 0.75;
/// Likeness from which a frame's looks are learned (frames mixing two people are not).
const LEARN_FROM: f32 = 0.9;
/// How fast the followed person's looks learn from frames that look like them.
const LOOKS_RATE: f32 = 0.05;
/// Share of the frame's width within which a box touches the frame's edge.
const EDGE_MARGIN: f32 = 0.02;
/// Landmark boxes overlapping at least this much (IoU) are one person read twice.
const SAME_PERSON_IOU: f32 = 0.3;
/// Seconds in which the detector finds only someone unlike the followed person where they
/// were, after which that someone is followed with their looks taken anew (the person turned
/// round, or changed clothes); shorter is a person hidden behind another.
const ALONE_SECONDS: f64 = 0.5;

/// Thresholds of one camera's tracking.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackerConfig {
    /// Which network finds the person to follow while nobody is followed.
    pub detector: PersonDetector,
    /// Score a BlazePose detection needs to start tracking.
    pub min_detection_score: f32,
    /// MoveNet's settings (its score, input side and keypoint score) for
    /// [`PersonDetector::MultiPose`]; the landmark and mask settings are this config's.
    pub people: PeopleConfig,
    /// Pose presence needed to keep tracking.
    pub min_presence: f32,
    /// Blend the previous frame's mask in where the new one is uncertain (video streams).
    pub smooth_masks: bool,
    /// Check each frame's person against the followed person's looks ([`Looks`]); off, the
    /// crop the landmarks place is followed wherever it goes, as MediaPipe does.
    pub check_looks: bool,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self {
            detector: PersonDetector::default(),
            min_detection_score: MIN_DETECTION_SCORE,
            people: PeopleConfig::default(),
            min_presence: MIN_PRESENCE,
            smooth_masks: true,
            check_looks: true,
        }
    }
}

/// The detection a person was taken up from.
#[derive(Debug, Clone, PartialEq)]
pub enum Detected {
    /// A BlazePose detection.
    BlazePose(PersonDetection),
    /// A MoveNet MultiPose person.
    MultiPose(PersonInstance),
}

impl Detected {
    /// The detector's score in [0, 1].
    pub fn score(&self) -> f32 {
        match self {
            Self::BlazePose(d) => d.score,
            Self::MultiPose(p) => p.score,
        }
    }

    /// The detector's box, frame pixels.
    pub fn bounds(&self) -> PixelBox {
        match self {
            Self::BlazePose(d) => PixelBox::new(d.min, d.max),
            Self::MultiPose(p) => PixelBox::new(p.min, p.max),
        }
    }
}

/// What one frame showed of the tracked person.
#[derive(Debug, Clone)]
pub struct Perceived {
    /// Landmarks (image and world) and the crop they came from.
    pub landmarks: PoseLandmarks,
    /// Person probability over the whole frame.
    pub mask: ProbabilityMap,
    /// The detection that started tracking in this frame (`None`: tracked from the previous
    /// frame's landmarks).
    pub detection: Option<Detected>,
    /// This frame took up someone after the person followed before was forgotten (gone for
    /// [`HOLD_SECONDS`], or out at the frame's edge), and they look unlike that person (below
    /// [`SAME_FROM`]): what was gathered of the one before is not theirs. Never set when looks
    /// are not checked, or for someone alone where the followed person was (they may have
    /// turned round).
    pub someone_else: bool,
}

/// Where the followed person was last seen.
#[derive(Debug, Clone, Copy)]
struct LastSeen {
    /// Their landmarks' box.
    bbox: PixelBox,
    /// The box touched the frame's edge (within [`EDGE_MARGIN`]): they may have walked out of
    /// view, and are not waited for.
    at_edge: bool,
    /// When, seconds.
    at: f64,
}

/// One reading of a crop: what the landmark model saw there and how it looks.
struct Reading {
    landmarks: PoseLandmarks,
    mask: ProbabilityMap,
    looks: Option<Looks>,
    detection: Option<Detected>,
}

/// Tracks one person in one camera's frames: the detector only while nobody is followed,
/// then the crop the previous frame's landmarks place (MediaPipe's pose graph), checked
/// against the person's looks.
pub struct PersonTracker {
    networks: Arc<PoseNetworks>,
    config: TrackerConfig,
    roi: Option<RotatedRect>,
    previous_mask: Option<ProbabilityMap>,
    last_seen: Option<LastSeen>,
    /// What the followed person looks like.
    looks: Option<Looks>,
    /// What the person followed before looked like, once forgotten: whom someone taken up
    /// anew is compared with ([`Perceived::someone_else`]).
    before: Option<Looks>,
    /// Since when only someone unlike them was found where they were, seconds.
    alone_unlike: Option<f64>,
    /// The current frame's time, seconds.
    clock: f64,
    /// MoveNet, made at the first frame that needs it.
    people: Option<PeopleFinder>,
    ran_detector: bool,
    input: Vec<f32>,
}

impl PersonTracker {
    /// A tracker with nobody tracked yet.
    pub fn new(networks: Arc<PoseNetworks>, config: TrackerConfig) -> Self {
        Self {
            networks,
            config,
            roi: None,
            previous_mask: None,
            last_seen: None,
            looks: None,
            before: None,
            alone_unlike: None,
            clock: 0.0,
            people: None,
            ran_detector: false,
            input: Vec::new(),
        }
    }

    /// The settings.
    pub fn config(&self) -> &TrackerConfig {
        &self.config
    }

    /// Whether a person is being tracked (the next frame skips the detector).
    pub fn tracking(&self) -> bool {
        self.roi.is_some()
    }

    /// Whether the last frame ran the detector (nobody was followed, the followed person was
    /// lost in it, or looked unlike themself).
    pub fn ran_detector(&self) -> bool {
        self.ran_detector
    }

    /// Forgets the tracked person (the next frame runs the detector and takes up whoever is
    /// most prominent).
    pub fn reset(&mut self) {
        self.lose();
        self.last_seen = None;
        self.forget_looks();
        self.alone_unlike = None;
    }

    /// Forgets the followed person's looks, kept as those of the person followed before.
    fn forget_looks(&mut self) {
        if let Some(looks) = self.looks.take() {
            self.before = Some(looks);
        }
    }

    /// Stops following from the previous frame's crop (the detector runs next).
    fn lose(&mut self) {
        self.roi = None;
        self.previous_mask = None;
    }

    /// What looks for a person while nobody is followed, for a `width × height` frame, in
    /// words (for messages): the detector and its input size.
    pub fn searched_with(&self, width: u32, height: u32) -> String {
        match self.config.detector {
            PersonDetector::MultiPose => {
                PeopleFinder::new(self.networks.clone(), self.config.people)
                    .searched_with(width, height)
            }
            PersonDetector::BlazePose => format!(
                "BlazePose's person detector at a {DETECTOR_INPUT}×{DETECTOR_INPUT} input (the \
                 whole frame letterboxed)"
            ),
        }
    }

    /// Starts a frame taken at `seconds` (a stamp before the last frame's counts as
    /// [`FRAME_SECONDS`] after it): nothing detected in it yet.
    fn start_frame(&mut self, seconds: f64) {
        self.clock = if seconds > self.clock {
            seconds
        } else {
            self.clock + FRAME_SECONDS
        };
        self.ran_detector = false;
    }

    /// How much `reading` looks like the person followed (`None`: nobody's looks are known,
    /// or the reading shows none).
    fn likeness(&self, reading: &Reading) -> Option<f32> {
        Some(self.looks.as_ref()?.likeness(reading.looks.as_ref()?))
    }

    /// The person in `image`, or `None` when nobody is found. A person lost while tracked is
    /// looked for again with the detector in the same frame.
    pub fn perceive(&mut self, image: &RgbImage) -> Result<Option<Perceived>, PerceptionError> {
        self.perceive_at(image, self.clock + FRAME_SECONDS)
    }

    /// [`PersonTracker::perceive`] for a frame taken at `seconds` (its stamp; a stamp before
    /// the last frame's counts as [`FRAME_SECONDS`] after it).
    pub fn perceive_at(
        &mut self,
        image: &RgbImage,
        seconds: f64,
    ) -> Result<Option<Perceived>, PerceptionError> {
        self.start_frame(seconds);
        let mut suspect = None;
        if let Some(roi) = self.roi {
            if let Some(reading) = self.read(image, roi, None)? {
                let likeness = self.likeness(&reading);
                tracing::trace!(?likeness, "followed from the last crop");
                if likeness.is_none_or(|l| l >= CHECK_BELOW) {
                    let learn = likeness.is_none_or(|l| l >= LEARN_FROM);
                    self.alone_unlike = None;
                    return Ok(Some(self.commit(image, reading, learn)));
                }
                suspect = Some(reading);
            }
            self.lose();
        }
        self.ran_detector = true;
        let mut readings: Vec<Reading> = suspect.into_iter().collect();
        match self.config.detector {
            PersonDetector::BlazePose => self.detect_blazepose(image, &mut readings)?,
            PersonDetector::MultiPose => self.detect_multipose(image, &mut readings)?,
        }
        let held = self
            .last_seen
            .is_some_and(|last| self.clock - last.at <= HOLD_SECONDS && !last.at_edge);
        let chosen = match (&self.looks, held, self.last_seen) {
            (Some(_), true, Some(last)) => self.choose_followed(readings, last),
            // Nobody followed (or gone for long): whoever came first.
            _ => {
                self.forget_looks();
                self.alone_unlike = None;
                readings.into_iter().next().map(|r| (r, true))
            }
        };
        match chosen {
            Some((reading, learn)) => Ok(Some(self.commit(image, reading, learn))),
            None => {
                if !held {
                    self.last_seen = None;
                    self.forget_looks();
                }
                Ok(None)
            }
        }
    }

    /// The person inside `within` (the box of a person mask given with the frame, frame pixels)
    /// in a frame taken at `seconds`, or `None` when the landmark model finds nobody there.
    /// No detector runs: the person followed is read from the previous frame's crop while
    /// they stay in the given box, otherwise from an upright crop around the box itself,
    /// read again where its landmarks place the crop.
    pub fn perceive_within(
        &mut self,
        image: &RgbImage,
        seconds: f64,
        within: PixelBox,
    ) -> Result<Option<Perceived>, PerceptionError> {
        self.start_frame(seconds);
        if let Some(roi) = self.roi {
            if let Some(reading) = self.read(image, roi, None)? {
                if reads_inside(&reading, &within) {
                    return Ok(Some(self.commit(image, reading, true)));
                }
            }
            self.lose();
        }
        let around = RotatedRect::around_box(within.min, within.max);
        let Some(first) = self.read(image, around, None)? else {
            return Ok(None);
        };
        let again = self
            .read(image, first.landmarks.next_roi, None)?
            .filter(|r| reads_inside(r, &within));
        match again {
            Some(reading) => Ok(Some(self.commit(image, reading, true))),
            None if reads_inside(&first, &within) => Ok(Some(self.commit(image, first, true))),
            None => Ok(None),
        }
    }

    /// Among `readings`, the person followed, and whether to learn their looks from it: the
    /// one most like them, if alike enough: [`SAME_FROM`] near where they were last seen
    /// (`last`), [`LEARN_FROM`] elsewhere; when all of them read one person near there who is
    /// unlike them, nobody, until that has gone on for [`ALONE_SECONDS`]: then that person,
    /// their looks taken anew.
    fn choose_followed(
        &mut self,
        readings: Vec<Reading>,
        last: LastSeen,
    ) -> Option<(Reading, bool)> {
        let boxes: Vec<PixelBox> = readings
            .iter()
            .map(|r| PixelBox::around_landmarks(&r.landmarks.image))
            .collect();
        let first = *boxes.first()?;
        let near = near_followed(&boxes, &last.bbox, self.clock - last.at);
        let alone = boxes.iter().all(|b| b.iou(&first) >= SAME_PERSON_IOU) && near.contains(&0);
        let mut scored: Vec<(f32, bool, Reading)> = readings
            .into_iter()
            .enumerate()
            .map(|(i, r)| (self.likeness(&r).unwrap_or(0.0), near.contains(&i), r))
            .collect();
        let best = (0..scored.len())
            .filter(|&i| {
                let (likeness, near, _) = &scored[i];
                *likeness >= if *near { SAME_FROM } else { LEARN_FROM }
            })
            .max_by(|&a, &b| scored[a].0.total_cmp(&scored[b].0));
        tracing::trace!(best = ?best.map(|i| scored[i].0), alone, "checked against the others");
        if let Some(i) = best {
            self.alone_unlike = None;
            let (likeness, _, reading) = scored.swap_remove(i);
            return Some((reading, alone || likeness >= LEARN_FROM));
        }
        if !alone {
            return None;
        }
        let since = *self.alone_unlike.get_or_insert(self.clock);
        if self.clock - since < ALONE_SECONDS {
            return None;
        }
        // Taken as the person followed, turned round: not compared with anyone before.
        self.alone_unlike = None;
        self.looks = None;
        self.before = None;
        Some((scored.swap_remove(0).2, true))
    }

    /// BlazePose's detector: its best detection, if present.
    fn detect_blazepose(
        &mut self,
        image: &RgbImage,
        readings: &mut Vec<Reading>,
    ) -> Result<(), PerceptionError> {
        let detections =
            self.networks
                .detect(image, self.config.min_detection_score, &mut self.input)?;
        if let Some(best) = detections.first().copied() {
            readings.extend(self.read(image, best.roi(), Some(Detected::BlazePose(best)))?);
        }
        Ok(())
    }

    /// MoveNet: the people near where the followed person was last seen, then the others by
    /// prominence ([`by_prominence`]); those of them (at most [`MAX_TRIES`]) the landmark
    /// model finds present.
    fn detect_multipose(
        &mut self,
        image: &RgbImage,
        readings: &mut Vec<Reading>,
    ) -> Result<(), PerceptionError> {
        let people = self.config.people;
        let finder = self
            .people
            .get_or_insert_with(|| PeopleFinder::new(self.networks.clone(), people));
        let instances = finder.instances(image)?;
        let boxes: Vec<PixelBox> = instances
            .iter()
            .map(|p| PixelBox::new(p.min, p.max))
            .collect();
        let mut order = match self.last_seen {
            Some(last) => near_followed(&boxes, &last.bbox, self.clock - last.at),
            None => Vec::new(),
        };
        for i in by_prominence(&boxes, image.width(), image.height()) {
            if !order.contains(&i) {
                order.push(i);
            }
        }
        // Someone must look like the person followed: read a few; otherwise the first present.
        let wanted = if self.looks.is_some() { MAX_TRIES } else { 1 };
        let before = readings.len();
        for i in order.into_iter().take(MAX_TRIES) {
            let p = &instances[i];
            let roi = person_roi(p.min, p.max, &p.keypoints, people.min_keypoint_score);
            readings.extend(self.read(image, roi, Some(Detected::MultiPose(p.clone())))?);
            if readings.len() - before >= wanted {
                break;
            }
        }
        Ok(())
    }

    /// Runs the landmark model on `roi`: a reading when the person is present.
    fn read(
        &mut self,
        image: &RgbImage,
        roi: RotatedRect,
        detection: Option<Detected>,
    ) -> Result<Option<Reading>, PerceptionError> {
        let (landmarks, mask) = self.networks.landmarks(image, &roi, &mut self.input)?;
        if landmarks.presence < self.config.min_presence {
            return Ok(None);
        }
        let looks = if self.config.check_looks {
            Looks::of(image, &mask, &landmarks)
        } else {
            None
        };
        Ok(Some(Reading {
            landmarks,
            mask,
            looks,
            detection,
        }))
    }

    /// Follows the person of `reading`: the next frame's crop from their landmarks; their looks
    /// are learned (`learn`), or taken as they are when nobody's are known.
    fn commit(&mut self, image: &RgbImage, reading: Reading, learn: bool) -> Perceived {
        let Reading {
            landmarks,
            mut mask,
            looks,
            detection,
        } = reading;
        if self.config.smooth_masks {
            if let Some(previous) = &self.previous_mask {
                mask.smooth_with(previous, MASK_SMOOTHING);
            }
            self.previous_mask = Some(mask.clone());
        }
        let mut someone_else = false;
        match (&mut self.looks, looks) {
            (Some(known), Some(new)) if learn => known.learn(&new, LOOKS_RATE),
            (known @ None, new) => {
                if let (Some(before), Some(new)) = (&self.before, &new) {
                    let likeness = before.likeness(new);
                    tracing::debug!(likeness, at = self.clock, "someone taken up anew");
                    someone_else = likeness < SAME_FROM;
                    self.before = None;
                }
                *known = new;
            }
            _ => {}
        }
        self.roi = Some(landmarks.next_roi);
        let bbox = PixelBox::around_landmarks(&landmarks.image);
        let margin = EDGE_MARGIN * image.width() as f32;
        let at_edge = bbox.min.x <= margin
            || bbox.min.y <= margin
            || bbox.max.x >= image.width() as f32 - margin
            || bbox.max.y >= image.height() as f32 - margin;
        self.last_seen = Some(LastSeen {
            bbox,
            at_edge,
            at: self.clock,
        });
        Perceived {
            landmarks,
            mask,
            detection,
            someone_else,
        }
    }
}

/// The share of the given mask's box a reading's landmark box must overlap (intersection
/// over union) to be the person of that mask.
const GIVEN_BOX_IOU: f32 = 0.3;

/// Whether `reading` reads the person of the mask whose box is `within`: the box around its
/// landmarks is centred inside that box and overlaps it.
fn reads_inside(reading: &Reading, within: &PixelBox) -> bool {
    let read = PixelBox::around_landmarks(&reading.landmarks.image);
    let c = read.centre();
    c.cmpge(within.min).all() && c.cmple(within.max).all() && read.iou(within) >= GIVEN_BOX_IOU
}
