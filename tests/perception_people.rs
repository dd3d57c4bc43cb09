//! Several people in one frame (`lhmpp::perception::people`): MoveNet MultiPose finds them, the
//! landmark model reads each from its own crop, and their masks are disjoint.
//!
//! On a real photo (the Pose2Sim multi-person demo frame of the MoveNet fixture, BSD-3-Clause,
//! `tests/fixtures/perception/NOTICE.md`) two people are found, each mask covers the centre of
//! its own box more than the other mask does, and each person's visible landmarks lie in its
//! box. Two synthetic people rendered side by side in one frame are found with masks close to
//! the renders' (IoU ≥ 0.8 each).

use glam::{Vec2, Vec3};
use image::{GrayImage, RgbImage};
use lhmpp::body::Pose;
use lhmpp::eval::photos::render_mask;
use lhmpp::perception::{FoundPerson, LandmarkModel, PeopleConfig, PeopleFinder, PoseNetworks};
use lhmpp::splat::{Camera, Intrinsics};
use lhmpp::synth::capture::render_views;
use lhmpp::synth::{RigCamera, SyntheticPerson};
use safetensors::SafeTensors;
use std::path::Path;
use std::sync::{Arc, OnceLock};

fn finder() -> PeopleFinder {
    static NETS: OnceLock<Arc<PoseNetworks>> = OnceLock::new();
    let nets = NETS
        .get_or_init(|| Arc::new(PoseNetworks::load(LandmarkModel::Full, None).unwrap()))
        .clone();
    PeopleFinder::new(nets, PeopleConfig::default())
}

/// The MoveNet fixture's 256×256 input (the letterboxed two-person frame), doubled to 512×512.
fn two_person_photo() -> RgbImage {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/perception/movenet_multipose_256.safetensors");
    let bytes = std::fs::read(&path).unwrap();
    let st = SafeTensors::deserialize(&bytes).unwrap();
    let pixels = st.tensor("input").unwrap().data().to_vec();
    assert_eq!(pixels.len(), 256 * 256 * 3);
    RgbImage::from_fn(512, 512, |x, y| {
        let at = ((y / 2) as usize * 256 + (x / 2) as usize) * 3;
        image::Rgb([pixels[at], pixels[at + 1], pixels[at + 2]])
    })
}

/// Share of the pixels of the middle half (both ways) of `p`'s box where `mask` is set.
fn centre_coverage(mask: &GrayImage, p: &FoundPerson) -> f64 {
    let size = p.max - p.min;
    let (a, b) = (p.min + 0.25 * size, p.max - 0.25 * size);
    let (mut on, mut all) = (0usize, 0usize);
    for y in a.y.max(0.0) as u32..(b.y as u32).min(mask.height()) {
        for x in a.x.max(0.0) as u32..(b.x as u32).min(mask.width()) {
            all += 1;
            on += usize::from(mask.get_pixel(x, y).0[0] >= 128);
        }
    }
    on as f64 / all.max(1) as f64
}

fn assert_disjoint(people: &[FoundPerson]) {
    for (i, a) in people.iter().enumerate() {
        for b in &people[i + 1..] {
            let shared = a
                .mask
                .pixels()
                .zip(b.mask.pixels())
                .filter(|(p, q)| p.0[0] > 0 && q.0[0] > 0)
                .count();
            assert_eq!(shared, 0, "masks overlap in {shared} pixels");
        }
    }
}

#[test]
fn two_people_in_a_real_photo_get_their_own_masks_and_landmarks() {
    let image = two_person_photo();
    let people = finder().find(&image).unwrap();
    for p in &people {
        eprintln!(
            "person: score {:.3}, box {:?}–{:?}, presence {:.3}",
            p.score, p.min, p.max, p.landmarks.presence
        );
    }
    assert_eq!(people.len(), 2, "two people in the photo");
    assert_disjoint(&people);
    for (i, p) in people.iter().enumerate() {
        let other = &people[1 - i];
        let own = centre_coverage(&p.mask, p);
        let theirs = centre_coverage(&other.mask, p);
        eprintln!(
            "person {i}: own mask covers {own:.3} of its box centre, the other's {theirs:.3}"
        );
        assert!(own > theirs, "person {i}: {own} vs {theirs}");
        assert!(own > 0.3, "person {i}: own mask covers {own}");
        let size = p.max - p.min;
        let (lo, hi) = (p.min - 0.15 * size, p.max + 0.15 * size);
        let visible: Vec<Vec2> = p
            .landmarks
            .image
            .iter()
            .filter(|l| l.visibility >= 0.5)
            .map(|l| l.position.truncate())
            .collect();
        let inside = visible
            .iter()
            .filter(|q| q.cmpge(lo).all() && q.cmple(hi).all())
            .count();
        eprintln!(
            "person {i}: {inside}/{} visible landmarks in its box",
            visible.len()
        );
        assert!(visible.len() >= 10, "person {i}: {} visible", visible.len());
        assert_eq!(
            inside,
            visible.len(),
            "person {i}: landmarks outside its box"
        );
    }
}

const SIDE: u32 = 256;

/// A front render of synthetic person `seed`: the image and its true mask.
fn render(seed: u64) -> (RgbImage, GrayImage) {
    let person = SyntheticPerson::new(seed, 20_000).unwrap();
    let h = person.template.height();
    let target = Vec3::new(0.0, 0.5 * h, 0.0);
    let distance = 0.62 * h / (0.5f32 * 0.75).tan();
    let cams = [RigCamera {
        name: "front".into(),
        camera: Camera::look_at(
            target + Vec3::new(0.0, 0.1, 1.0) * distance,
            target,
            Vec3::Y,
            Intrinsics::from_fov_y(SIDE, SIDE, 0.75),
        ),
    }];
    let views = render_views(&person, &Pose::identity(), &cams).unwrap();
    (views[0].output.to_rgb8(), render_mask(&views[0].output))
}

fn iou(a: &GrayImage, b: &GrayImage) -> f64 {
    let (mut inter, mut union) = (0usize, 0usize);
    for (p, q) in a.pixels().zip(b.pixels()) {
        let (p, q) = (p.0[0] >= 128, q.0[0] >= 128);
        inter += usize::from(p && q);
        union += usize::from(p || q);
    }
    inter as f64 / union.max(1) as f64
}

#[test]
fn two_synthetic_people_side_by_side_get_masks_close_to_the_truth() {
    let renders = [render(3), render(8)];
    let mut frame = RgbImage::new(2 * SIDE, SIDE);
    let mut truths = Vec::new();
    for (k, (image, mask)) in renders.iter().enumerate() {
        image::imageops::replace(&mut frame, image, i64::from(k as u32 * SIDE), 0);
        let mut truth = GrayImage::new(2 * SIDE, SIDE);
        image::imageops::replace(&mut truth, mask, i64::from(k as u32 * SIDE), 0);
        truths.push(truth);
    }
    let people = finder().find(&frame).unwrap();
    assert_eq!(people.len(), 2, "two synthetic people");
    assert_disjoint(&people);
    for p in &people {
        let k = usize::from((p.min.x + p.max.x) / 2.0 >= SIDE as f32);
        let score = iou(&p.mask, &truths[k]);
        eprintln!(
            "synthetic person {k}: score {:.3}, mask IoU {score:.3}",
            p.score
        );
        assert!(score >= 0.8, "person {k}: mask IoU {score}");
    }
    let sides: Vec<usize> = people
        .iter()
        .map(|p| usize::from((p.min.x + p.max.x) / 2.0 >= SIDE as f32))
        .collect();
    assert_ne!(sides[0], sides[1], "one person per half: {sides:?}");
}
