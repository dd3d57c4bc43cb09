//! Person ids on a calibrated bag without ground truth (real video, `lhmpp eval-tracking
//! --no-truth`): what can be checked without knowing who is who.
//!
//! - **per id and camera**: how often the camera saw the id, and the largest jump of its box
//!   centre between consecutive sightings, in box heights (an id that passes to another person
//!   jumps by about the distance between them);
//! - **per id**: which cameras saw it and how far apart the cameras put it on the floor at the
//!   same moment (one person seen by several calibrated cameras stands in one place; two
//!   people given one id stand where each is).

use super::tracking::{track_images, CrowdImage, TrackingEvalError};
use crate::perception::{FoundPerson, PeopleFinder};
use crate::tracking::{Assignment, BoxPx, PersonTracks};
use std::collections::BTreeMap;

/// Sightings of other cameras within this many nanoseconds are the same moment (cameras
/// triggered together, a few milliseconds apart).
pub const SAME_MOMENT_NS: i64 = 15_000_000;

/// One detection and the id the tracker gave it.
#[derive(Debug, Clone, PartialEq)]
pub struct IdSighting {
    /// The camera that took the image.
    pub camera: String,
    /// The image's stamp, nanoseconds.
    pub stamp_ns: i64,
    /// The tracker's id.
    pub id: String,
    /// The detection's box, frame pixels.
    pub bbox: BoxPx,
    /// Where it stands on the floor (calibrated cameras), `(x, z)` metres.
    pub floor: Option<[f32; 2]>,
}

/// One id as one camera saw it.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraTrack {
    /// The camera.
    pub camera: String,
    /// The id.
    pub id: String,
    /// Sightings of the id in this camera.
    pub sightings: usize,
    /// Largest move of the box centre between consecutive sightings, in box heights.
    pub largest_jump: f32,
    /// Mean floor position over the sightings that have one.
    pub mean_floor: Option<[f32; 2]>,
}

/// One id over all cameras.
#[derive(Debug, Clone, PartialEq)]
pub struct IdAgreement {
    /// The id.
    pub id: String,
    /// Cameras that saw it.
    pub cameras: Vec<String>,
    /// Pairs of sightings by two cameras at the same moment, both with a floor position.
    pub pairs: usize,
    /// Median floor distance over those pairs, metres.
    pub median_gap: Option<f32>,
    /// Largest floor distance over those pairs, metres.
    pub max_gap: Option<f32>,
}

/// Runs perception and the tracker over the images (in order) and returns every detection
/// with its id; `inspect(index, image, persons, ids)` sees each image's persons and ids.
pub fn track_ids(
    images: &[CrowdImage],
    finder: &mut PeopleFinder,
    tracks: &mut PersonTracks,
    mut inspect: impl FnMut(usize, &CrowdImage, &[FoundPerson], &[Assignment]),
) -> Result<Vec<IdSighting>, TrackingEvalError> {
    let mut out = Vec::new();
    track_images(images, finder, tracks, |t| {
        inspect(t.index, t.image, t.people, t.ids);
        out.extend(t.ids.iter().zip(t.detections).map(|(a, det)| IdSighting {
            camera: t.image.camera.clone(),
            stamp_ns: t.image.stamp_ns,
            id: a.person_id.clone(),
            bbox: det.bbox,
            floor: det.floor,
        }));
    })?;
    Ok(out)
}

/// Per camera and id, in (camera, id) order.
pub fn camera_tracks(sightings: &[IdSighting]) -> Vec<CameraTrack> {
    let mut by: BTreeMap<(&str, &str), Vec<&IdSighting>> = BTreeMap::new();
    for s in sightings {
        by.entry((&s.camera, &s.id)).or_default().push(s);
    }
    by.into_iter()
        .map(|((camera, id), mut seen)| {
            seen.sort_by_key(|s| s.stamp_ns);
            let centre = |b: &BoxPx| [0.5 * (b.min[0] + b.max[0]), 0.5 * (b.min[1] + b.max[1])];
            let largest_jump = seen
                .windows(2)
                .map(|w| {
                    let (a, b) = (centre(&w[0].bbox), centre(&w[1].bbox));
                    let height = (w[0].bbox.max[1] - w[0].bbox.min[1]).max(1.0);
                    (b[0] - a[0]).hypot(b[1] - a[1]) / height
                })
                .fold(0.0, f32::max);
            let floors: Vec<[f32; 2]> = seen.iter().filter_map(|s| s.floor).collect();
            let mean_floor = (!floors.is_empty()).then(|| {
                let n = floors.len() as f32;
                [
                    floors.iter().map(|f| f[0]).sum::<f32>() / n,
                    floors.iter().map(|f| f[1]).sum::<f32>() / n,
                ]
            });
            CameraTrack {
                camera: camera.to_owned(),
                id: id.to_owned(),
                sightings: seen.len(),
                largest_jump,
                mean_floor,
            }
        })
        .collect()
}

