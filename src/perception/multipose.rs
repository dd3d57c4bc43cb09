//! Several people at once: MoveNet MultiPose Lightning (Google, Apache-2.0; converted from the
//! TF.js graph model by `scripts/perception/convert_movenet.py`, see
//! `assets/perception/README.md`).
//!
//! The network (a MobileNetV2 + FPN backbone and six CenterNet heads at a quarter of the input
//! resolution) runs on the crate's kernels as a [`Network`]; the model's multi-person decoding,
//! which the TF.js graph does with top-k, gathers and arg-maxes, is [`decode`] here, op for op,
//! so that [`MultiPoseDetector::run`] gives the model's own `[1, 6, 56]` output:
//! per person 17 keypoints as (y, x, score), then the box (ymin, xmin, ymax, xmax) and the
//! person's score, coordinates normalised to the input. `tests/perception_multipose.rs` checks
//! it against TF.js's CPU backend.
//!
//! [`MultiPoseDetector::detect`] letterboxes a frame into the input (any sides that are
//! multiples of 32; 256×256 is the model's native size, an input of the frame's aspect wastes
//! nothing on bars) and maps the people back into frame pixels.

use glam::Vec2;
use image::RgbImage;
use std::path::Path;

use super::crop::{crop_into, ValueRange};
use super::network::{Network, NetworkOutputs};
use super::roi::RotatedRect;
use super::PerceptionError;

/// People the model reports per frame (its top-k).
pub const MAX_PEOPLE: usize = 6;
/// Keypoints per person (COCO order, [`KEYPOINT_NAMES`]).
pub const KEYPOINTS: usize = 17;
/// Values per person in the model's output: 17 × (y, x, score), box, score.
pub const PERSON_VALUES: usize = 3 * KEYPOINTS + 5;
/// The model's native input side.
pub const NATIVE_SIDE: usize = 256;
/// Input sides must be multiples of this (the backbone's total stride).
pub const SIDE_MULTIPLE: usize = 32;
/// The heads' stride: one heatmap cell per this many input pixels.
pub const OUTPUT_STRIDE: usize = 4;

/// The 17 keypoints, in the model's order (COCO's).
pub const KEYPOINT_NAMES: [&str; KEYPOINTS] = [
    "nose",
    "left_eye",
    "right_eye",
    "left_ear",
    "right_ear",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
];

/// Pixel scale of the input normalisation, `pixel × this − 1` (the model's float16 constant
/// for 1/127.5, exactly 0.007843017578125; `convert_movenet.py` checks it).
pub const PIXEL_SCALE: f32 = 0.007_843_018;
/// A centre-heatmap cell is a peak when it differs from its 5×5 max-pool by less than this
/// (exactly 1.0132789611816406e-6 as a float32).
const PEAK_EPSILON: f32 = 1.013_279e-6;
/// The max-pool window of the peak search.
const PEAK_WINDOW: usize = 5;
/// Keypoint weight `exp(−d² / (this × min(grid height, grid width)))` around the regressed
/// position (d in cells); exactly 0.300048828125 (float16).
const DISTANCE_SCALE: f32 = 0.300_048_83;
/// Keypoints scoring above this count towards their person's score (exactly 0.126953125,
/// float16).
pub const KEYPOINT_THRESHOLD: f32 = 0.126_953_13;

