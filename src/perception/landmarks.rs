//! The landmark model's outputs decoded as MediaPipe's pose-landmark graph does: 39 landmarks
//! in crop pixels (`TensorsToLandmarksCalculator`, sigmoid visibility and presence), refined on
//! the heatmaps (`RefineLandmarksFromHeatmapCalculator`, 7×7 window), projected back into the
//! frame (`LandmarkProjectionCalculator`) and the world landmarks turned into the frame's axes
//! (`WorldLandmarkProjectionCalculator`); the two auxiliary landmarks give the next frame's
//! crop (`PoseLandmarksToRoi`).

use super::detection::ROI_SCALE;
use super::landmark::{Landmark, BODY_LANDMARKS};
use super::roi::RotatedRect;
use glam::{Vec2, Vec3};
use std::f32::consts::FRAC_PI_2;

/// Side of the landmark models' square input, pixels.
pub const LANDMARK_INPUT: usize = 256;
/// Landmarks the models output: the 33 body landmarks and 6 auxiliary ones.
pub const MODEL_LANDMARKS: usize = 39;
/// Side of the heatmaps, cells.
pub const HEATMAP_SIDE: usize = 64;
/// Pose presence needed to keep tracking (MediaPipe's `ThresholdingCalculator`).
pub const MIN_PRESENCE: f32 = 0.5;
/// Heatmap window used to refine a landmark, cells.
const REFINE_KERNEL: usize = 7;
/// Peak heatmap confidence needed to refine a landmark.
const REFINE_MIN_CONFIDENCE: f32 = 0.5;

/// One person's pose read from one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseLandmarks {
    /// Body landmarks in frame pixels (x, y) with z in the same pixel scale (relative depth,
    /// the hips' midpoint near 0, negative towards the camera).
    pub image: [Landmark; BODY_LANDMARKS],
    /// Body landmarks in metres, origin between the hips, in the camera's axes (x right, y
    /// down, z away from the camera).
    pub world: [Landmark; BODY_LANDMARKS],
    /// The model's pose presence score in [0, 1].
    pub presence: f32,
    /// The crop the landmarks were read from.
    pub roi: RotatedRect,
    /// The crop for the next frame, from the auxiliary landmarks (hip midpoint and body scale).
    pub next_roi: RotatedRect,
}

/// Raw landmark-model outputs for one crop.
#[derive(Debug, Clone, Copy)]
pub struct LandmarkOutputs<'a> {
    /// `Identity`: 39 × (x, y, z, visibility logit, presence logit), crop pixels.
    pub landmarks: &'a [f32],
    /// `Identity_1`: pose presence probability.
    pub presence: f32,
    /// `Identity_3`: 64 × 64 × 39 heatmap logits.
    pub heatmaps: &'a [f32],
    /// `Identity_4`: 39 × (x, y, z) metres.
    pub world: &'a [f32],
}

/// Decodes one crop's outputs; `roi` is the frame rectangle the crop showed.
pub fn decode_landmarks(out: LandmarkOutputs<'_>, roi: &RotatedRect) -> PoseLandmarks {
    let side = LANDMARK_INPUT as f32;
    let mut crop: Vec<Landmark> = (0..MODEL_LANDMARKS)
        .map(|i| {
            let r = &out.landmarks[i * 5..i * 5 + 5];
            Landmark {
                position: Vec3::new(r[0] / side, r[1] / side, r[2] / side),
                visibility: sigmoid(r[3]),
                presence: sigmoid(r[4]),
            }
        })
        .collect();
    refine_on_heatmaps(&mut crop, out.heatmaps);
    let project = |l: &Landmark| {
        let p = roi.crop_to_frame(l.position.x, l.position.y);
        Landmark {
            position: Vec3::new(p.x, p.y, l.position.z * roi.size.x),
            ..*l
        }
    };
    let image: [Landmark; BODY_LANDMARKS] = std::array::from_fn(|i| project(&crop[i]));
    let world = std::array::from_fn(|i| {
        let r = &out.world[i * 3..i * 3 + 3];
        let xy = roi.rotate_to_frame(Vec2::new(r[0], r[1]));
        Landmark {
            position: Vec3::new(xy.x, xy.y, r[2]),
            visibility: image[i].visibility,
            presence: image[i].presence,
        }
    });
    let hips = project(&crop[BODY_LANDMARKS]).position.truncate();
    let scale = project(&crop[BODY_LANDMARKS + 1]).position.truncate();
    PoseLandmarks {
        image,
        world,
        presence: out.presence,
        roi: *roi,
        next_roi: RotatedRect::from_alignment(hips, scale, FRAC_PI_2).square_long_scaled(ROI_SCALE),
    }
}

