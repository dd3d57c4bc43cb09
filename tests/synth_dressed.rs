//! Dressed synthetic people: renders show each garment's colours where that garment is; the
//! per-anchor ground truth is the albedo of the garment over the anchor; samples repeat per
//! seed; lighting changes only the shading, never the albedo ground truth.

use glam::Vec3;
use lhmpp::body::{GarmentKind, Pose};
use lhmpp::splat::{render, Camera, Gaussians, Intrinsics, RenderOptions, RenderOutput};
use lhmpp::synth::dataset::{make_sample, DatasetOptions, Realism, TRAIN_SEED_START};
use lhmpp::synth::dressing_room::DressingRoom;
use lhmpp::synth::lighting::Lighting;
use lhmpp::synth::DressedPerson;
use rand::SeedableRng;

const SIZE: u32 = 192;

fn front_camera(person: &DressedPerson) -> Camera {
    let h = person.template.height();
    let target = Vec3::new(0.0, 0.5 * h, 0.0);
    Camera::look_at(
        target + Vec3::new(0.0, 0.0, 3.4),
        target,
        Vec3::Y,
        Intrinsics::from_fov_y(SIZE, SIZE, 0.65),
    )
}

fn posed(person: &DressedPerson) -> Gaussians {
    let m = person
        .template
        .skeleton
        .try_skinning_matrices(&Pose::identity())
        .unwrap();
    person.avatar.animate(&m)
}

/// The rendered colour at the pixel of world point `p` when the render shows `p` itself (not
/// something in front of it).
fn seen(out: &RenderOutput, camera: &Camera, p: Vec3) -> Option<Vec3> {
    let q = camera.camera_from_world().transform_point3(p);
    let uv = camera.project_camera_point(q);
    let (x, y) = (uv.x.round() as i64, uv.y.round() as i64);
    if x < 0 || y < 0 || x >= SIZE as i64 || y >= SIZE as i64 {
        return None;
    }
    let i = (y as u32 * SIZE + x as u32) as usize;
    (out.alpha[i] > 0.99 && (q.z - out.depth[i]).abs() < 0.01)
        .then(|| Vec3::from_slice(&out.rgb[3 * i..3 * i + 3]))
}

#[test]
fn a_render_shows_each_garment_where_it_is() {
    for seed in [11u64, 12, 13] {
        let person = DressedPerson::new(seed, 40_000).unwrap();
        let camera = front_camera(&person);
        let white = RenderOptions {
            background: Vec3::ONE,
            ..RenderOptions::default()
        };
        let posed = posed(&person);
        let out = render(&posed, &camera, &white);
        let albedo = person.albedo();
        let mut ids: Vec<u8> = person.garment_ids.clone();
        ids.sort();
        ids.dedup();
        assert!(
            ids.len() >= 3,
            "seed {seed}: skin and at least two garments"
        );
        // Garments only: the skin's small features (eyes, lips, the mouth inside) do not
        // average out.
        for id in ids.into_iter().filter(|id| *id > 0) {
            let (mut own, mut other) = (Vec::new(), Vec::new());
            let others: Vec<Vec3> = (0..albedo.len())
                .filter(|&i| person.garment_ids[i] != id)
                .step_by(37)
                .map(|i| albedo[i])
                .collect();
            let members: Vec<usize> = (0..albedo.len())
                .filter(|&i| person.garment_ids[i] == id)
                .collect();
            for &i in members.iter().step_by(3) {
                if let Some(c) = seen(&out, &camera, posed.positions[i]) {
                    // What the splats (σ about 7 mm) blend at that pixel: the garment's albedo within 2.5 cm
                    // (fine checks and stripes average out).
                    let p = posed.positions[i];
                    let near: Vec<Vec3> = members
                        .iter()
                        .filter(|&&j| posed.positions[j].distance(p) < 0.025)
                        .map(|&j| albedo[j])
                        .collect();
                    let local = near.iter().copied().sum::<Vec3>() / near.len() as f32;
                    own.push((c - local).abs().element_sum() / 3.0);
                    other.push(
                        others
                            .iter()
                            .map(|o| (c - *o).abs().element_sum() / 3.0)
                            .sum::<f32>()
                            / others.len() as f32,
                    );
                }
            }
            let n = own.len();
            if n < 10 {
                continue; // a garment hardly seen from the front (a ponytail's back)
            }
            // Medians: where two garments meet (a top's hem over trousers), pixels blend both.
            let median = |mut v: Vec<f32>| {
                v.sort_by(f32::total_cmp);
                v[v.len() / 2]
            };
            let (own, other) = (median(own), median(other));
            assert!(
                own < 0.08 && own < 0.5 * other,
                "seed {seed} garment {id}: error {own} against its own albedo, {other} against others ({n} seen)"
            );
        }
    }
}

