//! Persons across frames and cameras: stable person ids for the person instances a detector
//! finds in each frame (issue "several people at once").
//!
//! Within a camera, a detection continues a track whose predicted box (constant velocity from
//! its last two sightings) it overlaps, the one whose colours as this camera saw them are
//! closest and, for a detection standing clear of the others on a calibrated camera, whose
//! person stood nearest on the floor first, overlap breaking ties (greedy, best pair first).
//! Colours are learned only from detections whose boxes stand clear of the others': in a huddle
//! a person's pixels mix with their neighbours', and the colours from before it are what tell
//! them apart after it. A detection no live track of its camera claims is compared by
//! appearance ([`Appearance`]: colour histograms of the person's pixels in three bands of their
//! box) with every person not seen in that camera in this frame:
//! the same person seen by another camera, or coming back after leaving. Where the caller
//! knows where a detection stands on the floor (calibrated cameras), position decides first: a
//! person seen by another camera within [`TrackingConfig::floor_fresh`] seconds is the same
//! person only if they stood within [`TrackingConfig::max_floor_gap`] of it, whatever their
//! colours (a person's front and back rarely look alike). A box overlap in one camera never
//! continues a person whom the floor positions put more than
//! [`TrackingConfig::max_track_floor_gap`] away, and continues one whose colours as this camera
//! saw them differ ([`TrackingConfig::min_track_similarity`]) only after the floor and colour
//! matches, if they left the detection to no one. Only when no one matches does it
//! start a new person. Persons unseen for
//! [`TrackingConfig::forget_after`] are forgotten; past [`TrackingConfig::max_persons`] the
//! least recently seen one is dropped (counted).
//!
//! Tracking is deterministic: the same detections in the same order give the same ids, so
//! nodes that see the same images agree on ids without talking to each other.

mod appearance;
mod boxes;
mod floor;
mod lens;

pub use appearance::Appearance;
pub use boxes::BoxPx;
pub use floor::{floor_point, FloorCamera, BOX_BOTTOM_TO_STANDING};
pub use lens::LensDistortion;

use std::collections::BTreeMap;

/// How much colours count against box overlap when several predicted boxes of a camera overlap
/// one detection: colours decide (the similarity's weight is three times the IoU's), overlap
/// breaks ties between people who look alike. In a huddle every box overlaps every predicted
/// box; the colours each person showed before it tell them apart.
const OVERLAP_COLOUR_WEIGHT: f32 = 3.0;

/// How much the floor counts when several predicted boxes of a camera overlap one detection
/// that stands clear of the others: as much as colours. Its score is the nearness of the
/// person's last floor position (any camera) to the detection's, `1 − gap /
/// max_track_floor_gap`. People who look alike (similar colours, as in the same uniform) are
/// then told apart by where they stand. A huddled detection gets no floor bonus: its box bottom
/// may be another person's feet, or cut by the one in front.
const OVERLAP_FLOOR_WEIGHT: f32 = 3.0;

/// Share of a detection's box covered by another detection's box from which the detection is
/// in a huddle: its pixels mix people, so its colours are not learned (and the node's frame
/// store lets such a view go first).
pub const CROWDED_COVER: f32 = 0.15;

/// Tracking parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackingConfig {
    /// Seconds a person is kept without a sighting.
    pub forget_after: f64,
    /// Persons held at once; past it the least recently seen is dropped.
    pub max_persons: usize,
    /// IoU between a predicted box and a detection below which they are not the same person.
    pub min_iou: f32,
    /// Appearance similarity (Bhattacharyya coefficient of whole-box colours, 0..1) from which
    /// a detection is the same person as one tracked elsewhere or earlier.
    pub min_similarity: f32,
    /// Distance on the floor (metres) within which a detection can be a person another camera
    /// saw at nearly the same time.
    pub max_floor_gap: f32,
    /// How long (seconds) a person's floor position stays current for that comparison.
    pub floor_fresh: f64,
    /// Distance on the floor (metres) beyond which a detection cannot continue a person's box
    /// track, however well the boxes overlap: where two people cross in one camera's view,
    /// their boxes overlap while the other camera still sees them apart.
    pub max_track_floor_gap: f32,
    /// Appearance similarity (whole-box colours, as this camera saw the person) below which a
    /// box overlap continues a person's track only if neither floor position nor colours give
    /// the detection to someone else: a person coming out from behind another takes the box
    /// the hidden one left, but not their colours.
    pub min_track_similarity: f32,
}

