//! Person tracking scored on crowd bags (`lhmpp synth --people N`): every camera image is
//! split into persons (camera-only perception), given ids by [`PersonTracks`], and each
//! detection is matched to the true person under its mask by the bag's id maps.
//!
//! The measures:
//! - **found**: true persons visible in an image (at least [`MIN_VISIBLE_FRACTION`] of its
//!   pixels) that a detection covers; a detection covers the true person holding at least half
//!   of its mask's pixels, one detection per person and image;
//! - **id switches**: per true person, in time order over all cameras, how often the id given
//!   to it differs from the id it was given last (as CLEAR-MOT counts them);
//! - **wrong-person views**: detections given an id whose sightings mostly cover another true
//!   person: views that would land in another person's frame store;
//! - **ids per person**: distinct ids each true person was given (1 is perfect).

use crate::bag::{BagError, BagReader};
use crate::msgs::{CameraInfo, CompressedImage, Image, TFMessage};
use crate::perception::{FoundPerson, PeopleFinder, PerceptionError};
use crate::reconstruct::image_decode::{decode_compressed, decode_mask, decode_raw, RawImage};
use crate::splat::Camera;
use crate::synth::capture::TF_STATIC_TOPIC;
use crate::synth::crowd::ids_topic;
use crate::tracking::{Assignment, BoxPx, Detection, FloorCamera, LensDistortion, PersonTracks};
use glam::{Affine3A, Quat, Vec3};
use image::{GrayImage, RgbImage};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Share of an image's pixels from which a true person counts as visible in it.
pub const MIN_VISIBLE_FRACTION: f64 = 0.005;

