//! `lhmpp synth-motion`: a seeded synthetic person moving in front of fixed cameras, with the
//! true pose of every frame on `/truth/body_pose` (not the node's pose input) and true masks,
//! for the camera-only pose demo and tests.

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use lhmpp::synth::motion::{write_motion_bag, MotionOptions};
use std::path::PathBuf;

/// Arguments of `lhmpp synth-motion`.
#[derive(clap::Args, Debug)]
pub struct SynthMotionArgs {
    /// Seed of the person, outfit and motion.
    #[arg(long, default_value_t = 5)]
    seed: u64,
    /// Frames per camera.
    #[arg(long, default_value_t = 48)]
    frames: usize,
    /// Frames per second.
    #[arg(long, default_value_t = 12.0)]
    fps: f32,
    /// Seconds from one keyframe pose to the next.
    #[arg(long, default_value_t = 1.0)]
    key_interval: f32,
    /// Largest turn of the body about the vertical, degrees.
    #[arg(long, default_value_t = 35.0)]
    turn: f32,
    /// Fixed cameras on a ring (`cam0` in front of the person).
    #[arg(long, default_value_t = 1)]
    cameras: usize,
    /// Image width, pixels.
    #[arg(long, default_value_t = 320)]
    width: u32,
    /// Image height, pixels.
    #[arg(long, default_value_t = 240)]
    height: u32,
    /// Gaussians on the person.
    #[arg(long, default_value_t = 20_000)]
    points: usize,
    /// Output bag (`.mcap`).
    #[arg(short, long)]
    output: PathBuf,
}

/// Writes the bag and prints a one-line summary.
pub fn run(args: SynthMotionArgs) -> Result<()> {
    anyhow::ensure!(args.frames >= 1, "--frames must be at least 1");
    anyhow::ensure!(
        args.fps.is_finite() && args.fps > 0.0,
        "--fps must be positive"
    );
    anyhow::ensure!(
        (16..=4096).contains(&args.width) && (16..=4096).contains(&args.height),
        "--width and --height must be in 16..=4096"
    );
    if let Some(dir) = args.output.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let options = MotionOptions {
        seed: args.seed,
        frames: args.frames,
        fps: args.fps,
        key_interval_s: args.key_interval,
        turn_deg: args.turn,
        cameras: args.cameras,
        width: args.width,
        height: args.height,
        points: args.points,
    };
    let bar = ProgressBar::new(args.frames as u64);
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} frames {elapsed}")
            .expect("valid template"),
    );
    let messages = write_motion_bag(&args.output, &options, |done, _| {
        bar.set_position(done as u64)
    })
    .with_context(|| format!("writing {}", args.output.display()))?;
    bar.finish_and_clear();
    let bytes = std::fs::metadata(&args.output).map_or(0, |m| m.len());
    println!(
        "wrote {}: {messages} messages, {bytes} bytes ({} frames × {} camera(s), {}x{} px, seed {})",
        args.output.display(),
        args.frames,
        args.cameras,
        args.width,
        args.height,
        args.seed
    );
    Ok(())
}
