//! `lhmpp eval-crowd`: each tracked person's avatar against their own true person, beside the
//! avatar the node makes when that person is alone in the same scene.
//!
//! For each seed it renders the crowd scene of `lhmpp synth --people N` (all people, then each
//! person alone), replays every bag through the node with `--config` (one avatar per tracked
//! person), and scores the avatars on held-out views of each true person
//! (`lhmpp::eval::crowd`): unlit, rest pose, a ring of cameras that no scene camera matches.
//! A person's crowd avatar is the one built mostly from their views: perception and the tracker
//! are replayed on the crowd bag with the node's settings, and the bag's true id maps say whose
//! views each id got. The check: each person's avatar within 1 dB of their
//! single-person one.

use anyhow::{bail, Context, Result};
use clap::Args;
use lhmpp::config::NodeConfig;
use lhmpp::eval::crowd::{
    own_avatars, pair_avatars, person_truth, score_avatar, AvatarScore, TruthView,
};
use lhmpp::eval::tracking::{covered_person, read_crowd, track_and_score};
use lhmpp::node::run::{run as run_node, RunSummary};
use lhmpp::perception::{PeopleFinder, PoseNetworks};
use lhmpp::splat::{read_ply, Gaussians};
use lhmpp::synth::crowd::{write_crowd_bag, Crowd, CrowdOptions};
use lhmpp::tracking::PersonTracks;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Options of `lhmpp eval-crowd`.
#[derive(Args, Debug)]
pub struct EvalCrowdArgs {
    /// People in each scene.
    #[arg(long, default_value_t = 3)]
    people: usize,
    /// Scene seeds, one scene each (comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "2")]
    seeds: Vec<u64>,
    /// Fixed room cameras.
    #[arg(long, default_value_t = 2)]
    cameras: usize,
    /// Frames per camera.
    #[arg(long, default_value_t = 30)]
    frames: usize,
    /// Held-out views per person (a ring around them).
    #[arg(long, default_value_t = 4)]
    heldout: usize,
    /// Held-out view size in pixels (square).
    #[arg(long, default_value_t = 256)]
    size: u32,
    /// The node's config; the bag, the camera topics and the output folder are set per run.
    #[arg(long, default_value = "launch_configs/people.yaml")]
    config: PathBuf,
    /// Extra config overrides (`key=value`), after the config file.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    overrides: Vec<String>,
    /// Where the bags and each run's outputs go (bags are reused when present).
    #[arg(long, default_value = "target/eval-crowd")]
    work: PathBuf,
    /// Print the rows as JSON too.
    #[arg(long)]
    json: bool,
}

/// One person of one scene: their avatar in the crowd and alone.
#[derive(Debug, serde::Serialize)]
struct PersonRow {
    seed: u64,
    person: usize,
    /// The tracked id whose avatar was built mostly from their views (`None`: no such avatar).
    crowd_id: Option<String>,
    /// Of that id's views, how many show this person, and how many it got in all.
    crowd_views: Option<(usize, usize)>,
    crowd: Option<AvatarScore>,
    /// Crowd − alone PSNR with avatars paired to persons by score alone (best PSNR first).
    best_pairing_delta: Option<f64>,
    /// Avatars made alone (one when tracking holds).
    alone_avatars: usize,
    alone: Option<AvatarScore>,
}

