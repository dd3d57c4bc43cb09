//! Measures MoveNet MultiPose Lightning (`lhmpp::perception::multipose`) on the dev-set photos
//! (`scripts/devset/install` puts them in target/devset):
//!
//! 1. people found per photo (score ≥ `--min-score`, default 0.2) with their scores and boxes,
//!    at inputs 256², 384², 512² and 256×448 (a 16:9 frame's aspect);
//! 2. the small-person finding rate: a person cut from a photo (their box as MoveNet finds it
//!    at 512, plus a margin) is scaled to 1/2 … 1/12 of a 1280×720 frame's height and pasted on a
//!    flat grey frame at three places; "found" is a person scoring ≥ `--min-score` whose box
//!    overlaps the pasted person's box by IoU ≥ 0.5;
//! 3. the time per call of the network plus decoding at each side.
//!
//! ```sh
//! cargo run --release --example multipose_measure [-- --devset target/devset --min-score 0.2]
//! ```

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::Vec2;
use image::imageops::{self, FilterType};
use image::{Rgb, RgbImage};
use lhmpp::perception::multipose::{MultiPoseDetector, PersonInstance};

/// Input sizes (height, width) measured: three squares and one of a 16:9 frame's aspect.
const SIZES: [(usize, usize); 4] = [(256, 256), (384, 384), (512, 512), (256, 448)];

fn iou(a: (Vec2, Vec2), b: (Vec2, Vec2)) -> f32 {
    let lo = a.0.max(b.0);
    let hi = a.1.min(b.1);
    let inter = (hi - lo).max(Vec2::ZERO);
    let area = |r: (Vec2, Vec2)| (r.1 - r.0).max(Vec2::ZERO).element_product();
    let i = inter.element_product();
    i / (area(a) + area(b) - i).max(1e-6)
}

fn photos(devset: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for dir in ["pose2sim", "sports2d", "ultralytics"] {
        let Ok(entries) = std::fs::read_dir(devset.join(dir)) else {
            continue;
        };
        let mut files: Vec<PathBuf> = entries
            .flatten()
            .map(|e| e.path())
            .filter(|p| matches!(p.extension().and_then(|e| e.to_str()), Some("png" | "jpg")))
            .collect();
        files.sort();
        out.extend(files);
    }
    out
}

