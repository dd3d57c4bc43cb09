//! Command-line interface: one file per subcommand group; this file lists them and dispatches.

use clap::{Parser, Subcommand};

mod avatar;
mod bag;
mod bench;
mod body;
mod config_cmd;
mod config_source;
mod eval;
mod eval_crowd;
mod eval_following;
mod eval_perception;
mod eval_photos;
mod eval_tracking;
mod fuzz;
mod loadgen;
mod model;
mod model_parity;
mod perceive;
mod perceive_people;
mod record;
mod render;
mod replay;
mod ros_args;
mod run;
mod shm_echo;
mod synth;
mod synth_dataset;
mod synth_motion;
mod udp_buffers;

/// LHM++ human-avatar reconstruction node for ROS 2.
///
/// See docs/status.md for what each subcommand does today and docs/commands.md for examples.
#[derive(Parser, Debug)]
#[command(name = "lhmpp", version, about, long_about)]
struct Cli {
    /// Log filter (tracing-subscriber syntax, e.g. `info` or `lhmpp=debug,rustdds=warn`);
    /// RUST_LOG wins. Default: lhmpp at info, its dependencies (RustDDS, ros2-client, ...)
    /// at error only.
    #[arg(long, global = true)]
    log: Option<String>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Run the node: live ROS 2 topics, or replay a bag (`run --config launch_configs/demo.yaml`).
    Run(run::RunArgs),
    /// Photos of one person in, an animatable avatar out: each photo masked by camera-only
    /// perception, avatar PLY, turntable and walk as PNG frames and GIFs
    /// (`avatar IMAGE... -o DIR`).
    Avatar(avatar::AvatarArgs),
    /// Validate a launch config (ROS 2 parameter file) and print the resolved parameters
    /// (`--markdown`: the parameter reference table).
    Config(config_cmd::ConfigArgs),
    /// Play a bag into the node as if live (`replay BAG [--rate X | --fast]`).
    Replay(replay::ReplayArgs),
    /// Render a seeded synthetic person into an MCAP bag with ground truth.
    Synth(synth::SynthArgs),
    /// Render a seeded synthetic person moving in front of fixed cameras, the true pose of each
    /// frame on /truth/body_pose (the camera-only pose demo).
    SynthMotion(synth_motion::SynthMotionArgs),
    /// Write training samples (synthetic people, preprocessed views, ground truth) as shards.
    SynthDataset(synth_dataset::SynthDatasetArgs),
    /// Score reconstructions on held-out views of synthetic bags (PSNR, SSIM, mask IoU).
    Eval(eval::EvalArgs),
    /// Score camera-only perception on synthetic bags: persons found, mask IoU, 2D landmark
    /// and 3D joint errors against the ground truth (`eval-perception BAG... --model lite`).
    EvalPerception(eval_perception::EvalPerceptionArgs),
    /// Score the avatar's colours on real photos: per body region, the median colour on the
    /// photo and on the avatar rendered in the photo's pose, compared with CIEDE2000
    /// (`eval-photos --manifest scripts/devset/photos.json`).
    EvalPhotos(eval_photos::EvalPhotosArgs),
    /// Score person tracking on crowd bags of `synth --people N`: persons found, id switches
    /// per 100 images, views given another person's id (`eval-tracking BAG...`).
    EvalTracking(eval_tracking::EvalTrackingArgs),
    /// Score each tracked person's avatar against their own true person on crowd scenes, beside
    /// the avatar of that person alone in the same scene (`eval-crowd --people 3 --seeds 2`).
    EvalCrowd(eval_crowd::EvalCrowdArgs),
    /// Inspect MCAP bags in the rosbag2 layout (`bag info BAG`), recover damaged ones
    /// (`bag recover IN -o OUT`).
    Bag(bag::BagArgs),
    /// Record the node's input and output topics into an MCAP bag (`record [--config FILE]`).
    Record(record::RecordArgs),
    /// Body template: summary, posed point clouds, asset conversion.
    Body(body::BodyArgs),
    /// Create seeded model checkpoints and print parameter counts.
    Model(model::ModelArgs),
    /// What camera-only perception sees in photos: person mask, landmarks, overlay and the
    /// derived BodyPose (`perceive IMAGE... -o DIR`).
    Perceive(perceive::PerceiveArgs),
    /// Pose a Gaussian avatar PLY and write PNG frames (`render AVATAR.ply --pose walk:0..60`).
    Render(render::RenderArgs),
    /// Print avatars and frames received over shared memory (iceoryx2), one line each.
    ShmEcho(shm_echo::ShmEchoArgs),
    /// Benchmarks that print tables (`bench render|model|points|transport|compact|latency`).
    Bench(bench::BenchArgs),
    /// Publish synthetic camera streams on loopback for load and soak tests, sampling the
    /// node's memory (`loadgen --seconds 600 --watch-pid PID`).
    Loadgen(loadgen::LoadgenArgs),
    /// Mutation-fuzz a parser of untrusted input for a while (`fuzz cdr --seconds 600`).
    Fuzz(fuzz::FuzzArgs),
}