/// Errors while reading or scoring a crowd bag.
#[derive(Debug, thiserror::Error)]
pub enum TrackingEvalError {
    /// The bag could not be read.
    #[error(transparent)]
    Bag(#[from] BagError),
    /// The bag lacks the ground truth a crowd scene carries.
    #[error("{path}: {message}")]
    GroundTruth {
        /// The bag.
        path: PathBuf,
        /// What is missing or wrong.
        message: String,
    },
    /// Perception failed on an image.
    #[error("perception: {0}")]
    Perception(#[from] PerceptionError),
}

/// One camera image of a crowd bag with its id map.
pub struct CrowdImage {
    /// Camera name (`cam0`, ...).
    pub camera: String,
    /// Stamp, nanoseconds.
    pub stamp_ns: i64,
    /// The image.
    pub rgb: RgbImage,
    /// True person ids (`k + 1` for `person_k`, 0 nobody).
    pub ids: GrayImage,
    /// The camera, when the bag calibrates it (`camera_info` and its optical frame on
    /// `/tf_static`): detections then get a floor position.
    pub camera_model: Option<Camera>,
    /// The lens distortion of the camera's `camera_info` (`None`: none, or a model that is not
    /// supported, which is logged).
    pub distortion: Option<LensDistortion>,
}

impl CrowdImage {
    /// The camera as the tracker's floor positions need it, when calibrated.
    pub fn floor_camera(&self) -> Option<FloorCamera> {
        self.camera_model.as_ref().map(|camera| FloorCamera {
            distortion: self.distortion,
            ..floor_camera(camera)
        })
    }
}

/// The tracker's view of a person found in `image`: its box, its colours under its mask, and
/// where it stands when the camera is calibrated.
pub fn detection(
    image: &RgbImage,
    person: &FoundPerson,
    camera: Option<&FloorCamera>,
) -> Detection {
    let bbox = BoxPx::new(person.min.to_array(), person.max.to_array());
    Detection::seen(image, &person.mask, bbox, camera)
}

/// A rendering camera as the tracker's floor position needs it.
pub fn floor_camera(camera: &Camera) -> FloorCamera {
    let i = &camera.intrinsics;
    FloorCamera {
        intrinsics: [i.fx, i.fy, i.cx, i.cy],
        distortion: None,
        world_from_camera: camera.world_from_camera,
    }
}

/// Where a person whose box is `bbox` stands (see [`crate::tracking::floor_point`]).
pub fn floor_point(camera: &Camera, bbox: &BoxPx) -> Option<[f32; 2]> {
    crate::tracking::floor_point(&floor_camera(camera), bbox)
}

/// The camera images of a crowd bag, in bag order (time order), each with its id map.
pub fn read_crowd(path: &Path) -> Result<Vec<CrowdImage>, TrackingEvalError> {
    read_images(path, true)
}

/// Every camera image of a calibrated bag that need not carry id maps (real video): as
/// [`read_crowd`], but an image without an id map gets an empty one (nobody), and
/// `/<camera>/image_raw/compressed` (JPEG, PNG) is read beside `/<camera>/image_raw`.
pub fn read_camera_bag(path: &Path) -> Result<Vec<CrowdImage>, TrackingEvalError> {
    read_images(path, false)
}

/// [`read_crowd`] (`truth`: every image needs its id map) or [`read_camera_bag`].
fn read_images(path: &Path, truth: bool) -> Result<Vec<CrowdImage>, TrackingEvalError> {
    let bag = BagReader::open(path)?;
    let bad = |message: String| TrackingEvalError::GroundTruth {
        path: path.to_path_buf(),
        message,
    };
    let mut id_maps: BTreeMap<(String, i64), GrayImage> = BTreeMap::new();
    let mut poses: BTreeMap<String, Affine3A> = BTreeMap::new();
    let mut infos: BTreeMap<String, CameraInfo> = BTreeMap::new();
    for m in bag
        .messages()
        .iter()
        .filter(|m| &*m.topic == TF_STATIC_TOPIC)
    {
        let tf: TFMessage = bag.decode(m)?;
        for t in &tf.transforms {
            let q: Quat = t.transform.rotation.into();
            let p: Vec3 = t.transform.translation.into();
            poses.insert(
                t.child_frame_id.clone(),
                Affine3A::from_rotation_translation(q.normalize(), p),
            );
        }
    }
    let mut images = Vec::new();
    for m in bag.messages() {
        let topic = &*m.topic;
        let Some(camera) = topic
            .strip_prefix('/')
            .and_then(|t| t.split_once('/'))
            .map(|(c, rest)| (c.to_owned(), rest))
        else {
            continue;
        };
        match camera.1 {
            "image_raw" => {
                let msg: Image = bag.decode(m)?;
                let rgb = decode_raw(topic, &RawImage::from(&msg), 8192)
                    .map_err(|e| bad(format!("{topic}: {e}")))?;
                images.push((camera.0, msg.header.stamp.as_nanos(), rgb));
            }
            "image_raw/compressed" if !truth => {
                let msg: CompressedImage = bag.decode(m)?;
                let rgb = decode_compressed(topic, &msg.format, &msg.data, 8192)
                    .map_err(|e| bad(format!("{topic}: {e}")))?;
                images.push((camera.0, msg.header.stamp.as_nanos(), rgb));
            }
            "camera_info" => {
                infos.insert(camera.0, bag.decode(m)?);
            }
            "person_ids" => {
                let msg: Image = bag.decode(m)?;
                let ids = decode_mask(topic, &RawImage::from(&msg), 8192)
                    .map_err(|e| bad(format!("{topic}: {e}")))?;
                id_maps.insert((camera.0, msg.header.stamp.as_nanos()), ids);
            }
            _ => {}
        }
    }
    if images.is_empty() {
        return Err(bad(if truth {
            "no camera images (`/<camera>/image_raw`)".into()
        } else {
            "no camera images (`/<camera>/image_raw` or `/<camera>/image_raw/compressed`)".into()
        }));
    }
    // Each camera's lens, read once (a model that is not supported is logged, then ignored).
    let lenses: BTreeMap<String, Option<LensDistortion>> = infos
        .iter()
        .map(|(camera, info)| {
            let lens = LensDistortion::from_camera_info(&info.distortion_model, &info.d)
                .map_err(|e| tracing::warn!(camera = %camera, "{e}"))
                .ok()
                .flatten();
            (camera.clone(), lens)
        })
        .collect();
    // Cameras in time order, whatever order the bag stores them in.
    images.sort_by_key(|(camera, stamp_ns, _)| (*stamp_ns, camera.clone()));
    images
        .into_iter()
        .map(|(camera, stamp_ns, rgb)| {
            let ids = match id_maps.remove(&(camera.clone(), stamp_ns)) {
                Some(ids) => ids,
                None if !truth => GrayImage::new(rgb.width(), rgb.height()),
                None => {
                    return Err(bad(format!(
                        "no id map on {} for the image stamped {stamp_ns} (is this a bag of \
                         `lhmpp synth --people N`?)",
                        ids_topic(&camera)
                    )))
                }
            };
            if ids.dimensions() != rgb.dimensions() {
                return Err(bad(format!(
                    "{}: id map {:?} and image {:?} differ in size",
                    ids_topic(&camera),
                    ids.dimensions(),
                    rgb.dimensions()
                )));
            }
            let camera_model = infos.get(&camera).and_then(|info| {
                let pose = poses.get(&info.header.frame_id)?;
                Some(Camera::from_camera_info(
                    info.k,
                    rgb.width(),
                    rgb.height(),
                    *pose,
                ))
            });
            let distortion = lenses.get(&camera).copied().flatten();
            Ok(CrowdImage {
                camera,
                stamp_ns,
                rgb,
                ids,
                camera_model,
                distortion,
            })
        })
        .collect()
}

/// One detection: the true person under it (`None`: nobody holds half its mask) and the id
/// the tracker gave it.
#[derive(Debug, Clone, PartialEq)]
pub struct Sighting {
    /// Index of the image in the bag's order.
    pub image: usize,
    /// The camera that took it.
    pub camera: String,
    /// True person index (`k` of `person_k`), if any.
    pub truth: Option<usize>,
    /// The tracker's id.
    pub id: String,
}

/// What one bag scored.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TrackingScore {
    /// Camera images.
    pub images: usize,
    /// True persons in the scene.
    pub persons: usize,
    /// True person sightings (visible person × image).
    pub visible: usize,
    /// Of those, covered by a detection.
    pub found: usize,
    /// Detections covering no true person (or a second detection of the same one).
    pub false_detections: usize,
    /// Id switches (all persons), over all cameras in time order: a person given other ids by
    /// different cameras switches at every change of camera.
    pub id_switches: usize,
    /// Id switches within each camera's own sequence (tracking from frame to frame).
    pub camera_switches: usize,
    /// Detections given an id whose sightings mostly cover another person.
    pub wrong_person_views: usize,
    /// Distinct ids given, by true person.
    pub ids_per_person: Vec<usize>,
    /// Distinct ids the tracker gave in all.
    pub ids: usize,
    /// Perception time per image, milliseconds (mean).
    pub perception_ms: f64,
}

impl TrackingScore {
    /// Id switches per 100 camera images.
    pub fn switches_per_100(&self) -> f64 {
        100.0 * self.id_switches as f64 / self.images.max(1) as f64
    }

