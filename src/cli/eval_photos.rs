//! `lhmpp eval-photos [DIR] [--manifest FILE]`: the avatar's colours against real photos.
//! Each person's photos are reconstructed together as `lhmpp avatar` does; per photo, the
//! median colour of each body region (torso, upper arms, thighs, shins, feet, head) on the
//! photo and on the avatar rendered from the front in the photo's pose, compared with
//! CIEDE2000. The measure is defined in `lhmpp::eval::photos`.

use anyhow::{bail, Context, Result};
use clap::Args;
use lhmpp::config::ModelConfig;
use lhmpp::eval::photos::colour::hex;
use lhmpp::eval::photos::manifest::Manifest;
use lhmpp::eval::photos::regions::Region;
use lhmpp::eval::photos::sheet::contact_sheet;
use lhmpp::eval::photos::{
    overall_mean, score_person, EvalPhotosConfig, PersonScore, RegionStatus, RenderLandmarks,
};
use lhmpp::perception::{LandmarkModel, PoseNetworks};
use lhmpp::reconstruct::photos::{MaskSource, PersonHint};
use lhmpp::reconstruct::Reconstructor;
use serde_json::json;
use std::path::PathBuf;
use std::sync::Arc;

/// Options of `lhmpp eval-photos`.
#[derive(Args, Debug)]
pub struct EvalPhotosArgs {
    /// A folder of photos, each a person of its own, with `<stem>_mask.png` beside a photo as
    /// its mask (else perception's).
    #[arg(conflicts_with = "manifest", required_unless_present = "manifest")]
    dir: Option<PathBuf>,
    /// A JSON list of people, their photos, masks and person hints
    /// (`scripts/devset/photos.json` for the dev set).
    #[arg(long)]
    manifest: Option<PathBuf>,
    /// Write the tables as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Write a contact sheet (PNG): per photo, the photo and the render with their regions
    /// drawn, and the two colours of each region.
    #[arg(long)]
    picture: Option<PathBuf>,
    /// Network preset (`lhmpp model info` lists them); the default is the embedded model.
    #[arg(long, default_value = "tiny")]
    preset: String,
    /// Checkpoint (safetensors file or hub folder); empty = the embedded default.
    #[arg(long, default_value = "")]
    checkpoint: String,
    /// Landmark model of the perception: `lite`, `full` or `heavy`.
    #[arg(long, default_value = "full")]
    landmark_model: String,
    /// The converted heavy landmark model (with `--landmark-model heavy`).
    #[arg(long)]
    heavy_weights: Option<PathBuf>,
    /// Side of the avatar's renders, pixels.
    #[arg(long, default_value_t = 512)]
    render_size: u32,
    /// Keep the network's colours (no recolouring from the photos), to compare.
    #[arg(long)]
    network_colours: bool,
    /// Leave out the manifest's masks: every photo is masked by perception.
    #[arg(long)]
    perception_masks: bool,
    #[command(flatten)]
    refine: super::avatar::PhotoRefineArgs,
}

fn opt(v: Option<f64>) -> String {
    v.map_or_else(|| "–".into(), |v| format!("{v:.1}"))
}

