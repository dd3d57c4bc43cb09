//! `lhmpp synth`: render a seeded synthetic person into a rosbag2-layout MCAP bag.

use anyhow::{Context, Result};
use lhmpp::synth::crowd::{write_crowd_bag, CrowdOptions};
use lhmpp::synth::{write_bag, CameraMode, Realism, SynthOptions, SynthPose};
use std::path::PathBuf;

/// Arguments of `lhmpp synth`.
#[derive(clap::Args, Debug)]
pub struct SynthArgs {
    /// Seed of the person (shape, outfit), pose and cameras.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Input camera views (with `--camera moving`: frames of the moving camera).
    #[arg(long, default_value_t = 4)]
    views: usize,
    /// `ring`: fixed cameras cam0.. around the person; `moving`: one camera cam0 orbiting
    /// the person over the frames, its pose on /tf per frame.
    #[arg(long, value_enum, default_value_t = CameraArg::Ring)]
    camera: CameraArg,
    /// Held-out views (for `lhmpp eval`).
    #[arg(long, default_value_t = 2)]
    heldout: usize,
    /// Image side in pixels.
    #[arg(long, default_value_t = 256)]
    size: u32,
    /// Gaussians on the ground-truth body surface.
    #[arg(long, default_value_t = 30_000)]
    points: usize,
    /// Walk-cycle frame of the pose, `rest` for the canonical pose, or `random` for seeded
    /// random joint rotations within limits.
    #[arg(long, default_value = "8")]
    pose: String,
    /// Also write the ground-truth body shape (lhmpp_msgs/BodyShape, `makehuman-cc0`
    /// [height_scale, girth_scale]) on /lhmpp/body_shape.
    #[arg(long)]
    publish_shape: bool,
    /// `plain`: the template painted by body part, unlit (the fixtures); `dressed`: garments,
    /// hair and shoes with procedural materials, input views lit with camera effects,
    /// held-out views unlit (albedo).
    #[arg(long, value_enum, default_value_t = RealismArg::Plain)]
    realism: RealismArg,
    /// Give the person's upper garments a back of another colour (plain: the shirt's back;
    /// dressed: a back panel on tops, one-pieces and coats), so that views from behind show
    /// what the front does not.
    #[arg(long)]
    contrasting_back: bool,
    /// Several people walking across a room on crossing paths instead of one person: dressed,
    /// lit, over a backdrop, seen by `--cameras` fixed cameras for `--frames` frames, with the
    /// true person id of every pixel on `<camera>/person_ids` (mono8, `k + 1` for
    /// `person_k`). The one-person flags (`--views`, `--heldout`, `--size`, `--pose`,
    /// `--camera`, `--publish-shape`, `--realism`) do not apply.
    #[arg(long)]
    people: Option<usize>,
    /// With `--people`: render only `person_K` of the scene (same paths, cameras and light),
    /// the single-person reference that `lhmpp eval-crowd` compares each avatar with.
    #[arg(long, value_name = "K")]
    only: Option<usize>,
    /// With `--people`: fixed cameras around the room.
    #[arg(long, default_value_t = 2)]
    cameras: usize,
    /// With `--people`: frames per camera.
    #[arg(long, default_value_t = 40)]
    frames: usize,
    /// With `--people`: frames per second.
    #[arg(long, default_value_t = 10.0)]
    fps: f32,
    /// With `--people`: the cameras' distance from the middle of the room in metres (default:
    /// as near as keeps everyone in view, about 3.8 m, where people stand 1/3 to 4/5 of the
    /// frame high). Farther cameras see smaller people: a 1.7 m person in the middle of the
    /// room is about 1.76 / DISTANCE of the frame's height (a tenth at 17.6 m, a quarter at
    /// 7 m), more or less as they walk 1.6 m nearer or farther.
    #[arg(long, value_parser = parse_distance)]
    camera_distance: Option<f32>,
    /// With `--people`: image width and height in pixels.
    #[arg(long, value_parser = parse_resolution, default_value = "640x480")]
    resolution: (u32, u32),
    /// Output bag (`.mcap` file, or a rosbag2 directory for any other path).
    #[arg(short, long)]
    output: PathBuf,
}

