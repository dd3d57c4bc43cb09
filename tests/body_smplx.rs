//! SMPL-X loader on a small synthetic npz in the SMPL-X layout.

use candle_core::{Device, Tensor};
use glam::{Quat, Vec3};
use lhmpp::body::{load_smplx, BodyError, Pose};

/// A two-bone "leg": 6 vertices on a vertical bar, bone 1 (child) weights the top half.
fn write_npz(path: &std::path::Path, skip: Option<&str>) {
    let dev = Device::Cpu;
    let v: Vec<f64> = vec![
        0.0, 1.0, 0.0, 0.1, 1.0, 0.0, 0.0, 1.5, 0.0, 0.1, 1.5, 0.0, 0.0, 2.0, 0.0, 0.1, 2.0, 0.0,
    ];
    let f: Vec<u32> = vec![0, 1, 2, 1, 3, 2, 2, 3, 4, 3, 5, 4];
    // Joint 0 = mean of vertices 0, 1; joint 1 = mean of vertices 2, 3.
    let jr: Vec<f64> = vec![0.5, 0.5, 0., 0., 0., 0., 0., 0., 0.5, 0.5, 0., 0.];
    let w: Vec<f64> = vec![1., 0., 1., 0., 0.5, 0.5, 0.5, 0.5, 0., 1., 0., 1.];
    let kt: Vec<i64> = vec![-1, 0, 0, 1];
    // Shape component 0 stretches y by +0.1 per unit beta; component 1 moves x.
    let mut sd = vec![0f64; 6 * 3 * 2];
    for i in 0..6 {
        sd[i * 6 + 2] = 0.1 * v[i * 3 + 1]; // [i][1][0]
        sd[i * 6 + 1] = 0.05; // [i][0][1]
    }
    let tensors = [
        ("v_template", Tensor::from_vec(v, (6, 3), &dev).unwrap()),
        ("f", Tensor::from_vec(f, (4, 3), &dev).unwrap()),
        ("J_regressor", Tensor::from_vec(jr, (2, 6), &dev).unwrap()),
        ("weights", Tensor::from_vec(w, (6, 2), &dev).unwrap()),
        ("kintree_table", Tensor::from_vec(kt, (2, 2), &dev).unwrap()),
        ("shapedirs", Tensor::from_vec(sd, (6, 3, 2), &dev).unwrap()),
    ];
    let kept: Vec<(&str, &Tensor)> = tensors
        .iter()
        .filter(|(k, _)| Some(*k) != skip)
        .map(|(k, t)| (*k, t))
        .collect();
    Tensor::write_npz(&kept, path).unwrap();
}

#[test]
fn npz_round_trip_gives_a_template_in_the_canonical_frame() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("SMPLX_NEUTRAL.npz");
    write_npz(&path, None);
    let t = load_smplx(&path, &[]).unwrap();
    assert_eq!(t.vertices.len(), 6);
    assert_eq!(t.triangles.len(), 4);
    assert_eq!(t.skeleton.parents, vec![None, Some(0)]);
    assert!(
        t.vertices
            .iter()
            .map(|v| v.y)
            .fold(f32::MAX, f32::min)
            .abs()
            < 1e-6
    );
    // Joint 1 is 0.5 m above joint 0, as the regressor says.
    assert!((t.skeleton.joints[1] - t.skeleton.joints[0]).abs_diff_eq(Vec3::Y * 0.5, 1e-6));
    assert_eq!(t.skin.bones[5][0], 1);
}

#[test]
fn betas_change_the_shape_as_the_blend_shapes_say() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.npz");
    write_npz(&path, None);
    let base = load_smplx(&path, &[]).unwrap();
    let tall = load_smplx(&path, &[2.0]).unwrap();
    let wide = load_smplx(&path, &[0.0, 1.0]).unwrap();
    // Component 0: y scaled by 1 + 0.2 (source y from 1 to 2 → height 1.0 → 1.2).
    assert!(
        (tall.height() - 1.2 * base.height()).abs() < 1e-5,
        "{}",
        tall.height()
    );
    // Joints follow the shaped mesh: the bone got 20 % longer.
    let len = |t: &lhmpp::body::BodyTemplate| t.skeleton.joints[1].distance(t.skeleton.joints[0]);
    assert!((len(&tall) - 1.2 * len(&base)).abs() < 1e-5);
    // Component 1 moves every vertex by +0.05 in x, which re-centring removes.
    assert!((wide.vertices[0] - base.vertices[0]).length() < 1e-6);
    assert!(matches!(
        load_smplx(&path, &[0.0; 3]),
        Err(BodyError::Format { .. })
    ));
}

#[test]
fn skinning_an_smplx_template_rotates_the_child_part() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.npz");
    write_npz(&path, None);
    let t = load_smplx(&path, &[]).unwrap();
    let mut pose = Pose::identity();
    let name = t.skeleton.bone_names[1].clone();
    pose.rotations
        .insert(name, Quat::from_rotation_z(std::f32::consts::FRAC_PI_2));
    let posed = t.posed_vertices(&pose).unwrap();
    assert_eq!(posed[0], t.vertices[0]);
    // Vertex 4 (top, weight 1 on bone 1) swings about joint 1 to the −x side.
    let j1 = t.skeleton.joints[1];
    let expected = j1 + Quat::from_rotation_z(std::f32::consts::FRAC_PI_2) * (t.vertices[4] - j1);
    assert!(
        posed[4].abs_diff_eq(expected, 1e-5),
        "{} vs {expected}",
        posed[4]
    );
}

#[test]
fn missing_key_error_names_the_file_and_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("broken.npz");
    write_npz(&path, Some("J_regressor"));
    let err = load_smplx(&path, &[]).unwrap_err().to_string();
    assert!(
        err.contains("broken.npz") && err.contains("J_regressor"),
        "{err}"
    );
}
