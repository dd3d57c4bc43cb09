//! `lhmpp body garments` (build the garment library) and `lhmpp body garment-report`.

use anyhow::Context;
use clap::Args;
use lhmpp::body::garment::report::{fit_report, GarmentFit, REACH_THRESHOLDS};
use lhmpp::body::{convert, BodyTemplate, GarmentLibrary};
use std::path::PathBuf;

/// Arguments of `lhmpp body garments`.
#[derive(Args, Debug)]
pub struct ConvertArgs {
    /// The CC0 MakeHuman clothes folder (with `clothes/` and `hair/`).
    #[arg(long, default_value = "/work/shared/assets/makehuman-clothes")]
    clothes: PathBuf,
    /// The MakeHuman source folder the template was converted from (base.obj,
    /// weights.default.json).
    #[arg(long, default_value = "/work/shared/assets/makehuman")]
    makehuman: PathBuf,
    /// Output safetensors file.
    #[arg(short, long, default_value = "assets/body/garments.safetensors")]
    output: PathBuf,
}

/// Arguments of `lhmpp body garment-report`.
#[derive(Args, Debug)]
pub struct ReportArgs {
    /// A library file instead of the embedded one.
    #[arg(long)]
    library: Option<PathBuf>,
    /// Anchor points (the node's model.num_points).
    #[arg(long, default_value_t = 4096)]
    points: usize,
    /// Anchor sampling seed (the node's model.seed).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Surface samples per garment for the anchor reach.
    #[arg(long, default_value_t = 20_000)]
    samples: usize,
    /// Also write a picture of dressed people (rows: seeds; columns: front, side, back
    /// unlit, front lit).
    #[arg(long)]
    picture: Option<PathBuf>,
    /// Seeds of the people in the picture.
    #[arg(long, value_delimiter = ',', default_value = "1,2,3,4")]
    people: Vec<u64>,
}

fn print_report(rows: &[GarmentFit], points: usize) {
    let [a, b, c] = REACH_THRESHOLDS.map(|t| format!("≤{:.0} cm", t * 100.0));
    println!("| garment | vertices | skin median (mm) | skin p95 (mm) | skin covered | surface {a} of an anchor | {b} | {c} |");
    println!("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |");
    for r in rows {
        println!(
            "| {} | {} | {:.1} | {:.1} | {:.1}% | {:.1}% | {:.1}% | {:.1}% |",
            r.name,
            r.vertices,
            r.skin_median * 1000.0,
            r.skin_p95 * 1000.0,
            r.covered * 100.0,
            r.reach[0] * 100.0,
            r.reach[1] * 100.0,
            r.reach[2] * 100.0
        );
    }
    println!("({points} anchors on the template at rest shape)");
}

/// Runs `lhmpp body garments`.
pub fn convert(args: &ConvertArgs) -> anyhow::Result<()> {
    let template = BodyTemplate::load_default()?;
    let start = std::time::Instant::now();
    let library = convert::garments::convert_garments(&args.clothes, &args.makehuman, &template)
        .with_context(|| format!("converting {}", args.clothes.display()))?;
    let seconds = start.elapsed().as_secs_f64();
    library.save(&args.output)?;
    let bytes = std::fs::metadata(&args.output)
        .map(|m| m.len())
        .unwrap_or(0);
    println!(
        "wrote {} ({} garments, {} bytes) in {seconds:.1} s",
        args.output.display(),
        library.garments.len(),
        bytes
    );
    let anchors = template.sample_anchors(4096, 1);
    print_report(&fit_report(&library, &template, &anchors, 20_000), 4096);
    Ok(())
}

/// Runs `lhmpp body garment-report`.
pub fn report(args: &ReportArgs) -> anyhow::Result<()> {
    let template = BodyTemplate::load_default()?;
    let library = match &args.library {
        Some(path) => GarmentLibrary::load(path)?,
        None => GarmentLibrary::load_default()?,
    };
    library.validate(&template, "garment library")?;
    let anchors = template.sample_anchors(args.points, args.seed);
    print_report(
        &fit_report(&library, &template, &anchors, args.samples),
        args.points,
    );
    if let Some(path) = &args.picture {
        let sheet = lhmpp::synth::lookbook::lookbook(&args.people, 320, 60_000)?;
        sheet
            .save(path)
            .with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
