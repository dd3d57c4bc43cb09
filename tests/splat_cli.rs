//! `lhmpp render` end to end: avatar PLY in, PNG frames out.

use glam::{Quat, Vec3};
use lhmpp::avatar::Avatar;
use lhmpp::body::BodyTemplate;
use lhmpp::splat::{write_ply, Gaussians};
use std::process::Command;

/// 8,000 red discs on the template surface, with their skinning weights.
fn template_avatar() -> Avatar {
    let template = BodyTemplate::load_default().unwrap();
    let a = template.sample_anchors(8000, 1);
    let n = a.len();
    let g = Gaussians::from_rgb(
        a.positions.clone(),
        vec![Vec3::new(0.015, 0.015, 0.003); n],
        a.normals
            .iter()
            .map(|v| Quat::from_rotation_arc(Vec3::Z, v.normalize()))
            .collect(),
        vec![1.0; n],
        &vec![Vec3::X; n],
    )
    .unwrap();
    Avatar::new(g, a.skin, "makehuman-cc0").unwrap()
}

fn red_pixels(path: &std::path::Path) -> usize {
    let img = image::open(path).unwrap().to_rgb8();
    img.pixels()
        .filter(|p| p[0] > 200 && p[1] < 60 && p[2] < 60)
        .count()
}

#[test]
fn render_writes_one_png_per_pose_and_view_showing_the_avatar() {
    let dir = tempfile::tempdir().unwrap();
    let with_skin = dir.path().join("skinned.ply");
    let avatar = template_avatar();
    avatar.save_ply(&with_skin).unwrap();
    let without_skin = dir.path().join("plain.ply");
    write_ply(&without_skin, &avatar.canonical, None, None).unwrap();

    for (name, ply) in [("a", &with_skin), ("b", &without_skin)] {
        let out = dir.path().join(name);
        let status = Command::new(env!("CARGO_BIN_EXE_lhmpp"))
            .args([
                "render",
                ply.to_str().unwrap(),
                "--pose",
                "walk:3..5",
                "--camera",
                "orbit:2",
                "--size",
                "96",
                "-o",
            ])
            .arg(&out)
            .status()
            .unwrap();
        assert!(status.success());
        let mut files: Vec<_> = std::fs::read_dir(&out)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        files.sort();
        assert_eq!(
            files,
            [
                "f0000_v00.png",
                "f0000_v01.png",
                "f0001_v00.png",
                "f0001_v01.png"
            ]
        );
        for f in &files {
            let red = red_pixels(&out.join(f));
            assert!(
                red > 300,
                "{name}/{f}: the avatar should cover part of the frame, {red} red pixels"
            );
        }
    }
    // Both skin sources pose the avatar alike (nearest-vertex vs barycentric weights).
    let (a, b) = (
        red_pixels(&dir.path().join("a/f0001_v00.png")),
        red_pixels(&dir.path().join("b/f0001_v00.png")),
    );
    assert!((a as f32 - b as f32).abs() < 0.1 * a as f32, "{a} vs {b}");
}

#[test]
fn render_names_a_missing_avatar_file() {
    let out = Command::new(env!("CARGO_BIN_EXE_lhmpp"))
        .args(["render", "/nonexistent/avatar.ply", "-o", "/tmp/never"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent/avatar.ply"));
}
