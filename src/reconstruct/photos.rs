//! Photos → masked views → avatar, the path `lhmpp avatar` and `lhmpp eval-photos` share:
//!
//! 1. [`perceive_person`]: camera-only perception finds the person in a photo (the detector's
//!    best-scoring person, or the one a [`PersonHint`] names when several are in the frame);
//! 2. [`photo_view`]: the person mask (a given mask, else perception's), the pose perception's
//!    world landmarks solve to, and the view preprocessed for the encoder;
//! 3. [`reconstruct_photos`]: all views of one person through
//!    [`Reconstructor::reconstruct`](super::Reconstructor::reconstruct) together;
//! 4. [`FrontStage`]: renders of the avatar framed by its canonical bounds, from the front (or
//!    any camera of a ring), in any pose, on white.

use super::photo_colours::{colour_from_photos, PhotoColourConfig, PhotoColourReport, PhotoSample};
use super::preprocess::{mask_bbox, preprocess, PreprocessConfig, PreprocessError, Preprocessed};
use super::{ReconstructError, Reconstructor};
use crate::avatar::{Avatar, AvatarError};
use crate::body::{BodyError, BodyTemplate, Pose};
use crate::perception::detection::PersonDetection;
use crate::perception::pose::{PoseEstimator, PoseEstimatorConfig, PoseSolveError};
use crate::perception::roi::RotatedRect;
use crate::perception::{
    Detected, Perceived, PerceptionError, PersonTracker, PoseNetworks, TrackerConfig,
};
use crate::splat::{render, Camera, Gaussians, Intrinsics, RenderOptions, RenderOutput};
use glam::{Vec2, Vec3};
use image::{GrayImage, RgbImage};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Person-probability threshold of the mask made from perception's segmentation.
pub const MASK_THRESHOLD: f32 = 0.5;
/// Half-width of that mask's feathered edge, in probability.
pub const MASK_FEATHER: f32 = 0.1;

