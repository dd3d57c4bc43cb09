//! Cross-process: `lhmpp shm-echo` in a child process receives 100 avatars and 100 frames
//! published here, and prints the checksum of exactly what was sent.

mod shm_echo_support;

use shm_echo_support::{field, next_line, unique_person};
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};

use lhmpp::transport::{AvatarView, FrameView, PayloadBody, ShmNode, ShmOptions, Stamp};

/// An avatar whose size and values depend on `revision`.
struct Avatar {
    positions: Vec<[f32; 3]>,
    scales: Vec<[f32; 3]>,
    rotations: Vec<[f32; 4]>,
    opacities: Vec<f32>,
    colours: Vec<f32>,
    bones: Vec<[u16; 4]>,
    weights: Vec<[f32; 4]>,
}

impl Avatar {
    fn new(revision: u64) -> Self {
        let n = 50 + revision as usize * 37; // grows past the 4 KiB initial segment
        let v = |i: usize, k: usize| (i * 13 + k) as f32 + revision as f32 * 0.001;
        Self {
            positions: (0..n).map(|i| [v(i, 0), v(i, 1), v(i, 2)]).collect(),
            scales: (0..n).map(|i| [v(i, 3); 3]).collect(),
            rotations: (0..n).map(|i| [1.0, 0.0, 0.0, v(i, 4)]).collect(),
            opacities: (0..n).map(|i| v(i, 5)).collect(),
            colours: (0..n * 3).map(|i| v(i, 6)).collect(),
            bones: (0..n).map(|i| [i as u16, revision as u16, 0, 1]).collect(),
            weights: (0..n).map(|i| [v(i, 7), 0.0, 0.0, 0.0]).collect(),
        }
    }

    fn view(&self) -> AvatarView<'_> {
        AvatarView {
            positions: &self.positions,
            scales: &self.scales,
            rotations: &self.rotations,
            opacities: &self.opacities,
            sh_coeffs: 1,
            colours: &self.colours,
            bones: &self.bones,
            weights: &self.weights,
            rgb_latent: false,
        }
    }
}

#[test]
fn echo_process_prints_the_checksum_of_every_avatar_and_frame_sent() {
    let person = unique_person("echo");
    let mut child = Command::new(env!("CARGO_BIN_EXE_lhmpp"))
        .args(["shm-echo", "--person", &person, "--camera", "cam0"])
        .args(["--count", "100", "--timeout", "120"])
        .stdout(Stdio::piped())
        .spawn()
        .expect("spawn lhmpp shm-echo");
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let ready = next_line(&mut lines);
    assert_eq!(
        ready,
        format!("ready lhmpp/{person}/avatar lhmpp/{person}/frame/cam0")
    );

    let options = ShmOptions {
        initial_capacity: 4096,
        ..ShmOptions::default()
    };
    let node = ShmNode::new(&format!("{person}-test"), options).unwrap();
    let avatars = node.avatar_publisher(&person).unwrap();
    let frames = node.frame_publisher(&person, "cam0").unwrap();

    for revision in 1..=100u64 {
        // Lock-step: the next sample goes out once the echo printed the previous one, so
        // the latest-wins queues never drop anything here.
        let avatar = Avatar::new(revision);
        let body = PayloadBody::Avatar(avatar.view());
        assert_eq!(avatars.publish(Stamp::now(revision), &body).unwrap(), 1);
        let line = next_line(&mut lines);
        assert!(line.starts_with("avatar "), "{line}");
        assert_eq!(field(&line, "person"), person);
        assert_eq!(field(&line, "rev"), revision.to_string());
        assert_eq!(
            field(&line, "gaussians"),
            avatar.positions.len().to_string()
        );
        assert_eq!(
            field(&line, "checksum"),
            format!("{:#018x}", body.checksum())
        );

        let (w, h) = (32 + revision as u32, 24);
        let pixels: Vec<u8> = (0..w * h * 4)
            .map(|i| (i as u64 * revision % 256) as u8)
            .collect();
        let depth: Vec<f32> = (0..w * h).map(|i| i as f32 / revision as f32).collect();
        let frame = PayloadBody::Frame(FrameView {
            width: w,
            height: h,
            channels: 4,
            pixels: &pixels,
            alpha: None,
            depth: Some(&depth),
        });
        assert_eq!(frames.publish(Stamp::now(revision), &frame).unwrap(), 1);
        let line = next_line(&mut lines);
        assert!(
            line.starts_with(&format!(
                "frame person={person} rev={revision} {w}x{h}x4 alpha=0 depth=1 "
            )),
            "{line}"
        );
        assert_eq!(
            field(&line, "checksum"),
            format!("{:#018x}", frame.checksum())
        );
        let latency: f64 = field(&line, "latency_us").parse().unwrap();
        assert!(latency >= 0.0);
    }
    let status = child.wait().unwrap();
    assert!(status.success(), "shm-echo exited with {status}");
}

