//! `lhmpp eval-perception BAG...`: camera-only perception scored on synthetic bags made by
//! `lhmpp synth` (every camera image: persons found, mask IoU, 2D limb-landmark error, 3D
//! joint error after IK). The measures are defined in `lhmpp::eval::perception`.

use anyhow::{Context, Result};
use clap::Args;
use lhmpp::eval::perception::{
    contact_sheet, evaluate_scene, read_scene, scene_shape, ShapeResult, Summary, SyntheticScene,
    SyntheticView, ViewResult,
};
use lhmpp::perception::pose::SolverConfig;
use lhmpp::perception::{LandmarkModel, PoseNetworks};
use std::path::PathBuf;
use std::sync::Arc;

/// Options of `lhmpp eval-perception`.
#[derive(Args, Debug)]
pub struct EvalPerceptionArgs {
    /// Bags made by `lhmpp synth` (best with `--publish-shape`, so the truth has the person's
    /// body shape).
    #[arg(required = true)]
    bags: Vec<PathBuf>,
    /// Landmark model: `lite`, `full` or `heavy`.
    #[arg(long, default_value = "full")]
    model: String,
    /// The converted heavy model (with `--model heavy`).
    #[arg(long)]
    heavy_weights: Option<PathBuf>,
    /// Landmarks less visible than this are not used by the pose solver (their segments stay
    /// at rest).
    #[arg(long, default_value_t = 0.5)]
    min_visibility: f32,
    /// Write a contact sheet (PNG) of a few views spread over all bags: the image with the
    /// perceived mask and skeleton beside the true mask with the true skeleton.
    #[arg(long)]
    picture: Option<PathBuf>,
    /// Also read the body shape from each bag's calibrated input views and print it against
    /// the truth, with each segment's measured-over-true length and their means over the bags
    /// (the biases `perception::shape` corrects).
    #[arg(long)]
    shape_segments: bool,
    /// Views on the contact sheet.
    #[arg(long, default_value_t = 6)]
    picture_views: usize,
    /// Which detector finds the person in each view: `movenet` (MoveNet MultiPose, the most
    /// prominent person) or `blazepose` (BlazePose's own).
    #[arg(long, value_enum, default_value_t = super::perceive::DetectorArg::Movenet)]
    person_detector: super::perceive::DetectorArg,
}

const HEADER: &str = "| view | facing (°) | found | mask IoU | 2D limb err (px) | 2D err / box h | PCK@0.1 | 3D cam (mm) | 3D aligned (mm) | ms |\n| --- | ---: | :---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |";

fn opt(v: f64, digits: usize) -> String {
    if v.is_finite() {
        format!("{v:.digits$}")
    } else {
        "–".into()
    }
}

fn view_row(v: &ViewResult) -> String {
    let l = v.landmarks_2d;
    let j = v.joints_3d;
    format!(
        "| {}{} | {:.0} | {} | {:.3} | {} | {} | {} | {} | {} | {:.0} |",
        v.name,
        if v.heldout { " (held out)" } else { "" },
        v.facing_deg,
        if v.landmarks.is_some() { "yes" } else { "no" },
        v.mask_iou,
        opt(l.map_or(f64::NAN, |e| e.mean_px), 1),
        opt(l.map_or(f64::NAN, |e| e.mean_box_fraction), 3),
        opt(l.map_or(f64::NAN, |e| e.pck), 2),
        opt(j.map_or(f64::NAN, |e| e.camera_mm), 0),
        opt(j.map_or(f64::NAN, |e| e.aligned_mm), 0),
        v.perception_ms,
    )
}

fn summary_row(label: &str, s: &Summary) -> String {
    format!(
        "| **{label}** | | {}/{} | {:.3} (found: {}) | {} | {} | {} | {} | {} | {:.0} |",
        s.found,
        s.views,
        s.mask_iou_all,
        opt(s.mask_iou_found, 3),
        opt(s.mean_px, 1),
        opt(s.mean_box_fraction, 3),
        opt(s.pck, 2),
        opt(s.camera_mm, 0),
        opt(s.aligned_mm, 0),
        s.perception_ms,
    )
}