/// Why a photo could not become a view, or an avatar could not be rendered.
#[derive(Debug, thiserror::Error)]
pub enum PhotoError {
    /// A photo or mask could not be read.
    #[error("reading {path}: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        source: image::ImageError,
    },
    /// A perception network failed.
    #[error(transparent)]
    Perception(#[from] PerceptionError),
    /// The pose solver could not be set up for the template.
    #[error(transparent)]
    Pose(#[from] PoseSolveError),
    /// The photo could not be preprocessed (e.g. a mask of another size).
    #[error("preprocessing {path}: {source}")]
    Preprocess {
        /// The photo.
        path: PathBuf,
        /// What went wrong.
        source: PreprocessError,
    },
    /// The network failed.
    #[error(transparent)]
    Reconstruct(#[from] ReconstructError),
    /// A pose names bones the skeleton lacks.
    #[error(transparent)]
    Body(#[from] BodyError),
    /// The avatar does not fit the skeleton.
    #[error(transparent)]
    Avatar(#[from] AvatarError),
}

/// Which person of a photo to take when perception's detector finds several.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PersonHint {
    /// The best-scoring detection (what the camera tracker takes).
    #[default]
    Best,
    /// The detection whose landmark crop is largest (the nearest or tallest person).
    Largest,
    /// The detection whose hips are leftmost in the photo.
    Leftmost,
    /// The detection whose hips are rightmost in the photo.
    Rightmost,
    /// The person inside this box, `[x0, y0, x1, y1]` in photo pixels: the detection whose
    /// hips lie inside it, nearest its centre; when none does, the landmark model reads an
    /// upright square crop around the box itself.
    #[serde(rename = "box")]
    Box([f32; 4]),
}

impl PersonHint {
    /// The box hint around a mask's person pixels (≥ 128); `None` for an empty mask.
    pub fn from_mask(mask: &GrayImage) -> Option<Self> {
        mask_bbox(mask, 128)
            .map(|b| PersonHint::Box([b.x0 as f32, b.y0 as f32, b.x1 as f32, b.y1 as f32]))
    }

    /// The detection this hint picks among `detections` (best first).
    fn pick(&self, detections: &[PersonDetection]) -> Option<PersonDetection> {
        let hips = |d: &PersonDetection| d.keypoints[0];
        let by = |key: &dyn Fn(&PersonDetection) -> f32| {
            detections
                .iter()
                .copied()
                .min_by(|a, b| key(a).total_cmp(&key(b)))
        };
        match *self {
            PersonHint::Best => detections.first().copied(),
            PersonHint::Largest => by(&|d| -d.roi().size.x),
            PersonHint::Leftmost => by(&|d| hips(d).x),
            PersonHint::Rightmost => by(&|d| -hips(d).x),
            PersonHint::Box([x0, y0, x1, y1]) => {
                let (min, max) = (Vec2::new(x0, y0), Vec2::new(x1, y1));
                let centre = 0.5 * (min + max);
                detections
                    .iter()
                    .copied()
                    .filter(|d| hips(d).cmpge(min).all() && hips(d).cmple(max).all())
                    .min_by(|a, b| {
                        hips(a)
                            .distance(centre)
                            .total_cmp(&hips(b).distance(centre))
                    })
            }
        }
    }
}

/// The person of `image` that `hint` names, or `None` when perception finds nobody there.
///
/// With [`PersonHint::Best`] this is exactly a fresh [`PersonTracker`] (mask smoothing off) on
/// the photo. The other hints pick another detection (or, for a box no detection is in, an
/// upright square crop 1.25 times the box's longer side), read the landmarks in its crop, then
/// read them once more in the crop those landmarks place (the tracker's crop for a video's
/// next frame), which holds on to the person better when another one overlaps the first
/// crop.
pub fn perceive_person(
    networks: &Arc<PoseNetworks>,
    image: &RgbImage,
    hint: &PersonHint,
) -> Result<Option<Perceived>, PerceptionError> {
    let config = TrackerConfig {
        smooth_masks: false,
        ..TrackerConfig::default()
    };
    if *hint == PersonHint::Best {
        return PersonTracker::new(networks.clone(), config).perceive(image);
    }
    let mut input = Vec::new();
    let detections = networks.detect(image, config.min_detection_score, &mut input)?;
    let (roi, detection) = match (hint.pick(&detections), hint) {
        (Some(d), _) => (d.roi(), Some(d)),
        (None, PersonHint::Box([x0, y0, x1, y1])) => (
            RotatedRect::around_box(Vec2::new(*x0, *y0), Vec2::new(*x1, *y1)),
            None,
        ),
        (None, _) => return Ok(None),
    };
    let (mut landmarks, mut mask) = networks.landmarks(image, &roi, &mut input)?;
    if landmarks.presence < config.min_presence {
        return Ok(None);
    }
    // The detection's (or the box's) crop is rough; read again in the crop the landmarks
    // place, as the tracker does on a video's next frame.
    let (again, again_mask) = networks.landmarks(image, &landmarks.next_roi, &mut input)?;
    if again.presence >= config.min_presence {
        landmarks = again;
        mask = again_mask;
    }
    Ok(Some(Perceived {
        landmarks,
        mask,
        detection: detection.map(Detected::BlazePose),
        someone_else: false,
    }))
}

/// The pose perception's world landmarks solve to on `template` (no filtering: one photo).
pub fn photo_pose(template: &BodyTemplate, perceived: &Perceived) -> Result<Pose, PoseSolveError> {
    let config = PoseEstimatorConfig {
        filter: None,
        ..PoseEstimatorConfig::default()
    };
    Ok(PoseEstimator::new(template, config)?.update(0.0, &perceived.landmarks.world))
}

/// Where a view's person mask came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum MaskSource {
    /// A mask given with the photo (e.g. traced by hand).
    Given,
    /// Perception's segmentation ([`MASK_THRESHOLD`], [`MASK_FEATHER`]).
    Perception,
}

/// One photo of a person, ready for the network.
#[derive(Debug, Clone)]
pub struct PhotoView {
    /// The photo's file stem (names its outputs).
    pub stem: String,
    /// The photo.
    pub image: RgbImage,
    /// The person mask used (mono8, 255 = person).
    pub mask: GrayImage,
    /// Where the mask came from.
    pub mask_source: MaskSource,
    /// What perception read of the person (`None`: nobody found, with a given mask).
    pub perceived: Option<Perceived>,
    /// The pose solved from perception's world landmarks.
    pub pose: Option<Pose>,
    /// The view preprocessed for the encoder.
    pub view: Preprocessed,
}

/// Reads a photo, finds the person `hint` names, masks them (the mask at `given_mask`, else
/// perception's), solves their pose and preprocesses the view; `None` when there is no mask
/// (no mask given and perception finds nobody). Without a hint, the person is the one inside
/// the given mask's box ([`PersonHint::from_mask`]), else the best-scoring one.
pub fn photo_view(
    path: &Path,
    given_mask: Option<&Path>,
    hint: Option<&PersonHint>,
    networks: &Arc<PoseNetworks>,
    template: &BodyTemplate,
    prep: &PreprocessConfig,
) -> Result<Option<PhotoView>, PhotoError> {
    let read = |p: &Path| {
        image::open(p).map_err(|source| PhotoError::Read {
            path: p.to_path_buf(),
            source,
        })
    };
    let image = read(path)?.to_rgb8();
    let stem = path
        .file_stem()
        .map_or_else(|| "photo".into(), |s| s.to_string_lossy().into_owned());
    let given = given_mask.map(read).transpose()?.map(|m| m.to_luma8());
    let hint = match (hint, &given) {
        (Some(h), _) => *h,
        (None, Some(m)) => PersonHint::from_mask(m).unwrap_or_default(),
        (None, None) => PersonHint::Best,
    };
    let perceived = perceive_person(networks, &image, &hint)?;
    let (mask, mask_source) = match (given, &perceived) {
        (Some(m), _) => (m, MaskSource::Given),
        (None, Some(p)) => (
            p.mask.to_mask(MASK_THRESHOLD, MASK_FEATHER),
            MaskSource::Perception,
        ),
        (None, None) => return Ok(None),
    };
    let pose = perceived
        .as_ref()
        .map(|p| photo_pose(template, p))
        .transpose()?;
    let view =
        preprocess(&image, super::preprocess::Subject::Mask(&mask), prep).map_err(|source| {
            PhotoError::Preprocess {
                path: path.to_path_buf(),
                source,
            }
        })?;
    Ok(Some(PhotoView {
        stem,
        image,
        mask,
        mask_source,
        perceived,
        pose,
        view,
    }))
}

/// The preprocessing that produces `recon`'s encoder input (defaults otherwise).
pub fn preprocess_config(recon: &Reconstructor) -> PreprocessConfig {
    let (out_height, out_width) = recon.input_size();
    PreprocessConfig {
        out_height,
        out_width,
        ..PreprocessConfig::default()
    }
}

/// One avatar from all `views` (of one person) together. The views' image tokens are
/// forgotten afterwards, so the next call (another person's photos, numbered from 0 again)
/// encodes its own views instead of finding these in the token cache.
pub fn reconstruct_photos(
    recon: &mut Reconstructor,
    views: &[PhotoView],
) -> Result<Avatar, ReconstructError> {
    let refs: Vec<(u64, &Preprocessed)> = views
        .iter()
        .enumerate()
        .map(|(i, v)| (i as u64, &v.view))
        .collect();
    let avatar = recon.reconstruct(&refs);
    for (id, _) in &refs {
        recon.forget(*id);
    }
    avatar
}

/// Recolours `avatar` (made from `views` on `template`'s skeleton) from the photos where
/// perception read the person and their pose was solved
/// ([`super::photo_colours::colour_from_photos`]).
pub fn colour_from_views(
    avatar: &mut Avatar,
    template: &BodyTemplate,
    views: &[PhotoView],
    config: &PhotoColourConfig,
) -> PhotoColourReport {
    let samples: Vec<PhotoSample<'_>> = views
        .iter()
        .filter_map(|v| {
            Some(PhotoSample {
                image: &v.image,
                mask: &v.mask,
                landmarks: &v.perceived.as_ref()?.landmarks.image,
                pose: v.pose.as_ref()?,
                camera: None,
            })
        })
        .collect();
    let report = colour_from_photos(avatar, template, &samples, config);
    for why in &report.skipped {
        tracing::warn!("colours from the photos: {why}");
    }
    tracing::info!(
        photos = report.photos_used,
        seen = report.seen,
        mapped = report.mapped,
        "colours from the photos"
    );
    report
}

/// Cameras framing an avatar's canonical body: a ring around its bounds' centre at a distance
/// that fits its largest extent into the frame with a margin, 40° vertical field of view, on a
/// white background.
#[derive(Debug, Clone)]
pub struct FrontStage {
    target: Vec3,
    radius: f32,
    intrinsics: Intrinsics,
    options: RenderOptions,
}

impl FrontStage {
    /// The stage for `avatar`, square renders of `size` pixels.
    pub fn new(avatar: &Avatar, size: u32) -> Self {
        let (lo, hi) = bounds(&avatar.canonical);
        let fov = 40f32.to_radians();
        let extent = (hi - lo).max_element().max(0.1);
        Self {
            target: 0.5 * (lo + hi),
            radius: 0.62 * extent / (0.5 * fov).tan() + 0.5 * (hi.z - lo.z),
            intrinsics: Intrinsics::from_fov_y(size, size, fov),
            options: RenderOptions {
                background: Vec3::ONE,
                ..RenderOptions::default()
            },
        }
    }

    /// Camera `i` of `n` on the ring (camera 0 in front of the avatar, on +Z).
    pub fn camera(&self, i: usize, n: usize) -> Camera {
        Camera::orbit(i, n, self.radius, 0.0, self.target, self.intrinsics)
    }

    /// The avatar (bound to `template`'s skeleton) at `pose`, from camera `i` of `n`: colour
    /// on white and the accumulated opacity.
    pub fn render(
        &self,
        avatar: &Avatar,
        template: &BodyTemplate,
        pose: &Pose,
        i: usize,
        n: usize,
    ) -> Result<RenderOutput, PhotoError> {
        let matrices = template.skeleton.try_skinning_matrices(pose)?;
        avatar.check_matrices(&matrices)?;
        let posed = avatar.animate(&matrices);
        Ok(render(&posed, &self.camera(i, n), &self.options))
    }

    /// [`FrontStage::render`] as an 8-bit image.
    pub fn render_rgb8(
        &self,
        avatar: &Avatar,
        template: &BodyTemplate,
        pose: &Pose,
        i: usize,
        n: usize,
    ) -> Result<RgbImage, PhotoError> {
        Ok(self.render(avatar, template, pose, i, n)?.to_rgb8())
    }
}

/// Bounds of the finite Gaussian centres.
fn bounds(g: &Gaussians) -> (Vec3, Vec3) {
    g.positions
        .iter()
        .filter(|p| p.is_finite())
        .fold((Vec3::MAX, Vec3::MIN), |(l, h), p| (l.min(*p), h.max(*p)))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn detection(hips: Vec2, scale: f32, score: f32) -> PersonDetection {
        PersonDetection {
            score,
            min: hips - Vec2::splat(10.0),
            max: hips + Vec2::splat(10.0),
            keypoints: [hips, hips - Vec2::new(0.0, scale), hips, hips],
        }
    }

    #[test]
    fn hints_pick_their_detection() {
        let list = [
            detection(Vec2::new(500.0, 400.0), 100.0, 0.9),
            detection(Vec2::new(100.0, 420.0), 60.0, 0.8),
            detection(Vec2::new(800.0, 380.0), 200.0, 0.7),
        ];
        let x = |h: PersonHint| h.pick(&list).map(|d| d.keypoints[0].x);
        assert_eq!(x(PersonHint::Best), Some(500.0));
        assert_eq!(x(PersonHint::Largest), Some(800.0));
        assert_eq!(x(PersonHint::Leftmost), Some(100.0));
        assert_eq!(x(PersonHint::Rightmost), Some(800.0));
        assert_eq!(x(PersonHint::Box([0.0, 0.0, 300.0, 900.0])), Some(100.0));
        // Two inside: the one nearer the box's centre.
        assert_eq!(x(PersonHint::Box([0.0, 0.0, 900.0, 900.0])), Some(500.0));
        assert_eq!(x(PersonHint::Box([0.0, 0.0, 50.0, 50.0])), None);
        assert_eq!(PersonHint::Best.pick(&[]), None);
    }

    #[test]
    fn hints_read_from_json_and_masks() {
        let hint: PersonHint = serde_json::from_str(r#"{"box": [1, 2, 3, 4]}"#).unwrap();
        assert_eq!(hint, PersonHint::Box([1.0, 2.0, 3.0, 4.0]));
        let hint: PersonHint = serde_json::from_str(r#""leftmost""#).unwrap();
        assert_eq!(hint, PersonHint::Leftmost);
        let mut mask = GrayImage::new(20, 10);
        for (x, y) in [(3, 2), (7, 6)] {
            mask.put_pixel(x, y, image::Luma([255]));
        }
        mask.put_pixel(15, 8, image::Luma([100]));
        assert_eq!(
            PersonHint::from_mask(&mask),
            Some(PersonHint::Box([3.0, 2.0, 8.0, 7.0]))
        );
        assert_eq!(PersonHint::from_mask(&GrayImage::new(4, 4)), None);
    }
}
