//! Synthetic bags: the committed fixtures are what `lhmpp synth` makes (deterministic), and
//! they hold everything replay and evaluation need.

use lhmpp::bag::BagReader;
use lhmpp::msgs::{BodyPose, CameraInfo, Image, TFMessage};
use lhmpp::synth::{write_synthetic_bag, SynthOptions, SynthPose};

fn demo_options() -> SynthOptions {
    SynthOptions {
        seed: 0,
        views: 4,
        heldout: 2,
        size: 256,
        publish_shape: true,
        ..SynthOptions::default()
    }
}

#[test]
fn regenerated_demo_bag_matches_the_committed_fixture() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("demo.mcap");
    write_synthetic_bag(&path, &demo_options()).unwrap();
    let fresh = BagReader::open(&path).unwrap();
    let committed =
        BagReader::open(concat!(env!("CARGO_MANIFEST_DIR"), "/bags/demo.mcap")).unwrap();
    // The MCAP summary section lists channels in hash order (mcap crate), so compare the
    // message streams: every topic, time and payload byte must agree.
    assert_eq!(fresh.messages().len(), committed.messages().len());
    for (a, b) in fresh.messages().iter().zip(committed.messages()) {
        assert_eq!((&a.topic, a.log_time), (&b.topic, b.log_time));
        assert!(a.data == b.data, "payload of {} differs", a.topic);
    }
}

#[test]
fn synthetic_bag_carries_views_calibration_poses_and_heldout_masks() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.mcap");
    let options = SynthOptions {
        seed: 5,
        views: 3,
        heldout: 2,
        size: 96,
        points: 8000,
        pose: SynthPose::Walk(3.0),
        ..SynthOptions::default()
    };
    write_synthetic_bag(&path, &options).unwrap();
    let bag = BagReader::open(&path).unwrap();
    let find = |topic: &str| {
        bag.messages()
            .iter()
            .find(|m| &*m.topic == topic)
            .unwrap_or_else(|| panic!("{topic} missing"))
    };
    let tf: TFMessage = bag.decode(find("/tf_static")).unwrap();
    assert_eq!(tf.transforms.len(), 5);
    let pose: BodyPose = bag.decode(find("/lhmpp/body_pose")).unwrap();
    assert!(!pose.bone_names.is_empty());
    for cam in ["cam0", "cam1", "cam2", "heldout0", "heldout1"] {
        let image: Image = bag.decode(find(&format!("/{cam}/image_raw"))).unwrap();
        assert_eq!(
            (image.width, image.height, image.encoding.as_str()),
            (96, 96, "rgb8")
        );
        let info: CameraInfo = bag.decode(find(&format!("/{cam}/camera_info"))).unwrap();
        assert!(
            info.k[0] > 0.0 && (info.k[2] - 47.5).abs() < 1e-9,
            "K = {:?}",
            info.k
        );
        let mask: Image = bag.decode(find(&format!("/{cam}/mask"))).unwrap();
        let person = mask.data.iter().filter(|v| **v == 255).count();
        // The person covers a sizeable part of every view but not all of it.
        assert!(
            person > 96 * 96 / 20 && person < 96 * 96 / 2,
            "{cam}: {person} mask pixels"
        );
        // Where the mask is empty (alpha < 0.5) at least half of the white background shows.
        for (i, m) in mask.data.iter().enumerate() {
            if *m == 0 {
                let px = &image.data[3 * i..3 * i + 3];
                assert!(px.iter().all(|c| *c >= 127), "{cam}: pixel {i} = {px:?}");
            }
        }
    }
}
