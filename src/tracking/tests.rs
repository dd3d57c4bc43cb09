use super::*;
use image::{GrayImage, Luma, Rgb, RgbImage};

fn look(colour: [u8; 3]) -> Appearance {
    let image = RgbImage::from_pixel(8, 8, Rgb(colour));
    let mask = GrayImage::from_pixel(8, 8, Luma([255]));
    Appearance::from_masked(&image, &mask, None).unwrap()
}

fn person_box(cx: f32) -> BoxPx {
    BoxPx::new([cx - 30.0, 100.0], [cx + 30.0, 260.0])
}

fn det(cx: f32, colour: [u8; 3]) -> Detection {
    Detection {
        bbox: person_box(cx),
        appearance: Some(look(colour)),
        floor: None,
    }
}

fn on_floor(cx: f32, colour: [u8; 3], floor: [f32; 2]) -> Detection {
    Detection {
        floor: Some(floor),
        ..det(cx, colour)
    }
}

#[test]
fn floor_position_decides_across_cameras() {
    // Camera 0 sees A (red front) at (0, 0) and B (blue) at (2, 0). Camera 1, 10 ms later,
    // sees A's back (blue, like B) where A stands, and B (grey back) where B stands.
    let mut tracks = PersonTracks::new(TrackingConfig::default());
    let cam0 = tracks.update(
        "cam0",
        0.0,
        &[
            on_floor(100.0, [200, 30, 30], [0.0, 0.0]),
            on_floor(400.0, [30, 30, 200], [2.0, 0.0]),
        ],
    );
    let cam1 = tracks.update(
        "cam1",
        0.01,
        &[
            on_floor(150.0, [30, 30, 200], [0.1, 0.05]),
            on_floor(500.0, [128, 128, 128], [2.05, -0.1]),
        ],
    );
    assert_eq!(
        cam1[0].person_id, cam0[0].person_id,
        "A by position, not B by colour"
    );
    assert_eq!(cam1[1].person_id, cam0[1].person_id);
    assert_eq!(
        (cam1[0].matched, cam1[1].matched),
        (Matched::Floor, Matched::Floor)
    );
    // Someone far from everyone, looking like A: a new person while A's position is fresh.
    let far = tracks.update("cam2", 0.02, &[on_floor(300.0, [200, 30, 30], [5.0, 5.0])]);
    assert_eq!(far[0].matched, Matched::New);
}

#[test]
fn two_people_crossing_keep_their_ids() {
    // A walks right, B walks left at 150 px/s; they pass each other at t = 1.5 s. Same
    // clothes, so only the motion tells them apart while they overlap.
    let mut tracks = PersonTracks::new(TrackingConfig::default());
    let grey = [128, 128, 128];
    let first = tracks.update("cam0", 0.0, &[det(100.0, grey), det(550.0, grey)]);
    let (a, b) = (first[0].person_id.clone(), first[1].person_id.clone());
    assert_ne!(a, b);
    for k in 1..=30 {
        let t = k as f64 * 0.1;
        let xa = 100.0 + 150.0 * t as f32;
        let xb = 550.0 - 150.0 * t as f32;
        // Detector order flips every frame, as a detector's output order may.
        let (d, flip) = if k % 2 == 0 {
            (vec![det(xa, grey), det(xb, grey)], false)
        } else {
            (vec![det(xb, grey), det(xa, grey)], true)
        };
        let got = tracks.update("cam0", t, &d);
        let (ga, gb) = if flip {
            (&got[1], &got[0])
        } else {
            (&got[0], &got[1])
        };
        if (xa - xb).abs() > 1.0 {
            assert_eq!(
                (&ga.person_id, &gb.person_id),
                (&a, &b),
                "frame {k} (t {t:.1} s)"
            );
        }
    }
    assert_eq!(tracks.stats().persons_started, 2);
}

#[test]
fn a_person_coming_back_is_recognised_until_forgotten() {
    let config = TrackingConfig {
        forget_after: 5.0,
        ..TrackingConfig::default()
    };
    let mut tracks = PersonTracks::new(config);
    let red = [200, 30, 30];
    let id = tracks.update("cam0", 0.0, &[det(100.0, red)])[0]
        .person_id
        .clone();
    // Back 3 s later on the other side of the frame: no overlap, same look.
    let back = &tracks.update("cam0", 3.0, &[det(500.0, red)])[0];
    assert_eq!((&back.person_id, back.matched), (&id, Matched::Appearance));
    // Gone for longer than forget_after: a new person.
    let later = &tracks.update("cam0", 9.0, &[det(300.0, red)])[0];
    assert_ne!(later.person_id, id);
    assert_eq!(later.matched, Matched::New);
    assert_eq!(tracks.stats().persons_forgotten, 1);
}