    /// Found over visible.
    pub fn recall(&self) -> f64 {
        self.found as f64 / self.visible.max(1) as f64
    }
}

/// The true person a detection mask covers: the id holding at least half of the mask's
/// pixels (mask ≥ 128).
pub fn covered_person(mask: &GrayImage, ids: &GrayImage) -> Option<usize> {
    let mut counts = [0usize; 256];
    let mut total = 0usize;
    for (m, id) in mask.pixels().zip(ids.pixels()) {
        if m.0[0] >= 128 {
            total += 1;
            counts[id.0[0] as usize] += 1;
        }
    }
    let (best, n) = counts
        .iter()
        .enumerate()
        .skip(1)
        .max_by_key(|(i, n)| (**n, std::cmp::Reverse(*i)))?;
    (total > 0 && 2 * n >= total).then(|| best - 1)
}

/// True persons visible in an id map: `(k, pixels)` for those over [`MIN_VISIBLE_FRACTION`].
pub fn visible_persons(ids: &GrayImage) -> Vec<usize> {
    let mut counts = [0usize; 256];
    for p in ids.pixels() {
        counts[p.0[0] as usize] += 1;
    }
    let min = (MIN_VISIBLE_FRACTION * ids.len() as f64).ceil() as usize;
    (1..256)
        .filter(|&k| counts[k] >= min.max(1))
        .map(|k| k - 1)
        .collect()
}

/// One image after perception and the tracker: its persons, their detections (box, colours,
/// floor position) and the ids they got.
pub struct TrackedImage<'a> {
    /// Index of the image in the bag's order.
    pub index: usize,
    /// The image.
    pub image: &'a CrowdImage,
    /// The persons perception found.
    pub people: &'a [FoundPerson],
    /// The tracker's view of each person.
    pub detections: &'a [Detection],
    /// The id each person got.
    pub ids: &'a [Assignment],
}

