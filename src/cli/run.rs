//! `lhmpp run`: run the node with a launch config (live ROS 2 topics, or a bag replay).

use super::config_source::ConfigSource;
use anyhow::{Context, Result};
use std::collections::BTreeMap;

/// Arguments of `lhmpp run`.
#[derive(clap::Args, Debug)]
pub struct RunArgs {
    #[command(flatten)]
    pub source: ConfigSource,
    /// Remap a topic: `--remap /camera/image_raw:=/cam0/image_raw` (repeatable).
    #[arg(long = "remap", value_name = "FROM:=TO")]
    pub remaps: Vec<String>,
    /// Token the live page (`outputs.web`) asks for: needed when it listens on an address
    /// other than loopback; open the page with `?token=TOKEN`.
    #[arg(long, value_name = "TOKEN")]
    pub web_token: Option<String>,
}

/// Loads the config, runs the node until it finishes or is stopped, prints a summary.
pub fn run(args: RunArgs) -> Result<()> {
    let config = args.source.load()?;
    let mut remap = BTreeMap::new();
    for r in &args.remaps {
        let (from, to) = r
            .split_once(":=")
            .with_context(|| format!("--remap `{r}`: expected FROM:=TO"))?;
        remap.insert(from.to_owned(), to.to_owned());
    }
    let summary = lhmpp::node::run::run_with(&config, remap, args.web_token.clone())?;
    let s = &summary.stats;
    let median = |v: &std::collections::VecDeque<f64>| {
        let mut v: Vec<f64> = v.iter().copied().collect();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
    };
    println!(
        "frames {} (cropped by mask {}, duplicates {}), rejected messages {}, rate-limited {}, views held {}, views encoded {}, \
         reconstructions {} (failed {}), revision {}, median latency {:.0} ms, \
         median reconstruction {:.0} ms, rendered frames {} (dropped {}, last {:.1} ms/frame), \
         wall {:.1} s",
        s.frames,
        s.masked,
        s.duplicates,
        summary.rejections,
        summary.rate_limited,
        summary.views_held,
        summary.encoded_views,
        s.reconstructions,
        s.failures,
        summary.revision,
        median(&s.latencies_ms),
        median(&s.run_times_ms),
        s.rendered_frames,
        s.frames_dropped,
        s.last_render_ms,
        summary.wall.as_secs_f64()
    );
    if s.refinements > 0 {
        println!(
            "refinements {} (kept {}, {} steps in all; refine.enabled)",
            s.refinements, s.refinements_kept, s.refine_steps
        );
    }
    if config.replay.bag.is_empty() {
        println!(
            "inputs: received {}, queue dropped {}, rate-limited {}; queue wait {}; frame age {}; \
             latency {}",
            summary.received,
            summary.queue_dropped,
            summary.rate_limited,
            s.queue_waits,
            s.frame_ages,
            s.latencies
        );
    }
    if s.perceived > 0 || summary.perception_dropped > 0 {
        println!(
            "perception: frames {} (cropped by its mask {}, read inside a topic's mask {}, \
             nobody found {}, dropped for newer {}), time per frame {}, camera poses {} (frame \
             stamp → pose published {})",
            s.perceived,
            s.perception_masked,
            s.read_in_given_masks,
            s.no_person,
            summary.perception_dropped,
            s.perception_times,
            s.camera_poses,
            s.pose_ages
        );
    }
    if s.views_of_another > 0 {
        println!(
            "one person: {} views dropped when a camera took up someone else",
            s.views_of_another
        );
    }
    if config.tracking.enabled {
        let t = summary.tracking.unwrap_or_default();
        println!(
            "persons: {} tracked at the end, {} started, {} released (tracker: {} forgotten \
             after tracking.forget_after, {} dropped past tracking.max_persons)",
            summary.persons.len(),
            s.persons_started,
            s.persons_released,
            t.persons_forgotten,
            t.persons_dropped
        );
        for p in &summary.persons {
            match p.reconstructed_here {
                true => println!(
                    "  {}: views held {}, avatar revision {}",
                    p.id, p.views, p.revision
                ),
                false => println!(
                    "  {}: tracked, reconstructed by another cluster member",
                    p.id
                ),
            }
        }
    }
    if let Some(salvage) = summary.bag.as_ref().filter(|s| !s.is_complete()) {
        println!("bag {}: {salvage}", config.replay.bag);
    }
    if let Some(files) = &summary.files {
        println!("outputs in {}/: {files}", config.outputs.dir);
    }
    Ok(())
}