#[test]
fn the_same_person_in_another_camera_gets_the_same_id_and_a_stranger_does_not() {
    let mut tracks = PersonTracks::new(TrackingConfig::default());
    let (red, blue) = ([200, 30, 30], [30, 30, 200]);
    let cam0 = tracks.update("cam0", 0.0, &[det(100.0, red), det(400.0, blue)]);
    let cam1 = tracks.update("cam1", 0.02, &[det(300.0, blue), det(250.0, [30, 200, 30])]);
    assert_eq!(
        cam1[0].person_id, cam0[1].person_id,
        "blue seen by both cameras"
    );
    assert_eq!(cam1[0].matched, Matched::Appearance);
    assert_eq!(cam1[1].matched, Matched::New, "green was never seen");
    // Two detections in one frame never share an id, however alike.
    let same = tracks.update("cam2", 0.04, &[det(100.0, red), det(300.0, red)]);
    assert_ne!(same[0].person_id, same[1].person_id);
}

#[test]
fn past_max_persons_the_least_recently_seen_is_dropped_and_counted() {
    let config = TrackingConfig {
        max_persons: 2,
        ..TrackingConfig::default()
    };
    let mut tracks = PersonTracks::new(config);
    tracks.update("cam0", 0.0, &[det(100.0, [200, 30, 30])]);
    tracks.update("cam0", 1.0, &[det(400.0, [30, 30, 200])]);
    tracks.update("cam0", 2.0, &[det(700.0, [30, 200, 30])]);
    assert_eq!(tracks.persons(), ["person_1", "person_2"]);
    assert_eq!(tracks.stats().persons_dropped, 1);
}

#[test]
fn tracking_is_deterministic() {
    let frames: Vec<(f64, Vec<Detection>)> = (0..20)
        .map(|k| {
            let t = k as f64 * 0.1;
            let x = 100.0 + 40.0 * k as f32;
            (
                t,
                vec![
                    det(x, [90, 90, 90]),
                    det(900.0 - x, [90, 90, 90]),
                    det(500.0, [10, 200, 10]),
                ],
            )
        })
        .collect();
    let run = || {
        let mut tracks = PersonTracks::new(TrackingConfig::default());
        frames
            .iter()
            .flat_map(|(t, d)| tracks.update("cam0", *t, d))
            .map(|a| a.person_id)
            .collect::<Vec<_>>()
    };
    assert_eq!(run(), run());
}

#[test]
fn appearance_tells_colours_apart_and_boxes_overlap_as_expected() {
    assert!((look([200, 30, 30]).similarity(&look([200, 30, 30])) - 1.0).abs() < 1e-6);
    assert!(look([200, 30, 30]).similarity(&look([30, 30, 200])) < 0.01);
    let a = BoxPx::new([0.0, 0.0], [10.0, 10.0]);
    assert!((a.iou(&BoxPx::new([5.0, 0.0], [15.0, 10.0])) - 1.0 / 3.0).abs() < 1e-6);
    assert_eq!(a.iou(&BoxPx::new([20.0, 0.0], [30.0, 10.0])), 0.0);
    let empty_mask = GrayImage::new(8, 8);
    assert!(Appearance::from_masked(&RgbImage::new(8, 8), &empty_mask, None).is_none());
}

#[test]
fn a_box_overlap_does_not_continue_a_person_the_floor_puts_elsewhere() {
    // A and B look alike. Both cameras see them 2 m apart; then camera 0 sees one person
    // where B's box was, but standing where A stands (A has stepped in front of B).
    let grey = [90, 90, 90];
    let mut tracks = PersonTracks::new(TrackingConfig::default());
    let cam0 = tracks.update(
        "cam0",
        0.0,
        &[
            on_floor(100.0, grey, [0.0, 0.0]),
            on_floor(400.0, grey, [2.0, 0.0]),
        ],
    );
    let cam1 = tracks.update(
        "cam1",
        0.01,
        &[
            on_floor(300.0, grey, [0.05, 0.0]),
            on_floor(500.0, grey, [2.05, 0.0]),
        ],
    );
    assert_eq!(cam1[0].person_id, cam0[0].person_id);
    assert_eq!(cam1[1].person_id, cam0[1].person_id);
    let crossing = &tracks.update("cam0", 0.1, &[on_floor(400.0, grey, [0.1, 0.0])])[0];
    assert_eq!(
        crossing.person_id, cam0[0].person_id,
        "A, by where it stands"
    );
    assert_eq!(crossing.matched, Matched::Floor);
}

