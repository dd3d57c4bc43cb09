//! Walk cycle and pose specs on the committed template.

use lhmpp::body::motion::{parse_pose_spec, tpose, walk_pose, WALK_PERIOD_FRAMES};
use lhmpp::body::{BodyTemplate, Pose};

#[test]
fn every_walk_frame_gives_finite_vertices_and_preserves_bone_lengths() {
    let t = BodyTemplate::load_default().unwrap();
    let sk = &t.skeleton;
    let rest_len: Vec<f32> = (0..sk.len())
        .map(|j| sk.parents[j].map_or(0.0, |p| sk.joints[j].distance(sk.joints[p])))
        .collect();
    for frame in 0..WALK_PERIOD_FRAMES as u32 {
        let pose = walk_pose(frame as f32);
        sk.check_pose(&pose).unwrap();
        let m = sk.skinning_matrices(&pose);
        let posed = t.skin.skin_points(&t.vertices, &m);
        assert!(posed.iter().all(|v| v.is_finite()), "frame {frame}");
        let joints = sk.posed_joints(&m);
        for j in 0..sk.len() {
            if let Some(p) = sk.parents[j] {
                let len = joints[j].distance(joints[p]);
                let rel = (len - rest_len[j]).abs() / rest_len[j].max(1e-3);
                assert!(
                    rel < 0.01,
                    "frame {frame}: {} length {len} vs {}",
                    sk.bone_names[j],
                    rest_len[j]
                );
            }
        }
    }
}

#[test]
fn walk_keeps_the_lowest_foot_point_on_the_ground() {
    let t = BodyTemplate::load_default().unwrap();
    for frame in [0.0f32, 7.5, 13.0, 20.0, 33.0] {
        let v = t.posed_vertices(&walk_pose(frame)).unwrap();
        let lowest = v.iter().map(|p| p.y).fold(f32::MAX, f32::min);
        assert!(
            lowest.abs() < 2e-3,
            "frame {frame}: lowest point at y = {lowest}"
        );
    }
}

#[test]
fn walk_loops_and_moves_the_legs() {
    let t = BodyTemplate::load_default().unwrap();
    let a = walk_pose(3.0);
    let b = walk_pose(3.0 + WALK_PERIOD_FRAMES);
    for (bone, q) in &a.rotations {
        assert!(q.abs_diff_eq(b.rotations[bone], 1e-5), "{bone}");
    }
    // Ankles travel: the left ankle's z differs by > 15 cm over the cycle.
    let ankle = t.skeleton.bone_index("foot.L").unwrap();
    let zs: Vec<f32> = (0..40)
        .map(|f| {
            let m = t.skeleton.skinning_matrices(&walk_pose(f as f32));
            m[ankle].transform_point3(t.skeleton.joints[ankle]).z
        })
        .collect();
    let spread =
        zs.iter().cloned().fold(f32::MIN, f32::max) - zs.iter().cloned().fold(f32::MAX, f32::min);
    assert!(spread > 0.15, "ankle z spread {spread}");
}

#[test]
fn tpose_raises_the_arms_to_shoulder_height() {
    let t = BodyTemplate::load_default().unwrap();
    let wrist = t.skeleton.bone_index("wrist.L").unwrap();
    let shoulder = t.skeleton.bone_index("upperarm01.L").unwrap();
    let m = t.skeleton.try_skinning_matrices(&tpose()).unwrap();
    let j = t.skeleton.posed_joints(&m);
    let rest_drop = t.skeleton.joints[shoulder].y - t.skeleton.joints[wrist].y;
    let drop = j[shoulder].y - j[wrist].y;
    assert!(
        rest_drop > 0.2,
        "A-pose wrist hangs well below the shoulder: {rest_drop}"
    );
    eprintln!(
        "rest drop {rest_drop}, T-pose drop {drop}, wrist {}, shoulder {}",
        j[wrist], j[shoulder]
    );
    assert!(drop.abs() < 0.1, "T-pose wrist at shoulder height: {drop}");
    assert!(
        j[wrist].x > j[shoulder].x + 0.4,
        "arm out to the left: {}",
        j[wrist]
    );
}

#[test]
fn pose_specs_give_the_named_frames() {
    assert_eq!(parse_pose_spec("rest").unwrap(), vec![Pose::identity()]);
    assert_eq!(parse_pose_spec("walk:0..60").unwrap().len(), 60);
    assert_eq!(parse_pose_spec("walk:12").unwrap(), vec![walk_pose(12.0)]);
    assert_eq!(parse_pose_spec("tpose").unwrap(), vec![tpose()]);
    assert!(parse_pose_spec("dance:3").is_err());
}
