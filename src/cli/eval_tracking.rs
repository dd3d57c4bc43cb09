//! `lhmpp eval-tracking BAG...`: person ids scored on crowd bags made by
//! `lhmpp synth --people N` (persons found, id switches per 100 images, views that would land
//! in another person's store, ids per person). The measures are defined in
//! `lhmpp::eval::tracking`. With `--no-truth`, bags without id maps (real video): each id's
//! sightings per camera and how the cameras agree on where it stands (`lhmpp::eval::id_tracks`).
//! With `--one-person`, the one-person mode instead (`super::eval_following`).

use super::perceive_people::{number, COLOURS};
use anyhow::{Context, Result};
use clap::Args;
use image::{Rgb, RgbImage};
use lhmpp::eval::id_tracks::{camera_tracks, id_agreement, track_ids, SAME_MOMENT_NS};
use lhmpp::eval::tracking::{
    read_camera_bag, read_crowd, track_and_score, CrowdImage, TrackingScore,
};
use lhmpp::perception::people::tint_mask;
use lhmpp::perception::FoundPerson;
use lhmpp::perception::{LandmarkModel, PeopleConfig, PeopleFinder, PoseNetworks};
use lhmpp::picture::draw_text;
use lhmpp::tracking::Assignment;
use lhmpp::tracking::{PersonTracks, TrackingConfig};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Options of `lhmpp eval-tracking`.
#[derive(Args, Debug)]
pub struct EvalTrackingArgs {
    /// Bags made by `lhmpp synth --people N`.
    #[arg(required = true)]
    pub(super) bags: Vec<PathBuf>,
    /// Landmark model run on each person: `lite`, `full` or `heavy`.
    #[arg(long, default_value = "full")]
    model: String,
    /// Seconds a person is kept without a sighting.
    #[arg(long, default_value_t = TrackingConfig::default().forget_after)]
    forget_after: f64,
    /// Appearance similarity (0..1) from which a detection is a person seen elsewhere.
    #[arg(long, default_value_t = TrackingConfig::default().min_similarity)]
    min_similarity: f32,
    /// Floor distance (metres) within which a detection can be a person another camera just
    /// saw (calibrated cameras).
    #[arg(long, default_value_t = TrackingConfig::default().max_floor_gap)]
    max_floor_gap: f32,
    /// Short side of MoveNet's input (a multiple of 32; larger finds smaller people).
    #[arg(long, default_value_t = lhmpp::perception::multipose::NATIVE_SIDE)]
    pub(super) detector_side: usize,
    /// Write every image's overlay into this folder: each person's mask tinted by the id the
    /// tracker gave it, with the id, beside the true id map.
    #[arg(long)]
    pub(super) frames_dir: Option<PathBuf>,
    /// Print the table as JSON too.
    #[arg(long)]
    json: bool,
    /// Bags without id maps (real video, `/<camera>/image_raw` or `image_raw/compressed`,
    /// calibrated by `camera_info` and `/tf_static`): instead of scores, per camera and id the
    /// sightings and the largest box jump between them, and per id how far apart the cameras
    /// put it on the floor at the same moment.
    #[arg(long)]
    pub(super) no_truth: bool,
    /// The one-person mode instead of ids: each camera's frames through a one-person tracker
    /// per `--person-detector`, found against visible by the height of the tallest person in
    /// view, switches between people, time per frame (with `--no-truth`: finds and box jumps
    /// per camera). `--frames-dir` gets the first detector's mask and landmarks per frame.
    #[arg(long)]
    pub(super) one_person: bool,
    /// With `--one-person`: the detectors that find the person to follow, each run in turn.
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "movenet,blazepose"
    )]
    pub(super) person_detector: Vec<super::perceive::DetectorArg>,
    /// With `--one-person`: CPU threads of the networks (the node's `perception.threads`).
    #[arg(long, default_value_t = 1)]
    pub(super) threads: usize,
    /// With `--one-person`: follow the crop the landmarks place wherever it goes, without
    /// checking the person's looks (MediaPipe's tracking; for comparison).
    #[arg(long)]
    pub(super) no_looks: bool,
}

const HEADER: &str = "| bag | people | images | found | id switches / 100 images (all cameras) | within a camera | ids per person | wrong-person views | false detections | ms / image |\n| --- | ---: | ---: | ---: | ---: | ---: | --- | ---: | ---: | ---: |";