/// Runs the scenes and prints the table.
pub fn run(args: EvalCrowdArgs) -> Result<()> {
    if args.heldout == 0 || args.size < 32 {
        bail!("--heldout must be ≥ 1 and --size ≥ 32");
    }
    std::fs::create_dir_all(&args.work)
        .with_context(|| format!("creating {}", args.work.display()))?;
    println!("| seed | person | own crowd avatar | crowd PSNR / SSIM / IoU | alone PSNR / SSIM / IoU | crowd − alone dB |");
    println!("| ---: | ---: | --- | --- | --- | ---: |");
    let node = NodePerception::load(&args)?;
    let mut rows = Vec::new();
    for &seed in &args.seeds {
        let options = CrowdOptions {
            seed,
            people: args.people,
            cameras: args.cameras,
            frames: args.frames,
            ..CrowdOptions::default()
        };
        let crowd = Crowd::new(&options).context("making the crowd scene")?;
        let truths = crowd
            .people
            .iter()
            .map(|p| person_truth(p, args.heldout, args.size))
            .collect::<Result<Vec<_>, _>>()
            .context("rendering the held-out views")?;
        let (bag, together) = avatars_of(&args, &options)?;
        let scores: Vec<Vec<AvatarScore>> = together
            .iter()
            .map(|(_, g)| truths.iter().map(|t| score_avatar(g, t)).collect())
            .collect();
        let sightings = whose_views(&node, &bag)?;
        let ids: Vec<&str> = together.iter().map(|(id, _)| id.as_str()).collect();
        let own = own_avatars(&sightings, &ids, args.people);
        let paired = pair_avatars(&scores, args.people);
        let unpaired = together.len().saturating_sub(own.iter().flatten().count());
        for (k, truth) in truths.iter().enumerate() {
            let (_, alone_avatars) = avatars_of(
                &args,
                &CrowdOptions {
                    only: Some(k),
                    ..options.clone()
                },
            )?;
            let alone = best(&alone_avatars, truth);
            let row = PersonRow {
                seed,
                person: k,
                crowd_id: own[k].map(|a| together[a].0.clone()),
                crowd_views: own[k].map(|a| {
                    let counts = &sightings[&together[a].0];
                    (
                        counts.get(&k).copied().unwrap_or(0),
                        counts.values().sum::<usize>(),
                    )
                }),
                crowd: own[k].map(|a| scores[a][k]),
                best_pairing_delta: paired[k]
                    .zip(alone)
                    .map(|(a, alone)| scores[a][k].psnr - alone.psnr),
                alone_avatars: alone_avatars.len(),
                alone,
            };
            println!("{}", table_row(&row));
            rows.push(row);
        }
        if unpaired > 0 {
            println!("| {seed} | | {unpaired} avatar(s) of split ids or mixed views, nobody's own | | | |");
        }
    }
    let deltas: Vec<f64> = rows
        .iter()
        .filter_map(|r| Some(r.crowd?.psnr - r.alone?.psnr))
        .collect();
    if !deltas.is_empty() {
        let mean = deltas.iter().sum::<f64>() / deltas.len() as f64;
        let worst = deltas.iter().copied().fold(f64::INFINITY, f64::min);
        let paired: Vec<f64> = rows.iter().filter_map(|r| r.best_pairing_delta).collect();
        println!(
            "\ncrowd − alone over {} persons: mean {mean:+.2} dB, worst {worst:+.2} dB, \
             {} within 1 dB below; persons without an avatar of their own: {}",
            deltas.len(),
            deltas.iter().filter(|d| **d >= -1.0).count(),
            rows.iter().filter(|r| r.crowd.is_none()).count()
        );
        if !paired.is_empty() {
            println!(
                "with avatars paired to persons by score alone (best PSNR first): mean {:+.2} dB, \
                 worst {:+.2} dB",
                paired.iter().sum::<f64>() / paired.len() as f64,
                paired.iter().copied().fold(f64::INFINITY, f64::min)
            );
        }
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    }
    Ok(())
}

fn table_row(r: &PersonRow) -> String {
    let cell = |s: Option<AvatarScore>| {
        s.map_or("none".to_string(), |s| {
            format!("{:.2} / {:.3} / {:.3}", s.psnr, s.ssim, s.iou)
        })
    };
    let delta = match (r.crowd, r.alone) {
        (Some(c), Some(a)) => format!("{:+.2}", c.psnr - a.psnr),
        _ => String::new(),
    };
    let own = match (&r.crowd_id, r.crowd_views) {
        (Some(id), Some((theirs, all))) => format!("{id} ({theirs} of {all} views)"),
        _ => "none".to_string(),
    };
    format!(
        "| {} | person_{} | {own} | {} | {} ({} avatar{}) | {delta} |",
        r.seed,
        r.person,
        cell(r.crowd),
        cell(r.alone),
        r.alone_avatars,
        if r.alone_avatars == 1 { "" } else { "s" },
    )
}

/// The best-scoring of `avatars` against `truth`.
fn best(avatars: &[(String, Gaussians)], truth: &[TruthView]) -> Option<AvatarScore> {
    avatars
        .iter()
        .map(|(_, g)| score_avatar(g, truth))
        .max_by(|a, b| a.psnr.total_cmp(&b.psnr))
}

/// The node's perception and tracking, as `--config` and `--set` configure them, to replay on a
/// crowd bag.
struct NodePerception {
    config: NodeConfig,
    networks: Arc<PoseNetworks>,
}

impl NodePerception {
    fn load(args: &EvalCrowdArgs) -> Result<Self> {
        let config = NodeConfig::load(&args.config, &args.overrides)
            .with_context(|| format!("loading {}", args.config.display()))?;
        let networks = Arc::new(config.perception.networks()?);
        Ok(Self { config, networks })
    }
}

