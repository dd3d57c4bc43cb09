//! The committed MakeHuman template: integrity, joints inside the body, and skinning.

use glam::{Quat, Vec3};
use lhmpp::body::{generalized_winding_number, BodyTemplate, Pose, DEFAULT_ASSET};

fn template() -> BodyTemplate {
    BodyTemplate::load_default().expect("embedded template loads")
}

#[test]
fn embedded_asset_loads_with_the_expected_sizes() {
    let t = template();
    assert_eq!(t.vertices.len(), 13_380);
    assert_eq!(t.skeleton.len(), 163);
    assert_eq!(t.uvs.len(), t.vertices.len());
    assert!(t.triangles.len() > 20_000);
    assert_eq!(t.canonical_pose, "makehuman-a-pose");
}

#[test]
fn embedded_asset_reserialises_bit_for_bit() {
    let t = template();
    assert!(
        t.to_bytes().unwrap() == DEFAULT_ASSET,
        "serialisation is not canonical"
    );
}

#[test]
fn triangles_reference_valid_distinct_vertices() {
    let t = template();
    let n = t.vertices.len() as u32;
    for tri in &t.triangles {
        assert!(tri.iter().all(|&i| i < n), "{tri:?}");
        assert!(
            tri[0] != tri[1] && tri[1] != tri[2] && tri[0] != tri[2],
            "{tri:?}"
        );
    }
}

#[test]
fn skinning_weights_are_non_negative_and_sum_to_one() {
    let t = template();
    for (i, w) in t.skin.weights.iter().enumerate() {
        assert!(w.iter().all(|&x| x >= 0.0), "vertex {i}: {w:?}");
        assert!(
            (w.iter().sum::<f32>() - 1.0).abs() < 1e-5,
            "vertex {i}: {w:?}"
        );
    }
}

#[test]
fn frame_is_metres_y_up_facing_z_with_soles_at_zero() {
    let t = template();
    let lo = t
        .vertices
        .iter()
        .fold(Vec3::splat(f32::MAX), |a, v| a.min(*v));
    let hi = t
        .vertices
        .iter()
        .fold(Vec3::splat(f32::MIN), |a, v| a.max(*v));
    assert!(lo.y.abs() < 1e-6, "soles at y = 0: {lo}");
    let height = hi.y - lo.y;
    assert!(
        (1.5..2.0).contains(&height),
        "adult height in metres: {height}"
    );
    // Toes point to +Z: the left foot's vertices lie mostly in front of its ankle joint.
    let foot = t.part_names.iter().position(|n| n == "foot.L").unwrap() as u8;
    let ankle = t.skeleton.joints[t.skeleton.bone_index("foot.L").unwrap()];
    let zs: Vec<f32> = t
        .vertices
        .iter()
        .zip(&t.part_labels)
        .filter(|(_, &l)| l == foot)
        .map(|(v, _)| v.z)
        .collect();
    let mean_z = zs.iter().sum::<f32>() / zs.len() as f32;
    assert!(
        mean_z > ankle.z + 0.03,
        "toes towards +Z: foot mean z {mean_z}, ankle {ankle}"
    );
    // The face is on the +Z side of the head: the nose tip is the head's frontmost point.
    let head = t.part_names.iter().position(|n| n == "head").unwrap() as u8;
    let (zmin, zmax) = t
        .vertices
        .iter()
        .zip(&t.part_labels)
        .filter(|(_, &l)| l == head)
        .fold((f32::MAX, f32::MIN), |(a, b), (v, _)| {
            (a.min(v.z), b.max(v.z))
        });
    let neck = t.skeleton.joints[t.skeleton.bone_index("neck01").unwrap()];
    assert!(
        zmax - neck.z > neck.z - zmin,
        "face towards +Z: head z in [{zmin}, {zmax}], neck {neck}"
    );
    // The left side is +X: left-hand vertices have positive x.
    let hand_l = t.part_names.iter().position(|n| n == "hand.L").unwrap() as u8;
    assert!(t
        .vertices
        .iter()
        .zip(&t.part_labels)
        .filter(|(_, &l)| l == hand_l)
        .all(|(v, _)| v.x > 0.2));
}