impl Default for TrackingConfig {
    fn default() -> Self {
        Self {
            forget_after: 10.0,
            max_persons: 8,
            min_iou: 0.3,
            min_similarity: 0.8,
            max_floor_gap: 0.8,
            floor_fresh: 0.3,
            max_track_floor_gap: 1.2,
            min_track_similarity: 0.9,
        }
    }
}

/// One person instance found in a frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Detection {
    /// Its box in the frame, pixels.
    pub bbox: BoxPx,
    /// Its appearance, when the caller could measure one.
    pub appearance: Option<Appearance>,
    /// Where it stands on the floor (world metres, two ground-plane coordinates), when the
    /// caller's camera is calibrated.
    pub floor: Option<[f32; 2]>,
}

impl Detection {
    /// A person found in `image` under `mask` inside `bbox`: its colours measured under the
    /// mask, and where it stands when `camera` is calibrated.
    pub fn seen(
        image: &image::RgbImage,
        mask: &image::GrayImage,
        bbox: BoxPx,
        camera: Option<&FloorCamera>,
    ) -> Self {
        Self {
            bbox,
            appearance: Appearance::from_masked(image, mask, Some(bbox)),
            floor: camera.and_then(|c| floor_point(c, &bbox)),
        }
    }
}

/// How a detection was given its id.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Matched {
    /// It continues a track of the same camera (box overlap).
    Track,
    /// It looks like a person tracked in another camera or before (appearance).
    Appearance,
    /// It stands where another camera saw a person a moment ago (floor position).
    Floor,
    /// A new person.
    New,
}

/// The id given to one detection.
#[derive(Debug, Clone, PartialEq)]
pub struct Assignment {
    /// The person id (`person_<n>`, numbered from 0 in order of first sighting).
    pub person_id: String,
    /// How it was matched.
    pub matched: Matched,
    /// The largest share of the detection's box another detection's box covers in this frame
    /// (0..1): above [`CROWDED_COVER`] its pixels mix people.
    pub hidden: f32,
}

/// A person's state in one camera.
#[derive(Debug, Clone)]
struct CameraTrack {
    bbox: BoxPx,
    /// The person's colours as this camera sees them.
    appearance: Option<Appearance>,
    /// Box centre velocity, pixels per second.
    velocity: [f32; 2],
    stamp: f64,
}

/// A tracked person.
#[derive(Debug, Clone)]
struct Person {
    id: String,
    cameras: BTreeMap<String, CameraTrack>,
    appearance: Option<Appearance>,
    /// Last floor position and when.
    floor: Option<([f32; 2], f64)>,
    last_seen: f64,
}

/// What one frame's matching has settled so far: the id given to each detection, and which
/// persons are taken.
struct Claims {
    given: Vec<Option<Assignment>>,
    taken: Vec<bool>,
}

/// Counters of a tracker's life.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TrackingStats {
    /// Persons started.
    pub persons_started: u64,
    /// Persons forgotten after `forget_after` without a sighting.
    pub persons_forgotten: u64,
    /// Persons dropped because `max_persons` were held.
    pub persons_dropped: u64,
}

/// Gives the detections of each frame stable person ids.
#[derive(Debug, Clone)]
pub struct PersonTracks {
    config: TrackingConfig,
    persons: Vec<Person>,
    next_id: u64,
    stats: TrackingStats,
}

impl PersonTracks {
    /// A tracker holding nobody yet.
    pub fn new(config: TrackingConfig) -> Self {
        Self {
            config,
            persons: Vec::new(),
            next_id: 0,
            stats: TrackingStats::default(),
        }
    }

    /// Counters so far.
    pub fn stats(&self) -> TrackingStats {
        self.stats
    }

    /// Ids of the persons held, in order of first sighting.
    pub fn persons(&self) -> Vec<&str> {
        self.persons.iter().map(|p| p.id.as_str()).collect()
    }