/// Moves each landmark to the confidence-weighted mean cell of the 7×7 heatmap window around
/// it when the window's peak confidence reaches 0.5 (cells counted from their corner, as
/// MediaPipe does).
fn refine_on_heatmaps(landmarks: &mut [Landmark], heatmaps: &[f32]) {
    let side = HEATMAP_SIDE as i64;
    let half = (REFINE_KERNEL as i64 - 1) / 2;
    for (k, l) in landmarks.iter_mut().enumerate() {
        let col = (l.position.x * side as f32) as i64;
        let row = (l.position.y * side as f32) as i64;
        if col < 0 || col >= side || row < 0 || row >= side {
            continue;
        }
        let (mut sum, mut wx, mut wy, mut peak) = (0.0f32, 0.0f32, 0.0f32, 0.0f32);
        for r in (row - half).max(0)..(row + half + 1).min(side) {
            for c in (col - half).max(0)..(col + half + 1).min(side) {
                let at = ((r * side + c) as usize) * MODEL_LANDMARKS + k;
                let conf = sigmoid(heatmaps[at]);
                sum += conf;
                peak = peak.max(conf);
                wx += c as f32 * conf;
                wy += r as f32 * conf;
            }
        }
        if peak >= REFINE_MIN_CONFIDENCE && sum > 0.0 {
            l.position.x = wx / side as f32 / sum;
            l.position.y = wy / side as f32 / sum;
        }
    }
}

fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn outputs(landmark_px: Vec2, heat_peak_at: Option<(usize, usize)>) -> (Vec<f32>, Vec<f32>) {
        let mut lm = vec![0.0; MODEL_LANDMARKS * 5];
        for i in 0..MODEL_LANDMARKS {
            lm[i * 5] = landmark_px.x;
            lm[i * 5 + 1] = landmark_px.y;
            lm[i * 5 + 3] = 10.0;
            lm[i * 5 + 4] = 10.0;
        }
        // Auxiliary landmarks: hips at the crop centre, scale point straight above.
        lm[BODY_LANDMARKS * 5] = 128.0;
        lm[BODY_LANDMARKS * 5 + 1] = 128.0;
        lm[(BODY_LANDMARKS + 1) * 5] = 128.0;
        lm[(BODY_LANDMARKS + 1) * 5 + 1] = 28.0;
        let mut heat = vec![-20.0; HEATMAP_SIDE * HEATMAP_SIDE * MODEL_LANDMARKS];
        if let Some((row, col)) = heat_peak_at {
            for k in 0..MODEL_LANDMARKS {
                heat[(row * HEATMAP_SIDE + col) * MODEL_LANDMARKS + k] = 20.0;
            }
        }
        (lm, heat)
    }

    #[test]
    fn landmarks_project_through_the_crop_into_the_frame() {
        let roi = RotatedRect {
            center: Vec2::new(500.0, 300.0),
            size: Vec2::splat(512.0),
            rotation: FRAC_PI_2,
        };
        let (lm, heat) = outputs(Vec2::new(128.0, 0.0), None);
        let world = vec![0.1; MODEL_LANDMARKS * 3];
        let p = decode_landmarks(
            LandmarkOutputs {
                landmarks: &lm,
                presence: 0.9,
                heatmaps: &heat,
                world: &world,
            },
            &roi,
        );
        // Top centre of a crop turned a quarter clockwise is right of its centre.
        let nose = p.image[0];
        assert!((nose.position.truncate() - Vec2::new(756.0, 300.0)).length() < 1e-3);
        assert!(nose.visibility > 0.99 && nose.presence > 0.99);
        // World x/y turn with the crop: (0.1, 0.1) → (−0.1, 0.1).
        assert!((p.world[0].position - Vec3::new(-0.1, 0.1, 0.1)).length() < 1e-6);
        // The next crop keeps the centre and turns with the body: hips→scale point is
        // "up" in this crop, i.e. to the right in the frame.
        assert!((p.next_roi.center - roi.center).length() < 1e-3);
        assert!((p.next_roi.rotation - FRAC_PI_2).abs() < 1e-5);
        assert!((p.next_roi.size.x - 2.0 * 200.0 * 1.25).abs() < 1e-2);
    }

    #[test]
    fn a_confident_heatmap_peak_pulls_the_landmark_onto_its_cell() {
        let roi = RotatedRect {
            center: Vec2::splat(128.0),
            size: Vec2::splat(256.0),
            rotation: 0.0,
        };
        // Landmark at crop pixel (100, 100) = cell (25, 25); peak two cells right and down.
        let (lm, heat) = outputs(Vec2::new(100.0, 100.0), Some((27, 27)));
        let world = vec![0.0; MODEL_LANDMARKS * 3];
        let out = LandmarkOutputs {
            landmarks: &lm,
            presence: 0.9,
            heatmaps: &heat,
            world: &world,
        };
        let p = decode_landmarks(out, &roi);
        assert!(
            (p.image[5].position.x - 27.0 * 4.0).abs() < 1e-2,
            "{:?}",
            p.image[5]
        );
        // Without a confident peak the landmark stays where the regression put it.
        let (lm, heat) = outputs(Vec2::new(100.0, 100.0), None);
        let out = LandmarkOutputs {
            landmarks: &lm,
            heatmaps: &heat,
            ..out
        };
        let p = decode_landmarks(out, &roi);
        assert!((p.image[5].position.x - 100.0).abs() < 1e-3);
    }
}
