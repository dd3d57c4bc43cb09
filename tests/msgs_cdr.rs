//! CDR encoding of every message: round trips, the exact bytes of one Image, and clean errors
//! (never panics) on truncated or garbage buffers.

mod bag_support;

use bag_support::{avatar, transform_stamped};
use lhmpp::msgs::*;
use rand::{Rng, SeedableRng};
use std::fmt::Debug;

fn header(frame: &str) -> Header {
    Header::new(
        Time {
            sec: 1_700_000_000,
            nanosec: 123_456_789,
        },
        frame,
    )
}

fn round_trip<M: RosMessage + PartialEq + Debug>(msg: M) {
    let bytes = msg.encode_cdr();
    assert_eq!(&bytes[..4], &CDR_LE_HEADER, "{}", M::TYPE_NAME);
    assert_eq!(M::decode_cdr(&bytes).unwrap(), msg, "{}", M::TYPE_NAME);
    for cut in 0..bytes.len() {
        let err = M::decode_cdr(&bytes[..cut]);
        assert!(err.is_err(), "{} cut at {cut} decoded", M::TYPE_NAME);
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    for _ in 0..200 {
        let mut corrupt = bytes.clone();
        let at = rng.gen_range(4..corrupt.len());
        corrupt[at] = rng.gen();
        let _ = M::decode_cdr(&corrupt);
    }
}

#[test]
fn every_message_type_round_trips_and_rejects_every_truncation() {
    round_trip(Time {
        sec: -5,
        nanosec: 9,
    });
    round_trip(header("map"));
    round_trip(transform_stamped().transform.translation);
    round_trip(Point {
        x: 1.0,
        y: 2.0,
        z: 3.0,
    });
    round_trip(Quaternion::default());
    round_trip(lhmpp::msgs::GeometryPose::default());
    round_trip(transform_stamped().transform);
    round_trip(transform_stamped());
    round_trip(TFMessage {
        transforms: vec![transform_stamped(), transform_stamped()],
    });
    round_trip(RegionOfInterest {
        x_offset: 1,
        y_offset: 2,
        height: 3,
        width: 4,
        do_rectify: true,
    });
    round_trip(Image {
        header: header("cam"),
        height: 2,
        width: 3,
        encoding: "rgb8".into(),
        is_bigendian: 0,
        step: 9,
        data: (0..18).collect(),
    });
    round_trip(CompressedImage {
        header: header("cam"),
        format: "jpeg".into(),
        data: vec![0xFF, 0xD8, 0xFF, 0xD9],
    });
    round_trip(CameraInfo {
        header: header("cam"),
        height: 480,
        width: 640,
        distortion_model: "plumb_bob".into(),
        d: vec![0.1, -0.05, 0.0, 0.0, 0.01],
        k: [500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0],
        r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: [
            500.0, 0.0, 320.0, 0.0, 0.0, 500.0, 240.0, 0.0, 0.0, 0.0, 1.0, 0.0,
        ],
        binning_x: 1,
        binning_y: 1,
        roi: RegionOfInterest::default(),
    });
    round_trip(PointField {
        name: "x".into(),
        offset: 0,
        datatype: PointField::FLOAT32,
        count: 1,
    });
    round_trip(avatar().gaussians);
    round_trip(avatar());
    round_trip(BodyPose {
        header: header("world"),
        person_id: "person_7".into(),
        bone_names: vec!["spine".into(), "head".into()],
        rotations: vec![
            Quaternion::default(),
            transform_stamped().transform.rotation,
        ],
        root: transform_stamped().transform,
    });
    round_trip(ReconstructionStatus {
        header: header(""),
        person_id: "person_7".into(),
        views_held: 4,
        revision: 3,
        last_latency_ms: 812.5,
        last_render_ms: 37.5,
        state: ReconstructionStatus::STATE_RECONSTRUCTING,
        message: String::new(),
        rejected_reasons: vec!["cdr".into(), "image".into()],
        rejected_counts: vec![2, 4],
    });
}

#[test]
fn image_bytes_equal_a_hand_computed_cdr_buffer() {
    let image = Image {
        header: Header::new(Time { sec: 1, nanosec: 2 }, "cam"),
        height: 2,
        width: 3,
        encoding: "mono8".into(),
        is_bigendian: 0,
        step: 3,
        data: vec![1, 2, 3, 4, 5, 6],
    };
    #[rustfmt::skip]
    let expected: Vec<u8> = vec![
        0x00, 0x01, 0x00, 0x00,                 // encapsulation: CDR little endian
        1, 0, 0, 0,                             // header.stamp.sec
        2, 0, 0, 0,                             // header.stamp.nanosec
        4, 0, 0, 0, b'c', b'a', b'm', 0,        // header.frame_id, length with NUL
        2, 0, 0, 0,                             // height
        3, 0, 0, 0,                             // width
        6, 0, 0, 0, b'm', b'o', b'n', b'o', b'8', 0, // encoding
        0,                                      // is_bigendian
        0,                                      // padding to align step on 4
        3, 0, 0, 0,                             // step
        6, 0, 0, 0, 1, 2, 3, 4, 5, 6,           // data: length, bytes
    ];
    assert_eq!(image.encode_cdr(), expected);
}

#[test]
fn big_endian_buffers_decode_too() {
    #[rustfmt::skip]
    let bytes = [0x00, 0x00, 0x00, 0x00, 0, 0, 0, 1, 0, 0, 0, 2];
    assert_eq!(
        Time::decode_cdr(&bytes).unwrap(),
        Time { sec: 1, nanosec: 2 }
    );
}

#[test]
fn garbage_buffers_give_errors_that_name_the_type() {
    let cases: Vec<Vec<u8>> = vec![
        vec![],
        vec![0x00],
        vec![0x12, 0x34, 0x00, 0x00, 1, 2, 3, 4],
        // A string length of 4 GB in a 12-byte buffer.
        vec![
            0x00, 0x01, 0x00, 0x00, 0, 0, 0, 0, 0, 0, 0, 0, 0xFF, 0xFF, 0xFF, 0xFF,
        ],
    ];
    for bytes in cases {
        let err = Image::decode_cdr(&bytes).unwrap_err();
        assert!(err.to_string().contains("sensor_msgs/msg/Image"), "{err}");
    }
    let mut too_long = Time { sec: 1, nanosec: 2 }.encode_cdr();
    too_long.extend([0; 8]);
    assert!(matches!(
        Time::decode_cdr(&too_long),
        Err(MsgError::TrailingBytes { count: 8, .. })
    ));
}

#[test]
fn random_bytes_never_panic_the_decoders() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(42);
    for _ in 0..2000 {
        let len = rng.gen_range(0..256);
        let mut bytes: Vec<u8> = (0..len).map(|_| rng.gen()).collect();
        if bytes.len() >= 2 {
            bytes[0] = 0;
            bytes[1] = 1;
        }
        let _ = GaussianAvatar::decode_cdr(&bytes);
        let _ = CompactAvatar::decode_cdr(&bytes);
        let _ = CameraInfo::decode_cdr(&bytes);
        let _ = TFMessage::decode_cdr(&bytes);
        let _ = BodyPose::decode_cdr(&bytes);
        if let Ok(cloud) = PointCloud2::decode_cdr(&bytes) {
            let _ = GaussianCloud::from_point_cloud(&cloud, 0);
        }
    }
}

#[test]
fn type_names_follow_ros2_and_dds_conventions() {
    assert_eq!(Image::TYPE_NAME, "sensor_msgs/msg/Image");
    assert_eq!(Image::dds_type_name(), "sensor_msgs::msg::dds_::Image_");
    assert_eq!(
        GaussianAvatar::dds_type_name(),
        "lhmpp_msgs::msg::dds_::GaussianAvatar_"
    );
    assert!(Image::definition().contains("uint8[] data"));
}