/// The head maps the network outputs (graph names, TF's without `StatefulPartitionedCall/`).
pub mod heads {
    /// Centre heatmap after the sigmoid, 1 channel.
    pub const CENTRE: &str = "Sigmoid";
    /// Keypoint heatmaps after the sigmoid, 17 channels.
    pub const KEYPOINT_HEATMAPS: &str = "Sigmoid_1";
    /// Box height and width in cells, 2 channels.
    pub const BOX_SCALE: &str = "box_scale_0/conv2d_5/BiasAdd";
    /// Box centre offset in cells (y, x), 2 channels.
    pub const BOX_OFFSET: &str = "box_offset_0/conv2d_6/BiasAdd";
    /// Keypoint positions regressed from a centre cell, (y, x) per keypoint, 34 channels.
    pub const KEYPOINT_REGRESSION: &str = "kpt_regress_0/conv2d_8/BiasAdd";
    /// Sub-cell keypoint offsets, (y, x) per keypoint, 34 channels.
    pub const KEYPOINT_OFFSETS: &str = "kpt_offset_0/conv2d_9/BiasAdd";
    /// All six, in the graph's output order.
    pub const ALL: [&str; 6] = [
        CENTRE,
        KEYPOINT_HEATMAPS,
        BOX_SCALE,
        BOX_OFFSET,
        KEYPOINT_REGRESSION,
        KEYPOINT_OFFSETS,
    ];
}

/// One keypoint of a person, in frame pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Keypoint {
    /// Position in frame pixels.
    pub position: Vec2,
    /// The model's confidence in [0, 1].
    pub score: f32,
}

/// One person the model found, in frame pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct PersonInstance {
    /// The person's score in [0, 1]: centre score × mean score of the keypoints above
    /// [`KEYPOINT_THRESHOLD`].
    pub score: f32,
    /// Top-left corner of the box.
    pub min: Vec2,
    /// Bottom-right corner of the box.
    pub max: Vec2,
    /// The 17 keypoints, in [`KEYPOINT_NAMES`] order.
    pub keypoints: [Keypoint; KEYPOINTS],
}

/// MoveNet MultiPose Lightning at one input size.
#[derive(Debug)]
pub struct MultiPoseDetector {
    net: Network,
    height: usize,
    width: usize,
}

impl MultiPoseDetector {
    /// The embedded model at a square input of side `side` (a multiple of 32; [`NATIVE_SIDE`]
    /// is the size it was trained for, larger sides find smaller people at a higher cost).
    pub fn embedded(side: usize) -> Result<Self, PerceptionError> {
        Self::embedded_sized(side, side)
    }

    /// The embedded model at an `height × width` input (both multiples of 32): an input of the
    /// frames' aspect (256×448 for 16:9) spends no pixels on letterbox bars.
    pub fn embedded_sized(height: usize, width: usize) -> Result<Self, PerceptionError> {
        Self::from_bytes(
            super::weights::MOVENET_MULTIPOSE,
            "movenet_multipose.safetensors (embedded)",
            height,
            width,
        )
    }