/// Kills a child process when dropped (a failed assertion leaves no process behind).
struct KillOnDrop(std::process::Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// The node's shared-memory side across a crash: `lhmpp run` on the demo bag is killed with
/// SIGKILL while it publishes, and started again. The second node opens its publishers on the
/// services the dead one left behind (iceoryx2 cleans the dead node's resources), and the
/// `shm-echo` subscriber, which stayed up, receives the new node's avatar and frames, whose
/// sequence numbers (render stamps) go on increasing past the dead node's.
#[test]
fn node_killed_and_restarted_publishes_again_to_a_subscriber_that_stayed() {
    let person = unique_person("restart");
    let mut echo = KillOnDrop(
        Command::new(env!("CARGO_BIN_EXE_lhmpp"))
            .args(["shm-echo", "--person", &person, "--camera", "cam0"])
            .args(["--timeout", "120"])
            .stdout(Stdio::piped())
            .spawn()
            .expect("spawn lhmpp shm-echo"),
    );
    let mut lines = BufReader::new(echo.0.stdout.take().unwrap()).lines();
    assert!(next_line(&mut lines).starts_with("ready "));
    // The two nodes render at different sizes, so the frames tell which node sent them.
    let start_node = |side: u32| {
        KillOnDrop(
            Command::new(env!("CARGO_BIN_EXE_lhmpp"))
                .args(["--log", "warn", "run", "--config"])
                .arg(concat!(
                    env!("CARGO_MANIFEST_DIR"),
                    "/launch_configs/demo.yaml"
                ))
                .args(["--set", &format!("person_id={person}")])
                .args(["--set", "outputs.shm=true", "--set", "outputs.ros=false"])
                // The walk cycle animates the frames after the replay, so that their stamps
                // (those of the poses they show) keep increasing.
                .args(["--set", "inputs.pose_source=walk"])
                .args([
                    "--set",
                    "outputs.dir=''",
                    "--set",
                    "replay.exit_when_done=false",
                ])
                .args(["--set", &format!("outputs.render_size={side}")])
                .stdout(Stdio::null())
                .spawn()
                .expect("spawn lhmpp run"),
        )
    };
    // Reads echo lines until an avatar and then `frames` frames of `side`² pixels have
    // arrived; returns the avatar's revision and the frames' sequence numbers.
    let mut avatar_then_frames = |side: u32, frames: usize| {
        let mut revision = None;
        let mut sequence = Vec::new();
        while sequence.len() < frames {
            let line = next_line(&mut lines);
            assert_eq!(field(&line, "person"), person, "{line}");
            if line.starts_with("avatar ") {
                revision = Some(field(&line, "rev").parse::<u64>().unwrap());
            } else if revision.is_some() && line.contains(&format!(" {side}x{side}x3 ")) {
                sequence.push(field(&line, "rev").parse::<u64>().unwrap());
            }
        }
        (revision.unwrap(), sequence)
    };

    let first = start_node(64);
    let (revision, before) = avatar_then_frames(64, 3);
    assert_eq!(revision, 1, "the first node's first avatar");
    drop(first);
    let _second = start_node(48);
    let (revision, after) = avatar_then_frames(48, 3);
    assert_eq!(revision, 1, "the restarted node's first avatar");
    assert!(
        after[0] > *before.last().unwrap(),
        "frame sequence {after:?} after the restart, {before:?} before"
    );
}