    /// Assigns ids to the detections of one frame of `camera` taken at `stamp` seconds (frames
    /// of a camera must come in time order); returns one assignment per detection, in order.
    pub fn update(
        &mut self,
        camera: &str,
        stamp: f64,
        detections: &[Detection],
    ) -> Vec<Assignment> {
        self.forget(stamp);
        let mut claims = Claims {
            given: vec![None; detections.len()],
            taken: vec![false; self.persons.len()],
        };
        let hidden = hidden_shares(&detections.iter().map(|d| d.bbox).collect::<Vec<_>>());

        // 1. Box overlap with each person's predicted box in this camera, best pair first;
        // overlaps whose colours differ wait until after step 2.
        let mut pairs = Vec::new();
        let mut unlike_pairs = Vec::new();
        for (p, person) in self.persons.iter().enumerate() {
            let Some(track) = person.cameras.get(camera) else {
                continue;
            };
            let predicted = track
                .bbox
                .moved(track.velocity, (stamp - track.stamp) as f32);
            for (d, det) in detections.iter().enumerate() {
                let iou = predicted.iou(&det.bbox);
                if iou < self.config.min_iou {
                    continue;
                }
                let gap = self.floor_gap(person, det, stamp);
                if gap.is_some_and(|gap| gap > self.config.max_track_floor_gap) {
                    continue;
                }
                // The gate reads whole-box colours; the choice among overlaps, banded ones.
                let (unlike, similarity) = match (&det.appearance, &track.appearance) {
                    (Some(look), Some(known)) => (
                        look.whole_similarity(known) < self.config.min_track_similarity,
                        look.similarity(known),
                    ),
                    _ => (false, 0.0),
                };
                // Where the detection stands clear of the others, its box bottom is its own
                // feet: the person another camera saw standing nearest gets a bonus.
                let nearness = match gap {
                    Some(gap) if hidden[d] <= CROWDED_COVER => {
                        (1.0 - gap / self.config.max_track_floor_gap.max(1e-6)).max(0.0)
                    }
                    _ => 0.0,
                };
                let score =
                    iou + OVERLAP_COLOUR_WEIGHT * similarity + OVERLAP_FLOOR_WEIGHT * nearness;
                if unlike {
                    unlike_pairs.push((score, p, d));
                } else {
                    pairs.push((score, p, d));
                }
            }
        }
        self.assign_boxes(camera, stamp, detections, &hidden, pairs, &mut claims);

        // 2. Appearance against persons not matched in this frame, most similar first.
        let mut pairs = Vec::new();
        // Floor positions decide where both are known and fresh (scores above 1); colours
        // otherwise (scores up to 1).
        for (d, det) in detections.iter().enumerate() {
            if claims.given[d].is_some() {
                continue;
            }
            for (p, person) in self.persons.iter().enumerate() {
                if claims.taken[p] {
                    continue;
                }
                let similarity = match (&det.appearance, &person.appearance) {
                    (Some(look), Some(known)) => Some(look.whole_similarity(known)),
                    _ => None,
                };
                match self.floor_gap(person, det, stamp) {
                    Some(gap) => {
                        if gap <= self.config.max_floor_gap {
                            let closeness = 1.0 - gap / self.config.max_floor_gap.max(1e-6);
                            pairs.push((1.0 + closeness + 0.1 * similarity.unwrap_or(0.0), p, d));
                        }
                    }
                    None => {
                        if let Some(similarity) =
                            similarity.filter(|s| *s >= self.config.min_similarity)
                        {
                            pairs.push((similarity, p, d));
                        }
                    }
                }
            }
        }
        pairs.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
        for (score, p, d) in pairs {
            if claims.taken[p] || claims.given[d].is_some() {
                continue;
            }
            claims.taken[p] = true;
            let how = if score > 1.0 {
                Matched::Floor
            } else {
                Matched::Appearance
            };
            claims.given[d] = Some(self.sighted(p, camera, stamp, &detections[d], hidden[d], how));
        }

        // 2b. Box overlaps with other colours, where nobody else took the detection: the same
        // person turned or half hidden rather than a new one.
        self.assign_boxes(
            camera,
            stamp,
            detections,
            &hidden,
            unlike_pairs,
            &mut claims,
        );

        // 3. New persons, in detection order.
        for (d, det) in detections.iter().enumerate() {
            if claims.given[d].is_none() {
                let p = self.start(stamp);
                claims.given[d] =
                    Some(self.sighted(p, camera, stamp, det, hidden[d], Matched::New));
            }
        }
        claims
            .given
            .into_iter()
            .map(|a| a.expect("every detection assigned"))
            .collect()
    }

