//! The person detector's output decoded as MediaPipe's pose-detection graph does: SSD anchors
//! (`SsdAnchorsCalculator`), box and keypoint regressions relative to them
//! (`TensorsToDetectionsCalculator`), weighted non-maximum suppression
//! (`NonMaxSuppressionCalculator`, `WEIGHTED`), and the landmark crop a detection implies
//! (`PoseDetectionToRoi`).

use super::roi::RotatedRect;
use glam::Vec2;
use std::f32::consts::FRAC_PI_2;

/// Side of the detector's square input, pixels.
pub const DETECTOR_INPUT: usize = 224;
/// Anchors (and regressions) the detector outputs.
pub const DETECTOR_ANCHORS: usize = 2254;
/// Values per regression: box (x, y, w, h) and 4 keypoints (x, y).
pub const DETECTOR_COORDS: usize = 12;
/// Keypoints per detection: hip midpoint, a point fixing the whole body's scale and rotation,
/// shoulder midpoint, a point fixing the upper body's scale.
pub const DETECTOR_KEYPOINTS: usize = 4;

/// Default score a detection needs (MediaPipe's `min_score_thresh`).
pub const MIN_DETECTION_SCORE: f32 = 0.5;
/// IoU above which two detections are merged (`min_suppression_threshold`).
const SUPPRESSION_IOU: f32 = 0.3;
/// Raw scores are clipped to ± this before the sigmoid (`score_clipping_thresh`).
const SCORE_CLIP: f32 = 100.0;
/// How much larger than the keypoints' circle the landmark crop is (`scale_x`, `scale_y`).
pub const ROI_SCALE: f32 = 1.25;

/// An anchor centre in normalised input coordinates (anchor sizes are fixed at 1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Anchor {
    /// Centre x in [0, 1].
    pub x: f32,
    /// Centre y in [0, 1].
    pub y: f32,
}

/// The pose detector's SSD anchors: 5 layers of strides 8, 16, 32, 32, 32 on a 224² input,
/// two anchors per layer and cell (aspect ratio 1 and the interpolated scale), layers of equal
/// stride sharing one grid, fixed anchor size (MediaPipe's options for `pose_detection`).
pub fn pose_anchors() -> Vec<Anchor> {
    const STRIDES: [usize; 5] = [8, 16, 32, 32, 32];
    let mut anchors = Vec::with_capacity(DETECTOR_ANCHORS);
    let mut layer = 0;
    while layer < STRIDES.len() {
        let mut per_cell = 0;
        let mut last = layer;
        while last < STRIDES.len() && STRIDES[last] == STRIDES[layer] {
            // One anchor of aspect ratio 1 plus one of the interpolated scale; with fixed
            // anchor sizes only their number matters.
            per_cell += 2;
            last += 1;
        }
        let cells = DETECTOR_INPUT.div_ceil(STRIDES[layer]);
        for y in 0..cells {
            for x in 0..cells {
                for _ in 0..per_cell {
                    anchors.push(Anchor {
                        x: (x as f32 + 0.5) / cells as f32,
                        y: (y as f32 + 0.5) / cells as f32,
                    });
                }
            }
        }
        layer = last;
    }
    anchors
}

/// One detected person, in frame pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PersonDetection {
    /// Detection score in [0, 1].
    pub score: f32,
    /// Top-left corner of the box.
    pub min: Vec2,
    /// Bottom-right corner of the box.
    pub max: Vec2,
    /// The four keypoints (see [`DETECTOR_KEYPOINTS`]).
    pub keypoints: [Vec2; DETECTOR_KEYPOINTS],
}

impl PersonDetection {
    /// The landmark crop for this person: a square centred on the hips, side 2.5× the
    /// distance to the body-scale keypoint, turned so that the body points up in it.
    pub fn roi(&self) -> RotatedRect {
        RotatedRect::from_alignment(self.keypoints[0], self.keypoints[1], FRAC_PI_2)
            .square_long_scaled(ROI_SCALE)
    }

    fn area(&self) -> f32 {
        let d = (self.max - self.min).max(Vec2::ZERO);
        d.x * d.y
    }

    fn iou(&self, other: &Self) -> f32 {
        let inter_min = self.min.max(other.min);
        let inter_max = self.max.min(other.max);
        let d = (inter_max - inter_min).max(Vec2::ZERO);
        let inter = d.x * d.y;
        let union = self.area() + other.area() - inter;
        if union <= 0.0 {
            0.0
        } else {
            inter / union
        }
    }
}

/// Decodes the detector's raw outputs (`boxes`: anchors × 12, `scores`: anchors logits) into
/// detections scoring at least `min_score`, merged by weighted non-maximum suppression, best
/// first. `letterbox` is the frame rectangle the detector's input showed; positions come out in
/// frame pixels.
pub fn decode_detections(
    boxes: &[f32],
    scores: &[f32],
    anchors: &[Anchor],
    letterbox: &RotatedRect,
    min_score: f32,
) -> Vec<PersonDetection> {
    let scale = DETECTOR_INPUT as f32;
    let mut found = Vec::new();
    for (i, anchor) in anchors.iter().enumerate() {
        let (Some(raw), Some(&logit)) = (
            boxes.get(i * DETECTOR_COORDS..(i + 1) * DETECTOR_COORDS),
            scores.get(i),
        ) else {
            break;
        };
        let score = sigmoid(logit.clamp(-SCORE_CLIP, SCORE_CLIP));
        if score < min_score {
            continue;
        }
        let centre = Vec2::new(raw[0] / scale + anchor.x, raw[1] / scale + anchor.y);
        let half = Vec2::new(raw[2], raw[3]) / scale / 2.0;
        let to_frame = |p: Vec2| letterbox.crop_to_frame(p.x, p.y);
        let (a, b) = (to_frame(centre - half), to_frame(centre + half));
        let keypoints = std::array::from_fn(|k| {
            to_frame(Vec2::new(
                raw[4 + 2 * k] / scale + anchor.x,
                raw[5 + 2 * k] / scale + anchor.y,
            ))
        });
        found.push(PersonDetection {
            score,
            min: a.min(b),
            max: a.max(b),
            keypoints,
        });
    }
    weighted_nms(found)
}

