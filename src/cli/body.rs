//! `lhmpp body`: inspect the body template, write posed point clouds, rebuild the asset.

use anyhow::Context;
use clap::{Args, Subcommand};
use lhmpp::body::{convert, motion::PoseSpec, write_point_ply, BodyTemplate};
use std::path::{Path, PathBuf};

mod garments;

/// Body template: summary (no options), posed PLY (`-o`), or `convert`.
#[derive(Args, Debug)]
pub struct BodyArgs {
    #[command(subcommand)]
    command: Option<BodyCommand>,
    /// Sample this many anchor points (default: write the template vertices).
    #[arg(long)]
    points: Option<usize>,
    /// Seed of the anchor sampling.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Pose: `rest`, `tpose`, `walk:F` or `walk:A..B` (one file per frame).
    #[arg(long, default_value = "rest")]
    pose: String,
    /// Output PLY (coloured by body part); a frame range writes `<stem>_<frame>.ply`.
    #[arg(short, long)]
    output: Option<PathBuf>,
    /// Use a template file instead of the embedded MakeHuman asset.
    #[arg(long, conflicts_with = "smplx")]
    template: Option<PathBuf>,
    /// Use an SMPL-X model (`SMPLX_NEUTRAL.npz`) instead of the MakeHuman template.
    #[arg(long)]
    smplx: Option<PathBuf>,
    /// SMPL-X shape coefficients, comma-separated.
    #[arg(
        long,
        value_delimiter = ',',
        allow_negative_numbers = true,
        requires = "smplx"
    )]
    betas: Vec<f32>,
}

#[derive(Subcommand, Debug)]
enum BodyCommand {
    /// Rebuild the template asset (and walk.json, tpose.json beside it) from MakeHuman files.
    Convert {
        /// MakeHuman source folder (base.obj, rig.default.json, weights.default.json, ...).
        #[arg(long)]
        from: PathBuf,
        /// Output safetensors file.
        #[arg(short, long, default_value = "assets/body/makehuman.safetensors")]
        output: PathBuf,
    },
    /// Rebuild the garment library (assets/body/garments.safetensors) from the CC0 MakeHuman
    /// clothes and hair, fitted to the embedded template, and print its fit report.
    Garments(garments::ConvertArgs),
    /// Fit report of the garment library: distance to the skin, coverage, and how much of
    /// each garment the node's anchors reach; optionally a picture of dressed people.
    GarmentReport(garments::ReportArgs),
}

/// Runs `lhmpp body`.
pub fn run(args: BodyArgs) -> anyhow::Result<()> {
    match &args.command {
        Some(BodyCommand::Garments(a)) => return garments::convert(a),
        Some(BodyCommand::GarmentReport(a)) => return garments::report(a),
        _ => {}
    }
    if let Some(BodyCommand::Convert { from, output }) = &args.command {
        let assets = convert::convert_makehuman(from)
            .with_context(|| format!("converting {}", from.display()))?;
        convert::write_assets(&assets, output)?;
        println!(
            "wrote {} ({} vertices, {} triangles, {} bones) and walk.json, tpose.json beside it",
            output.display(),
            assets.template.vertices.len(),
            assets.template.triangles.len(),
            assets.template.skeleton.len()
        );
        return Ok(());
    }
    let template = match (&args.smplx, &args.template) {
        (Some(path), _) => lhmpp::body::load_smplx(path, &args.betas)?,
        (None, Some(path)) => BodyTemplate::load(path)?,
        (None, None) => BodyTemplate::load_default()?,
    };
    match &args.output {
        None => print_summary(&template),
        Some(out) => write_posed(&template, &args, out),
    }
}

fn print_summary(t: &BodyTemplate) -> anyhow::Result<()> {
    println!("vertices:       {}", t.vertices.len());
    println!("triangles:      {}", t.triangles.len());
    println!("bones:          {}", t.skeleton.len());
    println!("height:         {:.3} m", t.height());
    println!("canonical pose: {}", t.canonical_pose);
    println!(
        "frame:          metres, +Y up, facing +Z, y = 0 at the soles, centred between the feet"
    );
    println!("parts (vertices):");
    for (name, count) in t.part_names.iter().zip(t.part_counts()) {
        println!("  {name:<14} {count}");
    }
    Ok(())
}

fn write_posed(t: &BodyTemplate, args: &BodyArgs, out: &Path) -> anyhow::Result<()> {
    let spec = PoseSpec::parse(&args.pose)?;
    let (points, skin, labels) = match args.points {
        Some(n) => {
            let a = t.sample_anchors(n, args.seed);
            (a.positions, a.skin, a.part_labels)
        }
        None => (t.vertices.clone(), t.skin.clone(), t.part_labels.clone()),
    };
    let colors: Vec<[u8; 3]> = labels.iter().map(|&l| part_color(l)).collect();
    let first = match spec {
        PoseSpec::Walk { start, .. } => start,
        _ => 0,
    };
    let poses = spec.poses();
    for (k, pose) in poses.iter().enumerate() {
        let m = t.skeleton.try_skinning_matrices(pose)?;
        let posed = skin.skin_points(&points, &m);
        let path = if poses.len() == 1 {
            out.to_path_buf()
        } else {
            let stem = out.file_stem().and_then(|s| s.to_str()).unwrap_or("body");
            out.with_file_name(format!("{stem}_{:04}.ply", first as usize + k))
        };
        write_point_ply(&path, &posed, &colors)?;
        println!("wrote {} ({} points)", path.display(), posed.len());
    }
    Ok(())
}

/// A distinct colour per part index.
fn part_color(label: u8) -> [u8; 3] {
    const PALETTE: [[u8; 3]; 8] = [
        [200, 200, 200],
        [90, 86, 255],
        [255, 29, 35],
        [7, 200, 0],
        [255, 140, 0],
        [16, 200, 186],
        [220, 220, 16],
        [255, 0, 245],
    ];
    PALETTE[label as usize % PALETTE.len()]
}
