//! The real-photo colour score (`lhmpp::eval::photos`, `lhmpp eval-photos`) on synthetic
//! people, whose clothing colours are known: a front render of a seeded person stands in for
//! the photo, perception reads its landmarks, and the regions must find the shirt on the
//! torso and the trousers on the thighs; the same image scores ΔE00 = 0; a known colour shift
//! scores its CIEDE2000; and planted failures score large: shirt and trouser colours
//! swapped, and an avatar that renders nothing (scored against the white background). The
//! command runs end to end on a folder of renders and on a two-view manifest, and each
//! person's avatar comes from their own photos only. Colours taken from the photos carry over
//! to a view the avatar never saw, and a bun painted above the skull reaches the crown.

use glam::Vec3;
use lhmpp::body::Pose;
use lhmpp::config::ModelConfig;
use lhmpp::eval::photos::colour::{ciede2000, Srgb8};
use lhmpp::eval::photos::regions::{seen_parts, Region, RegionConfig};
use lhmpp::eval::photos::{
    photo_regions, region_colours, render_mask, score_view, RegionStatus, ViewPicture,
};
use lhmpp::perception::{Landmark, LandmarkModel, PoseNetworks, BODY_LANDMARKS};
use lhmpp::reconstruct::photos::{
    perceive_person, preprocess_config, reconstruct_photos, MaskSource, PersonHint, PhotoView,
};
use lhmpp::reconstruct::preprocess::{preprocess, PreprocessConfig, Subject};
use lhmpp::reconstruct::Reconstructor;
use lhmpp::splat::{Camera, Intrinsics};
use lhmpp::synth::capture::render_views;
use lhmpp::synth::outfit::Outfit;
use lhmpp::synth::{RigCamera, SyntheticPerson};
use std::sync::{Arc, OnceLock};

const SIZE: u32 = 384;

fn networks() -> Arc<PoseNetworks> {
    static NETS: OnceLock<Arc<PoseNetworks>> = OnceLock::new();
    NETS.get_or_init(|| Arc::new(PoseNetworks::load(LandmarkModel::Full, None).unwrap()))
        .clone()
}

fn rgb8(c: [f32; 3]) -> Srgb8 {
    c.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
}

/// The first seed whose outfit has a plain long-sleeved shirt far (ΔE00 > 30) from the
/// trousers: the torso and upper arms wear the shirt, the thighs and shins the trousers.
fn plain_seed() -> u64 {
    (1..200)
        .find(|&s| {
            let o = Outfit::random(s);
            o.stripes.is_none()
                && !o.short_sleeves
                && ciede2000(rgb8(o.shirt), rgb8(o.trousers)) > 30.0
        })
        .expect("a plain outfit among 200 seeds")
}

/// A front view of a synthetic person: the image, its true mask and the person.
struct Photo {
    person: SyntheticPerson,
    image: image::RgbImage,
    mask: image::GrayImage,
}

fn camera(person: &SyntheticPerson, angle: f32) -> RigCamera {
    let h = person.template.height();
    let target = Vec3::new(0.0, 0.5 * h, 0.0);
    let distance = 0.62 * h / (0.5f32 * 0.75).tan();
    let eye = target + Vec3::new(angle.sin(), 0.1, angle.cos()) * distance;
    RigCamera {
        name: "front".into(),
        camera: Camera::look_at(
            eye,
            target,
            Vec3::Y,
            Intrinsics::from_fov_y(SIZE, SIZE, 0.75),
        ),
    }
}

fn photo(angle: f32) -> Photo {
    let person = SyntheticPerson::new(plain_seed(), 20_000).unwrap();
    let cams = [camera(&person, angle)];
    let views = render_views(&person, &Pose::identity(), &cams).unwrap();
    let out = &views[0].output;
    Photo {
        image: out.to_rgb8(),
        mask: render_mask(out),
        person,
    }
}

fn front() -> &'static Photo {
    static FRONT: OnceLock<Photo> = OnceLock::new();
    FRONT.get_or_init(|| photo(0.0))
}

fn landmarks(image: &image::RgbImage) -> [Landmark; BODY_LANDMARKS] {
    perceive_person(&networks(), image, &PersonHint::Best)
        .unwrap()
        .expect("perception finds the synthetic person")
        .landmarks
        .image
}

fn delta(v: &ViewPicture, region: Region) -> f64 {
    let r = v.regions[region.index()];
    assert_eq!(r.status, RegionStatus::Scored, "{region:?}: {r:?}");
    r.delta_e.unwrap()
}