/// MediaPipe's weighted non-maximum suppression: the best remaining detection absorbs every
/// detection overlapping it by more than the IoU threshold; its box and keypoints become the
/// score-weighted mean of the group, its score stays the best one.
fn weighted_nms(mut detections: Vec<PersonDetection>) -> Vec<PersonDetection> {
    detections.sort_by(|a, b| b.score.total_cmp(&a.score));
    let mut kept = Vec::new();
    while let Some(best) = detections.first().copied() {
        let (group, rest): (Vec<_>, Vec<_>) = detections
            .into_iter()
            .partition(|d| best.iou(d) > SUPPRESSION_IOU);
        let total: f32 = group.iter().map(|d| d.score).sum();
        let mut merged = best;
        if group.len() > 1 && total > 0.0 {
            let mean = |f: &dyn Fn(&PersonDetection) -> Vec2| {
                group.iter().map(|d| f(d) * d.score).sum::<Vec2>() / total
            };
            merged.min = mean(&|d| d.min);
            merged.max = mean(&|d| d.max);
            for k in 0..DETECTOR_KEYPOINTS {
                merged.keypoints[k] = mean(&|d| d.keypoints[k]);
            }
        }
        kept.push(merged);
        detections = rest;
    }
    kept
}

fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn anchors_match_the_detector_outputs() {
        let anchors = pose_anchors();
        assert_eq!(anchors.len(), DETECTOR_ANCHORS);
        // First layer: 28×28 cells of stride 8, two anchors each.
        assert_eq!(anchors[0], anchors[1]);
        assert!((anchors[0].x - 0.5 / 28.0).abs() < 1e-7);
        assert!((anchors[2].x - 1.5 / 28.0).abs() < 1e-7);
        // Last block: 7×7 cells, six anchors each (three stride-32 layers).
        let last = anchors[DETECTOR_ANCHORS - 1];
        assert!((last.x - 6.5 / 7.0).abs() < 1e-6 && (last.y - 6.5 / 7.0).abs() < 1e-6);
        assert_eq!(anchors[DETECTOR_ANCHORS - 6], last);
    }

    fn raw_detection(anchor: usize, logit: f32, dx: f32) -> (Vec<f32>, Vec<f32>) {
        let mut boxes = vec![0.0; DETECTOR_ANCHORS * DETECTOR_COORDS];
        let mut scores = vec![-50.0; DETECTOR_ANCHORS];
        let r = &mut boxes[anchor * DETECTOR_COORDS..(anchor + 1) * DETECTOR_COORDS];
        r[0] = dx;
        r[2] = 56.0;
        r[3] = 112.0;
        r[4] = dx; // hips at the anchor
        r[6] = dx;
        r[7] = -56.0; // scale point above
        scores[anchor] = logit;
        (boxes, scores)
    }

    #[test]
    fn a_detection_decodes_into_frame_pixels_through_the_letterbox() {
        let anchors = pose_anchors();
        // Anchor 2 * (14 * 28 + 14): the first-layer cell at column 14, row 14 (centre 0.5357).
        let i = 2 * (14 * 28 + 14);
        let (boxes, scores) = raw_detection(i, 3.0, 0.0);
        // A 448×224 frame letterboxed into a 448² square.
        let letterbox = RotatedRect::letterbox(448, 224);
        let found = decode_detections(&boxes, &scores, &anchors, &letterbox, 0.5);
        assert_eq!(found.len(), 1);
        let d = found[0];
        assert!((d.score - sigmoid(3.0)).abs() < 1e-6);
        let c = (anchors[i].x * 448.0, anchors[i].y * 448.0 - 112.0);
        assert!((d.keypoints[0] - Vec2::new(c.0, c.1)).length() < 1e-3);
        // Box: 56/224 of the square wide, 112/224 high.
        assert!(((d.max.x - d.min.x) - 112.0).abs() < 1e-3);
        assert!(((d.max.y - d.min.y) - 224.0).abs() < 1e-3);
        // The crop: centred on the hips, side 2.5 × the keypoint distance (112 px).
        let roi = d.roi();
        assert!((roi.size.x - 280.0).abs() < 1e-3 && roi.rotation.abs() < 1e-5);
    }

    #[test]
    fn low_scores_are_dropped() {
        let (boxes, scores) = raw_detection(10, -1.0, 0.0);
        let found = decode_detections(
            &boxes,
            &scores,
            &pose_anchors(),
            &RotatedRect::letterbox(224, 224),
            0.5,
        );
        assert!(found.is_empty());
    }

    #[test]
    fn overlapping_detections_merge_into_their_score_weighted_mean() {
        let d = |score: f32, x: f32| PersonDetection {
            score,
            min: Vec2::new(x, 0.0),
            max: Vec2::new(x + 10.0, 10.0),
            keypoints: [Vec2::new(x, 0.0); 4],
        };
        let far = d(0.6, 100.0);
        let merged = weighted_nms(vec![d(0.9, 0.0), d(0.3, 1.0), far]);
        assert_eq!(merged.len(), 2);
        assert_eq!(merged[0].score, 0.9);
        assert!((merged[0].min.x - 0.25).abs() < 1e-5, "{}", merged[0].min.x);
        assert_eq!(merged[1], far);
    }
}
