//! `lhmpp avatar IMAGE... -o DIR`: photos of one person in, an animatable avatar out. Each
//! photo is masked by camera-only perception (no mask topic, no segmentation node), the views
//! go through the reconstruction network together, and the avatar is written with pictures to
//! look at:
//!
//! * `avatar.ply`: the canonical Gaussians with their skinning (3DGS layout);
//! * `turntable/NNN.png` + `turntable.gif`: the avatar at rest, turning once;
//! * `walk/NNN.png` + `walk.gif`: the avatar walking the built-in cycle, seen from the front;
//! * `posed_<photo>.png`: the avatar in the pose read from each photo, from the front;
//! * `masks/<photo>_mask.png` and `masks/<photo>_overlay.png`: what perception used.
//!
//! With `--refine` the avatar is then fitted to the photos ([`lhmpp::refine::photos`]): each
//! photo gets a camera placed from its landmarks, one is held out to stop the fit, so it takes
//! three photos in which perception finds the person.

use anyhow::{bail, Context, Result};
use clap::Args;
use image::codecs::gif::{GifEncoder, Repeat};
use image::{Delay, Frame, RgbImage};
use indicatif::{ProgressBar, ProgressStyle};
use lhmpp::body::{motion, Pose};
use lhmpp::config::ModelConfig;
use lhmpp::perception::overlay::draw_overlay;
use lhmpp::perception::{LandmarkModel, PoseNetworks};
use lhmpp::reconstruct::photo_camera::PhotoCameraConfig;
use lhmpp::reconstruct::photo_colours::PhotoColourConfig;
use lhmpp::reconstruct::photos::{
    colour_from_views, photo_view, preprocess_config, reconstruct_photos, FrontStage, PersonHint,
    PhotoView,
};
use lhmpp::reconstruct::Reconstructor;
use lhmpp::refine::photos::refine_photos;
use lhmpp::refine::RefineConfig;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Options of `lhmpp avatar`.
#[derive(Args, Debug)]
pub struct AvatarArgs {
    /// Photos of one person (JPEG or PNG), any number, from any side.
    #[arg(required = true)]
    images: Vec<PathBuf>,
    /// Output directory (created if missing).
    #[arg(short, long)]
    out: PathBuf,
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
    /// Use these masks (mono8 PNG, one per photo, same order) instead of perception's.
    #[arg(long, num_args = 1..)]
    masks: Vec<PathBuf>,
    /// Side of the rendered pictures, pixels.
    #[arg(long, default_value_t = 384)]
    size: u32,
    /// Turntable frames.
    #[arg(long, default_value_t = 36)]
    turntable_frames: usize,
    /// Walk frames (24 per second; the cycle is 40 frames).
    #[arg(long, default_value_t = 40)]
    walk_frames: usize,
    /// Keep the network's colours: no recolouring of the Gaussians the photos show from the
    /// photos themselves.
    #[arg(long)]
    network_colours: bool,
    #[command(flatten)]
    refine: PhotoRefineArgs,
}

/// The fit to the photos' flags, shared by `lhmpp avatar` and `lhmpp eval-photos`.
#[derive(Args, Debug)]
pub struct PhotoRefineArgs {
    /// Fit the avatar to the photos after the network (three photos at least: one is held out
    /// to stop the fit; with fewer the avatar is not fitted).
    #[arg(long, overrides_with = "no_refine")]
    refine: bool,
    /// Do not fit the avatar to the photos (the default).
    #[arg(long)]
    no_refine: bool,
    /// Seconds the fit may take.
    #[arg(long, default_value_t = 10.0)]
    refine_budget: f64,
}

impl PhotoRefineArgs {
    /// The fit's settings, or `None` when no fit is asked for.
    pub fn config(&self) -> Result<Option<RefineConfig>> {
        refine_wanted(self.refine, self.no_refine)
            .then(|| photo_refine_config(self.refine_budget))
            .transpose()
    }
}

/// Whether `lhmpp avatar` and `lhmpp eval-photos` fit the avatar to the photos without
/// `--refine` or `--no-refine` (docs/refinement.md says why).
pub const REFINE_PHOTOS_BY_DEFAULT: bool = false;

/// Whether the flags ask for a fit.
fn refine_wanted(refine: bool, no_refine: bool) -> bool {
    match (refine, no_refine) {
        (true, _) => true,
        (_, true) => false,
        _ => REFINE_PHOTOS_BY_DEFAULT,
    }
}

