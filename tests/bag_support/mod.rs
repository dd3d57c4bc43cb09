//! Shared by the bag and message tests: one sample message of every type, written to a bag,
//! with the field values an independent reader must find.

#![allow(dead_code)]

use lhmpp::bag::BagWriter;
use lhmpp::msgs::*;
use serde_json::{json, Value};

/// Base time of the sample bag (ns since the epoch).
pub const T0: u64 = 1_700_000_000_000_000_000;

fn header(frame: &str, offset_ns: u64) -> Header {
    Header::new(Time::from_nanos((T0 + offset_ns) as i64), frame)
}

/// A static camera transform.
pub fn transform_stamped() -> TransformStamped {
    TransformStamped {
        header: header("world", 0),
        child_frame_id: "camera_0".into(),
        transform: Transform {
            translation: Vector3 {
                x: 1.5,
                y: -2.0,
                z: 0.25,
            },
            rotation: Quaternion {
                x: 0.0,
                y: 0.0,
                z: 0.6,
                w: 0.8,
            },
        },
    }
}

/// A two-Gaussian avatar with RGB colours.
pub fn avatar() -> GaussianAvatar {
    let cloud = GaussianCloud {
        positions: vec![[0.0, 1.0, 0.1], [0.2, 1.5, -0.1]],
        scales: vec![[0.01, 0.02, 0.03]; 2],
        rotations: vec![[1.0, 0.0, 0.0, 0.0]; 2],
        opacities: vec![0.75, 0.5],
        colors: GaussianColors::Rgb(vec![[1.0, 0.5, 0.25], [0.0, 0.0, 1.0]]),
        skin: lhmpp::body::SkinWeights {
            bones: vec![[0, 1, 0, 0], [1, 0, 0, 0]],
            weights: vec![[0.75, 0.25, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]],
        },
    };
    GaussianAvatar {
        header: header("avatar", 0),
        person_id: "person_7".into(),
        revision: 3,
        views_used: 4,
        body_model: "makehuman-cc0".into(),
        shape_params: vec![0.5, -0.25],
        sh_degree: 0,
        rgb_display_ready: false,
        neural_renderer: "patch_4dptonly@/models/LHMPP-700M".into(),
        bone_names: vec!["root".into(), "spine".into()],
        bone_parents: vec![-1, 0],
        bone_rest_positions: vec![
            Point {
                x: 0.0,
                y: 0.9,
                z: 0.0,
            },
            Point {
                x: 0.0,
                y: 1.25,
                z: 0.0,
            },
        ],
        gaussians: cloud.to_point_cloud(header("avatar", 0)).unwrap(),
    }
}

