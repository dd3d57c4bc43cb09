//! The MakeHuman converter on a tiny synthetic source folder written by the test.

use glam::{Mat3, Vec3};
use lhmpp::body::convert::{convert_makehuman, write_assets};
use lhmpp::body::motion::KeyframeClip;
use lhmpp::body::BodyTemplate;
use std::path::Path;

/// A 2 × 10 × 2 dm box (group `body`, decimetres, +Y up) and a small helper cube centred at
/// (0, 4, 0) dm; a two-bone rig; weights; a 2×2 segmentation image; a walk and a T-pose.
fn write_source(dir: &Path) {
    let mut obj = String::from("# synthetic\n");
    for i in 0..8 {
        let (x, y, z) = (
            if i & 1 == 0 { -1.0 } else { 1.0 },
            if i & 2 == 0 { 0.0 } else { 10.0 },
            if i & 4 == 0 { -1.0 } else { 1.0 },
        );
        obj += &format!("v {x} {y} {z}\n");
    }
    for i in 0..8 {
        let (x, y, z) = (
            (i & 1) as f32 * 0.2 - 0.1,
            4.0 + (i & 2) as f32 * 0.1 - 0.1,
            (i & 4) as f32 * 0.05 - 0.1,
        );
        obj += &format!("v {x} {y} {z}\n");
    }
    obj += "vt 0.25 0.75\nvt 0.75 0.25\n";
    obj += "g body\n";
    // Bottom vertices (y = 0) use vt 2 (lower-right pixel), top ones vt 1 (upper-left).
    let quads = [
        [1, 3, 4, 2],
        [5, 6, 8, 7],
        [1, 2, 6, 5],
        [3, 7, 8, 4],
        [1, 5, 7, 3],
        [2, 4, 8, 6],
    ];
    for q in quads {
        let corner = |v: usize| format!("{v}/{}", if (v - 1) & 2 == 0 { 2 } else { 1 });
        obj += &format!("f {}\n", q.map(corner).join(" "));
    }
    obj += "g joint-hip\nf 9 10 12 11\nf 13 14 16 15\n";
    std::fs::write(dir.join("base.obj"), obj).unwrap();

    let end_cube =
        r#"{"strategy": "CUBE", "cube_name": "joint-hip", "default_position": [0, 0, 0.4]}"#;
    let end_top =
        r#"{"strategy": "MEAN", "vertex_indices": [2, 3, 6, 7], "default_position": [0, 0, 1]}"#;
    let end_v = r#"{"strategy": "VERTEX", "vertex_index": 3, "default_position": [0.1, 0, 1]}"#;
    let rig = format!(
        r#"{{"child": {{"parent": "root", "roll": 0.0, "head": {end_top}, "tail": {end_v}}},
            "root": {{"parent": "", "roll": 0.5, "head": {end_cube}, "tail": {end_top}}}}}"#
    );
    std::fs::write(dir.join("rig.default.json"), rig).unwrap();
    // Bottom vertices: root only; top vertices: child 0.3 + root 0.1 (sum 0.4 → renormalised).
    let weights = r#"{"weights": {"root": [[0, 1.0], [1, 1.0], [4, 1.0], [5, 1.0], [2, 0.1], [3, 0.1], [6, 0.1], [7, 0.1], [9, 1.0]],
                                  "child": [[2, 0.3], [3, 0.3], [6, 0.3], [7, 0.3]]}}"#;
    std::fs::write(dir.join("weights.default.json"), weights).unwrap();
    let mut img = image::RgbImage::new(2, 2);
    img.put_pixel(0, 0, image::Rgb([90, 86, 255])); // upper-left: head
    img.put_pixel(1, 1, image::Rgb([254, 251, 251])); // lower-right: foot.L
    img.save(dir.join("body_parts_segmentation.png")).unwrap();
    std::fs::write(
        dir.join("body_parts_segmentation.yaml"),
        "colors:\n  body: [0, 0, 0]\n  head: [90, 86, 255]\n  foot.L: [254, 251, 251]\n",
    )
    .unwrap();
    let key = |f: f32, v: f32| {
        format!(
            r#""{f}": {{"rotation_euler": {{"values": [{v}, 0, 0], "metadata": [
                {{"handle_left": [{}, {v}], "handle_right": [{}, {v}]}},
                {{"handle_left": [0, 0], "handle_right": [0, 0]}},
                {{"handle_left": [0, 0], "handle_right": [0, 0]}}]}}}}"#,
            f - 1.0,
            f + 1.0
        )
    };
    let walk = format!(
        r#"{{"animation_data": {{"root": {{{}, {}}}, "left_foot_ik": {{{}}}}}, "metadata": {{}}}}"#,
        key(0.0, 0.1),
        key(40.0, 0.1),
        key(0.0, 1.0)
    );
    std::fs::create_dir_all(dir.join("poses")).unwrap();
    std::fs::write(dir.join("walkcycle_female.json"), walk).unwrap();
    std::fs::write(
        dir.join("poses/t-pose.json"),
        r#"{"bone_rotations": {"child": [0.0, 0.0, 0.5]}}"#,
    )
    .unwrap();
}