/// An error that ends `lhmpp` with its own exit status, documented by its subcommand's
/// `--help`, instead of 1.
#[derive(Debug, thiserror::Error)]
#[error("{message}")]
pub struct ExitStatus {
    /// The exit status.
    pub code: u8,
    /// The error line.
    pub message: String,
}

/// The error and its causes on one line (`a: b: c`), leaving out a cause that the message
/// before it already ends with (errors that print their source, as most here do).
pub fn error_line(error: &anyhow::Error) -> String {
    let mut line = error.to_string();
    for cause in error.chain().skip(1) {
        let cause = cause.to_string();
        if !line.ends_with(&cause) {
            line.push_str(": ");
            line.push_str(&cause);
        }
    }
    line
}

/// The exit status for an error returned by [`main`]: an [`ExitStatus`]'s code, else 1.
pub fn exit_code(error: &anyhow::Error) -> u8 {
    error.downcast_ref::<ExitStatus>().map_or(1, |s| s.code)
}

/// Parses the command line, sets up logging and runs the subcommand.
pub fn main() -> anyhow::Result<()> {
    // `ros2 run lhmpp lhmpp --ros-args ...` (and `ros2 launch`): ROS 2 arguments become `run`'s.
    let cli = Cli::parse_from(ros_args::translate(std::env::args_os().collect())?);
    init_logging(cli.log.as_deref().unwrap_or(DEFAULT_LOG_FILTER));
    match cli.command {
        Command::Run(args) => run::run(args),
        Command::Avatar(args) => avatar::run(args),
        Command::Replay(args) => replay::run(args),
        Command::Eval(args) => eval::run(args),
        Command::EvalPerception(args) => eval_perception::run(args),
        Command::EvalPhotos(args) => eval_photos::run(args),
        Command::EvalTracking(args) => eval_tracking::run(args),
        Command::EvalCrowd(args) => eval_crowd::run(args),
        Command::Config(args) => config_cmd::run(args),
        Command::Body(args) => body::run(args),
        Command::Bag(args) => bag::run(args),
        Command::Record(args) => record::run(args),
        Command::Bench(args) => bench::run(args),
        Command::Fuzz(args) => fuzz::run(args),
        Command::Loadgen(args) => loadgen::run(args),
        Command::Perceive(args) => perceive::run(args),
        Command::Render(args) => render::run(args),
        Command::Synth(args) => synth::run(args),
        Command::SynthDataset(args) => synth_dataset::run(args),
        Command::SynthMotion(args) => synth_motion::run(args),
        Command::Model(args) => model::run(args),
        Command::ShmEcho(args) => shm_echo::run(args),
    }
}

/// The log filter without `--log` or `RUST_LOG`: the node's own messages at info, everything
/// else (RustDDS prints discovery chatter at info/warn, thousands of lines a minute with peers)
/// at error.
///
/// `rustdds::network::udp_listener` is off: its only error (RustDDS 0.15.1) is
/// "leave_multicast_group: AddrNotAvailable", logged when a multicast socket is dropped at
/// shutdown. RustDDS joins the group on each allowed interface but leaves it on the
/// unspecified one, which fails when DDS is restricted to interfaces other than the default
/// route's (`dds_interfaces: [127.0.0.1]`). Harmless: closing the socket right after drops the
/// membership. It cannot be fixed from outside RustDDS, so it is filtered here.
pub const DEFAULT_LOG_FILTER: &str = "error,lhmpp=info,rustdds::network::udp_listener=off";

fn init_logging(default: &str) {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .init();
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The `--config/--set` group each config-reading subcommand parsed, if it takes one.
    fn source(args: &[&str]) -> config_source::ConfigSource {
        let cli = Cli::try_parse_from(args).unwrap_or_else(|e| panic!("{args:?}: {e}"));
        match cli.command {
            Command::Run(a) => a.source,
            Command::Replay(a) => a.source,
            Command::Eval(a) => a.source,
            Command::Config(a) => a.source,
            Command::Record(a) => a.source,
            other => panic!("{other:?} takes no config"),
        }
    }

    #[test]
    fn every_command_that_reads_the_config_takes_config_and_set() {
        let tail = ["--config", "c.yaml", "--set", "model.seed=7"];
        for cmd in [
            &["lhmpp", "run"][..],
            &["lhmpp", "replay", "b.mcap"],
            &["lhmpp", "eval", "b.mcap"],
            &["lhmpp", "config"],
            &["lhmpp", "record"],
        ] {
            let args: Vec<&str> = cmd.iter().chain(&tail).copied().collect();
            let s = source(&args);
            assert_eq!(s.config.as_deref(), Some(std::path::Path::new("c.yaml")));
            assert_eq!(s.overrides, ["model.seed=7"], "{cmd:?}");
        }
    }

    #[test]
    fn the_set_overrides_reach_the_loaded_config() {
        let s = source(&["lhmpp", "record", "--set", "person_id=alice"]);
        assert_eq!(s.load().unwrap().person_id, "alice");
    }
}
