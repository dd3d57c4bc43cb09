//! One camera's person tracking, as MediaPipe's pose-landmark graph runs it: a detector only
//! while nobody is tracked, then each frame's crop from the previous frame's landmarks; the
//! landmark model's presence score decides whether the person is still there. The detector is
//! MoveNet MultiPose by default (it finds people who fill a small part of the frame; the person
//! taken up is chosen by [`super::follow`]), or BlazePose's own.

use super::crop::{crop_into, ValueRange};
use super::detection::{
    decode_detections, pose_anchors, Anchor, PersonDetection, DETECTOR_INPUT, MIN_DETECTION_SCORE,
};
use super::follow::{by_prominence, near_followed, PixelBox};
use super::landmarks::{
    decode_landmarks, LandmarkOutputs, PoseLandmarks, LANDMARK_INPUT, MIN_PRESENCE,
};
use super::multipose::PersonInstance;
use super::network::Network;
use super::people::{person_roi, PeopleConfig, PeopleFinder};
use super::roi::RotatedRect;
use super::segmentation::ProbabilityMap;
use super::weights::LandmarkModel;
use super::PerceptionError;
use image::RgbImage;
use std::path::Path;
use std::sync::Arc;

/// Share of the previous mask blended in where the new one is uncertain (MediaPipe's pose
/// graph uses 0.7).
const MASK_SMOOTHING: f32 = 0.7;

/// The person detector and a landmark model, loaded once and shared by every camera.
pub struct PoseNetworks {
    detector: Network,
    landmarks: Network,
    model: LandmarkModel,
    anchors: Vec<Anchor>,
}

impl PoseNetworks {
    /// Loads the embedded detector and landmark model `model` (`heavy_weights`: the converted
    /// heavy model, which is not embedded).
    pub fn load(
        model: LandmarkModel,
        heavy_weights: Option<&Path>,
    ) -> Result<Self, PerceptionError> {
        Ok(Self {
            detector: super::weights::pose_detector()?,
            landmarks: model.load(heavy_weights)?,
            model,
            anchors: pose_anchors(),
        })
    }

    /// Which landmark model runs.
    pub fn landmark_model(&self) -> LandmarkModel {
        self.model
    }

    /// Every person the detector finds in `image` scoring at least `min_score`, best first.
    pub fn detect(
        &self,
        image: &RgbImage,
        min_score: f32,
        input: &mut Vec<f32>,
    ) -> Result<Vec<PersonDetection>, PerceptionError> {
        let letterbox = RotatedRect::letterbox(image.width(), image.height());
        crop_into(
            image,
            &letterbox,
            DETECTOR_INPUT,
            DETECTOR_INPUT,
            ValueRange::SIGNED,
            input,
        );
        let out = self.detector.run(input)?;
        let boxes = output(&out, "Identity", "detector")?;
        let scores = output(&out, "Identity_1", "detector")?;
        Ok(decode_detections(
            boxes,
            scores,
            &self.anchors,
            &letterbox,
            min_score,
        ))
    }

    /// Landmarks and segmentation of the person in `roi` of `image`.
    pub fn landmarks(
        &self,
        image: &RgbImage,
        roi: &RotatedRect,
        input: &mut Vec<f32>,
    ) -> Result<(PoseLandmarks, ProbabilityMap), PerceptionError> {
        crop_into(
            image,
            roi,
            LANDMARK_INPUT,
            LANDMARK_INPUT,
            ValueRange::UNIT,
            input,
        );
        let out = self.landmarks.run(input)?;
        let what = self.model.name();
        let presence = output(&out, "Identity_1", what)?
            .first()
            .copied()
            .unwrap_or(0.0);
        let pose = decode_landmarks(
            LandmarkOutputs {
                landmarks: output(&out, "Identity", what)?,
                presence,
                heatmaps: output(&out, "Identity_3", what)?,
                world: output(&out, "Identity_4", what)?,
            },
            roi,
        );
        let mask = ProbabilityMap::from_crop_logits(
            output(&out, "Identity_2", what)?,
            roi,
            image.width(),
            image.height(),
        );
        Ok((pose, mask))
    }
}

fn output<'a>(
    out: &'a super::network::NetworkOutputs,
    name: &str,
    network: &str,
) -> Result<&'a [f32], PerceptionError> {
    out.get(name)
        .ok_or_else(|| PerceptionError::format(network, format!("no output `{name}`")))
}

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

/// Frames after losing the followed person during which only someone where they were last
/// seen is taken up again (someone else elsewhere is not: the person may be hidden for a
/// moment behind another).
pub const HOLD_FRAMES: u32 = 0;
/// People of one MoveNet pass the landmark model reads at most, in the order they are
/// preferred, until one of them is present.
const MAX_TRIES: usize = 3;

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
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self {
            detector: PersonDetector::default(),
            min_detection_score: MIN_DETECTION_SCORE,
            people: PeopleConfig::default(),
            min_presence: MIN_PRESENCE,
            smooth_masks: true,
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
}