/// The fit's settings for photos, `budget` seconds at most.
fn photo_refine_config(budget: f64) -> Result<RefineConfig> {
    if !(budget.is_finite() && budget > 0.0) {
        bail!("--refine-budget {budget}: expected a positive number of seconds");
    }
    Ok(RefineConfig {
        budget: std::time::Duration::from_secs_f64(budget),
        ..RefineConfig::default()
    })
}

/// Masks the photos, reconstructs, writes the avatar and its pictures.
pub fn run(args: AvatarArgs) -> Result<()> {
    if !args.masks.is_empty() && args.masks.len() != args.images.len() {
        bail!(
            "--masks: {} masks for {} photos (one per photo, in the same order)",
            args.masks.len(),
            args.images.len()
        );
    }
    let model = ModelConfig {
        preset: args.preset.clone(),
        checkpoint: args.checkpoint.clone(),
        ..ModelConfig::default()
    };
    let refine = args.refine.config()?;
    let mut recon = Reconstructor::new(&model, args.images.len().max(1))?;
    let prep = preprocess_config(&recon);
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
    let masks_dir = args.out.join("masks");
    std::fs::create_dir_all(&masks_dir)
        .with_context(|| format!("creating {}", masks_dir.display()))?;

    let mut views = Vec::new();
    for (i, path) in args.images.iter().enumerate() {
        let given = args.masks.get(i).map(PathBuf::as_path);
        let view = photo_view(
            path,
            given,
            Some(&PersonHint::Best),
            &networks,
            recon.template(),
            &prep,
        )
        .map_err(anyhow::Error::from)
        .and_then(|v| {
            v.map(|v| write_mask(&v, &masks_dir).map(|()| v))
                .transpose()
        });
        match view {
            Ok(Some(v)) => views.push(v),
            Ok(None) => tracing::warn!(photo = %path.display(), "no person found: photo skipped"),
            Err(e) => tracing::error!(photo = %path.display(), "{}", super::error_line(&e)),
        }
    }
    if views.is_empty() {
        bail!(
            "no person found in any of the {} photo(s)",
            args.images.len()
        );
    }
    let started = std::time::Instant::now();
    let mut avatar = reconstruct_photos(&mut recon, &views)?;
    if !args.network_colours {
        colour_from_views(
            &mut avatar,
            recon.template(),
            &views,
            &PhotoColourConfig::default(),
        );
    }
    tracing::info!(
        views = views.len(),
        ms = format!("{:.0}", started.elapsed().as_secs_f64() * 1e3),
        "avatar reconstructed"
    );
    if let Some(config) = &refine {
        avatar = refined(&avatar, recon.template(), &views, config)?;
    }
    let ply = args.out.join("avatar.ply");
    avatar
        .save_ply(&ply)
        .with_context(|| format!("writing {}", ply.display()))?;

    let template = recon.template();
    let stage = FrontStage::new(&avatar, args.size);
    let rest = Pose::identity();
    let turntable: Vec<RgbImage> = (0..args.turntable_frames)
        .map(|i| stage.render_rgb8(&avatar, template, &rest, i, args.turntable_frames))
        .collect::<Result<_, _>>()?;
    write_sequence(&args.out, "turntable", &turntable)?;
    let walk: Vec<RgbImage> = (0..args.walk_frames)
        .map(|f| stage.render_rgb8(&avatar, template, &motion::walk_pose(f as f32), 0, 1))
        .collect::<Result<_, _>>()?;
    write_sequence(&args.out, "walk", &walk)?;
    for v in &views {
        if let Some(pose) = &v.pose {
            let image = stage.render_rgb8(&avatar, template, pose, 0, 1)?;
            let path = args.out.join(format!("posed_{}.png", v.stem));
            image
                .save(&path)
                .with_context(|| format!("writing {}", path.display()))?;
        }
    }
    println!(
        "avatar from {} of {} photo(s): {} ({} Gaussians), turntable and walk in {}",
        views.len(),
        args.images.len(),
        ply.display(),
        avatar.canonical.len(),
        args.out.display()
    );
    Ok(())
}