#[test]
fn anchor_truth_is_the_albedo_of_the_garment_over_the_anchor() {
    let room = DressingRoom::shared().unwrap();
    let mut checked = 0;
    for seed in [21u64, 22, 23, 24] {
        let person = DressedPerson::new(seed, 30_000).unwrap();
        let anchors = person.template.sample_anchors(2048, 1);
        let truth = person.anchor_truth(&anchors).unwrap();
        let kinds: Vec<GarmentKind> = person
            .wardrobe
            .garments
            .iter()
            .map(|g| room.library.garments[g.index].kind)
            .collect();
        // Chest anchors (front, 1.15–1.3 m on the rest template) show the outermost upper
        // garment; hand anchors the skin.
        let h = person.template.height() / room.template.height();
        for i in 0..anchors.len() {
            let p = anchors.positions[i] / Vec3::new(1.0, h, 1.0);
            let id = truth.garment[i];
            let part = &person.template.part_names[anchors.part_labels[i] as usize];
            if part.starts_with("hand") {
                assert_eq!(id, 0, "seed {seed}: a hand anchor under garment {id}");
            }
            if p.y > 1.15 && p.y < 1.3 && p.x.abs() < 0.08 && anchors.normals[i].z > 0.7 {
                let kind = room.library.garments[id as usize - 1].kind;
                assert!(
                    matches!(
                        kind,
                        GarmentKind::Top
                            | GarmentKind::OnePiece
                            | GarmentKind::Coat
                            | GarmentKind::Hair
                    ),
                    "seed {seed}: chest anchor under {kind:?} ({kinds:?})"
                );
                if kinds.contains(&GarmentKind::Coat) {
                    assert_eq!(kind, GarmentKind::Coat, "the coat is outermost");
                }
                checked += 1;
            }
        }
        // The truth agrees with the Gaussians on that surface: the nearest Gaussian to each
        // anchor's surface point lies on the same garment and mostly has its albedo.
        let albedo = person.albedo();
        let grid = lhmpp::body::PointGrid::for_surface(&person.avatar.canonical.positions);
        let (mut same, mut close, mut n) = (0, 0, 0);
        for i in 0..anchors.len() {
            let g = grid.nearest(truth.surface[i]).unwrap();
            if person.avatar.canonical.positions[g].distance(truth.surface[i]) > 0.01 {
                continue; // surface hidden under another garment's poke-through
            }
            n += 1;
            same += (person.garment_ids[g] == truth.garment[i]) as usize;
            close += ((albedo[g] - truth.albedo[i]).abs().max_element() < 0.1) as usize;
        }
        assert!(n > 1500, "seed {seed}: {n}");
        assert!(
            same as f32 > 0.93 * n as f32,
            "seed {seed}: {same} of {n} on the same garment"
        );
        assert!(
            close as f32 > 0.85 * n as f32,
            "seed {seed}: {close} of {n} with the albedo"
        );
    }
    assert!(checked > 20, "{checked} chest anchors");
}

fn options() -> DatasetOptions {
    DatasetOptions {
        points: 1024,
        person_points: 12_000,
        max_views: 3,
        realism: Realism::Dressed,
        ..DatasetOptions::default()
    }
}

#[test]
fn dressed_samples_repeat_per_seed_and_carry_their_ground_truth() {
    let o = options();
    let seed = TRAIN_SEED_START + 41;
    let a = make_sample(seed, &o).unwrap();
    let b = make_sample(seed, &o).unwrap();
    assert_eq!(a.images, b.images);
    assert_eq!(a.colors, b.colors);
    assert_eq!(a.target_rgb, b.target_rgb);
    assert_eq!(a.anchor_garment, b.anchor_garment);
    let garment = a.anchor_garment.as_ref().unwrap();
    let surface = a.anchor_surface.as_ref().unwrap();
    assert_eq!(garment.len(), 1024);
    assert_eq!(surface.len(), 1024 * 3);
    assert!(garment.iter().filter(|g| **g > 0).count() > 600);
    // The surface lies on or outside its anchor, within the cover range.
    for i in 0..1024 {
        let d = Vec3::from_slice(&surface[3 * i..3 * i + 3])
            .distance(Vec3::from_slice(&a.anchors[3 * i..3 * i + 3]));
        assert!(d < 0.31, "anchor {i}: {d}");
    }
    let c = make_sample(seed + 1, &o).unwrap();
    assert_ne!(a.colors, c.colors);
    // A plain dataset's samples stay plain.
    let plain = make_sample(
        seed,
        &DatasetOptions {
            realism: Realism::Plain,
            ..o
        },
    )
    .unwrap();
    assert!(plain.anchor_garment.is_none());
}

