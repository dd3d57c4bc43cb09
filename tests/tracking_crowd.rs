//! Several people tracked on a synthetic crowd scene (`lhmpp synth --people N`, then
//! `lhmpp eval-tracking`): the scene's id maps are the truth, the tracker's ids must follow it.
//!
//! One camera, two people walking past each other: each person is found in most frames, keeps
//! one id throughout, and no view goes to the other person's id. People who fill a small part
//! of the frame need a larger detector input. A bag without id maps is refused with an error
//! naming the missing topic, unless read as one without truth (real video): then one person
//! seen by twelve calibrated cameras gets one id, placed in one spot by every camera.

use lhmpp::eval::id_tracks::{camera_tracks, id_agreement, track_ids, SAME_MOMENT_NS};
use lhmpp::eval::tracking::{
    read_camera_bag, read_crowd, track_and_score, visible_persons, CrowdImage,
};
use lhmpp::perception::{LandmarkModel, PeopleConfig, PeopleFinder, PoseNetworks};
use lhmpp::synth::crowd::{write_crowd_bag, CrowdOptions};
use lhmpp::tracking::{PersonTracks, TrackingConfig};
use std::path::Path;
use std::sync::Arc;

/// `frames` frames of the two people of seed 5 walking past each other in one camera, read
/// back from their bag.
fn two_people_in_one_camera(frames: usize) -> Vec<CrowdImage> {
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("crowd.mcap");
    let options = CrowdOptions {
        seed: 5,
        people: 2,
        cameras: 1,
        frames,
        ..CrowdOptions::default()
    };
    write_crowd_bag(&bag, &options, |_, _| {}).unwrap();
    read_crowd(&bag).unwrap()
}

#[test]
fn two_people_keep_their_ids_in_one_camera() {
    let images = two_people_in_one_camera(16);
    assert_eq!(images.len(), 16);
    // Both people show in the first frame's id map.
    assert_eq!(visible_persons(&images[0].ids), vec![0, 1]);

    let nets = Arc::new(PoseNetworks::load(LandmarkModel::Full, None).unwrap());
    let mut finder = PeopleFinder::new(nets, PeopleConfig::default());
    let mut tracks = PersonTracks::new(TrackingConfig::default());
    let score = track_and_score(&images, &mut finder, &mut tracks, |_, _, _, _| {}).unwrap();
    assert_eq!(score.persons, 2);
    assert!(
        score.recall() >= 0.8,
        "found {}/{} person sightings",
        score.found,
        score.visible
    );
    assert_eq!(score.id_switches, 0, "{score:?}");
    assert_eq!(score.ids_per_person, vec![1, 1], "{score:?}");
    assert_eq!(score.wrong_person_views, 0, "{score:?}");
}

#[test]
fn a_bag_without_id_maps_is_refused_by_name() {
    let bag = Path::new(env!("CARGO_MANIFEST_DIR")).join("bags/eval_seed1.mcap");
    let err = match read_crowd(&bag) {
        Ok(_) => panic!("a one-person bag has no id maps"),
        Err(e) => e.to_string(),
    };
    assert!(
        err.contains("person_ids") && err.contains("eval_seed1.mcap"),
        "{err}"
    );
}

/// People who fill a small part of the frame (a crowd frame shrunk to a quarter of its size and
/// set in the middle of a plain frame of the original size, so each person stands about a sixth
/// of the frame high): the detector at its native 256-pixel input misses them, a larger input
/// (`perception.people_detector_side`) finds them.
#[test]
fn a_larger_detector_input_finds_people_who_fill_a_small_part_of_the_frame() {
    let frame = &two_people_in_one_camera(1)[0];
    assert_eq!(visible_persons(&frame.ids), vec![0, 1]);
    let (w, h) = frame.rgb.dimensions();
    let small = image::imageops::resize(
        &frame.rgb,
        w / 4,
        h / 4,
        image::imageops::FilterType::Triangle,
    );
    let mean =
        |c: usize| frame.rgb.pixels().map(|p| p.0[c] as u64).sum::<u64>() / (w as u64 * h as u64);
    let fill = image::Rgb([mean(0) as u8, mean(1) as u8, mean(2) as u8]);
    let mut far = image::RgbImage::from_pixel(w, h, fill);
    image::imageops::replace(&mut far, &small, (w * 3 / 8) as i64, (h * 3 / 8) as i64);

    let nets = Arc::new(PoseNetworks::load(LandmarkModel::Full, None).unwrap());
    let found = |side: usize| {
        let config = PeopleConfig {
            detector_side: side,
            ..PeopleConfig::default()
        };
        let people = PeopleFinder::new(nets.clone(), config).find(&far).unwrap();
        eprintln!("side {side}: {} found", people.len());
        people.len()
    };
    let (native, large) = (found(256), found(640));
    assert!(
        native < 2,
        "the native input found {native} of 2 small people"
    );
    assert_eq!(
        large, 2,
        "a 640-pixel input found {large} of 2 small people"
    );
}

#[test]
fn one_person_in_twelve_calibrated_cameras_without_truth_gets_one_id_in_one_spot() {
    let bag = Path::new(env!("CARGO_MANIFEST_DIR")).join("bags/eval_seed1.mcap");
    let images = read_camera_bag(&bag).unwrap();
    assert_eq!(images.len(), 12);
    assert!(images.iter().all(|i| i.camera_model.is_some()));
    assert!(images.iter().all(|i| visible_persons(&i.ids).is_empty()));

    let nets = Arc::new(PoseNetworks::load(LandmarkModel::Full, None).unwrap());
    let mut finder = PeopleFinder::new(nets, PeopleConfig::default());
    let mut tracks = PersonTracks::new(TrackingConfig::default());
    let sightings = track_ids(&images, &mut finder, &mut tracks, |_, _, _, _| {}).unwrap();
    assert_eq!(sightings.len(), 12, "{sightings:?}");
    let agree = id_agreement(&sightings, SAME_MOMENT_NS);
    assert_eq!(agree.len(), 1, "one person, one id: {agree:?}");
    assert_eq!(agree[0].cameras.len(), 12);
    // Every camera puts them within 0.5 m of where the cameras put them on average.
    let floors: Vec<[f32; 2]> = camera_tracks(&sightings)
        .iter()
        .map(|t| t.mean_floor.expect("calibrated"))
        .collect();
    let n = floors.len() as f32;
    let mean = [
        floors.iter().map(|f| f[0]).sum::<f32>() / n,
        floors.iter().map(|f| f[1]).sum::<f32>() / n,
    ];
    for f in &floors {
        assert!((f[0] - mean[0]).hypot(f[1] - mean[1]) < 0.5, "{floors:?}");
    }
}