fn row(name: &str, s: &TrackingScore) -> String {
    format!(
        "| {name} | {} | {} | {}/{} ({:.1}%) | {:.2} ({}) | {:.2} ({}) | {} | {} | {} | {:.0} |",
        s.persons,
        s.images,
        s.found,
        s.visible,
        100.0 * s.recall(),
        s.switches_per_100(),
        s.id_switches,
        100.0 * s.camera_switches as f64 / s.images.max(1) as f64,
        s.camera_switches,
        s.ids_per_person
            .iter()
            .map(usize::to_string)
            .collect::<Vec<_>>()
            .join(" "),
        s.wrong_person_views,
        s.false_detections,
        s.perception_ms,
    )
}

/// The image with each person's mask tinted by its id and the id written at its box, beside
/// the true id map in the same colours.
fn overlay(img: &CrowdImage, people: &[FoundPerson], ids: &[Assignment]) -> RgbImage {
    let (w, h) = img.rgb.dimensions();
    let mut left = img.rgb.clone();
    for (p, a) in people.iter().zip(ids) {
        let k = number(&a.person_id);
        tint_mask(&mut left, &p.mask, COLOURS[k % COLOURS.len()], 0.5);
    }
    for (p, a) in people.iter().zip(ids) {
        let (x, y) = (p.min.x.max(0.0) as u32, (p.min.y - 18.0).max(0.0) as u32);
        draw_text(&mut left, x, y, &a.person_id, 2, Rgb([0, 0, 0]));
    }
    let mut out = RgbImage::new(2 * w, h);
    image::imageops::replace(&mut out, &left, 0, 0);
    let truth = RgbImage::from_fn(w, h, |x, y| match img.ids.get_pixel(x, y).0[0] {
        0 => Rgb([255, 255, 255]),
        k => Rgb(COLOURS[(k as usize - 1) % COLOURS.len()]),
    });
    image::imageops::replace(&mut out, &truth, w as i64, 0);
    out
}

/// Writes each image's [`overlay`] into `--frames-dir` when it is set; the first failure stops
/// the writing and comes back from [`Overlays::finish`].
struct Overlays {
    dir: Option<PathBuf>,
    bag: String,
    written: Result<()>,
}

impl Overlays {
    /// Overlays of `bag` (its file name) into `dir`, created if missing.
    fn new(dir: Option<&PathBuf>, bag: &Path) -> Result<Self> {
        if let Some(dir) = dir {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        }
        Ok(Self {
            dir: dir.cloned(),
            bag: bag
                .file_name()
                .map_or_else(|| bag.display().to_string(), |n| n.to_string_lossy().into()),
            written: Ok(()),
        })
    }

    fn write(&mut self, i: usize, img: &CrowdImage, people: &[FoundPerson], ids: &[Assignment]) {
        if let (Some(dir), Ok(())) = (&self.dir, &self.written) {
            let target = dir.join(format!("{}_{i:04}_{}.png", self.bag, img.camera));
            self.written = overlay(img, people, ids)
                .save(&target)
                .with_context(|| format!("writing {}", target.display()));
        }
    }

    fn finish(self) -> Result<()> {
        self.written
    }
}

/// A fresh finder (at `--detector-side`) and tracker for one bag.
fn fresh_tracking(
    args: &EvalTrackingArgs,
    networks: &Arc<PoseNetworks>,
    config: &TrackingConfig,
) -> (PeopleFinder, PersonTracks) {
    let people = PeopleConfig {
        detector_side: args.detector_side,
        ..PeopleConfig::default()
    };
    (
        PeopleFinder::new(networks.clone(), people),
        PersonTracks::new(config.clone()),
    )
}