/// Writes `copies` rounds of one message of every type, 10 ms apart, to `writer`; returns the
/// expected JSON for `check_bag.py` (first message of each topic, and counts).
pub fn write_every_type(writer: &mut BagWriter, copies: u64) -> Value {
    let mut expected = serde_json::Map::new();
    for i in 0..copies {
        let t = T0 + i * 10_000_000;
        let mut put = |topic: &str, type_name: &str, fields: Value| {
            expected.insert(
                topic.to_string(),
                json!({"type": type_name, "count": copies, "fields": fields}),
            );
        };
        writer
            .write("/time", t, &Time { sec: 5, nanosec: 6 })
            .unwrap();
        put("/time", Time::TYPE_NAME, json!({"sec": 5, "nanosec": 6}));
        writer.write("/header", t, &header("map", 1)).unwrap();
        put(
            "/header",
            Header::TYPE_NAME,
            json!({"frame_id": "map", "stamp.sec": 1_700_000_000, "stamp.nanosec": 1}),
        );
        let ts = transform_stamped();
        writer
            .write("/vector3", t, &ts.transform.translation)
            .unwrap();
        put(
            "/vector3",
            Vector3::TYPE_NAME,
            json!({"x": 1.5, "y": -2.0, "z": 0.25}),
        );
        writer
            .write(
                "/point",
                t,
                &Point {
                    x: 1.0,
                    y: 2.0,
                    z: 3.0,
                },
            )
            .unwrap();
        put("/point", Point::TYPE_NAME, json!({"x": 1.0, "z": 3.0}));
        writer
            .write("/quaternion", t, &ts.transform.rotation)
            .unwrap();
        put(
            "/quaternion",
            Quaternion::TYPE_NAME,
            json!({"z": 0.6, "w": 0.8}),
        );
        let pose = lhmpp::msgs::GeometryPose {
            position: Point {
                x: 4.0,
                y: 5.0,
                z: 6.0,
            },
            orientation: Quaternion::default(),
        };
        writer.write("/pose", t, &pose).unwrap();
        put(
            "/pose",
            lhmpp::msgs::GeometryPose::TYPE_NAME,
            json!({"position.y": 5.0, "orientation.w": 1.0}),
        );
        writer.write("/transform", t, &ts.transform).unwrap();
        put(
            "/transform",
            Transform::TYPE_NAME,
            json!({"translation.x": 1.5}),
        );
        writer.write("/transform_stamped", t, &ts).unwrap();
        put(
            "/transform_stamped",
            TransformStamped::TYPE_NAME,
            json!({"child_frame_id": "camera_0", "header.frame_id": "world", "transform.rotation.z": 0.6}),
        );
        let tf = TFMessage {
            transforms: vec![ts.clone(), ts.clone()],
        };
        writer.write("/tf", t, &tf).unwrap();
        put(
            "/tf",
            TFMessage::TYPE_NAME,
            json!({"transforms.1.child_frame_id": "camera_0", "transforms.0.transform.translation.y": -2.0}),
        );
        let roi = RegionOfInterest {
            x_offset: 1,
            y_offset: 2,
            height: 3,
            width: 4,
            do_rectify: true,
        };
        writer.write("/roi", t, &roi).unwrap();
        put(
            "/roi",
            RegionOfInterest::TYPE_NAME,
            json!({"x_offset": 1, "width": 4, "do_rectify": true}),
        );
        let image = Image {
            header: header("cam", 2),
            height: 2,
            width: 3,
            encoding: "rgb8".into(),
            is_bigendian: 0,
            step: 9,
            data: (0..18).collect(),
        };
        writer.write("/camera/image_raw", t, &image).unwrap();
        put(
            "/camera/image_raw",
            Image::TYPE_NAME,
            json!({"encoding": "rgb8", "step": 9, "height": 2, "data": (0..18).collect::<Vec<u8>>()}),
        );
        let jpeg = CompressedImage {
            header: header("cam", 2),
            format: "jpeg".into(),
            data: vec![0xFF, 0xD8, 0xFF, 0xD9],
        };
        writer
            .write("/camera/image_raw/compressed", t, &jpeg)
            .unwrap();
        put(
            "/camera/image_raw/compressed",
            CompressedImage::TYPE_NAME,
            json!({"format": "jpeg", "data": [255, 216, 255, 217]}),
        );
        let info = CameraInfo {
            header: header("cam", 2),
            height: 480,
            width: 640,
            distortion_model: "plumb_bob".into(),
            d: vec![0.125, -0.0625, 0.0, 0.0, 0.5],
            k: [500.0, 0.0, 320.0, 0.0, 510.0, 240.0, 0.0, 0.0, 1.0],
            r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            p: [
                500.0, 0.0, 320.0, 0.0, 0.0, 510.0, 240.0, 0.0, 0.0, 0.0, 1.0, 0.0,
            ],
            binning_x: 1,
            binning_y: 2,
            roi,
        };
        writer.write("/camera/camera_info", t, &info).unwrap();
        put(
            "/camera/camera_info",
            CameraInfo::TYPE_NAME,
            json!({"distortion_model": "plumb_bob", "d": [0.125, -0.0625, 0.0, 0.0, 0.5],
                   "k": [500.0, 0.0, 320.0, 0.0, 510.0, 240.0, 0.0, 0.0, 1.0], "p.6": 240.0,
                   "binning_y": 2, "roi.do_rectify": true}),
        );
        let field = PointField {
            name: "x".into(),
            offset: 4,
            datatype: PointField::FLOAT32,
            count: 1,
        };
        writer.write("/point_field", t, &field).unwrap();
        put(
            "/point_field",
            PointField::TYPE_NAME,
            json!({"name": "x", "offset": 4, "datatype": 7, "count": 1}),
        );
        let av = avatar();
        writer.write("/points", t, &av.gaussians).unwrap();
        put(
            "/points",
            PointCloud2::TYPE_NAME,
            json!({"width": 2, "height": 1, "point_step": av.gaussians.point_step,
                   "fields.0.name": "x", "fields.14.name": "weight_0", "fields.18.datatype": 4,
                   "is_dense": true, "data": av.gaussians.data.clone()}),
        );
        writer.write("/avatar", t, &av).unwrap();
        put(
            "/avatar",
            GaussianAvatar::TYPE_NAME,
            json!({"person_id": "person_7", "revision": 3, "views_used": 4,
                   "body_model": "makehuman-cc0", "shape_params": [0.5, -0.25], "sh_degree": 0,
                   "rgb_display_ready": false, "neural_renderer": "patch_4dptonly@/models/LHMPP-700M",
                   "bone_names": ["root", "spine"], "bone_parents": [-1, 0],
                   "bone_rest_positions.1.y": 1.25, "gaussians.width": 2,
                   "gaussians.data": av.gaussians.data.clone()}),
        );
        let body_pose = BodyPose {
            header: header("world", 3),
            person_id: "person_7".into(),
            bone_names: vec!["spine".into(), "head".into()],
            rotations: vec![Quaternion::default(), ts.transform.rotation],
            root: ts.transform,
        };
        writer.write("/body_pose", t, &body_pose).unwrap();
        put(
            "/body_pose",
            BodyPose::TYPE_NAME,
            json!({"bone_names": ["spine", "head"], "rotations.1.w": 0.8, "root.translation.z": 0.25}),
        );
        let status = ReconstructionStatus {
            header: header("", 4),
            person_id: "person_7".into(),
            views_held: 4,
            revision: 3,
            last_latency_ms: 812.5,
            last_render_ms: 41.25,
            state: ReconstructionStatus::STATE_RECONSTRUCTING,
            message: "running".into(),
            rejected_reasons: vec!["cdr".into(), "image".into()],
            rejected_counts: vec![2, 4],
        };
        writer.write("/status", t, &status).unwrap();
        put(
            "/status",
            ReconstructionStatus::TYPE_NAME,
            json!({"views_held": 4, "last_latency_ms": 812.5, "last_render_ms": 41.25, "state": 2, "message": "running",
                   "rejected_reasons": ["cdr", "image"], "rejected_counts": [2, 4]}),
        );
    }
    Value::Object(expected)
}