#[test]
fn converter_keeps_the_body_group_in_metres_with_soles_at_zero() {
    let dir = tempfile::tempdir().unwrap();
    write_source(dir.path());
    let t = convert_makehuman(dir.path()).unwrap().template;
    assert_eq!(t.vertices.len(), 8, "helper vertices are dropped");
    assert_eq!(t.triangles.len(), 12, "6 quads → 12 triangles");
    let lo = t
        .vertices
        .iter()
        .fold(Vec3::splat(f32::MAX), |a, v| a.min(*v));
    let hi = t
        .vertices
        .iter()
        .fold(Vec3::splat(f32::MIN), |a, v| a.max(*v));
    assert!(lo.abs_diff_eq(Vec3::new(-0.1, 0.0, -0.1), 1e-6), "{lo}");
    assert!(hi.abs_diff_eq(Vec3::new(0.1, 1.0, 0.1), 1e-6), "{hi}");
    // Quads split into counter-clockwise triangles keep the outward orientation.
    let w = lhmpp::body::generalized_winding_number(
        Vec3::new(0.0, 0.5, 0.0),
        &t.vertices,
        &t.triangles,
    );
    assert!((w - 1.0).abs() < 1e-3, "{w}");
}

#[test]
fn joints_follow_the_cube_mean_and_vertex_strategies() {
    let dir = tempfile::tempdir().unwrap();
    write_source(dir.path());
    let t = convert_makehuman(dir.path()).unwrap().template;
    assert_eq!(t.skeleton.bone_names, ["root", "child"]);
    assert_eq!(t.skeleton.parents, [None, Some(0)]);
    // CUBE: centre of the helper cube (0, 4, 0) dm minus the offset (0, 0, 0) → (0, 0.4, 0) m.
    assert!(
        t.skeleton.joints[0].abs_diff_eq(Vec3::new(0.0, 0.4, 0.0), 1e-6),
        "{}",
        t.skeleton.joints[0]
    );
    // MEAN of the four top vertices.
    assert!(t.skeleton.joints[1].abs_diff_eq(Vec3::new(0.0, 1.0, 0.0), 1e-6));
    // child points from the top centre to vertex 3 (+x, top, −z) with zero roll.
    let y = t.skeleton.rest_orientations[1].y_axis;
    assert!(
        y.abs_diff_eq(Vec3::new(1.0, 0.0, -1.0).normalize(), 1e-5),
        "{y}"
    );
    // root points straight up (Blender +Z) and is rolled by 0.5 rad.
    let r = t.skeleton.rest_orientations[0];
    assert!(r.y_axis.abs_diff_eq(Vec3::Y, 1e-5));
    assert!(((r * r.transpose()) - Mat3::IDENTITY).abs_diff_eq(Mat3::ZERO, 1e-5));
    assert!((r.x_axis.x - 0.5f32.cos()).abs() < 1e-5, "{r:?}");
}

#[test]
fn weights_are_top_four_renormalised_and_labels_come_from_the_image() {
    let dir = tempfile::tempdir().unwrap();
    write_source(dir.path());
    let t = convert_makehuman(dir.path()).unwrap().template;
    // Source vertex 3 (top): child 0.3, root 0.1 → 0.75 / 0.25.
    assert_eq!(t.skin.bones[2][..2], [1, 0]);
    assert!(
        (t.skin.weights[2][0] - 0.75).abs() < 1e-6 && (t.skin.weights[2][1] - 0.25).abs() < 1e-6
    );
    assert_eq!(t.skin.weights[0], [1.0, 0.0, 0.0, 0.0]);
    assert_eq!(t.part_names, ["body", "head", "foot.L"]);
    assert_eq!(t.part_labels, [2, 2, 1, 1, 2, 2, 1, 1]);
}

#[test]
fn conversion_is_bit_for_bit_reproducible_and_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    write_source(dir.path());
    let a = convert_makehuman(dir.path()).unwrap();
    let b = convert_makehuman(dir.path()).unwrap();
    assert!(a.template.to_bytes().unwrap() == b.template.to_bytes().unwrap());
    assert_eq!(a.walk_json, b.walk_json);
    let out = dir.path().join("out/makehuman.safetensors");
    write_assets(&a, &out).unwrap();
    assert_eq!(BodyTemplate::load(&out).unwrap(), a.template);
    let walk: KeyframeClip =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("out/walk.json")).unwrap())
            .unwrap();
    assert!(
        walk.channels.iter().all(|c| c.bone == "root"),
        "IK controls are dropped"
    );
    assert_eq!(walk.channels.len(), 3);
    assert!(dir.path().join("out/tpose.json").exists());
}

#[test]
fn missing_source_file_is_an_error_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    write_source(dir.path());
    std::fs::remove_file(dir.path().join("rig.default.json")).unwrap();
    let err = convert_makehuman(dir.path()).unwrap_err().to_string();
    assert!(err.contains("rig.default.json"), "{err}");
}