#[test]
fn a_person_coming_out_from_behind_another_keeps_their_own_id() {
    // One camera: red A stands still at x = 100, blue B walks behind A and comes out where A's
    // box was while A is hidden behind B. B's colours, not A's box, decide.
    let (red, blue) = ([200, 30, 30], [30, 30, 200]);
    let mut tracks = PersonTracks::new(TrackingConfig::default());
    let first = tracks.update("cam0", 0.0, &[det(100.0, red), det(400.0, blue)]);
    let out = &tracks.update("cam0", 0.1, &[det(100.0, blue)])[0];
    assert_eq!(out.person_id, first[1].person_id, "B, by its colours");
    assert_eq!(out.matched, Matched::Appearance);
}

#[test]
fn colours_seen_while_boxes_overlap_are_not_learned() {
    // Red A stands at x = 100; blue B walks up and stands half in front of A for a second, so
    // A's detection shows mostly B's blue. Then they swap places within the huddle: each
    // box overlaps both predicted boxes, and the colours from before the huddle must decide.
    // Had A learned the huddle's blue, it would take B's detection.
    let (red, blue) = ([200, 30, 30], [30, 30, 200]);
    let mut tracks = PersonTracks::new(TrackingConfig::default());
    let first = tracks.update("cam0", 0.0, &[det(100.0, red), det(400.0, blue)]);
    let (a, b) = (first[0].person_id.clone(), first[1].person_id.clone());
    for k in 1..=25 {
        let t = k as f64 * 0.1;
        let x_b = (400.0 - 200.0 * t as f32).max(130.0);
        let look_a = if x_b - 100.0 < 60.0 { blue } else { red };
        let got = tracks.update("cam0", t, &[det(100.0, look_a), det(x_b, blue)]);
        assert_eq!(
            (&got[0].person_id, &got[1].person_id),
            (&a, &b),
            "frame {k}"
        );
    }
    let swapped = tracks.update("cam0", 2.6, &[det(100.0, blue), det(130.0, red)]);
    assert_eq!(
        (&swapped[0].person_id, &swapped[1].person_id),
        (&b, &a),
        "each by the colours seen before the huddle"
    );
}

#[test]
fn bands_tell_a_red_shirt_over_blue_trousers_from_the_reverse() {
    // Same pixels overall, in other places: one histogram of the whole box could not tell them
    // apart.
    let outfit = |top: [u8; 3], bottom: [u8; 3]| {
        let image = RgbImage::from_fn(20, 100, |_, y| Rgb(if y < 50 { top } else { bottom }));
        let mask = GrayImage::from_pixel(20, 100, Luma([255]));
        let bbox = BoxPx::new([0.0, 0.0], [20.0, 100.0]);
        Appearance::from_masked(&image, &mask, Some(bbox)).unwrap()
    };
    let (red, blue) = ([200, 30, 30], [30, 30, 200]);
    let a = outfit(red, blue);
    assert!((a.similarity(&outfit(red, blue)) - 1.0).abs() < 1e-6);
    assert!(a.similarity(&outfit(blue, red)) < 0.5);
}

#[test]
fn people_who_look_alike_are_told_apart_by_where_they_stand() {
    // A and B wear the same grey and stand 0.6 m apart. Camera 1 sees them apart; camera 0
    // sees their boxes side by side, then one box over both of them, which overlaps B's box
    // more but stands at A's feet (B behind A): it is A.
    let grey = [128, 128, 128];
    let seen = |x0: f32, x1: f32, floor: [f32; 2]| Detection {
        bbox: BoxPx::new([x0, 100.0], [x1, 300.0]),
        appearance: Some(look(grey)),
        floor: Some(floor),
    };
    let mut tracks = PersonTracks::new(TrackingConfig::default());
    let first = tracks.update(
        "cam0",
        0.0,
        &[
            seen(150.0, 250.0, [0.0, 0.0]),
            seen(240.0, 340.0, [0.6, 0.0]),
        ],
    );
    let (a, b) = (first[0].person_id.clone(), first[1].person_id.clone());
    for t in [0.0, 0.1] {
        let ids = tracks.update(
            "cam1",
            t,
            &[
                seen(100.0, 180.0, [0.0, 0.0]),
                seen(400.0, 480.0, [0.6, 0.0]),
            ],
        );
        assert_eq!((&ids[0].person_id, &ids[1].person_id), (&a, &b));
    }
    let merged = tracks.update("cam0", 0.1, &[seen(190.0, 330.0, [0.02, 0.0])]);
    assert_eq!(
        merged[0].person_id, a,
        "the floor under the box, not its overlap"
    );
    assert_eq!(merged[0].matched, Matched::Track);
}