/// A small mono8 image whose bytes depend on `i` (incompressible-ish, so chunks have size).
pub fn numbered_image(i: u32) -> Image {
    Image {
        height: 8,
        width: 8,
        encoding: "mono8".into(),
        step: 8,
        data: (0..64u32)
            .map(|k| (k.wrapping_mul(2654435761).wrapping_add(i * 97) >> 13) as u8)
            .collect(),
        ..Default::default()
    }
}

/// Log time of [`numbered_image`] `i` in [`chunked_image_bag`].
pub fn image_time(i: u32) -> u64 {
    1_000_000_000 + i as u64
}

/// Writes `chunks` × `per_chunk` numbered images on `/img` into `path` (`.mcap` file or bag
/// directory), one flushed chunk each, and finishes it; returns the MCAP file's bytes and its
/// chunk index (sorted by offset).
pub fn chunked_image_bag(
    path: &std::path::Path,
    chunks: u32,
    per_chunk: u32,
) -> (Vec<u8>, Vec<mcap::records::ChunkIndex>) {
    let mut writer = BagWriter::create_with(path, flushed_chunks()).unwrap();
    for i in 0..chunks * per_chunk {
        writer
            .write("/img", image_time(i), &numbered_image(i))
            .unwrap();
        if (i + 1) % per_chunk == 0 {
            writer.flush().unwrap();
        }
    }
    let file = writer.path().to_path_buf();
    writer.finish().unwrap();
    let bytes = std::fs::read(file).unwrap();
    let index = chunk_index(&bytes);
    assert_eq!(index.len(), chunks as usize);
    (bytes, index)
}