    /// Gives each detection of `pairs` (box overlap, person, detection) the person it overlaps
    /// most, best pair first, persons and detections once each.
    fn assign_boxes(
        &mut self,
        camera: &str,
        stamp: f64,
        detections: &[Detection],
        hidden: &[f32],
        mut pairs: Vec<(f32, usize, usize)>,
        claims: &mut Claims,
    ) {
        pairs.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
        for (_, p, d) in pairs {
            if claims.taken[p] || claims.given[d].is_some() {
                continue;
            }
            claims.taken[p] = true;
            claims.given[d] =
                Some(self.sighted(p, camera, stamp, &detections[d], hidden[d], Matched::Track));
        }
    }

    /// Floor distance (metres) between a detection and a person's fresh floor position, when
    /// both are known.
    fn floor_gap(&self, person: &Person, det: &Detection, stamp: f64) -> Option<f32> {
        let ((known, _), here) = person
            .floor
            .filter(|(_, at)| (stamp - at).abs() <= self.config.floor_fresh)
            .zip(det.floor)?;
        Some((known[0] - here[0]).hypot(known[1] - here[1]))
    }

    /// Records a sighting of person `p`.
    fn sighted(
        &mut self,
        p: usize,
        camera: &str,
        stamp: f64,
        det: &Detection,
        hidden: f32,
        matched: Matched,
    ) -> Assignment {
        let person = &mut self.persons[p];
        let velocity = match (matched, person.cameras.get(camera)) {
            (Matched::Track, Some(track)) if stamp > track.stamp => {
                let dt = (stamp - track.stamp) as f32;
                let (a, b) = (track.bbox.center(), det.bbox.center());
                [(b[0] - a[0]) / dt, (b[1] - a[1]) / dt]
            }
            _ => [0.0, 0.0],
        };
        let known_here = person
            .cameras
            .get(camera)
            .and_then(|t| t.appearance.as_ref());
        // Colours seen in a huddle mix people: keep those from before it.
        let frozen = hidden > CROWDED_COVER;
        let seen_here = match (known_here, &det.appearance) {
            (Some(known), Some(_)) if frozen => Some(known.clone()),
            (Some(known), Some(look)) => Some(known.blend(look, 0.2)),
            (known, look) => look.clone().or_else(|| known.cloned()),
        };
        person.cameras.insert(
            camera.to_owned(),
            CameraTrack {
                appearance: seen_here,
                bbox: det.bbox,
                velocity,
                stamp,
            },
        );
        if let Some(look) = &det.appearance {
            person.appearance = Some(match &person.appearance {
                Some(known) if frozen => known.clone(),
                Some(known) => known.blend(look, 0.2),
                None => look.clone(),
            });
        }
        if let Some(floor) = det.floor {
            person.floor = Some((floor, stamp));
        }
        person.last_seen = person.last_seen.max(stamp);
        Assignment {
            person_id: person.id.clone(),
            matched,
            hidden,
        }
    }

    /// Starts a person, dropping the least recently seen one when full; returns its index.
    fn start(&mut self, stamp: f64) -> usize {
        if self.persons.len() >= self.config.max_persons.max(1) {
            let oldest = self
                .persons
                .iter()
                .enumerate()
                .min_by(|a, b| a.1.last_seen.total_cmp(&b.1.last_seen))
                .map(|(i, _)| i)
                .expect("a person is held");
            self.persons.remove(oldest);
            self.stats.persons_dropped += 1;
        }
        self.persons.push(Person {
            id: format!("person_{}", self.next_id),
            cameras: BTreeMap::new(),
            appearance: None,
            floor: None,
            last_seen: stamp,
        });
        self.next_id += 1;
        self.stats.persons_started += 1;
        self.persons.len() - 1
    }

    /// Forgets persons unseen for `forget_after` before `stamp`.
    fn forget(&mut self, stamp: f64) {
        let horizon = stamp - self.config.forget_after;
        let before = self.persons.len();
        self.persons.retain(|p| p.last_seen >= horizon);
        self.stats.persons_forgotten += (before - self.persons.len()) as u64;
    }
}

/// For each box, the largest share of its area that one of the other boxes covers: 0 for a
/// person standing clear of everyone in the frame, towards 1 for one behind or in front of
/// another.
fn hidden_shares(boxes: &[BoxPx]) -> Vec<f32> {
    boxes
        .iter()
        .enumerate()
        .map(|(i, b)| {
            let area = b.area().max(1.0);
            boxes
                .iter()
                .enumerate()
                .filter(|(j, _)| *j != i)
                .map(|(_, other)| b.intersection(other) / area)
                .fold(0.0, f32::max)
        })
        .collect()
}

#[cfg(test)]
mod tests;
