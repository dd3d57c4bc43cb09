//! `lhmpp perceive --people IMAGE... -o DIR`: every person of each photo. Per photo:
//! `<stem>_person<k>_mask.png` per person (`k` from the person id), `<stem>_people.png` (each
//! person's mask tinted in its own colour, the skeleton, the id and MoveNet score) and
//! `<stem>_people.json`. The photos are frames of one camera, in order: ids come from
//! `lhmpp::tracking::PersonTracks` (box overlap, then appearance), so a sequence keeps them.

use super::perceive::{write_json, PerceiveArgs};
use anyhow::{Context, Result};
use image::{Rgb, RgbImage};
use lhmpp::eval::tracking::detection;
use lhmpp::perception::overlay::{draw_line, draw_overlay};
use lhmpp::perception::people::tint_mask;
use lhmpp::perception::{FoundPerson, LandmarkId, PeopleConfig, PeopleFinder, PoseNetworks};
use lhmpp::picture::draw_text;
use lhmpp::tracking::{Detection, PersonTracks, TrackingConfig};
use serde_json::{json, Value};
use std::path::Path;
use std::sync::Arc;

/// Colours of persons, by id number.
pub(super) const COLOURS: [[u8; 3]; 6] = [
    [40, 200, 255],
    [255, 60, 160],
    [120, 255, 60],
    [255, 200, 0],
    [160, 90, 255],
    [255, 90, 40],
];

/// Perceives the photos as frames of one camera; fails when nobody is found in any.
pub fn run(args: &PerceiveArgs, networks: Arc<PoseNetworks>) -> Result<()> {
    let config = PeopleConfig {
        min_score: args.min_score,
        mask_threshold: args.mask_threshold,
        mask_feather: args.mask_feather,
        detector_side: args.detector_side,
        ..PeopleConfig::default()
    };
    let mut finder = PeopleFinder::new(networks, config);
    let mut tracks = PersonTracks::new(TrackingConfig::default());
    let mut total = 0;
    for (frame, path) in args.images.iter().enumerate() {
        match perceive_frame(args, &mut finder, &mut tracks, frame, path) {
            Ok(n) => total += n,
            Err(e) => tracing::error!(image = %path.display(), "{}", super::error_line(&e)),
        }
    }
    if total == 0 {
        anyhow::bail!("nobody found in any of the {} image(s)", args.images.len());
    }
    tracing::info!(persons = total, images = args.images.len(), out = %args.out.display(), "perceived");
    Ok(())
}

/// Writes one photo's outputs; how many persons it showed.
fn perceive_frame(
    args: &PerceiveArgs,
    finder: &mut PeopleFinder,
    tracks: &mut PersonTracks,
    frame: usize,
    path: &Path,
) -> Result<usize> {
    let image = image::open(path)
        .with_context(|| format!("reading {}", path.display()))?
        .to_rgb8();
    let started = std::time::Instant::now();
    let people = finder.find(&image)?;
    let ms = started.elapsed().as_secs_f64() * 1e3;
    let detections: Vec<Detection> = people.iter().map(|p| detection(&image, p, None)).collect();
    let ids = tracks.update("camera", frame as f64, &detections);
    let stem = path
        .file_stem()
        .map_or_else(|| "image".into(), |s| s.to_string_lossy().into_owned());
    let mut overlay = image.clone();
    let mut persons = Vec::new();
    for (p, id) in people.iter().zip(&ids) {
        let k = number(&id.person_id);
        let target = args.out.join(format!("{stem}_person{k}_mask.png"));
        p.mask
            .save(&target)
            .with_context(|| format!("writing {}", target.display()))?;
        tint_mask(&mut overlay, &p.mask, COLOURS[k % COLOURS.len()], 0.5);
        persons.push(person_json(&id.person_id, &format!("{:?}", id.matched), p));
    }
    for (p, id) in people.iter().zip(&ids) {
        let k = number(&id.person_id);
        overlay = draw_overlay(
            &overlay,
            None,
            Some(&p.landmarks.image),
            args.min_visibility,
        );
        label(
            &mut overlay,
            p,
            &id.person_id,
            Rgb(COLOURS[k % COLOURS.len()]),
        );
    }
    let target = args.out.join(format!("{stem}_people.png"));
    overlay
        .save(&target)
        .with_context(|| format!("writing {}", target.display()))?;
    let json = json!({
        "image": path,
        "width": image.width(),
        "height": image.height(),
        "frame": frame,
        "ms": ms,
        "persons": persons,
    });
    write_json(&args.out.join(format!("{stem}_people.json")), &json)?;
    Ok(people.len())
}

/// The number of a `person_<n>` id (0 for another form).
pub(super) fn number(id: &str) -> usize {
    id.trim_start_matches("person_").parse().unwrap_or(0)
}

/// The box outline and `id score` above it.
fn label(image: &mut RgbImage, p: &FoundPerson, id: &str, colour: Rgb<u8>) {
    let width = (image.width().max(image.height()) as f32 / 400.0).max(1.0);
    let (a, b) = (p.min, p.max);
    let corners = [a, glam::Vec2::new(b.x, a.y), b, glam::Vec2::new(a.x, b.y)];
    for i in 0..4 {
        draw_line(image, corners[i], corners[(i + 1) % 4], width, colour);
    }
    let scale = (image.height() / 400).max(1);
    let text = format!("{id} {:.2}", p.score);
    let x = a.x.max(0.0) as u32;
    let y = (a.y - 10.0 * scale as f32).max(0.0) as u32;
    draw_text(image, x + scale, y + scale, &text, scale, Rgb([0, 0, 0]));
    draw_text(image, x, y, &text, scale, colour);
}

/// The JSON record of one person.
fn person_json(id: &str, matched: &str, p: &FoundPerson) -> Value {
    let roi = p.landmarks.roi;
    json!({
        "id": id,
        "matched": matched,
        "box_min": p.min.to_array(),
        "box_max": p.max.to_array(),
        "score": p.score,
        "presence": p.landmarks.presence,
        "roi": {
            "center": roi.center.to_array(),
            "size": roi.size.to_array(),
            "rotation": roi.rotation,
        },
        "landmarks_px": LandmarkId::ALL
            .iter()
            .zip(&p.landmarks.image)
            .map(|(id, l)| json!({
                "name": id.name(),
                "position": l.position.to_array(),
                "visibility": l.visibility,
                "presence": l.presence,
            }))
            .collect::<Vec<_>>(),
    })
}
