//! `lhmpp eval-tracking --one-person BAG...`: the node's one-person perception (a
//! [`PersonTracker`] per camera, frames in time order) with each detector it can start from,
//! scored on crowd bags (`lhmpp synth --people N`): frames in which the person was found
//! against frames in which someone is visible, by the height of the tallest person in view;
//! switches between people; time per frame, followed and searching. With `--no-truth`, bags
//! of real video: finds, box jumps and times per camera. Measures in
//! `lhmpp::eval::following`.

use super::eval_tracking::EvalTrackingArgs;
use super::perceive::DetectorArg;
use anyhow::{Context, Result};
use lhmpp::eval::following::{
    camera_following, follow_frames, quantile, score_following, CameraFollowing, FollowedFrame,
    FollowingScore, FrameTimes, HEIGHT_CLASSES,
};
use lhmpp::eval::tracking::{read_camera_bag, read_crowd, CrowdImage};
use lhmpp::perception::overlay::draw_overlay;
use lhmpp::perception::{PeopleConfig, Perceived, PersonTracker, PoseNetworks, TrackerConfig};
use std::path::Path;
use std::sync::Arc;

/// Mask threshold and feather, as the node's defaults.
const MASK: (f32, f32) = (0.5, 0.1);

/// One detector's run over one bag.
struct Run {
    detector: DetectorArg,
    frames: Vec<FollowedFrame>,
}

/// Runs every `--person-detector` over every bag and prints the tables.
pub fn run(args: &EvalTrackingArgs, networks: Arc<PoseNetworks>) -> Result<()> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.threads.max(1))
        .build()
        .context("building the perception thread pool")?;
    let mut runs: Vec<(String, Vec<CrowdImage>, Vec<Run>)> = Vec::new();
    for bag in &args.bags {
        let images = if args.no_truth {
            read_camera_bag(bag)
        } else {
            read_crowd(bag)
        }
        .with_context(|| format!("reading {}", bag.display()))?;
        let name = bag
            .file_name()
            .map_or_else(|| bag.display().to_string(), |n| n.to_string_lossy().into());
        let mut bag_runs = Vec::new();
        for (d, &detector) in args.person_detector.iter().enumerate() {
            tracing::info!(bag = %name, images = images.len(), ?detector, "following one person");
            let config = TrackerConfig {
                detector: detector.into(),
                people: PeopleConfig {
                    detector_side: args.detector_side,
                    ..PeopleConfig::default()
                },
                check_looks: !args.no_looks,
                ..TrackerConfig::default()
            };
            let overlays = (d == 0).then_some(args.frames_dir.as_ref()).flatten();
            let mut written = Ok(());
            let frames = pool.install(|| {
                follow_frames(
                    &images,
                    || PersonTracker::new(networks.clone(), config),
                    |p| p.mask.to_mask(MASK.0, MASK.1),
                    |i, img, p| {
                        if let (Some(dir), Ok(())) = (overlays, &written) {
                            written = write_overlay(dir, &name, i, img, p);
                        }
                    },
                )
            })?;
            written?;
            bag_runs.push(Run { detector, frames });
        }
        runs.push((name, images, bag_runs));
    }
    if args.no_truth {
        print_without_truth(&runs);
    } else {
        print_scores(args, &runs);
    }
    Ok(())
}

/// One frame's overlay: the found person's mask and landmarks.
fn write_overlay(
    dir: &Path,
    bag: &str,
    i: usize,
    img: &CrowdImage,
    p: Option<&Perceived>,
) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let mask = p.map(|p| p.mask.to_mask(MASK.0, MASK.1));
    let overlay = draw_overlay(&img.rgb, mask.as_ref(), p.map(|p| &p.landmarks.image), 0.5);
    let target = dir.join(format!("{bag}_{i:04}_{}.png", img.camera));
    overlay
        .save(&target)
        .with_context(|| format!("writing {}", target.display()))
}

fn ms(values: &[f64]) -> String {
    match (quantile(values, 0.5), quantile(values, 0.95)) {
        (Some(p50), Some(p95)) => format!("{p50:.1} / {p95:.1}"),
        _ => "—".into(),
    }
}

