//! `lhmpp bench compact out/avatar_person_0.ply ...`: the compact avatar (SPZ + skin,
//! `lhmpp_msgs/CompactAvatar`) against the full one (`GaussianAvatar`) for avatars the node
//! wrote: both messages' CDR sizes and their ratio, the blobs' sizes, encode and decode times,
//! and the PSNR of the decoded avatar's renders against the original's (CPU rasteriser, white
//! background, 4 cameras around the body at rest and in two walk poses).

use anyhow::{bail, Context, Result};
use clap::Args;
use lhmpp::avatar::Avatar;
use lhmpp::body::{motion::walk_pose, BodyTemplate, Pose};
use lhmpp::compact::fidelity::{orbit_cameras, round_trip_psnr};
use lhmpp::compact::{CompactAvatar, CompactOptions};
use lhmpp::msgs::RosMessage;
use lhmpp::node::outputs::{avatar_message, compact_message, AvatarUpdate};
use lhmpp::splat::read_ply;
use std::path::PathBuf;
use std::time::Instant;

/// Options of `lhmpp bench compact`.
#[derive(Args, Debug)]
pub struct CompactBenchArgs {
    /// Avatar PLYs written by the node (`outputs.dir`), with their skinning.
    #[arg(required = true)]
    avatars: Vec<PathBuf>,
    /// Side of the square renders compared (pixels).
    #[arg(long, default_value_t = 512)]
    size: u32,
    /// Cameras around the body.
    #[arg(long, default_value_t = 4)]
    views: usize,
    /// Position fraction bits (default: the node's).
    #[arg(long)]
    fractional_bits: Option<u8>,
    /// Rotation bits kept, 1 to 9 (default: the node's).
    #[arg(long)]
    rotation_bits: Option<u8>,
    /// Skinning weight levels, 1 to 255 (default: the node's).
    #[arg(long)]
    weight_levels: Option<u8>,
}

/// One avatar's row.
struct Row {
    name: String,
    gaussians: usize,
    full_bytes: usize,
    compact_bytes: usize,
    gaussians_bytes: usize,
    skin_bytes: usize,
    spz_bytes: usize,
    encode_ms: f64,
    decode_ms: f64,
    psnr_min: f64,
    psnr_mean: f64,
}

/// Runs `lhmpp bench compact`.
pub fn run(args: CompactBenchArgs) -> Result<()> {
    let template = BodyTemplate::load_default().context("loading the embedded body template")?;
    let poses: Vec<Pose> = vec![Pose::identity(), walk_pose(8.0), walk_pose(20.0)];
    let defaults = CompactOptions::default();
    let options = CompactOptions {
        fractional_bits: args.fractional_bits.unwrap_or(defaults.fractional_bits),
        rotation_bits: args.rotation_bits.unwrap_or(defaults.rotation_bits),
        weight_levels: args.weight_levels.unwrap_or(defaults.weight_levels),
    };
    let mut rows = Vec::new();
    for path in &args.avatars {
        let ply = read_ply(path).with_context(|| format!("reading {}", path.display()))?;
        let Some(skin) = ply.skin else {
            bail!(
                "{}: no skinning weights (write it with the node)",
                path.display()
            );
        };
        let body_model = ply.body_model.unwrap_or_else(|| "makehuman-cc0".into());
        let avatar = Avatar::new(ply.gaussians, skin, body_model)
            .with_context(|| format!("binding {}", path.display()))?;
        let update = AvatarUpdate {
            person: "person_0",
            revision: 1,
            views_used: 4,
            stamp_ns: 0,
            avatar: &avatar,
            template: &template,
            shape_params: &[],
            rgb_display_ready: true,
            neural_renderer: "",
            compact: Default::default(),
        };
        let full = avatar_message(&update)?.encode_cdr();
        let started = Instant::now();
        let compact = CompactAvatar::encode_with(&avatar, options)?;
        let encode_ms = started.elapsed().as_secs_f64() * 1e3;
        let started = Instant::now();
        let decoded = compact.decode(&avatar.body_model)?;
        let decode_ms = started.elapsed().as_secs_f64() * 1e3;
        let mut message = compact_message(&update)?;
        message.gaussians = compact.gaussians.clone();
        message.skin = compact.skin.clone();
        let message = message.encode_cdr();
        let spz_bytes = compact.to_spz()?.len();
        let cameras = orbit_cameras(&avatar, args.views, args.size);
        let scores = round_trip_psnr(&avatar, &decoded, &template.skeleton, &poses, &cameras)
            .map_err(anyhow::Error::msg)?;
        rows.push(Row {
            name: path.display().to_string(),
            gaussians: avatar.canonical.len(),
            full_bytes: full.len(),
            compact_bytes: message.len(),
            gaussians_bytes: compact.gaussians.len(),
            skin_bytes: compact.skin.len(),
            spz_bytes,
            encode_ms,
            decode_ms,
            psnr_min: scores.iter().copied().fold(f64::INFINITY, f64::min),
            psnr_mean: scores.iter().sum::<f64>() / scores.len().max(1) as f64,
        });
    }
    println!(
        "| avatar | Gaussians | GaussianAvatar (B) | CompactAvatar (B) | ratio | Gaussians (B) | skin (B) \
         | as SPZ (B) | encode (ms) | decode (ms) | PSNR min (dB) | PSNR mean (dB) |"
    );
    println!(
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"
    );
    for r in rows {
        println!(
            "| {} | {} | {} | {} | {:.2}× | {} | {} | {} | {:.1} | {:.1} | {:.2} | {:.2} |",
            r.name,
            r.gaussians,
            r.full_bytes,
            r.compact_bytes,
            r.full_bytes as f64 / r.compact_bytes as f64,
            r.gaussians_bytes,
            r.skin_bytes,
            r.spz_bytes,
            r.encode_ms,
            r.decode_ms,
            r.psnr_min,
            r.psnr_mean
        );
    }
    println!(
        "({options:?}; PSNR over {} cameras × {} poses at {}², CPU rasteriser, white \
         background; `as SPZ`: the Gaussians blob as a standard SPZ file)",
        args.views,
        poses.len(),
        args.size
    );
    Ok(())
}
