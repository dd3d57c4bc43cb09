//! The compact avatar (Gaussians as SPZ quantises them + skin, `lhmpp_msgs/CompactAvatar`) of an avatar made by the
//! embedded network: decoded and rendered by the CPU rasteriser, at rest and in two walk poses
//! from four cameras, it stays at least 40 dB PSNR of the full avatar's renders, and its
//! message is at least 8× smaller than the `GaussianAvatar` of the same revision.

use lhmpp::avatar::Avatar;
use lhmpp::body::{motion::walk_pose, BodyTemplate, Pose};
use lhmpp::compact::fidelity::{orbit_cameras, round_trip_psnr};
use lhmpp::compact::{CompactAvatar, CompactOptions};
use lhmpp::config::ModelConfig;
use lhmpp::msgs::{self, RosMessage};
use lhmpp::node::outputs::{avatar_message, compact_message, AvatarUpdate};
use lhmpp::reconstruct::photos::preprocess_config;
use lhmpp::reconstruct::preprocess::{preprocess, Subject};
use lhmpp::reconstruct::Reconstructor;

/// An avatar of the embedded trained network from one patterned full-frame view.
fn network_avatar() -> (Avatar, BodyTemplate) {
    let mut recon = Reconstructor::new(&ModelConfig::default(), 8).unwrap();
    let image = image::RgbImage::from_fn(96, 160, |x, y| {
        let band = (y / 20) as u8;
        image::Rgb([40 + 25 * band, 200 - 20 * band, ((x * 3) % 255) as u8])
    });
    let view = preprocess(&image, Subject::FullFrame, &preprocess_config(&recon)).unwrap();
    let avatar = recon.reconstruct(&[(1, &view)]).unwrap();
    (avatar, BodyTemplate::load_default().unwrap())
}

fn update<'a>(avatar: &'a Avatar, template: &'a BodyTemplate) -> AvatarUpdate<'a> {
    AvatarUpdate {
        person: "person_0",
        revision: 3,
        views_used: 1,
        stamp_ns: 1_700_000_000_123_456_789,
        avatar,
        template,
        shape_params: &[1.0, 0.9],
        rgb_display_ready: true,
        neural_renderer: "",
        compact: Default::default(),
    }
}

#[test]
fn the_compact_avatar_renders_within_40_db_of_the_full_one_at_an_eighth_of_the_size() {
    let (avatar, template) = network_avatar();
    let compact = CompactAvatar::encode(&avatar).unwrap();
    let decoded = compact.decode(&avatar.body_model).unwrap();
    assert_eq!(decoded.canonical.len(), avatar.canonical.len());
    assert_eq!(decoded.body_model, avatar.body_model);
    let poses: Vec<Pose> = vec![Pose::identity(), walk_pose(8.0), walk_pose(20.0)];
    let cameras = orbit_cameras(&avatar, 4, 256);
    let scores = round_trip_psnr(&avatar, &decoded, &template.skeleton, &poses, &cameras).unwrap();
    eprintln!("round-trip PSNR per pose × camera (dB): {scores:.2?}");
    assert_eq!(scores.len(), 12);
    for (i, s) in scores.iter().enumerate() {
        assert!(*s >= 40.0, "pose {} camera {}: {s:.2} dB", i / 4, i % 4);
    }

    let u = update(&avatar, &template);
    let full = avatar_message(&u).unwrap().encode_cdr();
    let small = compact_message(&u).unwrap();
    let bytes = small.encode_cdr();
    eprintln!(
        "{} Gaussians: GaussianAvatar {} B, CompactAvatar {} B ({:.2}×; Gaussians {} B, skin {} B)",
        avatar.canonical.len(),
        full.len(),
        bytes.len(),
        full.len() as f64 / bytes.len() as f64,
        small.gaussians.len(),
        small.skin.len()
    );
    assert!(
        bytes.len() * 8 <= full.len(),
        "CompactAvatar {} B is not 8× under GaussianAvatar {} B",
        bytes.len(),
        full.len()
    );
}

#[test]
fn the_message_carries_what_the_gaussian_avatar_does_and_survives_cdr() {
    let (avatar, template) = network_avatar();
    let u = update(&avatar, &template);
    let full = avatar_message(&u).unwrap();
    let small = compact_message(&u).unwrap();
    assert_eq!(small.header, full.header);
    assert_eq!(small.person_id, full.person_id);
    assert_eq!(small.revision, full.revision);
    assert_eq!(small.views_used, full.views_used);
    assert_eq!(small.body_model, full.body_model);
    assert_eq!(small.shape_params, full.shape_params);
    assert_eq!(small.bone_names, full.bone_names);
    assert_eq!(small.bone_parents, full.bone_parents);
    let rest: Vec<f32> = full
        .bone_rest_positions
        .iter()
        .flat_map(|p| [p.x as f32, p.y as f32, p.z as f32])
        .collect();
    assert_eq!(small.bone_rest_positions, rest);
    assert_eq!(small.rgb_display_ready, full.rgb_display_ready);
    let back = msgs::CompactAvatar::decode_cdr(&small.encode_cdr()).unwrap();
    assert_eq!(back, small);
    // The blobs decode to the avatar's Gaussians, in another (spatial) order: same count, same
    // set of positions to within the position step.
    let unit = (1u32 << CompactOptions::default().fractional_bits) as f32;
    let blobs = CompactAvatar {
        gaussians: back.gaussians,
        skin: back.skin,
    };
    let decoded = blobs.decode(&back.body_model).unwrap();
    let mut a: Vec<[i32; 3]> = avatar
        .canonical
        .positions
        .iter()
        .map(|p| (*p * unit).round().as_ivec3().to_array())
        .collect();
    let mut b: Vec<[i32; 3]> = decoded
        .canonical
        .positions
        .iter()
        .map(|p| (*p * unit).round().as_ivec3().to_array())
        .collect();
    a.sort();
    b.sort();
    assert!(a == b, "the decoded positions are not the avatar's");
    // A damaged skin blob is refused with a reason, not decoded into garbage.
    let mut broken = blobs.clone();
    broken.skin.truncate(broken.skin.len() / 2);
    let e = broken.decode("makehuman-cc0").unwrap_err().to_string();
    assert!(e.contains("skin"), "{e}");
}