#[test]
fn regions_find_the_colours_the_person_wears() {
    let p = front();
    let config = RegionConfig::default();
    let l = landmarks(&p.image);
    let sides = seen_parts(&l, &config);
    for region in [Region::Torso, Region::Head] {
        assert!(sides[region.index()][0], "{region:?} not seen: {sides:?}");
    }
    for region in [Region::UpperArms, Region::Thighs, Region::Shins] {
        assert_eq!(sides[region.index()], [true, true], "{region:?}");
    }
    let map = photo_regions(&l, &p.mask, &config);
    let colours = region_colours(&p.image, &map);
    let outfit = &p.person.outfit;
    for (region, wears) in [
        (Region::Torso, outfit.shirt),
        (Region::UpperArms, outfit.shirt),
        (Region::Thighs, outfit.trousers),
        (Region::Shins, outfit.trousers),
    ] {
        let c = colours[region.index()].expect("pixels in the region");
        assert!(c.pixels >= config.min_pixels, "{region:?}: {c:?}");
        let e = ciede2000(c.rgb, rgb8(wears));
        assert!(
            e < 3.0,
            "{region:?}: median {:?} vs worn {:?}: ΔE00 {e:.2}",
            c.rgb,
            rgb8(wears)
        );
    }
}

#[test]
fn the_same_image_scores_zero_and_a_known_shift_its_ciede2000() {
    let p = front();
    let config = RegionConfig::default();
    let l = landmarks(&p.image);
    let same = score_view(&p.image, &p.mask, Some(&l), &p.image, &p.mask, &l, &config);
    let scored: Vec<f64> = same.regions.iter().filter_map(|r| r.delta_e).collect();
    assert!(scored.len() >= 5, "{:?}", same.regions);
    assert!(scored.iter().all(|e| *e == 0.0), "{scored:?}");

    // Every person pixel shifted by a fixed offset: each region's median moves by the same
    // offset (clamping is monotone, so medians commute with it).
    let offset = [24i16, -16, 8];
    let shift = |c: Srgb8| -> Srgb8 {
        std::array::from_fn(|k| (i16::from(c[k]) + offset[k]).clamp(0, 255) as u8)
    };
    let mut shifted = p.image.clone();
    for (px, m) in shifted.pixels_mut().zip(p.mask.pixels()) {
        if m.0[0] >= 128 {
            px.0 = shift(px.0);
        }
    }
    let v = score_view(&p.image, &p.mask, Some(&l), &shifted, &p.mask, &l, &config);
    for r in &v.regions {
        if let (Some(photo), Some(e)) = (r.photo, r.delta_e) {
            let want = ciede2000(photo.rgb, shift(photo.rgb));
            assert!((e - want).abs() < 1e-9, "{:?}: {e} vs {want}", r.region);
            assert!(e > 1.0, "{:?}: a visible shift scores {e}", r.region);
        }
    }
    let shirt = rgb8(p.person.outfit.shirt);
    let want = ciede2000(shirt, shift(shirt));
    let torso = delta(&v, Region::Torso);
    assert!((torso - want).abs() < 1.5, "torso {torso:.2} vs {want:.2}");
}

#[test]
fn swapped_garment_colours_score_large() {
    let p = front();
    let config = RegionConfig::default();
    let l = landmarks(&p.image);
    let outfit = &p.person.outfit;
    let (shirt, trousers) = (rgb8(outfit.shirt), rgb8(outfit.trousers));
    let near = |a: Srgb8, b: Srgb8| a.iter().zip(b).all(|(x, y)| x.abs_diff(y) <= 12);
    let mut swapped = p.image.clone();
    for px in swapped.pixels_mut() {
        if near(px.0, shirt) {
            px.0 = trousers;
        } else if near(px.0, trousers) {
            px.0 = shirt;
        }
    }
    // The render's landmarks from perception on the render itself, as eval-photos does.
    let lr = landmarks(&swapped);
    let v = score_view(&p.image, &p.mask, Some(&l), &swapped, &p.mask, &lr, &config);
    let expected = ciede2000(shirt, trousers);
    for region in [
        Region::Torso,
        Region::UpperArms,
        Region::Thighs,
        Region::Shins,
    ] {
        let e = delta(&v, region);
        assert!(
            e > 0.8 * expected && e > 25.0,
            "{region:?}: ΔE00 {e:.1}, the garments differ by {expected:.1}"
        );
    }
    // Head and feet kept their colours.
    assert!(delta(&v, Region::Head) < 3.0);
    let same = score_view(&p.image, &p.mask, Some(&l), &p.image, &p.mask, &lr, &config);
    assert!(delta(&same, Region::Torso) < 3.0);
}