/// Where the followed person was last seen.
#[derive(Debug, Clone, Copy)]
struct LastSeen {
    /// Their landmarks' box.
    bbox: PixelBox,
    /// Frames since (0: the previous frame).
    frames_ago: u32,
}

/// Tracks one person in one camera's frames: the detector only while nobody is followed,
/// then the crop the previous frame's landmarks place (MediaPipe's pose graph).
pub struct PersonTracker {
    networks: Arc<PoseNetworks>,
    config: TrackerConfig,
    roi: Option<RotatedRect>,
    previous_mask: Option<ProbabilityMap>,
    last_seen: Option<LastSeen>,
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

    /// Whether the last frame ran the detector (nobody was followed, or the followed person
    /// was lost in it).
    pub fn ran_detector(&self) -> bool {
        self.ran_detector
    }

    /// Forgets the tracked person (the next frame runs the detector and takes up whoever is
    /// most prominent).
    pub fn reset(&mut self) {
        self.lose();
        self.last_seen = None;
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

    /// The person in `image`, or `None` when nobody is found. A person lost while tracked is
    /// looked for again with the detector in the same frame.
    pub fn perceive(&mut self, image: &RgbImage) -> Result<Option<Perceived>, PerceptionError> {
        self.ran_detector = false;
        if let Some(last) = &mut self.last_seen {
            last.frames_ago += 1;
        }
        if let Some(roi) = self.roi {
            if let Some(found) = self.read(image, roi, None)? {
                return Ok(Some(found));
            }
            self.lose();
        }
        self.ran_detector = true;
        let found = match self.config.detector {
            PersonDetector::BlazePose => self.detect_blazepose(image)?,
            PersonDetector::MultiPose => self.detect_multipose(image)?,
        };
        if found.is_none() {
            self.lose();
            if self
                .last_seen
                .is_some_and(|last| last.frames_ago > HOLD_FRAMES)
            {
                self.last_seen = None;
            }
        }
        Ok(found)
    }

    /// BlazePose's detector: its best detection, if present.
    fn detect_blazepose(&mut self, image: &RgbImage) -> Result<Option<Perceived>, PerceptionError> {
        let detections =
            self.networks
                .detect(image, self.config.min_detection_score, &mut self.input)?;
        let Some(best) = detections.first().copied() else {
            return Ok(None);
        };
        self.read(image, best.roi(), Some(Detected::BlazePose(best)))
    }

    /// MoveNet: the person last seen where they were (while held), else the most prominent;
    /// the first of them (at most [`MAX_TRIES`]) the landmark model finds present.
    fn detect_multipose(&mut self, image: &RgbImage) -> Result<Option<Perceived>, PerceptionError> {
        let people = self.config.people;
        let finder = self
            .people
            .get_or_insert_with(|| PeopleFinder::new(self.networks.clone(), people));
        let instances = finder.instances(image)?;
        let boxes: Vec<PixelBox> = instances
            .iter()
            .map(|p| PixelBox::new(p.min, p.max))
            .collect();
        let order = match self.last_seen {
            Some(last) => {
                let near = near_followed(&boxes, &last.bbox);
                if near.is_empty() && last.frames_ago > HOLD_FRAMES {
                    by_prominence(&boxes, image.width(), image.height())
                } else {
                    near
                }
            }
            None => by_prominence(&boxes, image.width(), image.height()),
        };
        for i in order.into_iter().take(MAX_TRIES) {
            let p = &instances[i];
            let roi = person_roi(p.min, p.max, &p.keypoints, people.min_keypoint_score);
            if let Some(found) = self.read(image, roi, Some(Detected::MultiPose(p.clone())))? {
                return Ok(Some(found));
            }
        }
        Ok(None)
    }

    /// Runs the landmark model on `roi`; keeps tracking when the person is present.
    fn read(
        &mut self,
        image: &RgbImage,
        roi: RotatedRect,
        detection: Option<Detected>,
    ) -> Result<Option<Perceived>, PerceptionError> {
        let (landmarks, mut mask) = self.networks.landmarks(image, &roi, &mut self.input)?;
        if landmarks.presence < self.config.min_presence {
            return Ok(None);
        }
        if self.config.smooth_masks {
            if let Some(previous) = &self.previous_mask {
                mask.smooth_with(previous, MASK_SMOOTHING);
            }
            self.previous_mask = Some(mask.clone());
        }
        self.roi = Some(landmarks.next_roi);
        self.last_seen = Some(LastSeen {
            bbox: PixelBox::around_landmarks(&landmarks.image),
            frames_ago: 0,
        });
        Ok(Some(Perceived {
            landmarks,
            mask,
            detection,
        }))
    }
}