/// Per id, in id order: its cameras and how far apart two cameras put it on the floor at the
/// same moment (within `same_moment_ns`).
pub fn id_agreement(sightings: &[IdSighting], same_moment_ns: i64) -> Vec<IdAgreement> {
    let mut by: BTreeMap<&str, Vec<&IdSighting>> = BTreeMap::new();
    for s in sightings {
        by.entry(&s.id).or_default().push(s);
    }
    by.into_iter()
        .map(|(id, seen)| {
            let mut cameras: Vec<String> = seen.iter().map(|s| s.camera.clone()).collect();
            cameras.sort();
            cameras.dedup();
            let mut gaps = Vec::new();
            for (i, a) in seen.iter().enumerate() {
                for b in &seen[i + 1..] {
                    if a.camera == b.camera || (a.stamp_ns - b.stamp_ns).abs() > same_moment_ns {
                        continue;
                    }
                    if let (Some(p), Some(q)) = (a.floor, b.floor) {
                        gaps.push((p[0] - q[0]).hypot(p[1] - q[1]));
                    }
                }
            }
            gaps.sort_by(f32::total_cmp);
            IdAgreement {
                id: id.to_owned(),
                cameras,
                pairs: gaps.len(),
                median_gap: gaps.get(gaps.len() / 2).copied(),
                max_gap: gaps.last().copied(),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seen(camera: &str, t: i64, id: &str, x: f32, floor: Option<[f32; 2]>) -> IdSighting {
        IdSighting {
            camera: camera.into(),
            stamp_ns: t * 100_000_000,
            id: id.into(),
            bbox: BoxPx {
                min: [x, 100.0],
                max: [x + 50.0, 300.0],
            },
            floor,
        }
    }

    #[test]
    fn an_id_that_passes_to_someone_else_jumps_and_a_steady_one_does_not() {
        let sightings = vec![
            seen("cam0", 0, "person_0", 100.0, None),
            seen("cam0", 1, "person_0", 104.0, None),
            // person_0's box is now on someone 300 px away: 1.5 box heights.
            seen("cam0", 2, "person_0", 404.0, None),
            seen("cam0", 0, "person_1", 400.0, None),
            seen("cam0", 1, "person_1", 396.0, None),
        ];
        let tracks = camera_tracks(&sightings);
        assert_eq!(tracks.len(), 2);
        assert_eq!(
            (tracks[0].id.as_str(), tracks[0].sightings),
            ("person_0", 3)
        );
        assert!((tracks[0].largest_jump - 1.5).abs() < 1e-4, "{tracks:?}");
        assert!((tracks[1].largest_jump - 0.02).abs() < 1e-4, "{tracks:?}");
    }

    #[test]
    fn cameras_agree_on_one_person_and_disagree_on_two_under_one_id() {
        let sightings = vec![
            // person_0: both cameras put them within 0.1 m, at every moment.
            seen("cam0", 0, "person_0", 0.0, Some([1.0, 2.0])),
            seen("cam1", 0, "person_0", 0.0, Some([1.1, 2.0])),
            seen("cam0", 1, "person_0", 0.0, Some([1.0, 2.1])),
            seen("cam1", 1, "person_0", 0.0, Some([1.0, 2.0])),
            // person_1: the cameras see two people 2 m apart under one id.
            seen("cam0", 0, "person_1", 0.0, Some([0.0, 0.0])),
            seen("cam1", 0, "person_1", 0.0, Some([2.0, 0.0])),
            // a sighting of another moment is not paired.
            seen("cam1", 5, "person_1", 0.0, Some([9.0, 0.0])),
        ];
        let agree = id_agreement(&sightings, SAME_MOMENT_NS);
        assert_eq!(agree[0].cameras, vec!["cam0", "cam1"]);
        assert_eq!(agree[0].pairs, 2);
        assert!(agree[0].max_gap.unwrap() <= 0.1 + 1e-5, "{agree:?}");
        assert_eq!(agree[1].pairs, 1);
        assert!(
            (agree[1].median_gap.unwrap() - 2.0).abs() < 1e-5,
            "{agree:?}"
        );
    }
}