    /// The model in the weights file at `path` (written by `convert_movenet.py`), at an
    /// `height × width` input.
    pub fn load(path: &Path, height: usize, width: usize) -> Result<Self, PerceptionError> {
        let bytes = std::fs::read(path).map_err(|source| PerceptionError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_bytes(&bytes, &path.display().to_string(), height, width)
    }

    /// The model in the bytes of a weights file (`origin` names it in errors), at an
    /// `height × width` input.
    pub fn from_bytes(
        bytes: &[u8],
        origin: &str,
        height: usize,
        width: usize,
    ) -> Result<Self, PerceptionError> {
        check_side(height, origin)?;
        check_side(width, origin)?;
        let net = Network::from_bytes_resized(bytes, origin, height, width)?;
        Self::from_network(net)
    }

    /// Wraps a loaded network (its input sides must be multiples of 32, its input RGB and its
    /// outputs the six [`heads`]).
    pub fn from_network(net: Network) -> Result<Self, PerceptionError> {
        let [_, h, w, c] = net.input_shape();
        check_side(h, net.origin())?;
        check_side(w, net.origin())?;
        if c != 3 {
            return Err(PerceptionError::format(
                net.origin(),
                format!("input {h}×{w}×{c}, expected an RGB image"),
            ));
        }
        let names = net.output_names();
        if let Some(missing) = heads::ALL.iter().find(|n| !names.contains(n)) {
            return Err(PerceptionError::format(
                net.origin(),
                format!("output `{missing}` is missing: not a MoveNet MultiPose network"),
            ));
        }
        Ok(Self {
            net,
            height: h,
            width: w,
        })
    }

    /// The input size in pixels, `(height, width)`.
    pub fn input_size(&self) -> (usize, usize) {
        (self.height, self.width)
    }

    /// The network (for profiles).
    pub fn network(&self) -> &Network {
        &self.net
    }

    /// The six head maps for an input image: `height × width × 3` RGB pixels, row-major.
    pub fn heads(&self, pixels: &[u8]) -> Result<NetworkOutputs, PerceptionError> {
        let want = self.height * self.width * 3;
        if pixels.len() != want {
            return Err(PerceptionError::Input {
                what: format!("{} input pixels", self.net.origin()),
                expected: format!("{want} values ({}×{}×3)", self.height, self.width),
                got: format!("{} values", pixels.len()),
            });
        }
        let input: Vec<f32> = pixels
            .iter()
            .map(|&p| f32::from(p) * PIXEL_SCALE - 1.0)
            .collect();
        self.net.run(&input)
    }

    /// The model's output for an input image (`height × width × 3` RGB pixels): the
    /// `[1, 6, 56]` tensor TF.js computes, row-major (see the module doc).
    pub fn run(&self, pixels: &[u8]) -> Result<Vec<f32>, PerceptionError> {
        let out = self.heads(pixels)?;
        decode(&out, self.height, self.width)
            .map_err(|e| PerceptionError::format(self.net.origin(), e))
    }

    /// The rectangle of a `width × height` frame the input covers: the frame centred in the
    /// smallest rectangle of the input's aspect around it (black bars on the short sides).
    pub fn letterbox(&self, width: u32, height: u32) -> RotatedRect {
        let (fw, fh) = (width as f32, height as f32);
        let aspect = self.width as f32 / self.height as f32;
        RotatedRect {
            center: Vec2::new(fw / 2.0, fh / 2.0),
            size: Vec2::new(fw.max(fh * aspect), fh.max(fw / aspect)),
            rotation: 0.0,
        }
    }

    /// The people in `image` scoring at least `min_score`, best first: the frame is letterboxed
    /// ([`MultiPoseDetector::letterbox`]) into the input and the results mapped back into frame
    /// pixels.
    pub fn detect(
        &self,
        image: &RgbImage,
        min_score: f32,
    ) -> Result<Vec<PersonInstance>, PerceptionError> {
        let letterbox = self.letterbox(image.width(), image.height());
        let mut input = Vec::new();
        crop_into(
            image,
            &letterbox,
            self.width,
            self.height,
            ValueRange {
                min: 0.0,
                max: 255.0,
            },
            &mut input,
        );
        // the model reads integer pixels
        let pixels: Vec<u8> = input
            .iter()
            .map(|&v| v.round().clamp(0.0, 255.0) as u8)
            .collect();
        let out = self.run(&pixels)?;
        Ok(people(&out, &letterbox, min_score))
    }
}

fn check_side(side: usize, origin: &str) -> Result<(), PerceptionError> {
    if side == 0 || side % SIDE_MULTIPLE != 0 {
        return Err(PerceptionError::Input {
            what: format!("{origin} input side"),
            expected: format!("a positive multiple of {SIDE_MULTIPLE}"),
            got: side.to_string(),
        });
    }
    Ok(())
}

/// The people of a model output (`[6 × 56]`, coordinates normalised to the input, which
/// covers `letterbox` of the frame) scoring at least `min_score`, best first, in frame pixels.
pub fn people(out: &[f32], letterbox: &RotatedRect, min_score: f32) -> Vec<PersonInstance> {
    let mut found: Vec<PersonInstance> = out
        .chunks_exact(PERSON_VALUES)
        .filter(|p| p[PERSON_VALUES - 1] >= min_score)
        .map(|p| {
            let at = |y: f32, x: f32| letterbox.crop_to_frame(x, y);
            let keypoints = std::array::from_fn(|k| Keypoint {
                position: at(p[3 * k], p[3 * k + 1]),
                score: p[3 * k + 2],
            });
            let b = &p[3 * KEYPOINTS..];
            PersonInstance {
                score: b[4],
                min: at(b[0], b[1]),
                max: at(b[2], b[3]),
                keypoints,
            }
        })
        .collect();
    found.sort_by(|a, b| b.score.total_cmp(&a.score));
    found
}

/// The model's multi-person decoding of the six head maps of an `height × width` input, as the
/// TF.js graph computes it (float32, same order of operations; sums accumulate in float64
/// as TF.js's CPU backend does): the `[6 × 56]` output.
///
/// 1. Centre peaks: centre-heatmap cells within 1e-6 of their 5×5 max-pool; the 6 highest
///    (ties: lower index first) are the people, their values the centre scores.
/// 2. Box per person from the box heads at its centre cell, clipped to the grid.
/// 3. Per keypoint, the regressed position from the centre cell; every heatmap cell inside the
///    box is weighted by `exp(−d² / (0.3 × min(grid sides)))` of its distance to it, and the
///    arg-max cell (plus its sub-cell offset) is the keypoint. Its score is the largest
///    weighted value at that cell over all six people.
/// 4. Person score: centre score × the mean of the keypoint scores above
///    [`KEYPOINT_THRESHOLD`] (0 when none is).
pub fn decode(out: &NetworkOutputs, height: usize, width: usize) -> Result<Vec<f32>, String> {
    let (gh, gw) = (height / OUTPUT_STRIDE, width / OUTPUT_STRIDE);
    let cells = gh * gw;
    let get = |name: &str, channels: usize| -> Result<&[f32], String> {
        let t = out
            .tensor(name)
            .ok_or_else(|| format!("head `{name}` is missing"))?;
        if t.shape != [1, gh, gw, channels] {
            return Err(format!(
                "head `{name}` has shape {:?}, expected [1, {gh}, {gw}, {channels}]",
                t.shape
            ));
        }
        Ok(&t.data)
    };
    let centre = get(heads::CENTRE, 1)?;
    let heat = get(heads::KEYPOINT_HEATMAPS, KEYPOINTS)?;
    let box_scale = get(heads::BOX_SCALE, 2)?;
    let box_offset = get(heads::BOX_OFFSET, 2)?;
    let regress = get(heads::KEYPOINT_REGRESSION, 2 * KEYPOINTS)?;
    let offsets = get(heads::KEYPOINT_OFFSETS, 2 * KEYPOINTS)?;

    // 1. peaks of the centre heatmap and the top 6
    let r = (PEAK_WINDOW / 2) as isize;
    let mut peaks: Vec<(f32, usize)> = (0..cells)
        .map(|i| {
            let (y, x) = ((i / gw) as isize, (i % gw) as isize);
            let mut m = f32::NEG_INFINITY;
            for yy in (y - r).max(0)..(y + r + 1).min(gh as isize) {
                for xx in (x - r).max(0)..(x + r + 1).min(gw as isize) {
                    m = m.max(centre[yy as usize * gw + xx as usize]);
                }
            }
            let s = centre[i];
            let peak = if (s - m).abs() < PEAK_EPSILON {
                1.0
            } else {
                0.0
            };
            (s * peak, i)
        })
        .collect();
    peaks.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    peaks.truncate(MAX_PEOPLE);
    if peaks.len() < MAX_PEOPLE {
        return Err(format!(
            "{cells} heatmap cells, fewer than {MAX_PEOPLE} people"
        ));
    }

    // 2. boxes (grid units, clipped) and regressed keypoints
    let (fh, fw) = (gh as f32, gw as f32);
    let clip = |v: f32, hi: f32| v.min(hi).max(0.0);
    let mut boxes = [[0f32; 4]; MAX_PEOPLE];
    let mut regressed = [[(0f32, 0f32); KEYPOINTS]; MAX_PEOPLE];
    for (p, &(_, i)) in peaks.iter().enumerate() {
        let (y, x) = ((i / gw) as f32, (i % gw) as f32);
        let sh = box_scale[2 * i].max(0.0);
        let sw = box_scale[2 * i + 1].max(0.0);
        let (cy, cx) = (y + box_offset[2 * i], x + box_offset[2 * i + 1]);
        boxes[p] = [
            clip(cy - sh * 0.5, fh),
            clip(cx - sw * 0.5, fw),
            clip(cy + sh * 0.5, fh),
            clip(cx + sw * 0.5, fw),
        ];
        for (k, r) in regressed[p].iter_mut().enumerate() {
            let at = i * 2 * KEYPOINTS + 2 * k;
            *r = (y + regress[at], x + regress[at + 1]);
        }
    }

    // 3. per person and keypoint, the best weighted heatmap cell inside the box
    let spread = (gh.min(gw) as f32) * DISTANCE_SCALE;
    // weighted[(cell * 6 + p) * 17 + k]
    let mut weighted = vec![0f32; cells * MAX_PEOPLE * KEYPOINTS];
    for c in 0..cells {
        let (y, x) = ((c / gw) as f32, (c % gw) as f32);
        for p in 0..MAX_PEOPLE {
            let b = boxes[p];
            let inside = y >= b[0] && y < b[2] && x >= b[1] && x < b[3];
            let mask = if inside { 1.0 } else { 0.0 };
            for k in 0..KEYPOINTS {
                let (ry, rx) = regressed[p][k];
                let d2 = (y - ry) * (y - ry) + (x - rx) * (x - rx);
                let w = (-d2 / spread).exp();
                weighted[(c * MAX_PEOPLE + p) * KEYPOINTS + k] = heat[c * KEYPOINTS + k] * w * mask;
            }
        }
    }
    let mut result = vec![0f32; MAX_PEOPLE * PERSON_VALUES];
    let (sy, sx) = (4.0 / height as f32, 4.0 / width as f32);
    for (p, &(centre_score, _)) in peaks.iter().enumerate() {
        let row = &mut result[p * PERSON_VALUES..(p + 1) * PERSON_VALUES];
        let (mut count, mut sum) = (0f32, 0f64);
        for k in 0..KEYPOINTS {
            let mut best = (0usize, weighted[p * KEYPOINTS + k]);
            for c in 1..cells {
                let v = weighted[(c * MAX_PEOPLE + p) * KEYPOINTS + k];
                if v > best.1 {
                    best = (c, v);
                }
            }
            let c = best.0;
            let score = (0..MAX_PEOPLE)
                .map(|q| weighted[(c * MAX_PEOPLE + q) * KEYPOINTS + k])
                .fold(f32::NEG_INFINITY, f32::max);
            let (y, x) = ((c / gw) as f32, (c % gw) as f32);
            let at = c * 2 * KEYPOINTS + 2 * k;
            row[3 * k] = (y + offsets[at]) * sy;
            row[3 * k + 1] = (x + offsets[at + 1]) * sx;
            row[3 * k + 2] = score;
            if score > KEYPOINT_THRESHOLD {
                count += 1.0;
                sum += f64::from(centre_score * score);
            }
        }
        let b = boxes[p];
        let norm = [height, width, height, width];
        for j in 0..4 {
            row[3 * KEYPOINTS + j] = (b[j] * 4.0 / norm[j] as f32).clamp(0.0, 1.0);
        }
        row[PERSON_VALUES - 1] = (1.0 / count.max(1.0)) * sum as f32;
    }
    Ok(result)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The shortened literals are the exact float16 values the model uses.
    #[test]
    fn constants_are_the_models_float16_values() {
        assert_eq!(f64::from(PIXEL_SCALE), 0.007843017578125);
        assert_eq!(f64::from(PEAK_EPSILON), 1.0132789611816406e-6);
        assert_eq!(f64::from(DISTANCE_SCALE), 0.300048828125);
        assert_eq!(f64::from(KEYPOINT_THRESHOLD), 0.126953125);
    }
}
