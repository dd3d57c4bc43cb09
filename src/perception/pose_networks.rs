//! BlazePose's networks, loaded once and shared by every camera: the person detector (the
//! whole frame letterboxed into 224 × 224) and a landmark model that reads a person's crop
//! (33 landmarks in the frame and in metres, presence, and the person's segmentation).

use super::crop::{crop_into, ValueRange};
use super::detection::{decode_detections, pose_anchors, Anchor, PersonDetection, DETECTOR_INPUT};
use super::landmarks::{decode_landmarks, LandmarkOutputs, PoseLandmarks, LANDMARK_INPUT};
use super::network::Network;
use super::roi::RotatedRect;
use super::segmentation::ProbabilityMap;
use super::weights::LandmarkModel;
use super::PerceptionError;
use image::RgbImage;
use std::path::Path;

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