#[test]
fn lighting_changes_the_shading_not_the_albedo() {
    let person = DressedPerson::new(31, 30_000).unwrap();
    let camera = front_camera(&person);
    let posed = posed(&person);
    let white = RenderOptions {
        background: Vec3::ONE,
        render_features: true,
        background_features: vec![1.0; 3],
        ..RenderOptions::default()
    };
    let eye = Vec3::from(camera.world_from_camera.translation);
    let unlit = render(&posed, &camera, &white);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    for _ in 0..3 {
        let lighting = Lighting::random(&mut rng);
        let lit = render(
            &lighting.lit(&person, &posed, eye, None, true),
            &camera,
            &white,
        );
        // The albedo carried through the lit render is the unlit render.
        let worst = lit
            .features
            .iter()
            .zip(&unlit.rgb)
            .map(|(a, b)| (a - b).abs())
            .fold(0f32, f32::max);
        assert!(worst < 1e-4, "albedo differs by {worst}");
        // The lit colour is the albedo times a shading that is nearly grey per pixel (the
        // light colours are near white): the three channel ratios agree within the tint.
        let (mut n, mut spread, mut changed) = (0usize, 0f32, 0usize);
        for i in 0..unlit.alpha.len() {
            let a = Vec3::from_slice(&unlit.rgb[3 * i..3 * i + 3]);
            let l = Vec3::from_slice(&lit.rgb[3 * i..3 * i + 3]);
            if unlit.alpha[i] > 0.99 && a.min_element() > 0.15 {
                let ratio = l / a;
                spread +=
                    (ratio.max_element() - ratio.min_element()) / ratio.max_element().max(1e-3);
                changed += ((l - a).abs().max_element() > 0.02) as usize;
                n += 1;
            }
        }
        assert!(n > 1000);
        assert!(
            changed > n / 2,
            "lighting changed only {changed} of {n} pixels"
        );
        assert!(
            spread / (n as f32) < 0.45,
            "mean ratio spread {}",
            spread / n as f32
        );
    }
    // Flat lighting is the albedo.
    let flat = render(
        &Lighting::flat().lit(&person, &posed, eye, None, false),
        &camera,
        &white,
    );
    let worst = flat
        .rgb
        .iter()
        .zip(&unlit.rgb)
        .map(|(a, b)| (a - b).abs())
        .fold(0f32, f32::max);
    assert!(worst < 1e-5, "{worst}");
}

#[test]
fn a_dressed_bag_has_lit_inputs_and_unlit_heldout_views() {
    use lhmpp::bag::BagReader;
    use lhmpp::msgs::Image;
    use lhmpp::synth::capture::render_dressed_views;
    use lhmpp::synth::{write_bag, Rig, SynthOptions};
    let dir = tempfile::tempdir().unwrap();
    let options = SynthOptions {
        seed: 8,
        views: 2,
        heldout: 2,
        size: 96,
        points: 12_000,
        pose: lhmpp::synth::SynthPose::Rest,
        ..SynthOptions::default()
    };
    let path = dir.path().join("d.mcap");
    write_bag(&path, &options, Realism::Dressed).unwrap();
    let bag = BagReader::open(&path).unwrap();
    let image = |topic: &str| -> Vec<u8> {
        let m = bag.messages().iter().find(|m| &*m.topic == topic).unwrap();
        bag.decode::<Image>(m).unwrap().data
    };
    let person = DressedPerson::new(8, 12_000).unwrap();
    let rig = Rig::ring(8, 2, 2, 96, person.template.height());
    let unlit_in = render_dressed_views(&person, &Pose::identity(), &rig.inputs, false, 8).unwrap();
    let unlit_out =
        render_dressed_views(&person, &Pose::identity(), &rig.heldout, false, 8).unwrap();
    for (k, view) in unlit_out.iter().enumerate() {
        assert_eq!(
            image(&format!("/heldout{k}/image_raw")),
            view.output.to_rgb8().into_raw(),
            "held-out view {k} is the albedo"
        );
    }
    for (k, view) in unlit_in.iter().enumerate() {
        let lit = image(&format!("/cam{k}/image_raw"));
        let unlit = view.output.to_rgb8().into_raw();
        let differ = lit
            .iter()
            .zip(&unlit)
            .filter(|(a, b)| a.abs_diff(**b) > 8)
            .count();
        assert!(
            differ > 300,
            "input view {k}: only {differ} bytes lit differently"
        );
    }
}