/// Evaluates every bag and prints a table per bag, then the overall means.
pub fn run(args: EvalPerceptionArgs) -> Result<()> {
    let model = LandmarkModel::from_name(&args.model)
        .with_context(|| format!("--model `{}`: expected lite, full or heavy", args.model))?;
    let networks = Arc::new(PoseNetworks::load(model, args.heavy_weights.as_deref())?);
    let solver = SolverConfig {
        min_visibility: args.min_visibility,
        ..SolverConfig::default()
    };
    let mut all: Vec<ViewResult> = Vec::new();
    let mut shown: Vec<(SyntheticView, ViewResult)> = Vec::new();
    let mut scenes = Vec::new();
    let mut shapes = Vec::new();
    for bag in &args.bags {
        let scene = read_scene(bag).with_context(|| format!("reading {}", bag.display()))?;
        let results = evaluate_scene(&scene, &networks, solver, args.person_detector.into())
            .with_context(|| format!("evaluating {}", bag.display()))?;
        println!("\n### {}\n", bag.display());
        match scene.shape {
            Some(s) => println!(
                "person shape: height × {:.3}, girth × {:.3}\n",
                s.height_scale, s.girth_scale
            ),
            None => println!(
                "WARNING: no BodyShape in the bag (`lhmpp synth` without --publish-shape): the \
                 truth uses the unshaped template, not the rendered person\n"
            ),
        }
        println!("{HEADER}");
        for v in &results {
            println!("{}", view_row(v));
        }
        println!("{}", summary_row("bag", &Summary::of(&results)));
        if args.shape_segments {
            let shape = scene_shape(&scene, &results, args.min_visibility)
                .with_context(|| format!("reading the shape of {}", bag.display()))?;
            print_shape(&scene, &shape);
            shapes.push(shape);
        }
        all.extend(results.iter().cloned());
        scenes.push((scene, results));
    }
    if args.picture.is_some() {
        // Views spread evenly over every view of every bag.
        let total: usize = scenes.iter().map(|(s, _)| s.views.len()).sum();
        let k = args.picture_views.clamp(1, total.max(1));
        let picks: Vec<usize> = (0..k).map(|i| i * total / k).collect();
        let mut index = 0;
        for (scene, results) in &scenes {
            for (view, result) in scene.views.iter().zip(results) {
                if picks.contains(&index) {
                    shown.push((view.clone(), result.clone()));
                }
                index += 1;
            }
        }
    }
    let overall = Summary::of(&all);
    println!("\n### overall ({} bags)\n", args.bags.len());
    println!("{HEADER}");
    println!(
        "{}",
        summary_row(
            "input views",
            &Summary::of(all.iter().filter(|v| !v.heldout))
        )
    );
    println!(
        "{}",
        summary_row(
            "held-out views",
            &Summary::of(all.iter().filter(|v| v.heldout))
        )
    );
    println!(
        "{}",
        summary_row(
            "facing the camera (< 90°)",
            &Summary::of(all.iter().filter(|v| v.facing_deg < 90.0))
        )
    );
    println!(
        "{}",
        summary_row(
            "back to the camera (≥ 90°)",
            &Summary::of(all.iter().filter(|v| v.facing_deg >= 90.0))
        )
    );
    println!("{}", summary_row("all views", &overall));
    println!(
        "\nmodel: {}; one fresh tracker per image, mask smoothing off; mask at probability 0.5; \
         2D: 12 limb joints, normalised by the true mask's box height; 3D: 14 major joints, \
         root-aligned at the hips, `cam` with the truth in the camera's axes, `aligned` after \
         the best-fitting rotation; solver min visibility {}",
        model.name(),
        args.min_visibility
    );
    if !shapes.is_empty() {
        print_segment_means(&shapes);
    }
    if let Some(path) = &args.picture {
        let pairs: Vec<(&SyntheticView, &ViewResult)> = shown.iter().map(|(v, r)| (v, r)).collect();
        contact_sheet(&pairs)
            .save(path)
            .with_context(|| format!("writing {}", path.display()))?;
        println!("picture: {}", path.display());
    }
    Ok(())
}

/// One bag's shape estimate against the truth.
fn print_shape(scene: &SyntheticScene, shape: &ShapeResult) {
    let truth = scene.shape.map_or(1.0, |s| s.height_scale);
    match &shape.estimate {
        Some(e) => println!(
            "\nbody shape from the calibrated input views: height × {:.3} (true {truth:.3}, \
             error {:+.1} %), from {} segments, spread {:.3}",
            e.shape.height_scale,
            100.0 * (e.shape.height_scale / truth - 1.0),
            e.segments,
            e.misfit
        ),
        None => println!("\nbody shape: too few segments seen in two or more views"),
    }
}

/// Each segment's mean and spread of measured-over-true length over the bags.
fn print_segment_means(shapes: &[ShapeResult]) {
    println!("\n| segment | bags | measured / true | spread |\n| --- | ---: | ---: | ---: |");
    for (i, (a, b)) in lhmpp::perception::shape::SEGMENTS.iter().enumerate() {
        let r: Vec<f32> = shapes.iter().filter_map(|s| s.ratios[i]).collect();
        let n = r.len().max(1) as f32;
        let mean = r.iter().sum::<f32>() / n;
        let sd = (r.iter().map(|x| (x - mean).powi(2)).sum::<f32>() / n).sqrt();
        println!(
            "| {}–{} | {} | {mean:.4} | {sd:.4} |",
            a.name(),
            b.name(),
            r.len()
        );
    }
}