fn describe(people: &[PersonInstance]) -> String {
    people
        .iter()
        .map(|p| {
            format!(
                "{:.2} [{:.0},{:.0}–{:.0},{:.0}]",
                p.score, p.min.x, p.min.y, p.max.x, p.max.y
            )
        })
        .collect::<Vec<_>>()
        .join(", ")
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut devset = PathBuf::from("target/devset");
    let mut min_score = 0.2f32;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--devset" => devset = PathBuf::from(args.next().ok_or("--devset PATH")?),
            "--min-score" => min_score = args.next().ok_or("--min-score X")?.parse()?,
            other => return Err(format!("unknown argument {other}").into()),
        }
    }
    let detectors: Vec<MultiPoseDetector> = SIZES
        .iter()
        .map(|&(h, w)| MultiPoseDetector::embedded_sized(h, w))
        .collect::<Result<_, _>>()?;

    println!("## People found (score ≥ {min_score})\n");
    println!("| photo | size | 256 | 384 | 512 | 256×448 |");
    println!("| --- | --- | --- | --- | --- | --- |");
    let files = photos(&devset);
    if files.is_empty() {
        return Err(format!(
            "no photos under {} (scripts/devset/install)",
            devset.display()
        )
        .into());
    }
    for path in &files {
        let img = image::open(path)
            .map_err(|e| format!("{}: {e}", path.display()))?
            .to_rgb8();
        let mut row = format!(
            "| {} | {}×{} |",
            path.strip_prefix(&devset).unwrap_or(path).display(),
            img.width(),
            img.height()
        );
        for det in &detectors {
            let people = det.detect(&img, min_score)?;
            row += &format!(" {}: {} |", people.len(), describe(&people));
        }
        println!("{row}");
    }

    // small people: sources and the person's box in them (the best person at 512)
    println!("\n## Small people on a 1280×720 grey frame (found / placed, best score)\n");
    let sources = [
        "pose2sim/single_cam1_f040.png",
        "pose2sim/single_cam3_f040.png",
        "sports2d/demo_f120.png",
    ];
    let mut cutouts = Vec::new();
    for s in sources {
        let path = devset.join(s);
        let Ok(img) = image::open(&path) else {
            continue;
        };
        let img = img.to_rgb8();
        let best = detectors[2].detect(&img, min_score)?;
        let Some(p) = best.first() else {
            println!("({s}: no person at 512, skipped)");
            continue;
        };
        let margin = (p.max - p.min) * 0.1;
        let lo = (p.min - margin).max(Vec2::ZERO);
        let hi = (p.max + margin).min(Vec2::new(img.width() as f32, img.height() as f32));
        let cut = imageops::crop_imm(
            &img,
            lo.x as u32,
            lo.y as u32,
            (hi.x - lo.x) as u32,
            (hi.y - lo.y) as u32,
        )
        .to_image();
        // the person's box inside the cut-out
        cutouts.push((s, cut, p.min - lo, p.max - lo));
    }
    let (fw, fh) = (1280u32, 720u32);
    let fractions = [2u32, 3, 4, 6, 8, 10, 12];
    print!("| person height |");
    for (h, w) in SIZES {
        print!(" {h}×{w} |");
    }
    println!();
    println!("| --- |{}", " --- |".repeat(SIZES.len()));
    for k in fractions {
        let target_h = fh as f32 / k as f32;
        print!("| 1/{k} ({target_h:.0} px) |");
        for det in &detectors {
            let (mut found, mut placed, mut best) = (0, 0, Vec::new());
            for (_, cut, bmin, bmax) in &cutouts {
                let scale = target_h / (bmax.y - bmin.y);
                let (w, h) = (
                    ((cut.width() as f32 * scale).round() as u32).max(1),
                    ((cut.height() as f32 * scale).round() as u32).max(1),
                );
                if w >= fw || h >= fh {
                    continue;
                }
                let small = imageops::resize(cut, w, h, FilterType::Triangle);
                for place in [0.2f32, 0.5, 0.8] {
                    let mut frame = RgbImage::from_pixel(fw, fh, Rgb([128, 128, 128]));
                    let x = ((fw - w) as f32 * place) as i64;
                    let y = ((fh - h) as f32 * 0.6) as i64;
                    imageops::overlay(&mut frame, &small, x, y);
                    let offset = Vec2::new(x as f32, y as f32);
                    let truth = (offset + *bmin * scale, offset + *bmax * scale);
                    let people = det.detect(&frame, 0.0)?;
                    let hit = people
                        .iter()
                        .filter(|p| iou((p.min, p.max), truth) >= 0.5)
                        .map(|p| p.score)
                        .fold(0f32, f32::max);
                    placed += 1;
                    if hit >= min_score {
                        found += 1;
                    }
                    best.push(hit);
                }
            }
            let top = best.iter().copied().fold(0f32, f32::max);
            print!(" {found}/{placed} (best {top:.2}) |");
        }
        println!();
    }

    println!("\n## Time per call (network + decoding), median of 5\n");
    for det in &detectors {
        let (h, w) = det.input_size();
        let pixels: Vec<u8> = (0..h * w * 3).map(|i| (i * 7919 % 251) as u8).collect();
        let mut times: Vec<f64> = Vec::new();
        det.run(&pixels)?;
        for _ in 0..5 {
            let t = Instant::now();
            det.run(&pixels)?;
            times.push(t.elapsed().as_secs_f64() * 1e3);
        }
        times.sort_by(f64::total_cmp);
        println!(
            "- {h}×{w}: {:.1} ms ({} rayon threads)",
            times[2],
            rayon::current_num_threads()
        );
    }
    Ok(())
}
