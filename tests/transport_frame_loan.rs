//! Frames written straight into loaned shared-memory samples (`ShmPublisher::loan_frame`) reach
//! subscribers, in another process and in this one, with the checksum of what was written; the
//! node's shared-memory output converts renders through the same path.

mod shm_echo_support;

use shm_echo_support::{field, next_line, unique_person};
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

use lhmpp::node::outputs::{Publisher, ShmOutputs};
use lhmpp::node::pipeline::RenderedFrame;
use lhmpp::splat::RenderOutput;
use lhmpp::transport::layout::Encoder;
use lhmpp::transport::{
    FrameShape, FrameView, PayloadBody, ShmNode, ShmOptions, ShmSubscriber, Stamp,
};

/// Pixels, alpha and depth of frame `revision` (size varies with the revision).
struct Expected {
    width: u32,
    height: u32,
    pixels: Vec<u8>,
    alpha: Vec<f32>,
    depth: Vec<f32>,
}

impl Expected {
    fn new(revision: u64) -> Self {
        let (width, height) = (40 + revision as u32, 30);
        let n = (width * height) as usize;
        Self {
            width,
            height,
            pixels: (0..n * 4)
                .map(|i| (i as u64 * 7 + revision) as u8)
                .collect(),
            alpha: (0..n).map(|i| (i % 11) as f32 / 10.0).collect(),
            depth: (0..n).map(|i| 1.0 + i as f32 / revision as f32).collect(),
        }
    }

    fn body(&self) -> PayloadBody<'_> {
        PayloadBody::Frame(FrameView {
            width: self.width,
            height: self.height,
            channels: 4,
            pixels: &self.pixels,
            alpha: Some(&self.alpha),
            depth: Some(&self.depth),
        })
    }

    fn shape(&self) -> FrameShape {
        FrameShape {
            width: self.width,
            height: self.height,
            channels: 4,
            alpha: true,
            depth: true,
        }
    }
}

#[test]
fn echo_process_receives_loaned_frames_with_the_checksum_written() {
    let person = unique_person("loanecho");
    let mut child = Command::new(env!("CARGO_BIN_EXE_lhmpp"))
        .args(["shm-echo", "--person", &person, "--camera", "cam0"])
        .args(["--timeout", "120"])
        .stdout(Stdio::piped())
        .spawn()
        .expect("spawn lhmpp shm-echo");
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    assert!(next_line(&mut lines).starts_with("ready "));
    let options = ShmOptions {
        initial_capacity: 4096,
        ..ShmOptions::default()
    };
    let node = ShmNode::new(&format!("{person}-test"), options).unwrap();
    let frames = node.frame_publisher(&person, "cam0").unwrap();
    for revision in 1..=50u64 {
        let expected = Expected::new(revision);
        let mut loan = frames
            .loan_frame(Stamp::now(revision), expected.shape())
            .unwrap();
        let arrays = loan.arrays_mut();
        arrays.pixels.copy_from_slice(&expected.pixels);
        arrays.alpha.unwrap().copy_from_slice(&expected.alpha);
        arrays.depth.unwrap().copy_from_slice(&expected.depth);
        assert_eq!(loan.send().unwrap(), 1);
        let line = next_line(&mut lines);
        let prefix = format!(
            "frame person={person} rev={revision} {}x{}x4 alpha=1 depth=1 ",
            expected.width, expected.height
        );
        assert!(line.starts_with(&prefix), "{line}");
        assert_eq!(
            field(&line, "checksum"),
            format!("{:#018x}", expected.body().checksum())
        );
    }
    child.kill().unwrap();
    child.wait().unwrap();
}

#[test]
fn loaned_frame_is_byte_identical_to_the_encoded_one() {
    let person = unique_person("loanbytes");
    let node = ShmNode::new(&format!("{person}-n"), ShmOptions::default()).unwrap();
    let publisher = node.frame_publisher(&person, "cam0").unwrap();
    let mut subscriber = node.subscriber(&person, &["cam0"]).unwrap();
    let expected = Expected::new(3);
    let stamp = Stamp {
        revision: 3,
        timestamp_ns: 1234,
    };
    let mut loan = publisher.loan_frame(stamp, expected.shape()).unwrap();
    let arrays = loan.arrays_mut();
    arrays.pixels.copy_from_slice(&expected.pixels);
    arrays.alpha.unwrap().copy_from_slice(&expected.alpha);
    arrays.depth.unwrap().copy_from_slice(&expected.depth);
    loan.send().unwrap();
    let sample = receive(&mut subscriber);
    let person_id = lhmpp::transport::layout::PersonId::new(&person).unwrap();
    let encoded = Encoder::new(&person_id, stamp, &expected.body())
        .unwrap()
        .to_vec();
    // Same header, arrays and zeroed padding as `publish` would have written.
    assert_eq!(&sample.bytes()[..encoded.len()], &encoded[..]);
}

#[test]
fn a_frame_loan_on_an_avatar_stream_is_refused() {
    let person = unique_person("loankind");
    let node = ShmNode::new(&format!("{person}-n"), ShmOptions::default()).unwrap();
    let avatars = node.avatar_publisher(&person).unwrap();
    let err = avatars
        .loan_frame(Stamp::now(1), FrameShape::rgb8(4, 4))
        .unwrap_err();
    assert!(err.to_string().contains("avatar"), "{err}");
}

fn receive(subscriber: &mut ShmSubscriber) -> lhmpp::transport::ShmSample {
    for _ in 0..50 {
        if let Some(sample) = subscriber.try_receive().unwrap() {
            return sample;
        }
        subscriber.wait(Duration::from_millis(100)).unwrap();
    }
    panic!("no sample within 5 s");
}

/// A render with a colour ramp that leaves [0, 1] on both sides (clamped when converted).
fn ramp_render(width: u32, height: u32) -> RenderOutput {
    let n = (width * height) as usize;
    RenderOutput {
        width,
        height,
        rgb: (0..n * 3)
            .map(|i| i as f32 / (n * 3) as f32 * 1.4 - 0.2)
            .collect(),
        alpha: vec![1.0; n],
        depth: vec![2.0; n],
        feature_channels: 0,
        features: Vec::new(),
    }
}

#[test]
fn node_shm_output_sends_renders_as_their_rgb8_pixels() {
    let person = unique_person("loannode");
    let outputs = ShmOutputs::new(&person, 2, 4).unwrap();
    let node = ShmNode::new(&format!("{person}-sub"), ShmOptions::default()).unwrap();
    let mut subscriber = node.subscriber(&person, &["cam1"]).unwrap();
    let frame = RenderedFrame::new(ramp_render(64, 48));
    outputs.frame(&person, 1, &frame, 42);
    let sample = receive(&mut subscriber);
    let decoded = sample.decode().unwrap();
    assert_eq!(decoded.stamp.revision, 42);
    let PayloadBody::Frame(view) = decoded.body else {
        panic!("not a frame");
    };
    assert_eq!((view.width, view.height, view.channels), (64, 48, 3));
    // The bytes written straight from the floats equal the rgb8 image ROS 2 and PNG get.
    assert_eq!(view.pixels, frame.rgb8().as_raw().as_slice());
    assert!(view.pixels.contains(&0) && view.pixels.contains(&255));
}
