//! The official per-frame SMPL-X motion JSON: parsing into poses and cameras, folders as
//! sequences, FLAME sidecars, and errors naming the file and key.

use std::path::Path;

use glam::{Quat, Vec3};
use lhmpp::body::motion::official::{SmplxFrame, SmplxMotion};
use serde_json::{json, Value};

fn frame_json(angle: f32) -> Value {
    let mut body = vec![[0.0f32; 3]; 21];
    body[0] = [0.0, 0.0, angle]; // left_hip about z
    body[3] = [angle, 0.0, 0.0]; // left_knee about x
    let mut rhand = vec![0.0f32; 45];
    rhand[0] = 0.25; // right_index1 about x
    json!({
        "betas": [0.1, -0.2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        "root_pose": [std::f32::consts::PI, 0.0, 0.0],
        "body_pose": body,
        "jaw_pose": [0.2, 0.0, 0.0],
        "leye_pose": [0.0, 0.0, 0.0],
        "reye_pose": [0.0, 0.0, 0.0],
        "lhand_pose": vec![[0.0f32; 3]; 15],
        "rhand_pose": rhand,
        "trans": [0.05, 0.3, 4.0],
        "focal": [1100.0, 1100.0],
        "princpt": [252.0, 420.0],
        "img_size_wh": [504.0, 840.0],
        "pad_ratio": 0.2
    })
}

fn write(path: &Path, v: &Value) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(path, v.to_string()).unwrap();
}

fn close(a: Quat, b: Quat) -> bool {
    a.dot(b).abs() > 1.0 - 1e-6
}

#[test]
fn frame_becomes_an_smplx_pose_and_a_centred_camera() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("00001.json");
    write(&path, &frame_json(0.5));
    let frame = SmplxFrame::from_file(&path).unwrap();
    let pose = frame.pose();
    assert!(close(
        pose.rotations["left_hip"],
        Quat::from_rotation_z(0.5)
    ));
    assert!(close(
        pose.rotations["left_knee"],
        Quat::from_rotation_x(0.5)
    ));
    assert!(close(pose.rotations["jaw"], Quat::from_rotation_x(0.2)));
    assert!(close(
        pose.rotations["right_index1"],
        Quat::from_rotation_x(0.25)
    ));
    // Zero rotations are left out: only the four rotated joints are named.
    assert_eq!(pose.rotations.len(), 4, "{:?}", pose.rotations.keys());
    assert!(close(
        pose.root_rotation,
        Quat::from_rotation_x(std::f32::consts::PI)
    ));
    assert_eq!(pose.root_translation, Vec3::new(0.05, 0.3, 4.0));
    let cam = frame.camera();
    assert_eq!((cam.width, cam.height), (504, 840));
    assert_eq!((cam.fx, cam.cx, cam.cy), (1100.0, 252.0, 420.0));
    assert_eq!(frame.betas.len(), 10);
    assert_eq!(frame.pad_ratio, Some(0.2));
    assert_eq!(frame.img_size_wh, Some([504.0, 840.0]));
}

#[test]
fn flat_and_nested_pose_lists_parse_the_same() {
    let dir = tempfile::tempdir().unwrap();
    let nested = frame_json(0.3);
    let mut flat = nested.clone();
    let flatten = |v: &Value| -> Value {
        Value::Array(
            v.as_array()
                .unwrap()
                .iter()
                .flat_map(|r| r.as_array().unwrap().clone())
                .collect(),
        )
    };
    flat["body_pose"] = flatten(&nested["body_pose"]);
    flat["lhand_pose"] = flatten(&nested["lhand_pose"]);
    write(&dir.path().join("a.json"), &nested);
    write(&dir.path().join("b.json"), &flat);
    let a = SmplxFrame::from_file(&dir.path().join("a.json")).unwrap();
    let b = SmplxFrame::from_file(&dir.path().join("b.json")).unwrap();
    assert_eq!(a, b);
}

#[test]
fn errors_name_the_file_and_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.json");
    let mut v = frame_json(0.1);
    v.as_object_mut().unwrap().remove("trans");
    write(&path, &v);
    let err = SmplxFrame::from_file(&path).unwrap_err().to_string();
    assert!(err.contains("bad.json") && err.contains("`trans`"), "{err}");

    let mut v = frame_json(0.1);
    v["body_pose"] = json!(vec![0.0f32; 60]);
    write(&path, &v);
    let err = SmplxFrame::from_file(&path).unwrap_err().to_string();
    assert!(
        err.contains("bad.json")
            && err.contains("`body_pose`")
            && err.contains("63")
            && err.contains("60"),
        "{err}"
    );

    let mut v = frame_json(0.1);
    v["focal"] = json!(["a", 2]);
    write(&path, &v);
    let err = SmplxFrame::from_file(&path).unwrap_err().to_string();
    assert!(err.contains("`focal`"), "{err}");

    std::fs::write(&path, "[1, 2").unwrap();
    let err = SmplxFrame::from_file(&path).unwrap_err().to_string();
    assert!(err.contains("bad.json"), "{err}");
}

#[test]
fn flame_sidecar_replaces_jaw_and_eyes() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("smplx_params/00000.json");
    write(&path, &frame_json(0.1));
    write(
        &dir.path().join("flame_params/00000.json"),
        &json!({
            "expcode": vec![0.5f32; 100],
            "posecode": [0.0, 0.0, 0.0, 0.4, 0.0, 0.0],
            "eyecode": [0.0, 0.1, 0.0, 0.0, -0.1, 0.0]
        }),
    );
    let frame = SmplxFrame::from_file(&path).unwrap();
    assert_eq!(frame.jaw_pose, Vec3::new(0.4, 0.0, 0.0));
    assert_eq!(frame.leye_pose, Vec3::new(0.0, 0.1, 0.0));
    assert_eq!(frame.reye_pose, Vec3::new(0.0, -0.1, 0.0));
    assert_eq!(frame.expr.as_ref().map(Vec::len), Some(100));
}

#[test]
fn a_folder_of_frames_is_a_sequence_in_file_name_order() {
    let dir = tempfile::tempdir().unwrap();
    for (i, angle) in [(2, 0.3), (0, 0.1), (1, 0.2)] {
        write(
            &dir.path().join(format!("smplx_params/{i:05}.json")),
            &frame_json(angle),
        );
    }
    std::fs::write(dir.path().join("smplx_params/notes.txt"), "ignored").unwrap();
    let motion = SmplxMotion::from_dir(dir.path()).unwrap();
    assert_eq!(motion.len(), 3);
    let angles: Vec<f32> = motion.frames.iter().map(|f| f.body_pose[0].z).collect();
    assert_eq!(angles, [0.1, 0.2, 0.3]);

    let empty = tempfile::tempdir().unwrap();
    let err = SmplxMotion::from_dir(empty.path()).unwrap_err().to_string();
    assert!(err.contains("no per-frame"), "{err}");
    // A broken frame in a sequence names its own file.
    write(
        &dir.path().join("smplx_params/00003.json"),
        &json!({"betas": []}),
    );
    let err = SmplxMotion::from_dir(dir.path()).unwrap_err().to_string();
    assert!(
        err.contains("00003.json") && err.contains("root_pose"),
        "{err}"
    );
}
