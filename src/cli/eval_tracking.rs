//! `lhmpp eval-tracking BAG...`: person ids scored on crowd bags made by
//! `lhmpp synth --people N` (persons found, id switches per 100 images, views that would land
//! in another person's store, ids per person). The measures are defined in
//! `lhmpp::eval::tracking`.

use super::perceive_people::{number, COLOURS};
use anyhow::{Context, Result};
use clap::Args;
use image::{Rgb, RgbImage};
use lhmpp::eval::tracking::{read_crowd, track_and_score, CrowdImage, TrackingScore};
use lhmpp::perception::people::tint_mask;
use lhmpp::perception::FoundPerson;
use lhmpp::perception::{LandmarkModel, PeopleConfig, PeopleFinder, PoseNetworks};
use lhmpp::picture::draw_text;
use lhmpp::tracking::Assignment;
use lhmpp::tracking::{PersonTracks, TrackingConfig};
use std::path::PathBuf;
use std::sync::Arc;

/// Options of `lhmpp eval-tracking`.
#[derive(Args, Debug)]
pub struct EvalTrackingArgs {
    /// Bags made by `lhmpp synth --people N`.
    #[arg(required = true)]
    bags: Vec<PathBuf>,
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
    detector_side: usize,
    /// Write every image's overlay into this folder: each person's mask tinted by the id the
    /// tracker gave it, with the id, beside the true id map.
    #[arg(long)]
    frames_dir: Option<PathBuf>,
    /// Print the table as JSON too.
    #[arg(long)]
    json: bool,
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
    println!("{HEADER}");
    let mut total = TrackingScore::default();
    let mut json = Vec::new();
    for bag in &args.bags {
        let images = read_crowd(bag).with_context(|| format!("reading {}", bag.display()))?;
        tracing::info!(bag = %bag.display(), images = images.len(), "tracking");
        let mut finder = PeopleFinder::new(
            networks.clone(),
            PeopleConfig {
                detector_side: args.detector_side,
                ..PeopleConfig::default()
            },
        );
        let mut tracks = PersonTracks::new(config.clone());
        let name = bag
            .file_name()
            .map_or_else(|| bag.display().to_string(), |n| n.to_string_lossy().into());
        if let Some(dir) = &args.frames_dir {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        }
        let mut written = Ok(());
        let score = track_and_score(&images, &mut finder, &mut tracks, |i, img, people, ids| {
            if let (Some(dir), Ok(())) = (&args.frames_dir, &written) {
                let target = dir.join(format!("{name}_{i:04}_{}.png", img.camera));
                written = overlay(img, people, ids)
                    .save(&target)
                    .with_context(|| format!("writing {}", target.display()));
            }
        })
        .with_context(|| format!("scoring {}", bag.display()))?;
        written?;
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