/// Writer options whose chunks close only at a flush (no size limit, no timer).
pub fn flushed_chunks() -> lhmpp::bag::BagWriterOptions {
    lhmpp::bag::BagWriterOptions {
        chunk_size: 1 << 30,
        flush_interval: None,
        ..Default::default()
    }
}

/// The chunk index of a complete bag, sorted by offset.
pub fn chunk_index(bytes: &[u8]) -> Vec<mcap::records::ChunkIndex> {
    let mut index = mcap::Summary::read(bytes).unwrap().unwrap().chunk_indexes;
    index.sort_by_key(|c| c.chunk_start_offset);
    index
}

/// Damages a chunk's uncompressed CRC (the field after its start time, end time and
/// uncompressed size), so the chunk fails its CRC check and nothing else.
pub fn flip_chunk_crc(bytes: &mut [u8], chunk: &mcap::records::ChunkIndex) {
    bytes[chunk.chunk_start_offset as usize + 9 + 24] ^= 0x5A;
}

/// Offset of the data end record of a complete bag: cutting there drops summary and footer.
pub fn data_end(bytes: &[u8]) -> usize {
    let at = mcap::read::footer(bytes).unwrap().summary_start as usize - 13;
    assert_eq!(bytes[at], 0x0F, "data end record");
    at
}

/// The Python interpreter with the bag readers, from `LHMPP_TEST_PYTHON` (set by
/// `scripts/test`, which installs them).
pub fn python() -> String {
    std::env::var("LHMPP_TEST_PYTHON").unwrap_or_else(|_| {
        panic!(
            "LHMPP_TEST_PYTHON is not set: run the tests with `scripts/test`, which installs the \
             Python bag readers (scripts/setup-test-deps) and sets it"
        )
    })
}

/// Runs `tests/python/check_bag.py` (the `mcap_ros2` and `rosbags` readers) on the bag
/// directory `bag` against `expected` (topic → type, count, fields); panics with its output
/// unless it prints OK.
pub fn check_with_python_readers(bag: &std::path::Path, expected: &Value) {
    let python = python();
    let expected_path = bag.with_extension("expected.json");
    std::fs::write(
        &expected_path,
        serde_json::to_string_pretty(expected).unwrap(),
    )
    .unwrap();
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/check_bag.py");
    let output = std::process::Command::new(&python)
        .arg(&script)
        .arg(bag)
        .arg(&expected_path)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {python}: {e}"));
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    println!("{stdout}");
    assert!(
        output.status.success() && stdout.contains("OK"),
        "check_bag.py rejected {}:\n{stdout}\n{stderr}",
        bag.display()
    );
}

/// A synthetic person's bag in `dir` (`name`): `views` input views of 96 px, no held-out
/// views, no body shape; the source the bad-message bags are built from.
pub fn synthetic_person_bag(dir: &std::path::Path, name: &str, views: usize) -> std::path::PathBuf {
    let path = dir.join(name);
    let options = lhmpp::synth::SynthOptions {
        views,
        heldout: 0,
        size: 96,
        points: 4000,
        publish_shape: false,
        ..lhmpp::synth::SynthOptions::default()
    };
    lhmpp::synth::write_synthetic_bag(&path, &options).unwrap();
    path
}
