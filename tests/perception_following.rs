//! The one-person mode's tracker on synthetic scenes with true person ids
//! (`lhmpp::eval::following`): a person who stands an eighth of the frame high is found in
//! every frame (BlazePose's own detector, the tracker's only detector before, finds people who
//! fill much of the frame), and where another person walks past, the one followed is kept.
//! Someone taken up once the one followed is gone is told apart from that person coming back
//! (`Perceived::someone_else`: the node then drops that camera's views of the one before).

use lhmpp::eval::following::{follow_frames, score_following, FollowingScore};
use lhmpp::eval::tracking::{read_crowd, CrowdImage};
use lhmpp::perception::{
    LandmarkModel, PersonDetector, PersonTracker, PoseNetworks, TrackerConfig,
};
use lhmpp::synth::crowd::{write_crowd_bag, CrowdOptions};
use std::sync::{Arc, OnceLock};

fn networks() -> Arc<PoseNetworks> {
    static NETS: OnceLock<Arc<PoseNetworks>> = OnceLock::new();
    NETS.get_or_init(|| Arc::new(PoseNetworks::load(LandmarkModel::Full, None).unwrap()))
        .clone()
}

/// One camera's frames of a crowd scene, read back from its bag.
fn scene(options: CrowdOptions) -> Vec<CrowdImage> {
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("scene.mcap");
    write_crowd_bag(&bag, &options, |_, _| {}).unwrap();
    read_crowd(&bag).unwrap()
}

/// The frames through one tracker, scored.
fn follow(images: &[CrowdImage], config: TrackerConfig) -> FollowingScore {
    let nets = networks();
    let frames = follow_frames(
        images,
        || PersonTracker::new(nets.clone(), config),
        |p| p.mask.to_mask(0.5, 0.1),
        |_, _, _| {},
    )
    .unwrap();
    score_following(images, &frames)
}

fn summary(what: &str, s: &FollowingScore) {
    let all = s.at_least(0.0);
    println!(
        "{what}: found {}/{}, switches {}, finds of another {}, searching frames {}",
        all.found,
        all.frames,
        s.switches,
        s.finds_of_another,
        s.times.detector.len()
    );
}

#[test]
fn a_person_an_eighth_of_the_frame_high_is_found_in_every_frame() {
    // 640×480, the camera 14.1 m from the middle of the room: she stands 1/9 to 1/7 of the
    // frame high as she walks.
    let images = scene(CrowdOptions {
        seed: 31,
        people: 1,
        cameras: 1,
        frames: 12,
        points: 8000,
        camera_distance: Some(14.1),
        ..CrowdOptions::default()
    });
    let movenet = follow(&images, TrackerConfig::default());
    let blazepose = follow(
        &images,
        TrackerConfig {
            detector: PersonDetector::BlazePose,
            check_looks: false,
            ..TrackerConfig::default()
        },
    );
    summary("MoveNet, then the landmarks' crop", &movenet);
    summary("BlazePose's detector, then the crop", &blazepose);
    let all = movenet.at_least(0.0);
    assert_eq!(all.frames, 12, "she is in view in every frame");
    assert!(all.found >= 11, "found in {}/12", all.found);
    let eighth = movenet.at_least(0.125);
    assert_eq!(
        eighth.found, eighth.frames,
        "every frame she stands ≥ 1/8 high"
    );
    assert!(
        all.found > blazepose.at_least(0.0).found,
        "BlazePose's detector found her as often"
    );
    assert_eq!(movenet.false_finds, 0);
}

#[test]
fn the_person_followed_is_kept_while_another_walks_past() {
    // Two people passing close in one camera (320×240): following the landmarks' crop alone
    // slides onto the other one; checked against the followed person's looks it does not.
    let images = scene(CrowdOptions {
        seed: 43,
        people: 2,
        cameras: 1,
        frames: 24,
        width: 320,
        height: 240,
        points: 8000,
        ..CrowdOptions::default()
    });
    let checked = follow(&images, TrackerConfig::default());
    let unchecked = follow(
        &images,
        TrackerConfig {
            check_looks: false,
            ..TrackerConfig::default()
        },
    );
    summary("looks checked", &checked);
    summary("crop followed unchecked", &unchecked);
    assert!(
        unchecked.switches >= 1,
        "the scene no longer makes the unchecked crop slide onto the other person"
    );
    assert_eq!(checked.switches, 0);
    assert_eq!(checked.finds_of_another, 0);
    let all = checked.at_least(0.0);
    assert!(all.found >= 18, "found in {}/{}", all.found, all.frames);
}

/// Whether each frame found someone, and whether they were someone else than the person the
/// tracker followed before: `clips` of frames, each clip starting `gap_s` after the one before.
fn takeups(clips: &[&[CrowdImage]], gap_s: f64) -> Vec<(bool, bool)> {
    let mut tracker = PersonTracker::new(networks(), TrackerConfig::default());
    let mut t = 0.0;
    let mut out = Vec::new();
    for clip in clips {
        for frame in *clip {
            let found = tracker.perceive_at(&frame.rgb, t).unwrap();
            out.push((found.is_some(), found.is_some_and(|p| p.someone_else)));
            t += 1.0 / 30.0;
        }
        t += gap_s;
    }
    out
}

#[test]
fn someone_taken_up_after_the_one_followed_left_is_told_apart_from_them_coming_back() {
    // The crossing scene's two people, each alone in the room (320×240).
    let alone = |k| {
        scene(CrowdOptions {
            seed: 43,
            people: 2,
            cameras: 1,
            frames: 6,
            width: 320,
            height: 240,
            points: 8000,
            only: Some(k),
            ..CrowdOptions::default()
        })
    };
    let (a, b) = (alone(0), alone(1));
    let flags = |v: &[(bool, bool)]| v.iter().filter(|f| f.1).count();
    // A, then 2 s later B, then A again: two take-ups of someone else, each in the first frame
    // that finds the new person.
    let switched = takeups(&[&a, &b, &a], 2.0);
    println!("A, B, A: {switched:?}");
    for (clip, range) in [("A", 0..6), ("B", 6..12), ("A again", 12..18)] {
        let found = switched[range].iter().filter(|f| f.0).count();
        assert!(found >= 4, "{clip}: found in {found}/6 frames");
    }
    assert_eq!(flags(&switched[..6]), 0, "the first person is nobody else");
    let first_found = |r: std::ops::Range<usize>| r.clone().find(|&i| switched[i].0).unwrap();
    for range in [6..12, 12..18] {
        assert!(
            switched[first_found(range.clone())].1,
            "a new person's first frame is not flagged: {switched:?}"
        );
        assert_eq!(flags(&switched[range]), 1, "{switched:?}");
    }
    // A, then 2 s later A again: the same person back, never someone else.
    let back = takeups(&[&a, &a], 2.0);
    println!("A, A: {back:?}");
    assert!(back[6..].iter().filter(|f| f.0).count() >= 4, "{back:?}");
    assert_eq!(flags(&back), 0, "{back:?}");
}