#[test]
fn eval_photos_scores_a_folder_and_a_two_view_manifest() {
    let dir = tempfile::tempdir().unwrap();
    let p = front();
    let side = photo(0.6);
    p.image.save(dir.path().join("front.png")).unwrap();
    p.mask.save(dir.path().join("front_mask.png")).unwrap();
    side.image.save(dir.path().join("side.png")).unwrap();
    let json = dir.path().join("scores.json");
    let sheet = dir.path().join("sheet.png");
    let run = |args: &[&std::ffi::OsStr]| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_lhmpp"))
            .arg("eval-photos")
            .args(args)
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
        assert!(
            out.status.success(),
            "{stdout}\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        stdout
    };
    let stdout = run(&[
        dir.path().as_os_str(),
        "--json".as_ref(),
        json.as_os_str(),
        "--picture".as_ref(),
        sheet.as_os_str(),
        "--render-size".as_ref(),
        "384".as_ref(),
    ]);
    for needle in [
        "### front (1 photo)",
        "| front (given mask) | torso |",
        "| side | thighs |",
        "**overall**",
        "weights: embedded default",
    ] {
        assert!(stdout.contains(needle), "no `{needle}` in\n{stdout}");
    }
    let value: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let people = value["people"].as_array().unwrap();
    assert_eq!(people.len(), 2);
    let torso = &people[0]["views"][0]["regions"][0];
    assert_eq!(torso["region"], "torso");
    assert_eq!(torso["status"], "scored");
    assert!(torso["photo"]["hex"].as_str().unwrap().starts_with('#'));
    let e = torso["delta_e00"].as_f64().unwrap();
    assert!(e.is_finite() && e >= 0.0, "{e}");
    let mean = value["overall_mean_delta_e00"].as_f64().unwrap();
    assert!(mean > 0.0 && mean < 100.0, "{mean}");
    let picture = image::open(&sheet).unwrap();
    assert_eq!(picture.height(), 2 * (300 + 6) + 6, "two rows");

    // The two renders as two views of one person, through a manifest.
    let manifest = dir.path().join("people.json");
    std::fs::write(
        &manifest,
        r#"{"people": [{"name": "synthetic", "views": [
            {"photo": "front.png", "mask": "front_mask.png"},
            {"photo": "side.png", "person": "largest"}]}]}"#,
    )
    .unwrap();
    let stdout = run(&["--manifest".as_ref(), manifest.as_os_str()]);
    assert!(stdout.contains("### synthetic (2 photos)"), "{stdout}");
    assert!(stdout.contains("| side | torso |"), "{stdout}");
}

/// A photo view of `p` as `photo_view` makes it from a file with a given mask.
fn photo_view_of(p: &Photo, prep: &PreprocessConfig) -> PhotoView {
    PhotoView {
        stem: "synthetic".into(),
        image: p.image.clone(),
        mask: p.mask.clone(),
        mask_source: MaskSource::Given,
        perceived: None,
        pose: None,
        view: preprocess(&p.image, Subject::Mask(&p.mask), prep).unwrap(),
    }
}

#[test]
fn each_person_is_reconstructed_from_their_own_photos() {
    // Person after person through one Reconstructor, each numbering views from 0: the second
    // avatar must be the one a fresh Reconstructor makes, not the first person's cached views.
    let model = ModelConfig::default();
    let mut shared = Reconstructor::new(&model, 2).unwrap();
    let prep = preprocess_config(&shared);
    let first = [photo_view_of(front(), &prep)];
    let other = Photo {
        person: front().person.clone(),
        image: {
            let mut image = front().image.clone();
            for px in image.pixels_mut() {
                px.0 = [px.0[2], px.0[0], px.0[1]];
            }
            image
        },
        mask: front().mask.clone(),
    };
    let second = [photo_view_of(&other, &prep)];
    let a = reconstruct_photos(&mut shared, &first).unwrap();
    let b = reconstruct_photos(&mut shared, &second).unwrap();
    let fresh = reconstruct_photos(&mut Reconstructor::new(&model, 2).unwrap(), &second).unwrap();
    assert!(
        a.canonical.sh != b.canonical.sh,
        "the second person got the first's views"
    );
    assert!(
        b.canonical.sh == fresh.canonical.sh,
        "the second avatar differs from a fresh Reconstructor's"
    );
}