fn share(found: usize, frames: usize) -> String {
    if frames == 0 {
        return "—".into();
    }
    format!(
        "{found}/{frames} ({:.1}%)",
        100.0 * found as f64 / frames as f64
    )
}

fn times_cells(t: &FrameTimes) -> String {
    format!(
        "{} | {} | {} ({}) | {}",
        ms(&t.all),
        ms(&t.followed),
        ms(&t.detector),
        t.detector.len(),
        t.all.len()
    )
}

/// Crowd bags: per detector and bag, then by height class over all bags.
fn print_scores(args: &EvalTrackingArgs, runs: &[(String, Vec<CrowdImage>, Vec<Run>)]) {
    let detectors = &args.person_detector;
    let mut totals: Vec<FollowingScore> = vec![FollowingScore::default(); detectors.len()];
    println!(
        "| bag | detector | found / frames with someone visible | of those ≥ 1/8 of the frame high | \
         switches between people | finds of another | false finds | masks mostly another's | ms \
         per frame p50 / p95 | followed | searching (frames) | frames |"
    );
    println!("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |");
    for (name, images, bag_runs) in runs {
        for (d, run) in bag_runs.iter().enumerate() {
            let s = score_following(images, &run.frames);
            println!("{}", score_row(name, run.detector, &s));
            totals[d].add(&s);
        }
    }
    if runs.len() > 1 {
        for (d, s) in totals.iter().enumerate() {
            println!("{}", score_row("**all**", detectors[d], s));
        }
    }
    println!();
    let heads: Vec<String> = detectors
        .iter()
        .map(|d| format!("found: {}", d.name()))
        .collect();
    println!(
        "| tallest person in view (share of the frame's height) | frames | {} |",
        heads.join(" | ")
    );
    println!("| --- | ---: |{}", " ---: |".repeat(detectors.len()));
    for (c, (_, label)) in HEIGHT_CLASSES.iter().enumerate() {
        let frames = totals[0].classes[c].frames;
        if frames == 0 {
            continue;
        }
        let cells: Vec<String> = totals
            .iter()
            .map(|s| share(s.classes[c].found, frames))
            .collect();
        println!("| {label} | {frames} | {} |", cells.join(" | "));
    }
    let at = |s: &FollowingScore| s.at_least(0.125);
    let cells: Vec<String> = totals
        .iter()
        .map(|s| share(at(s).found, at(s).frames))
        .collect();
    println!(
        "| **1/8 and more** | {} | {} |",
        at(&totals[0]).frames,
        cells.join(" | ")
    );
}

fn score_row(name: &str, detector: DetectorArg, s: &FollowingScore) -> String {
    let visible = s.at_least(0.0);
    let eighth = s.at_least(0.125);
    format!(
        "| {name} | {} | {} | {} | {} | {} | {} | {} | {} |",
        detector.name(),
        share(visible.found, visible.frames),
        share(eighth.found, eighth.frames),
        s.switches,
        s.finds_of_another,
        s.false_finds,
        s.mixed_masks,
        times_cells(&s.times)
    )
}

/// Bags without truth: per bag, camera and detector.
fn print_without_truth(runs: &[(String, Vec<CrowdImage>, Vec<Run>)]) {
    println!(
        "| bag | camera | detector | found / frames | box jumps > 0.5 box heights | largest jump | \
         ms per frame p50 / p95 | followed | searching (frames) | frames |"
    );
    println!("| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |");
    for (name, _, bag_runs) in runs {
        for run in bag_runs {
            for c in camera_following(&run.frames) {
                println!("{}", camera_row(name, run.detector, &c));
            }
        }
    }
}

fn camera_row(name: &str, detector: DetectorArg, c: &CameraFollowing) -> String {
    format!(
        "| {name} | {} | {} | {} | {} | {:.2} | {} |",
        c.camera,
        detector.name(),
        share(c.found, c.frames),
        c.jumps,
        c.largest_jump,
        times_cells(&c.times)
    )
}