/// Scores every person and prints the tables.
pub fn run(args: EvalPhotosArgs) -> Result<()> {
    let mut manifest = match (&args.manifest, &args.dir) {
        (Some(m), _) => Manifest::load(m)?,
        (None, Some(d)) => Manifest::from_dir(d)?,
        (None, None) => bail!("give a folder of photos or --manifest FILE"),
    };
    if args.perception_masks {
        // The person stays the one the mask picked out (the box around it).
        for view in manifest.people.iter_mut().flat_map(|p| &mut p.views) {
            if let (None, Some(mask)) = (&view.person, view.mask.take()) {
                let image = image::open(&mask)
                    .with_context(|| format!("reading {}", mask.display()))?
                    .to_luma8();
                view.person = PersonHint::from_mask(&image);
            }
        }
    }
    let refine = args.refine.config()?;
    let model = ModelConfig {
        preset: args.preset.clone(),
        checkpoint: args.checkpoint.clone(),
        ..ModelConfig::default()
    };
    let max_views = manifest
        .people
        .iter()
        .map(|p| p.views.len())
        .max()
        .unwrap_or(1);
    let mut recon = Reconstructor::new(&model, max_views)?;
    let landmark_model = LandmarkModel::from_name(&args.landmark_model).with_context(|| {
        format!(
            "--landmark-model `{}`: expected lite, full or heavy",
            args.landmark_model
        )
    })?;
    let networks = Arc::new(PoseNetworks::load(
        landmark_model,
        args.heavy_weights.as_deref(),
    )?);
    let defaults = EvalPhotosConfig::default();
    let config = EvalPhotosConfig {
        render_size: args.render_size,
        photo_colours: defaults.photo_colours.filter(|_| !args.network_colours),
        refine,
        ..defaults
    };
    println!(
        "weights: {} (preset {}); perception: {}; masks: {}; refinement: {}",
        recon.weights(),
        args.preset,
        args.landmark_model,
        if args.perception_masks {
            "perception's"
        } else {
            "the manifest's where given"
        },
        match &config.refine {
            Some(r) => format!("on (budget {:.1} s)", r.budget.as_secs_f64()),
            None => "off".into(),
        }
    );
    let mut people = Vec::new();
    let mut pictures = Vec::new();
    for person in &manifest.people {
        let started = std::time::Instant::now();
        let (score, pics) = score_person(&mut recon, &networks, person, &config)
            .with_context(|| format!("person `{}`", person.name))?;
        tracing::info!(
            person = %person.name,
            views = score.views.len(),
            s = format!("{:.1}", started.elapsed().as_secs_f64()),
            "scored"
        );
        print_person(&score);
        people.push(score);
        pictures.extend(pics);
    }
    print_summary(&people);

    if let Some(path) = &args.json {
        let value = json!({
            "weights": recon.weights(),
            "preset": args.preset,
            "checkpoint": args.checkpoint,
            "landmark_model": args.landmark_model,
            "render_size": args.render_size,
            "people": people.iter().map(PersonScore::to_json).collect::<Vec<_>>(),
            "region_means_delta_e00": Region::ALL
                .iter()
                .map(|r| (r.name().to_string(), json!(region_mean(&people, *r))))
                .collect::<serde_json::Map<_, _>>(),
            "overall_mean_delta_e00": overall_mean(&people),
        });
        let text = serde_json::to_string_pretty(&value).expect("JSON values serialise");
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?;
    }
    if let Some(path) = &args.picture {
        contact_sheet(&pictures)
            .save(path)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    if overall_mean(&people).is_none() {
        bail!("no region scored on any photo");
    }
    Ok(())
}

/// Mean ΔE00 of one region over every photo of every person.
fn region_mean(people: &[PersonScore], region: Region) -> Option<f64> {
    let values: Vec<f64> = people
        .iter()
        .flat_map(|p| &p.views)
        .filter_map(|v| v.regions[region.index()].delta_e)
        .collect();
    (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64)
}

fn print_person(p: &PersonScore) {
    println!();
    println!(
        "### {} ({} photo{}){}",
        p.name,
        p.views.len(),
        if p.views.len() == 1 { "" } else { "s" },
        if p.note.is_empty() {
            String::new()
        } else {
            format!(": {}", p.note)
        }
    );
    if let Some(r) = &p.refinement {
        println!("refinement: {r}");
    }
    for (photo, why) in &p.skipped {
        println!("skipped {}: {why}", photo.display());
    }
    if p.views.is_empty() {
        return;
    }
    println!();
    println!("| photo | region | photo colour | render colour | ΔE00 |");
    println!("| --- | --- | --- | --- | ---: |");
    for v in &p.views {
        let stem = v
            .photo
            .file_stem()
            .map_or_else(String::new, |s| s.to_string_lossy().into_owned());
        let mut notes = Vec::new();
        if v.mask == MaskSource::Given {
            notes.push("given mask");
        }
        if !v.person_found {
            notes.push("nobody found");
        } else if !v.posed {
            notes.push("rest pose");
        }
        if v.render_landmarks == RenderLandmarks::Template {
            notes.push("render landmarks: template");
        }
        let label = if notes.is_empty() {
            stem
        } else {
            format!("{stem} ({})", notes.join(", "))
        };
        for r in &v.regions {
            let colour = |c: Option<lhmpp::eval::photos::RegionColour>| {
                c.map_or_else(|| "–".into(), |c| format!("`{}`", hex(c.rgb)))
            };
            let delta = match r.status {
                RegionStatus::Scored => opt(r.delta_e),
                RegionStatus::Uncovered => format!("{} (uncovered)", opt(r.delta_e)),
                other => other.name().into(),
            };
            let (photo, render) = match r.status {
                RegionStatus::NotShown => ("–".into(), "–".into()),
                RegionStatus::NotRendered => (colour(r.photo), "–".into()),
                RegionStatus::Scored | RegionStatus::Uncovered => {
                    (colour(r.photo), colour(r.render))
                }
            };
            println!(
                "| {label} | {} | {photo} | {render} | {delta} |",
                r.region.name()
            );
        }
    }
    println!();
    println!(
        "mean ΔE00 {}: {} regions scored",
        opt(p.mean()),
        p.scored().len()
    );
}

fn print_summary(people: &[PersonScore]) {
    println!();
    println!("### Summary");
    println!();
    println!("| person | photos | regions scored | mean ΔE00 |");
    println!("| --- | ---: | ---: | ---: |");
    for p in people {
        println!(
            "| {} | {} | {} | {} |",
            p.name,
            p.views.len(),
            p.scored().len(),
            opt(p.mean())
        );
    }
    println!(
        "| **overall** (mean of the persons' means) | | | **{}** |",
        opt(overall_mean(people))
    );
    println!();
    println!("| region | mean ΔE00 over all photos |");
    println!("| --- | ---: |");
    for r in Region::ALL {
        println!("| {} | {} |", r.name(), opt(region_mean(people, r)));
    }
}
