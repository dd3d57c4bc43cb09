//! `lhmpp bench`: benchmarks that print tables (one file per subject).

use clap::{Args, Subcommand};

mod compact;
mod cpu_peer;
mod model;
mod perception;
mod points;
mod render;
mod transport;

/// Arguments of `lhmpp bench`.
#[derive(Args, Debug)]
pub struct BenchArgs {
    #[command(subcommand)]
    command: BenchCommand,
}

#[derive(Subcommand, Debug)]
enum BenchCommand {
    /// CPU splatting (frames per second) and Gaussian LBS posing.
    Render(render::RenderBenchArgs),
    /// Time image encoding, PIT fusion, the Gaussian head, end to end, and an incremental update.
    Model(model::ModelBenchArgs),
    /// Time each point-backbone stage (embed, pooling levels, unpooling levels).
    Points(points::PointsBenchArgs),
    /// Publish→receive latency (p50/p99) and throughput of a 160K-Gaussian avatar and a
    /// 1920×1080 RGBA frame over iceoryx2, plus the shared memory each service reserves.
    Transport(transport::TransportArgs),
    /// The pieces of the PyTorch CPU peer benchmark (matmul 1024³, DINOv2 ViT-S/B, SD3 joint
    /// attention) timed with our code; `scripts/bench-cpu-peer` runs both side by side.
    CpuPeer(cpu_peer::CpuPeerArgs),
    /// The BlazePose networks (person detector, lite/full/heavy landmarks) on our CPU kernels
    /// at 1 and 2 threads, with an optional per-step profile; `scripts/perception/bench` runs
    /// it next to LiteRT/XNNPACK.
    Perception(perception::PerceptionBenchArgs),
    /// The compact avatar (SPZ + skin) against GaussianAvatar for avatar PLYs the node wrote:
    /// message sizes and ratio, encode/decode times, round-trip render PSNR.
    Compact(compact::CompactBenchArgs),
}

/// Runs `lhmpp bench`.
pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    match args.command {
        BenchCommand::Render(a) => render::run(a),
        BenchCommand::Model(a) => model::run(a),
        BenchCommand::Points(a) => points::run(a),
        BenchCommand::Transport(a) => transport::run(a),
        BenchCommand::CpuPeer(a) => cpu_peer::run(a),
        BenchCommand::Perception(a) => perception::run(a),
        BenchCommand::Compact(a) => compact::run(a),
    }
}