/// Whose views each tracked id got in the bag: perception and a fresh tracker with the node's
/// settings replayed on every image in order, as the node does in bag replay; `[id][person]`
/// counts the detections given `id` whose masks cover true `person`.
fn whose_views(
    node: &NodePerception,
    bag: &Path,
) -> Result<BTreeMap<String, BTreeMap<usize, usize>>> {
    let mut finder = PeopleFinder::new(node.networks.clone(), node.config.perception.people());
    let mut tracks = PersonTracks::new(node.config.tracking.tracker());
    let images = read_crowd(bag).with_context(|| format!("reading {}", bag.display()))?;
    let mut counts: BTreeMap<String, BTreeMap<usize, usize>> = BTreeMap::new();
    track_and_score(&images, &mut finder, &mut tracks, |_, img, people, ids| {
        for (person, a) in people.iter().zip(ids) {
            if let Some(k) = covered_person(&person.mask, &img.ids) {
                *counts
                    .entry(a.person_id.clone())
                    .or_default()
                    .entry(k)
                    .or_default() += 1;
            }
        }
    })
    .with_context(|| format!("tracking {}", bag.display()))?;
    Ok(counts)
}

/// Renders the scene of `options` into a bag under `--work` (kept for reruns), replays it
/// through the node and returns the bag's MCAP file and each tracked person's latest avatar
/// (id, canonical Gaussians).
fn avatars_of(
    args: &EvalCrowdArgs,
    options: &CrowdOptions,
) -> Result<(PathBuf, Vec<(String, Gaussians)>)> {
    let name = format!(
        "p{}s{}c{}f{}{}",
        options.people,
        options.seed,
        options.cameras,
        options.frames,
        options.only.map_or(String::new(), |k| format!("_only{k}"))
    );
    // A rosbag2 folder, written under `.partial/` and moved into `bags/` when complete.
    let bag = args.work.join("bags").join(&name);
    if !bag.join("metadata.yaml").is_file() {
        tracing::info!(bag = %bag.display(), "rendering the scene");
        let partial = args.work.join(".partial").join(&name);
        if partial.exists() {
            std::fs::remove_dir_all(&partial)
                .with_context(|| format!("clearing {}", partial.display()))?;
        }
        write_crowd_bag(&partial, options, |_, _| {})
            .with_context(|| format!("writing {}", partial.display()))?;
        if bag.exists() {
            std::fs::remove_dir_all(&bag).with_context(|| format!("clearing {}", bag.display()))?;
        }
        let bags = args.work.join("bags");
        std::fs::create_dir_all(&bags).with_context(|| format!("creating {}", bags.display()))?;
        std::fs::rename(&partial, &bag).with_context(|| format!("writing {}", bag.display()))?;
    }
    let out = args.work.join(&name);
    if out.exists() {
        std::fs::remove_dir_all(&out).with_context(|| format!("clearing {}", out.display()))?;
    }
    let topics = |suffix: &str| {
        let list: Vec<String> = (0..options.cameras)
            .map(|c| format!("/cam{c}/{suffix}"))
            .collect();
        format!("[{}]", list.join(","))
    };
    let mut overrides = args.overrides.clone();
    overrides.extend([
        format!("replay.bag={}", bag.display()),
        format!("outputs.dir={}", out.display()),
        "outputs.render_rate_hz=0".to_string(),
        format!("inputs.image_topics={}", topics("image_raw")),
        format!("inputs.camera_info_topics={}", topics("camera_info")),
    ]);
    let config = NodeConfig::load(&args.config, &overrides)
        .with_context(|| format!("loading {}", args.config.display()))?;
    tracing::info!(bag = %bag.display(), "replaying through the node");
    let summary: RunSummary = run_node(&config, BTreeMap::new())
        .with_context(|| format!("replaying {}", bag.display()))?;
    let file = bag.join(format!("{name}_0.mcap"));
    Ok((file, read_avatars(&out, &summary)?))
}

/// The latest avatar PLY of every person of `summary` that has one.
fn read_avatars(dir: &Path, summary: &RunSummary) -> Result<Vec<(String, Gaussians)>> {
    summary
        .persons
        .iter()
        .filter(|p| p.revision > 0)
        .map(|p| {
            let path = dir.join(format!("avatar_{}.ply", p.id));
            let ply = read_ply(&path).with_context(|| format!("reading {}", path.display()))?;
            Ok((p.id.clone(), ply.gaussians))
        })
        .collect()
}