/// Runs perception and the tracker over the images (in order), handing each image's result
/// to `each`; returns the seconds spent in perception.
pub fn track_images(
    images: &[CrowdImage],
    finder: &mut PeopleFinder,
    tracks: &mut PersonTracks,
    mut each: impl FnMut(TrackedImage<'_>),
) -> Result<f64, TrackingEvalError> {
    let mut perception_s = 0.0;
    for (index, image) in images.iter().enumerate() {
        let started = std::time::Instant::now();
        let people = finder.find(&image.rgb)?;
        perception_s += started.elapsed().as_secs_f64();
        let floor = image.floor_camera();
        let detections: Vec<Detection> = people
            .iter()
            .map(|p| detection(&image.rgb, p, floor.as_ref()))
            .collect();
        let ids = tracks.update(&image.camera, image.stamp_ns as f64 * 1e-9, &detections);
        each(TrackedImage {
            index,
            image,
            people: &people,
            detections: &detections,
            ids: &ids,
        });
    }
    Ok(perception_s)
}

/// Runs perception and the tracker over the images (in order) and scores them;
/// `inspect(index, image, persons, ids)` sees each image's persons and the ids they got.
pub fn track_and_score(
    images: &[CrowdImage],
    finder: &mut PeopleFinder,
    tracks: &mut PersonTracks,
    mut inspect: impl FnMut(usize, &CrowdImage, &[FoundPerson], &[Assignment]),
) -> Result<TrackingScore, TrackingEvalError> {
    let mut sightings = Vec::new();
    let mut visible = Vec::new();
    let mut persons = 0;
    let perception_s = track_images(images, finder, tracks, |t| {
        inspect(t.index, t.image, t.people, t.ids);
        for ((p, a), det) in t.people.iter().zip(t.ids).zip(t.detections) {
            let truth = covered_person(&p.mask, &t.image.ids);
            tracing::debug!(
                image = t.index,
                camera = %t.image.camera,
                truth = ?truth,
                id = %a.person_id,
                matched = ?a.matched,
                hidden = a.hidden,
                floor = ?det.floor,
                bbox = ?det.bbox,
                "sighting"
            );
            sightings.push(Sighting {
                image: t.index,
                camera: t.image.camera.clone(),
                truth,
                id: a.person_id.clone(),
            });
        }
        let seen = visible_persons(&t.image.ids);
        persons = persons.max(seen.iter().map(|k| k + 1).max().unwrap_or(0));
        visible.push(seen);
    })?;
    let mut score = score_sightings(&sightings, &visible, persons);
    score.perception_ms = 1e3 * perception_s / images.len().max(1) as f64;
    Ok(score)
}

/// Scores sightings against the visible persons of each image (`visible[image]`); `persons`
/// true persons in the scene.
pub fn score_sightings(
    sightings: &[Sighting],
    visible: &[Vec<usize>],
    persons: usize,
) -> TrackingScore {
    let mut score = TrackingScore {
        images: visible.len(),
        persons,
        visible: visible.iter().map(Vec::len).sum(),
        ids_per_person: vec![0; persons],
        ..TrackingScore::default()
    };
    // One detection per true person and image: the first one covering it (later ones count
    // as false detections, as does a detection covering nobody).
    let mut claimed = std::collections::BTreeSet::new();
    let mut matched = Vec::new();
    for s in sightings {
        match s.truth {
            Some(k) if claimed.insert((s.image, k)) => {
                if visible[s.image].contains(&k) {
                    score.found += 1;
                }
                matched.push(s);
            }
            _ => score.false_detections += 1,
        }
    }
    // Id switches (over all cameras, and within each camera) and distinct ids per true person.
    let mut last: BTreeMap<usize, &str> = BTreeMap::new();
    let mut last_in_camera: BTreeMap<(&str, usize), &str> = BTreeMap::new();
    let mut given: BTreeMap<usize, std::collections::BTreeSet<&str>> = BTreeMap::new();
    for s in &matched {
        let k = s.truth.expect("matched sightings have a truth");
        if last.insert(k, &s.id).is_some_and(|prev| prev != s.id) {
            score.id_switches += 1;
        }
        if last_in_camera
            .insert((&s.camera, k), &s.id)
            .is_some_and(|prev| prev != s.id)
        {
            score.camera_switches += 1;
        }
        given.entry(k).or_default().insert(&s.id);
    }
    for (k, ids) in given {
        if k < persons {
            score.ids_per_person[k] = ids.len();
        }
    }
    // Each id's majority person; sightings of others under that id are wrong-person views.
    let mut by_id: BTreeMap<&str, BTreeMap<usize, usize>> = BTreeMap::new();
    for s in &matched {
        *by_id
            .entry(&s.id)
            .or_default()
            .entry(s.truth.expect("matched"))
            .or_default() += 1;
    }
    score.ids = sightings
        .iter()
        .map(|s| s.id.as_str())
        .collect::<std::collections::BTreeSet<_>>()
        .len();
    for counts in by_id.values() {
        let total: usize = counts.values().sum();
        let majority = counts.values().copied().max().unwrap_or(0);
        score.wrong_person_views += total - majority;
    }
    score
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sight(image: usize, truth: Option<usize>, id: &str) -> Sighting {
        Sighting {
            image,
            camera: "cam0".into(),
            truth,
            id: id.into(),
        }
    }

    /// A clean run scores perfectly; a swap of two ids counts two switches and the swapped
    /// views as wrong-person views; a detection of nobody is a false detection.
    #[test]
    fn scores_switches_and_wrong_views() {
        let visible = vec![vec![0, 1]; 4];
        let clean: Vec<Sighting> = (0..4)
            .flat_map(|i| [sight(i, Some(0), "person_0"), sight(i, Some(1), "person_1")])
            .collect();
        let s = score_sightings(&clean, &visible, 2);
        assert_eq!((s.found, s.visible, s.id_switches), (8, 8, 0));
        assert_eq!(
            (s.wrong_person_views, s.ids_per_person.clone()),
            (0, vec![1, 1])
        );

        let mut swapped = clean.clone();
        for s in swapped.iter_mut().filter(|s| s.image >= 3) {
            s.id = if s.id == "person_0" {
                "person_1"
            } else {
                "person_0"
            }
            .into();
        }
        swapped.push(sight(3, None, "person_2"));
        let s = score_sightings(&swapped, &visible, 2);
        assert_eq!((s.id_switches, s.camera_switches), (2, 2));
        assert_eq!(s.wrong_person_views, 2);
        assert_eq!(s.false_detections, 1);
        assert_eq!(s.ids_per_person, vec![2, 2]);
        assert_eq!(s.ids, 3);
    }

    /// The bottom centre of a box lands where the tip of the nearer foot is, and the person
    /// stands `BOX_BOTTOM_TO_STANDING` beyond it: a floor point projected into a camera and cast
    /// back comes out that far behind it, seen from the camera; a box bottom above the horizon
    /// misses.
    #[test]
    fn floor_point_inverts_the_projection() {
        use crate::splat::Intrinsics;
        let camera = Camera::look_at(
            Vec3::new(0.5, 1.6, 5.0),
            Vec3::new(0.0, 0.9, 0.0),
            Vec3::Y,
            Intrinsics::from_fov_y(640, 480, 0.9),
        );
        let foot = Vec3::new(0.7, 0.0, -0.4);
        let optical = camera.world_from_camera.inverse().transform_point3(foot);
        let px = camera.project_camera_point(optical);
        let bbox = BoxPx::new([px.x - 40.0, px.y - 300.0], [px.x + 40.0, px.y]);
        let [x, z] = floor_point(&camera, &bbox).unwrap();
        let away =
            (foot - Vec3::new(0.5, 0.0, 5.0)).normalize() * crate::tracking::BOX_BOTTOM_TO_STANDING;
        let (ex, ez) = (0.7 + away.x, -0.4 + away.z);
        assert!((x - ex).abs() < 1e-3 && (z - ez).abs() < 1e-3, "({x}, {z})");
        let sky = BoxPx::new([300.0, -50.0], [340.0, 0.0]);
        assert_eq!(floor_point(&camera, &sky), None);
    }

    /// A mask is matched to the id holding half its pixels, else to nobody.
    #[test]
    fn covered_person_needs_half_the_mask() {
        let ids = GrayImage::from_fn(4, 1, |x, _| image::Luma([[1, 1, 2, 0][x as usize]]));
        let all = GrayImage::from_pixel(4, 1, image::Luma([255]));
        assert_eq!(covered_person(&all, &ids), Some(0));
        let right = GrayImage::from_fn(4, 1, |x, _| image::Luma([if x >= 2 { 255 } else { 0 }]));
        assert_eq!(covered_person(&right, &ids), Some(1));
        let none = GrayImage::from_fn(4, 1, |x, _| image::Luma([if x == 3 { 255 } else { 0 }]));
        assert_eq!(covered_person(&none, &ids), None);
    }
}
