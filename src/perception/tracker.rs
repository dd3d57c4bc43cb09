//! One camera's person tracking, as MediaPipe's pose-landmark graph runs it: the detector only
//! while nobody is tracked, then each frame's crop from the previous frame's landmarks; the
//! landmark model's presence score decides whether the person is still there.

use super::crop::{crop_into, ValueRange};
use super::detection::{
    decode_detections, pose_anchors, Anchor, PersonDetection, DETECTOR_INPUT, MIN_DETECTION_SCORE,
};
use super::landmarks::{
    decode_landmarks, LandmarkOutputs, PoseLandmarks, LANDMARK_INPUT, MIN_PRESENCE,
};
use super::network::Network;
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

/// Thresholds of one camera's tracking.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackerConfig {
    /// Score a detection needs to start tracking.
    pub min_detection_score: f32,
    /// Pose presence needed to keep tracking.
    pub min_presence: f32,
    /// Blend the previous frame's mask in where the new one is uncertain (video streams).
    pub smooth_masks: bool,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self {
            min_detection_score: MIN_DETECTION_SCORE,
            min_presence: MIN_PRESENCE,
            smooth_masks: true,
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
    pub detection: Option<PersonDetection>,
}

/// Tracks one person in one camera's frames.
pub struct PersonTracker {
    networks: Arc<PoseNetworks>,
    config: TrackerConfig,
    roi: Option<RotatedRect>,
    previous_mask: Option<ProbabilityMap>,
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
            input: Vec::new(),
        }
    }

    /// Whether a person is being tracked (the next frame skips the detector).
    pub fn tracking(&self) -> bool {
        self.roi.is_some()
    }

    /// Forgets the tracked person (the next frame runs the detector).
    pub fn reset(&mut self) {
        self.roi = None;
        self.previous_mask = None;
    }

    /// The person in `image`, or `None` when nobody is found. A person lost while tracked is
    /// looked for again with the detector in the same frame.
    pub fn perceive(&mut self, image: &RgbImage) -> Result<Option<Perceived>, PerceptionError> {
        if let Some(roi) = self.roi {
            if let Some(found) = self.read(image, roi, None)? {
                return Ok(Some(found));
            }
            self.reset();
        }
        let detections =
            self.networks
                .detect(image, self.config.min_detection_score, &mut self.input)?;
        let Some(best) = detections.first().copied() else {
            return Ok(None);
        };
        let found = self.read(image, best.roi(), Some(best))?;
        if found.is_none() {
            self.reset();
        }
        Ok(found)
    }

    /// Runs the landmark model on `roi`; keeps tracking when the person is present.
    fn read(
        &mut self,
        image: &RgbImage,
        roi: RotatedRect,
        detection: Option<PersonDetection>,
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
        Ok(Some(Perceived {
            landmarks,
            mask,
            detection,
        }))
    }
}