/// Parses a camera distance in metres (1..=100).
fn parse_distance(s: &str) -> Result<f32, String> {
    s.parse::<f32>()
        .ok()
        .filter(|d| (1.0..=100.0).contains(d))
        .ok_or_else(|| format!("`{s}`: expected metres in 1..=100, for example 12.5"))
}

/// Parses `WIDTHxHEIGHT`.
fn parse_resolution(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once('x')
        .ok_or_else(|| format!("`{s}`: expected WIDTHxHEIGHT, for example 640x480"))?;
    let side = |v: &str| {
        v.parse::<u32>()
            .ok()
            .filter(|n| (16..=4096).contains(n))
            .ok_or_else(|| format!("`{s}`: sides must be whole numbers in 16..=4096"))
    };
    Ok((side(w)?, side(h)?))
}

/// `--realism` values (`lhmpp synth`, `lhmpp synth-dataset`).
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum RealismArg {
    /// The template painted by body part, unlit.
    Plain,
    /// Dressed, lit people.
    Dressed,
}

impl From<RealismArg> for Realism {
    fn from(r: RealismArg) -> Self {
        match r {
            RealismArg::Plain => Realism::Plain,
            RealismArg::Dressed => Realism::Dressed,
        }
    }
}

/// `--camera` values.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
enum CameraArg {
    /// Fixed cameras on a ring.
    Ring,
    /// One moving camera.
    Moving,
}

/// Writes the bag and prints a one-line summary.
pub fn run(args: SynthArgs) -> Result<()> {
    if let Some(people) = args.people {
        return run_crowd(&args, people);
    }
    let pose = match args.pose.as_str() {
        "rest" => SynthPose::Rest,
        "random" => SynthPose::Random,
        f => SynthPose::Walk(f.parse::<f32>().with_context(|| {
            format!("--pose `{f}`: expected `rest`, `random` or a walk frame number")
        })?),
    };
    anyhow::ensure!(args.views >= 1, "--views must be at least 1");
    anyhow::ensure!(
        (16..=4096).contains(&args.size),
        "--size {} is not in 16..=4096",
        args.size
    );
    if let Some(dir) = args.output.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let options = SynthOptions {
        seed: args.seed,
        views: args.views,
        heldout: args.heldout,
        size: args.size,
        points: args.points,
        pose,
        camera: match args.camera {
            CameraArg::Ring => CameraMode::Ring,
            CameraArg::Moving => CameraMode::Moving,
        },
        publish_shape: args.publish_shape,
        contrasting_back: args.contrasting_back,
    };
    let summary = write_bag(&args.output, &options, args.realism.into())
        .with_context(|| format!("writing {}", args.output.display()))?;
    println!(
        "wrote {}: {} messages, {} bytes ({} input + {} held-out views, {}x{} px, seed {})",
        args.output.display(),
        summary.messages,
        summary.bytes,
        args.views,
        args.heldout,
        args.size,
        args.size,
        args.seed
    );
    Ok(())
}

/// `--people N`: the crowd scene.
fn run_crowd(args: &SynthArgs, people: usize) -> Result<()> {
    if let Some(dir) = args.output.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let (width, height) = args.resolution;
    let options = CrowdOptions {
        seed: args.seed,
        people,
        cameras: args.cameras,
        frames: args.frames,
        fps: args.fps,
        width,
        height,
        points: args.points,
        only: args.only,
        camera_distance: args.camera_distance,
    };
    let started = std::time::Instant::now();
    let mut last_report = started;
    let summary = write_crowd_bag(&args.output, &options, |done, total| {
        if last_report.elapsed().as_secs_f32() >= 5.0 || done == total {
            last_report = std::time::Instant::now();
            tracing::info!("rendered {done}/{total} images");
        }
    })
    .with_context(|| format!("writing {}", args.output.display()))?;
    println!(
        "wrote {}: {} messages, {} bytes ({} people, {} cameras × {} frames at {} fps, {}x{} px, \
         seed {}, {:.1} s)",
        args.output.display(),
        summary.messages,
        summary.bytes,
        people,
        args.cameras,
        args.frames,
        args.fps,
        width,
        height,
        args.seed,
        started.elapsed().as_secs_f32()
    );
    Ok(())
}
