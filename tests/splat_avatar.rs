//! Avatar posing by linear blend skinning of Gaussians.

use glam::{Mat4, Quat, Vec3};
use lhmpp::avatar::{Avatar, AvatarError};
use lhmpp::body::SkinWeights;
use lhmpp::splat::synthetic::body_cloud;
use lhmpp::splat::{render, Camera, Intrinsics, RenderOptions};
use rand::{Rng, SeedableRng};

/// Random two-bone skin (of `bones` bones) for `n` Gaussians.
fn random_skin(n: usize, bones: u16, seed: u64) -> SkinWeights {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut s = SkinWeights::default();
    for _ in 0..n {
        let w: f32 = rng.gen_range(0.0..1.0);
        s.bones
            .push([rng.gen_range(0..bones), rng.gen_range(0..bones), 0, 0]);
        s.weights.push([w, 1.0 - w, 0.0, 0.0]);
    }
    s
}

#[test]
fn identity_skinning_leaves_gaussians_and_render_exactly_unchanged() {
    let g = body_cloud(5000, 2, 3);
    let avatar = Avatar::new(g.clone(), random_skin(5000, 20, 1), "test").unwrap();
    let posed = avatar.animate(&[Mat4::IDENTITY; 20]);
    assert!(posed.positions == g.positions, "positions moved");
    assert!(posed.rotations == g.rotations, "rotations changed");
    assert!(posed == g, "other attributes changed");
    let cam = Camera::orbit(
        0,
        4,
        2.5,
        0.0,
        Vec3::new(0.0, 0.9, 0.0),
        Intrinsics::from_fov_y(64, 96, 0.9),
    );
    let (a, b) = (
        render(&posed, &cam, &RenderOptions::default()),
        render(&g, &cam, &RenderOptions::default()),
    );
    assert!(a.alpha.iter().any(|v| *v > 0.5), "the body is in view");
    assert!(a == b, "rendered image changed");
}

#[test]
fn rotated_bone_rotates_orientation_as_well_as_position() {
    let g = lhmpp::splat::Gaussians::from_rgb(
        vec![Vec3::new(1.0, 0.0, 0.0)],
        vec![Vec3::new(0.3, 0.1, 0.05)],
        vec![Quat::from_rotation_x(0.4)],
        vec![1.0],
        &[Vec3::ONE],
    )
    .unwrap();
    let skin = SkinWeights {
        bones: vec![[1, 0, 0, 0]],
        weights: vec![[1.0, 0.0, 0.0, 0.0]],
    };
    let avatar = Avatar::new(g.clone(), skin, "test").unwrap();
    // Bone 1 turns 90° about +Y around the pivot (0, 0, 0) and lifts by 0.5.
    let turn = Quat::from_rotation_y(std::f32::consts::FRAC_PI_2);
    let m = Mat4::from_rotation_translation(turn, Vec3::new(0.0, 0.5, 0.0));
    let posed = avatar.animate(&[Mat4::IDENTITY, m]);
    assert!(
        (posed.positions[0] - Vec3::new(0.0, 0.5, -1.0)).length() < 1e-6,
        "{}",
        posed.positions[0]
    );
    let expected = turn * g.rotations[0];
    assert!(
        posed.rotations[0].dot(expected).abs() > 1.0 - 1e-6,
        "{} vs {expected}",
        posed.rotations[0]
    );
    assert_eq!(posed.scales, g.scales, "scales unchanged");
    // The long axis (local X, scale 0.3) now points along world -Z.
    let long_axis = posed.rotations[0] * Vec3::X;
    assert!(
        (long_axis - Vec3::new(0.0, 0.0, -1.0)).length() < 1e-5,
        "{long_axis}"
    );
}

#[test]
fn blended_bones_move_a_gaussian_to_the_weighted_mean_of_its_bone_positions() {
    let g = body_cloud(1, 0, 9);
    let skin = SkinWeights {
        bones: vec![[0, 1, 0, 0]],
        weights: vec![[0.25, 0.75, 0.0, 0.0]],
    };
    let avatar = Avatar::new(g.clone(), skin, "test").unwrap();
    let a = Mat4::from_translation(Vec3::X);
    let b = Mat4::from_translation(Vec3::Y);
    let posed = avatar.animate(&[a, b]);
    let expected = g.positions[0] + Vec3::new(0.25, 0.75, 0.0);
    assert!((posed.positions[0] - expected).length() < 1e-6);
    assert_eq!(
        posed.rotations[0], g.rotations[0],
        "pure translations keep orientation"
    );
}

#[test]
fn too_few_matrices_and_bad_skins_are_reported() {
    let g = body_cloud(10, 0, 2);
    let avatar = Avatar::new(g.clone(), random_skin(10, 5, 4), "test").unwrap();
    assert!(matches!(
        avatar.check_matrices(&[Mat4::IDENTITY; 2]),
        Err(AvatarError::MissingBone { .. })
    ));
    let err = Avatar::new(g.clone(), random_skin(9, 5, 4), "test").unwrap_err();
    assert_eq!(
        err,
        AvatarError::SkinRows {
            skin: 9,
            gaussians: 10
        }
    );
    let mut skin = random_skin(10, 5, 4);
    skin.weights[3] = [0.0; 4];
    assert!(matches!(
        Avatar::new(g, skin, "test"),
        Err(AvatarError::BadWeights { row: 3, .. })
    ));
}