/// The avatar fitted to the photos, with a progress bar while it runs and a line on what the
/// fit did; the avatar unchanged when the fit could not run or did not beat it.
fn refined(
    avatar: &lhmpp::avatar::Avatar,
    template: &lhmpp::body::BodyTemplate,
    views: &[PhotoView],
    config: &RefineConfig,
) -> Result<lhmpp::avatar::Avatar> {
    let bar = ProgressBar::new(config.max_iterations as u64);
    bar.set_style(
        ProgressStyle::with_template("refining {bar:30} {pos}/{len} steps {msg}")
            .expect("valid template"),
    );
    let fit = refine_photos(
        avatar,
        template,
        views,
        config,
        &PhotoCameraConfig::default(),
        |p| {
            bar.set_position(p.iteration as u64);
            bar.set_message(format!(
                "loss {:.4}, held-out photo {:.4}, {} Gaussians",
                p.loss, p.held, p.gaussians
            ));
            true
        },
    )?;
    bar.finish_and_clear();
    for (photo, camera) in &fit.cameras {
        match camera {
            Ok(c) => tracing::info!(
                photo = %photo,
                miss = format!("{:.1} %", 100.0 * c.rms),
                "camera placed from the landmarks"
            ),
            Err(why) => tracing::warn!(photo = %photo, "no camera: {why}"),
        }
    }
    let Some(done) = fit.refined else {
        println!(
            "not refined: {}",
            fit.skipped.unwrap_or_else(|| "no fit".into())
        );
        return Ok(avatar.clone());
    };
    let r = &done.report;
    println!(
        "refined: {} steps over {} photos in {:.1} s ({:?}), held-out photo `{}` loss {:.4} -> {:.4}, {} -> {} Gaussians, {}",
        r.iterations,
        r.views_fitted,
        r.elapsed.as_secs_f64(),
        r.stop,
        r.held_view.as_deref().unwrap_or("-"),
        r.held.0,
        r.held.1,
        r.gaussians.0,
        r.gaussians.1,
        if r.improved { "kept" } else { "not better: the network's avatar kept" }
    );
    for c in &r.corrections {
        tracing::info!(
            photo = %c.view,
            shift_cm = format!("{:.1} {:.1} {:.1}", 100.0 * c.translation.x, 100.0 * c.translation.y, 100.0 * c.translation.z),
            degrees = format!("{:.1}", c.degrees),
            "camera corrected"
        );
    }
    Ok(done.avatar)
}

/// Writes what perception used for one photo: `<stem>_mask.png` (the mask) and
/// `<stem>_overlay.png` (the mask tinted and the landmark skeleton).
fn write_mask(view: &PhotoView, masks_dir: &Path) -> Result<()> {
    let save = |name: String, img: &dyn Fn(&Path) -> image::ImageResult<()>| {
        let target = masks_dir.join(name);
        img(&target).with_context(|| format!("writing {}", target.display()))
    };
    save(format!("{}_mask.png", view.stem), &|t| view.mask.save(t))?;
    let overlay = draw_overlay(
        &view.image,
        Some(&view.mask),
        view.perceived.as_ref().map(|p| &p.landmarks.image),
        0.5,
    );
    save(format!("{}_overlay.png", view.stem), &|t| overlay.save(t))
}

/// Writes `DIR/NAME/NNN.png` and `DIR/NAME.gif` (24 fps, looping).
fn write_sequence(dir: &Path, name: &str, frames: &[RgbImage]) -> Result<()> {
    let folder = dir.join(name);
    std::fs::create_dir_all(&folder).with_context(|| format!("creating {}", folder.display()))?;
    let bar = ProgressBar::new(frames.len() as u64);
    bar.set_style(
        ProgressStyle::with_template(&format!("{name} {{bar:30}} {{pos}}/{{len}}"))
            .expect("valid template"),
    );
    for (i, f) in frames.iter().enumerate() {
        let path = folder.join(format!("{i:03}.png"));
        f.save(&path)
            .with_context(|| format!("writing {}", path.display()))?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    let gif = dir.join(format!("{name}.gif"));
    let file =
        std::fs::File::create(&gif).with_context(|| format!("creating {}", gif.display()))?;
    let mut encoder = GifEncoder::new_with_speed(std::io::BufWriter::new(file), 10);
    encoder
        .set_repeat(Repeat::Infinite)
        .with_context(|| format!("writing {}", gif.display()))?;
    let delay = Delay::from_numer_denom_ms(1000, 24);
    encoder
        .encode_frames(frames.iter().map(|f| {
            Frame::from_parts(
                image::DynamicImage::ImageRgb8(f.clone()).to_rgba8(),
                0,
                0,
                delay,
            )
        }))
        .with_context(|| format!("writing {}", gif.display()))?;
    Ok(())
}
