//! `lhmpp render AVATAR.ply --pose walk:0..60 --camera orbit:8 --size 592 -o out/frames/`:
//! poses a Gaussian avatar on the body template's skeleton and writes PNG frames.
//!
//! Every pose frame is rendered from every camera view, into `f{frame:04}_v{view:02}.png`.
//! Skinning weights come from the PLY's `skin_*` extension properties; without them each
//! Gaussian takes the weights of the nearest template vertex.

use anyhow::{bail, Context, Result};
use clap::Args;
use glam::Vec3;
use indicatif::{ProgressBar, ProgressStyle};
use lhmpp::avatar::Avatar;
use lhmpp::body::{motion::parse_pose_spec, BodyTemplate};
use lhmpp::splat::{nearest_vertex_skin, read_ply, render, Camera, Intrinsics, RenderOptions};
use std::path::PathBuf;

/// Options of `lhmpp render`.
#[derive(Args, Debug)]
pub struct RenderArgs {
    /// Avatar PLY (3DGS layout; canonical pose of the body template).
    avatar: PathBuf,
    /// Poses: `rest`, `tpose`, `walk:F` or `walk:A..B` (frames A to B-1).
    #[arg(long, default_value = "rest")]
    pose: String,
    /// Cameras: `orbit:N` (N views around the body) or `front`.
    #[arg(long, default_value = "orbit:8")]
    camera: String,
    /// Image width and height (pixels).
    #[arg(long, default_value_t = 592)]
    size: u32,
    /// Vertical field of view (degrees).
    #[arg(long, default_value_t = 45.0)]
    fov: f32,
    /// Background colour `r,g,b` in [0, 1].
    #[arg(long, value_delimiter = ',', default_value = "1,1,1")]
    background: Vec<f32>,
    /// Output directory (created if missing).
    #[arg(short, long)]
    out: PathBuf,
}

/// Number of orbit views in a camera spec.
fn parse_camera_spec(spec: &str) -> Result<usize> {
    match spec.split_once(':') {
        None if spec == "front" => Ok(1),
        Some(("orbit", n)) => {
            let n: usize = n
                .trim()
                .parse()
                .with_context(|| format!("camera spec `{spec}`: `{n}` is not a count"))?;
            if n == 0 {
                bail!("camera spec `{spec}`: need at least one view");
            }
            Ok(n)
        }
        _ => bail!("camera spec `{spec}`: expected `orbit:N` or `front`"),
    }
}

/// Renders the frames.
pub fn run(args: RenderArgs) -> Result<()> {
    let views = parse_camera_spec(&args.camera)?;
    let poses =
        parse_pose_spec(&args.pose).with_context(|| format!("pose spec `{}`", args.pose))?;
    let [r, g, b] = args.background[..] else {
        bail!(
            "--background needs three values r,g,b, got {:?}",
            args.background
        );
    };
    let ply = read_ply(&args.avatar)?;
    let template = BodyTemplate::load_default().context("loading the embedded body template")?;
    let gaussians = ply.gaussians;
    let skin = match ply.skin {
        Some(skin) => skin,
        None => {
            tracing::info!(path = %args.avatar.display(), "no skinning weights in the PLY: binding to the nearest template vertices");
            nearest_vertex_skin(&gaussians.positions, &template.vertices, &template.skin)
        }
    };
    let body_model = ply.body_model.unwrap_or_else(|| "makehuman-cc0".into());
    let avatar = Avatar::new(gaussians, skin, body_model)
        .with_context(|| format!("binding {}", args.avatar.display()))?;

    // Frame the canonical body: orbit its bounding-box centre at a distance that fits its height.
    let (lo, hi) = avatar
        .canonical
        .positions
        .iter()
        .filter(|p| p.is_finite())
        .fold((Vec3::MAX, Vec3::MIN), |(l, h), p| (l.min(*p), h.max(*p)));
    if lo.x > hi.x {
        bail!(
            "{}: the avatar has no finite Gaussian",
            args.avatar.display()
        );
    }
    let target = 0.5 * (lo + hi);
    let fov = args.fov.to_radians();
    let extent = (hi - lo).max_element();
    let radius = 0.6 * extent / (0.5 * fov).tan() + 0.5 * (hi.z - lo.z);
    let intrinsics = Intrinsics::from_fov_y(args.size, args.size, fov);
    let cameras: Vec<Camera> = (0..views)
        .map(|i| Camera::orbit(i, views, radius, 0.0, target, intrinsics))
        .collect();
    let options = RenderOptions {
        background: Vec3::new(r, g, b),
        ..Default::default()
    };

    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let bar = ProgressBar::new((poses.len() * views) as u64);
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} frames {elapsed} ({per_sec})")
            .expect("valid template"),
    );
    let mut posed = avatar.canonical.clone();
    for (f, pose) in poses.iter().enumerate() {
        let matrices = template
            .skeleton
            .try_skinning_matrices(pose)
            .with_context(|| format!("pose {f} of `{}`", args.pose))?;
        avatar.check_matrices(&matrices)?;
        avatar.animate_into(&matrices, &mut posed);
        for (v, camera) in cameras.iter().enumerate() {
            let frame = render(&posed, camera, &options);
            let path = args.out.join(format!("f{f:04}_v{v:02}.png"));
            frame
                .to_rgb8()
                .save(&path)
                .with_context(|| format!("writing {}", path.display()))?;
            bar.inc(1);
        }
    }
    bar.finish();
    tracing::info!(frames = poses.len() * views, out = %args.out.display(), "rendered");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::parse_camera_spec;

    #[test]
    fn camera_specs_parse_or_name_the_bad_spec() {
        assert_eq!(parse_camera_spec("orbit:8").unwrap(), 8);
        assert_eq!(parse_camera_spec("front").unwrap(), 1);
        assert!(parse_camera_spec("orbit:x")
            .unwrap_err()
            .to_string()
            .contains("orbit:x"));
        assert!(parse_camera_spec("orbit:0").is_err());
        assert!(parse_camera_spec("spiral")
            .unwrap_err()
            .to_string()
            .contains("spiral"));
    }
}