#[test]
fn a_missing_avatar_scores_against_the_background() {
    // Nothing rendered: every region the photo shows is uncovered and scored against the
    // white background, so a model that renders nothing cannot escape the mean.
    let p = front();
    let config = RegionConfig::default();
    let l = landmarks(&p.image);
    let white = image::RgbImage::from_pixel(SIZE, SIZE, image::Rgb([255, 255, 255]));
    let nothing = image::GrayImage::new(SIZE, SIZE);
    let v = score_view(&p.image, &p.mask, Some(&l), &white, &nothing, &l, &config);
    let mut uncovered = 0;
    for r in &v.regions {
        if r.status == RegionStatus::NotShown {
            continue;
        }
        assert_eq!(r.status, RegionStatus::Uncovered, "{r:?}");
        let photo = r.photo.unwrap().rgb;
        assert_eq!(r.render.unwrap().rgb, [255, 255, 255]);
        assert_eq!(r.delta_e, Some(ciede2000(photo, [255, 255, 255])));
        uncovered += 1;
    }
    assert!(uncovered >= 5, "{:?}", v.regions);
    assert!(delta_any(&v, Region::Thighs) > 25.0);
}

fn delta_any(v: &ViewPicture, region: Region) -> f64 {
    v.regions[region.index()].delta_e.unwrap()
}

/// A photo with the colour channels rotated (skin blue, and so on): far from the synthetic
/// people the default was trained on.
fn rotated(p: &Photo) -> image::RgbImage {
    let mut image = p.image.clone();
    for px in image.pixels_mut() {
        px.0 = [px.0[2], px.0[0], px.0[1]];
    }
    image
}

/// Mean ΔE00 over the regions scored in every view of `score`.
fn mean_delta(score: &lhmpp::eval::photos::PersonScore) -> f64 {
    let d: Vec<f64> = score
        .views
        .iter()
        .flat_map(|v| v.regions.iter().filter_map(|r| r.delta_e))
        .collect();
    assert!(d.len() >= 4, "{score:?}");
    d.iter().sum::<f64>() / d.len() as f64
}

#[test]
fn colours_from_the_photos_carry_over_to_a_held_out_view() {
    // The avatar is made from the front photo and scored on a side photo it never saw, both
    // in an unusual palette: taking the colours from the front photo must bring the side view
    // far closer than the network's own colours.
    use lhmpp::eval::photos::manifest::{ManifestPerson, ManifestView};
    use lhmpp::eval::photos::{score_person, EvalPhotosConfig};
    let dir = tempfile::tempdir().unwrap();
    let front_photo = front();
    let side_photo = photo(0.6);
    let (front_path, side_path) = (dir.path().join("front.png"), dir.path().join("side.png"));
    let mask_path = dir.path().join("front_mask.png");
    rotated(front_photo).save(&front_path).unwrap();
    front_photo.mask.save(&mask_path).unwrap();
    rotated(&side_photo).save(&side_path).unwrap();
    let person = ManifestPerson {
        name: "rotated".into(),
        note: String::new(),
        views: vec![
            ManifestView {
                photo: front_path,
                mask: Some(mask_path),
                person: None,
                heldout: false,
            },
            ManifestView {
                photo: side_path,
                mask: None,
                person: None,
                heldout: true,
            },
        ],
    };
    let mut recon = Reconstructor::new(&ModelConfig::default(), 2).unwrap();
    let mut score = |photo_colours| {
        let config = EvalPhotosConfig {
            photo_colours,
            ..EvalPhotosConfig::default()
        };
        let (score, _) = score_person(&mut recon, &networks(), &person, &config).unwrap();
        assert_eq!(score.views.len(), 1, "only the held-out view is scored");
        mean_delta(&score)
    };
    let network = score(None);
    let from_photos = score(EvalPhotosConfig::default().photo_colours);
    eprintln!("held-out ΔE00: network {network:.1}, from the photos {from_photos:.1}");
    assert!(
        from_photos < 12.0 && from_photos < 0.6 * network,
        "held-out ΔE00: colours from the photos {from_photos:.1}, network colours {network:.1}"
    );
}