/// Scores every bag with a fresh tracker and prints one row per bag and a total.
pub fn run(args: EvalTrackingArgs) -> Result<()> {
    let model = LandmarkModel::from_name(&args.model)
        .with_context(|| format!("--model `{}`: expected lite, full or heavy", args.model))?;
    let networks = Arc::new(PoseNetworks::load(model, None)?);
    let config = TrackingConfig {
        forget_after: args.forget_after,
        min_similarity: args.min_similarity,
        max_floor_gap: args.max_floor_gap,
        ..TrackingConfig::default()
    };
    if args.one_person {
        return super::eval_following::run(&args, networks);
    }
    if args.no_truth {
        return run_without_truth(&args, networks, &config);
    }
    println!("{HEADER}");
    let mut total = TrackingScore::default();
    let mut json = Vec::new();
    for bag in &args.bags {
        let images = read_crowd(bag).with_context(|| format!("reading {}", bag.display()))?;
        tracing::info!(bag = %bag.display(), images = images.len(), "tracking");
        let (mut finder, mut tracks) = fresh_tracking(&args, &networks, &config);
        let mut overlays = Overlays::new(args.frames_dir.as_ref(), bag)?;
        let score = track_and_score(&images, &mut finder, &mut tracks, |i, img, people, ids| {
            overlays.write(i, img, people, ids)
        })
        .with_context(|| format!("scoring {}", bag.display()))?;
        let name = overlays.bag.clone();
        overlays.finish()?;
        println!("{}", row(&name, &score));
        json.push(serde_json::json!({
            "bag": bag,
            "people": score.persons,
            "images": score.images,
            "visible": score.visible,
            "found": score.found,
            "id_switches": score.id_switches,
            "id_switches_per_100_images": score.switches_per_100(),
            "camera_switches": score.camera_switches,
            "ids_per_person": score.ids_per_person,
            "wrong_person_views": score.wrong_person_views,
            "false_detections": score.false_detections,
            "ms_per_image": score.perception_ms,
        }));
        let ms =
            total.perception_ms * total.images as f64 + score.perception_ms * score.images as f64;
        total.persons += score.persons;
        total.images += score.images;
        total.visible += score.visible;
        total.found += score.found;
        total.id_switches += score.id_switches;
        total.camera_switches += score.camera_switches;
        total.wrong_person_views += score.wrong_person_views;
        total.false_detections += score.false_detections;
        total.ids_per_person.extend(score.ids_per_person);
        total.perception_ms = ms / total.images.max(1) as f64;
    }
    if args.bags.len() > 1 {
        println!("{}", row("**all**", &total));
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&json)?);
    }
    Ok(())
}

/// `--no-truth`: per bag, the per-camera and per-id tables of `lhmpp::eval::id_tracks`.
fn run_without_truth(
    args: &EvalTrackingArgs,
    networks: Arc<PoseNetworks>,
    config: &TrackingConfig,
) -> Result<()> {
    for bag in &args.bags {
        let images = read_camera_bag(bag).with_context(|| format!("reading {}", bag.display()))?;
        tracing::info!(bag = %bag.display(), images = images.len(), "tracking (no truth)");
        let (mut finder, mut tracks) = fresh_tracking(args, &networks, config);
        let mut overlays = Overlays::new(args.frames_dir.as_ref(), bag)?;
        let sightings = track_ids(&images, &mut finder, &mut tracks, |i, img, people, ids| {
            overlays.write(i, img, people, ids)
        })
        .with_context(|| format!("tracking {}", bag.display()))?;
        let name = overlays.bag.clone();
        overlays.finish()?;
        let floor =
            |f: Option<[f32; 2]>| f.map_or("—".into(), |[x, z]| format!("({x:.2}, {z:.2})"));
        println!(
            "{name}: {} images, {} detections\n",
            images.len(),
            sightings.len()
        );
        println!(
            "| camera | id | sightings | largest box jump / box height | mean floor (x, z) m |"
        );
        println!("| --- | --- | ---: | ---: | --- |");
        for t in camera_tracks(&sightings) {
            println!(
                "| {} | {} | {} | {:.2} | {} |",
                t.camera,
                t.id,
                t.sightings,
                t.largest_jump,
                floor(t.mean_floor)
            );
        }
        println!(
            "\n| id | cameras | same-moment pairs | floor gap between cameras: median / max (m) |"
        );
        println!("| --- | --- | ---: | --- |");
        let metres = |g: Option<f32>| g.map_or("—".into(), |g| format!("{g:.2}"));
        for a in id_agreement(&sightings, SAME_MOMENT_NS) {
            println!(
                "| {} | {} | {} | {} / {} |",
                a.id,
                a.cameras.join(" "),
                a.pairs,
                metres(a.median_gap),
                metres(a.max_gap)
            );
        }
        println!();
    }
    Ok(())
}