#[test]
fn part_labels_split_the_body_symmetrically() {
    let t = template();
    let counts = t.part_counts();
    let count = |name: &str| counts[t.part_names.iter().position(|n| n == name).unwrap()];
    assert_eq!(count("hand.L"), count("hand.R"));
    assert_eq!(count("foot.L"), count("foot.R"));
    // Counts measured independently (numpy) on the source files, per the assets' README.
    assert_eq!(
        [
            count("body"),
            count("head"),
            count("hand.L"),
            count("foot.L"),
            count("mouth_cavity")
        ],
        [3831, 3178, 1605, 1074, 403]
    );
}

/// Torso and limb joints must lie inside the skin. The mesh is not watertight (eye and mouth
/// cavities), so the test uses the generalized winding number, which stays near 1 inside a
/// mesh with small holes; > 0.5 is the standard inside threshold.
#[test]
fn torso_and_limb_joints_sit_inside_the_mesh() {
    let t = template();
    let bones = [
        "spine01",
        "spine02",
        "spine03",
        "spine04",
        "spine05",
        "neck01",
        "neck02",
        "head",
        "pelvis.L",
        "pelvis.R",
        "upperleg01.L",
        "upperleg01.R",
        "lowerleg01.L",
        "lowerleg01.R",
        "foot.L",
        "foot.R",
        "upperarm01.L",
        "upperarm01.R",
        "lowerarm01.L",
        "lowerarm01.R",
        "wrist.L",
        "wrist.R",
        "clavicle.L",
        "clavicle.R",
    ];
    for name in bones {
        let i = t
            .skeleton
            .bone_index(name)
            .unwrap_or_else(|| panic!("bone {name}"));
        let w = generalized_winding_number(t.skeleton.joints[i], &t.vertices, &t.triangles);
        assert!(
            w > 0.5,
            "{name} at {} has winding number {w}",
            t.skeleton.joints[i]
        );
    }
}

#[test]
fn identity_pose_leaves_every_vertex_in_place() {
    let t = template();
    let posed = t.posed_vertices(&Pose::identity()).unwrap();
    for (a, b) in posed.iter().zip(&t.vertices) {
        assert!(a.abs_diff_eq(*b, 1e-5), "{a} vs {b}");
    }
}

#[test]
fn rotating_one_bone_moves_only_the_vertices_it_or_its_children_weight() {
    let t = template();
    let bone = t.skeleton.bone_index("lowerarm01.L").unwrap();
    let mask = t.skeleton.subtree_mask(bone);
    let mut pose = Pose::identity();
    pose.rotations
        .insert("lowerarm01.L".into(), Quat::from_rotation_x(0.8));
    let posed = t.posed_vertices(&pose).unwrap();
    let (mut moved, mut weighted) = (0, 0);
    for i in 0..t.vertices.len() {
        let w_subtree: f32 = (0..4)
            .filter(|&k| mask[t.skin.bones[i][k] as usize])
            .map(|k| t.skin.weights[i][k])
            .sum();
        if w_subtree == 0.0 {
            assert_eq!(posed[i], t.vertices[i], "vertex {i} moved without weight");
        } else {
            weighted += 1;
            if posed[i].distance(t.vertices[i]) > 1e-4 {
                moved += 1;
            }
        }
    }
    assert!(
        weighted > 100 && moved * 10 > weighted * 9,
        "{moved} of {weighted} moved"
    );
}

#[test]
fn unknown_bones_in_a_pose_are_an_error_listing_them() {
    let t = template();
    let mut pose = Pose::identity();
    pose.rotations.insert("left_elbow".into(), Quat::IDENTITY);
    let err = t.posed_vertices(&pose).unwrap_err().to_string();
    assert!(err.contains("left_elbow"), "{err}");
}

#[test]
fn loading_a_missing_file_names_it() {
    let err = BodyTemplate::load(std::path::Path::new("/nonexistent/body.safetensors"))
        .unwrap_err()
        .to_string();
    assert!(err.contains("/nonexistent/body.safetensors"), "{err}");
}