#[test]
fn a_bun_above_the_skull_colours_the_crown() {
    // Hair and caps stand off the template's skull: a green bun painted on the photo above
    // the person's head (and added to the mask) must reach the avatar's crown, whose
    // Gaussians would otherwise sample the top of the skull where it projects.
    let p = front();
    let (mut image, mut mask) = (p.image.clone(), p.mask.clone());
    let top = (0..SIZE)
        .find(|&y| (0..SIZE).any(|x| mask.get_pixel(x, y).0[0] > 128))
        .expect("the mask has a person");
    let xs: Vec<u32> = (0..SIZE)
        .filter(|&x| mask.get_pixel(x, top + 6).0[0] > 128)
        .collect();
    let centre = (xs[0] + xs[xs.len() - 1]) as f32 / 2.0;
    let half_width = (xs[xs.len() - 1] - xs[0]) as f32 / 2.0 + 2.0;
    let bun = [40u8, 190, 70];
    let bun_height = 14.0;
    for y in top.saturating_sub(bun_height as u32)..top + 2 {
        for x in 0..SIZE {
            let (dx, dy) = (
                (x as f32 - centre) / half_width,
                (y as f32 - top as f32 - 2.0) / bun_height,
            );
            if dx * dx + dy * dy <= 1.0 {
                image.put_pixel(x, y, image::Rgb(bun));
                mask.put_pixel(x, y, image::Luma([255]));
            }
        }
    }
    let (_, avatar) = avatar_from_photo_file(&image, &mask);
    // The crown: the Gaussians within 2 cm of the avatar's top.
    let g = &avatar.canonical;
    let k = g.sh_per_gaussian();
    let top_y = g.positions.iter().map(|p| p.y).fold(f32::MIN, f32::max);
    let crown: Vec<Srgb8> = (0..g.len())
        .filter(|&i| g.positions[i].y > top_y - 0.02)
        .map(|i| {
            let c = lhmpp::splat::sh_dc_to_rgb(g.sh[i * k]);
            rgb8([c.x, c.y, c.z])
        })
        .collect();
    assert!(crown.len() >= 10, "{} crown Gaussians", crown.len());
    // Half the crown faces the front camera; the rest is hidden behind it and keeps the
    // network's colour.
    let green = crown.iter().filter(|c| ciede2000(**c, bun) < 10.0).count();
    assert!(
        green * 3 >= crown.len(),
        "{green} of {} crown Gaussians wear the bun: {crown:?}",
        crown.len()
    );
}

#[test]
fn a_monochrome_photo_gives_a_grey_avatar_all_round() {
    // A greyscale camera's photo of the front: the back the camera never saw must not come
    // out in the network's colours (a blue shirt on a grey person), nor the front tinted.
    use lhmpp::reconstruct::photo_colours::is_monochrome;
    let p = front();
    let grey = image::DynamicImage::ImageRgb8(p.image.clone()).to_luma8();
    let grey = image::DynamicImage::ImageLuma8(grey).to_rgb8();
    assert!(is_monochrome(&grey, &p.mask));
    assert!(
        !is_monochrome(&p.image, &p.mask),
        "the colour photo is not grey"
    );
    let (network, avatar) = avatar_from_photo_file(&grey, &p.mask);
    let before = {
        let g = &network.canonical;
        let k = g.sh_per_gaussian();
        (0..g.len())
            .map(|i| lhmpp::splat::sh_dc_to_rgb(g.sh[i * k]))
            .map(|c| c.max_element() - c.min_element())
            .fold(0.0f32, f32::max)
    };
    assert!(
        before > 0.05,
        "the network's avatar has colour to lose ({before})"
    );
    let g = &avatar.canonical;
    let k = g.sh_per_gaussian();
    for i in 0..g.len() {
        for c in &g.sh[i * k..(i + 1) * k] {
            assert!(
                (c[0] - c[1]).abs() < 1e-5 && (c[1] - c[2]).abs() < 1e-5,
                "Gaussian {i} at {:?} is tinted: {c:?}",
                g.positions[i]
            );
        }
    }
}

/// `lhmpp avatar`'s path for one photo and its mask (written to files and read back): the
/// network's avatar, and the same avatar recoloured from the photo.
fn avatar_from_photo_file(
    image: &image::RgbImage,
    mask: &image::GrayImage,
) -> (lhmpp::avatar::Avatar, lhmpp::avatar::Avatar) {
    use lhmpp::reconstruct::photo_colours::PhotoColourConfig;
    use lhmpp::reconstruct::photos::{colour_from_views, photo_view};
    let dir = tempfile::tempdir().unwrap();
    let (photo_path, mask_path) = (dir.path().join("photo.png"), dir.path().join("mask.png"));
    image.save(&photo_path).unwrap();
    mask.save(&mask_path).unwrap();
    let mut recon = Reconstructor::new(&ModelConfig::default(), 2).unwrap();
    let prep = preprocess_config(&recon);
    let template = recon.template().clone();
    let view = photo_view(
        &photo_path,
        Some(&mask_path),
        None,
        &networks(),
        &template,
        &prep,
    )
    .unwrap()
    .expect("perception reads the person");
    let views = [view];
    let network = reconstruct_photos(&mut recon, &views).unwrap();
    let mut avatar = network.clone();
    colour_from_views(
        &mut avatar,
        &template,
        &views,
        &PhotoColourConfig::default(),
    );
    (network, avatar)
}
