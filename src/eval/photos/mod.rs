//! Colour fidelity on real photos (`lhmpp eval-photos`): how far the avatar's clothing, skin
//! and hair colours are from the photos it was made from.
//!
//! Per person (one or more photos of them, [`manifest`]):
//!
//! 1. each photo is masked (a given mask, else perception's) and posed by camera-only
//!    perception, and all the person's photos are reconstructed into one avatar, exactly as
//!    `lhmpp avatar` does ([`crate::reconstruct::photos`]);
//!    With [`EvalPhotosConfig::refine`] the avatar is then fitted to the input photos
//!    ([`crate::refine::photos`]), as `lhmpp avatar --refine` does;
//! 2. per photo, the avatar is rendered from the front in the photo's pose (perception's world
//!    landmarks through the pose solver; the rest pose where perception found nobody) on white,
//!    [`EvalPhotosConfig::render_size`] pixels square;
//! 3. body regions ([`regions`]: torso, upper arms, thighs, shins, feet, head) are drawn on
//!    both images from perception's landmarks: on the photo with its mask, on the render with
//!    perception run on the render and the render's opacity (≥ ½) as mask. Where perception
//!    finds nobody in the render, the posed template's landmarks projected by the render's
//!    camera stand in (reported). The render draws the parts (left, right) the photo shows;
//! 4. per region, the per-channel median sRGB colour of its pixels on each image, compared
//!    with CIEDE2000 ([`colour`]).
//!
//! A region the photo does not show (its landmarks not seen, or fewer than
//! [`RegionConfig::min_pixels`] mask pixels) is *not shown* and counts in no mean. One the
//! photo shows but the avatar covers fewer than `min_pixels` of in the render is *uncovered*:
//! its render colour is taken over the region's shapes without the render's mask, so what
//! shows there (the white background where the avatar is missing) is scored, and a model that
//! renders nothing scores badly instead of not at all. (Only a region whose shapes fall outside
//! the render is *not rendered* and unscored.) A person's mean is over all their (photo,
//! region) pairs scored; the overall mean is the mean of the persons' means (each person
//! weighs the same, however many photos they have).

pub mod colour;
pub mod manifest;
pub mod regions;
pub mod sheet;

use crate::body::{BodyTemplate, Pose};
use crate::perception::pose::{template_landmarks, PoseSolveError};
use crate::perception::{Landmark, PerceptionError, PoseNetworks, BODY_LANDMARKS};
use crate::reconstruct::photo_camera::PhotoCameraConfig;
use crate::reconstruct::photo_colours::PhotoColourConfig;
use crate::reconstruct::photos::{
    colour_from_views, perceive_person, photo_view, preprocess_config, reconstruct_photos,
    FrontStage, MaskSource, PersonHint, PhotoError, PhotoView,
};
use crate::reconstruct::{ReconstructError, Reconstructor};
use crate::refine::photos::refine_photos;
use crate::refine::{RefineConfig, RefineError};
use crate::splat::{Camera, RenderOutput};
use colour::{ciede2000, hex, ChannelHistogram, Srgb8};
use image::{GrayImage, RgbImage};
use manifest::{ManifestError, ManifestPerson};
use regions::{region_map, seen_parts, Region, RegionConfig, RegionMap, Sides};
use serde_json::{json, Value};
use std::path::PathBuf;
use std::sync::Arc;

/// Why people could not be scored.
#[derive(Debug, thiserror::Error)]
pub enum EvalPhotosError {
    /// The manifest or photo directory could not be read.
    #[error(transparent)]
    Manifest(#[from] ManifestError),
    /// A photo could not be read, masked or preprocessed, or the avatar rendered.
    #[error(transparent)]
    Photo(#[from] PhotoError),
    /// A perception network failed.
    #[error(transparent)]
    Perception(#[from] PerceptionError),
    /// The template's landmarks could not be placed.
    #[error(transparent)]
    Pose(#[from] PoseSolveError),
    /// The network failed.
    #[error(transparent)]
    Reconstruct(#[from] ReconstructError),
    /// The fit to the photos failed.
    #[error(transparent)]
    Refine(#[from] RefineError),
}

/// Settings of the evaluation.
#[derive(Debug, Clone, PartialEq)]
pub struct EvalPhotosConfig {
    /// Side of the avatar's renders, pixels.
    pub render_size: u32,
    /// Region extraction.
    pub regions: RegionConfig,
    /// Recolour the avatar from the photos (`None`: the network's colours).
    pub photo_colours: Option<PhotoColourConfig>,
    /// Fit the avatar to the input photos after the colours (`None`: no fit).
    pub refine: Option<RefineConfig>,
}

impl Default for EvalPhotosConfig {
    fn default() -> Self {
        Self {
            render_size: 512,
            regions: RegionConfig::default(),
            photo_colours: Some(PhotoColourConfig::default()),
            refine: None,
        }
    }
}

/// How a region compared.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RegionStatus {
    /// Both images show it: ΔE00 taken.
    Scored,
    /// The photo does not show it (landmarks not seen, or too few pixels).
    NotShown,
    /// The photo shows it, the avatar covers too little of it in the render: the render's
    /// colour over the region's shapes, background included, is scored.
    Uncovered,
    /// The photo shows it, the region's shapes fall outside the render: not scored.
    NotRendered,
}

impl RegionStatus {
    /// Name in tables and JSON.
    pub fn name(self) -> &'static str {
        match self {
            RegionStatus::Scored => "scored",
            RegionStatus::NotShown => "not shown",
            RegionStatus::Uncovered => "uncovered",
            RegionStatus::NotRendered => "not rendered",
        }
    }
}

/// A region's median colour on one image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RegionColour {
    /// Per-channel median, 8-bit sRGB.
    pub rgb: Srgb8,
    /// Pixels the median was taken over.
    pub pixels: usize,
}

/// One region of one photo compared with the render.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RegionScore {
    /// The region.
    pub region: Region,
    /// Whether it was compared.
    pub status: RegionStatus,
    /// Its colour on the photo (absent when the photo has no pixel of it).
    pub photo: Option<RegionColour>,
    /// Its colour on the render (absent when the render has no pixel of it).
    pub render: Option<RegionColour>,
    /// CIEDE2000 between the two colours (only when scored).
    pub delta_e: Option<f64>,
}

impl RegionScore {
    /// The JSON record.
    pub fn to_json(&self) -> Value {
        let colour = |c: Option<RegionColour>| {
            c.map(|c| json!({ "hex": hex(c.rgb), "rgb": c.rgb, "pixels": c.pixels }))
        };
        json!({
            "region": self.region.name(),
            "status": self.status.name(),
            "photo": colour(self.photo),
            "render": colour(self.render),
            "delta_e00": self.delta_e,
        })
    }
}

/// The median colour of each region of `image`, with its pixel count.
pub fn region_colours(image: &RgbImage, map: &RegionMap) -> [Option<RegionColour>; 6] {
    let mut hist: [ChannelHistogram; 6] = Default::default();
    for (x, y, p) in image.enumerate_pixels() {
        if x < map.width && y < map.height {
            if let Some(r) = map.at(x, y) {
                hist[r.index()].add(p.0);
            }
        }
    }
    hist.map(|h| {
        h.median().map(|rgb| RegionColour {
            rgb,
            pixels: h.pixels(),
        })
    })
}

/// Compares the regions of a photo and of a render (maps from [`region_map`]; the render's
/// drawn with the photo's parts, once on its mask and once, `render_shapes`, on a full mask
/// for the regions the avatar leaves uncovered).
pub fn compare_regions(
    photo: &RgbImage,
    photo_map: &RegionMap,
    render: &RgbImage,
    render_map: &RegionMap,
    render_shapes: &RegionMap,
    config: &RegionConfig,
) -> Vec<RegionScore> {
    let seen = region_colours(photo, photo_map);
    let drawn = region_colours(render, render_map);
    let shapes = region_colours(render, render_shapes);
    let enough = |c: &Option<RegionColour>| c.is_some_and(|c| c.pixels >= config.min_pixels);
    Region::ALL
        .iter()
        .map(|&region| {
            let i = region.index();
            let p = seen[i];
            let (status, r) = if !enough(&p) {
                (RegionStatus::NotShown, drawn[i])
            } else if enough(&drawn[i]) {
                (RegionStatus::Scored, drawn[i])
            } else if enough(&shapes[i]) {
                (RegionStatus::Uncovered, shapes[i])
            } else {
                (RegionStatus::NotRendered, drawn[i])
            };
            let delta_e = match (status, p, r) {
                (RegionStatus::Scored | RegionStatus::Uncovered, Some(p), Some(r)) => {
                    Some(ciede2000(p.rgb, r.rgb))
                }
                _ => None,
            };
            RegionScore {
                region,
                status,
                photo: p,
                render: r,
                delta_e,
            }
        })
        .collect()
}

/// The photo's regions: the parts its landmarks show, on its mask.
pub fn photo_regions(
    landmarks: &[Landmark; BODY_LANDMARKS],
    mask: &GrayImage,
    config: &RegionConfig,
) -> RegionMap {
    region_map(landmarks, mask, seen_parts(landmarks, config), config)
}

/// Where the render's landmarks came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RenderLandmarks {
    /// Perception on the render, as on the photo.
    Perception,
    /// Perception found nobody in the render: the posed template's landmarks, projected.
    Template,
}

/// One photo of a person, scored.
#[derive(Debug, Clone)]
pub struct ViewScore {
    /// The photo.
    pub photo: PathBuf,
    /// Where its mask came from.
    pub mask: MaskSource,
    /// Whether perception found the person in it (without, no region is shown).
    pub person_found: bool,
    /// Whether the render is in the photo's pose (else the rest pose).
    pub posed: bool,
    /// Where the render's landmarks came from.
    pub render_landmarks: RenderLandmarks,
    /// The regions, in [`Region::ALL`] order.
    pub regions: Vec<RegionScore>,
}

impl ViewScore {
    /// ΔE00 of the scored regions.
    pub fn scored(&self) -> impl Iterator<Item = f64> + '_ {
        self.regions.iter().filter_map(|r| r.delta_e)
    }

    /// The JSON record.
    pub fn to_json(&self) -> Value {
        json!({
            "photo": self.photo,
            "mask": match self.mask {
                MaskSource::Given => "given",
                MaskSource::Perception => "perception",
            },
            "person_found": self.person_found,
            "pose": if self.posed { "photo" } else { "rest" },
            "render_landmarks": match self.render_landmarks {
                RenderLandmarks::Perception => "perception",
                RenderLandmarks::Template => "template",
            },
            "regions": self.regions.iter().map(RegionScore::to_json).collect::<Vec<_>>(),
        })
    }
}

/// What a scored view looked like, for the contact sheet.
#[derive(Debug, Clone)]
pub struct ViewPicture {
    /// The photo.
    pub photo: RgbImage,
    /// The photo's person mask.
    pub photo_mask: GrayImage,
    /// The photo's regions.
    pub photo_map: RegionMap,
    /// The render.
    pub render: RgbImage,
    /// The render's mask.
    pub render_mask: GrayImage,
    /// The render's regions.
    pub render_map: RegionMap,
    /// The comparison.
    pub regions: Vec<RegionScore>,
}

/// One person scored.
#[derive(Debug, Clone)]
pub struct PersonScore {
    /// Name from the manifest.
    pub name: String,
    /// Note from the manifest.
    pub note: String,
    /// The photos scored.
    pub views: Vec<ViewScore>,
    /// Photos left out, and why.
    pub skipped: Vec<(PathBuf, String)>,
    /// What the fit to the photos did (with [`EvalPhotosConfig::refine`]).
    pub refinement: Option<String>,
}

impl PersonScore {
    /// ΔE00 of every scored (photo, region) pair.
    pub fn scored(&self) -> Vec<f64> {
        self.views.iter().flat_map(ViewScore::scored).collect()
    }

    /// Mean ΔE00 over the scored pairs; `None` when none was scored.
    pub fn mean(&self) -> Option<f64> {
        mean(&self.scored())
    }

    /// The JSON record.
    pub fn to_json(&self) -> Value {
        json!({
            "name": self.name,
            "note": self.note,
            "views": self.views.iter().map(ViewScore::to_json).collect::<Vec<_>>(),
            "skipped": self.skipped.iter().map(|(p, why)| json!({ "photo": p, "why": why }))
                .collect::<Vec<_>>(),
            "refinement": self.refinement,
            "regions_scored": self.scored().len(),
            "mean_delta_e00": self.mean(),
        })
    }
}

/// The mean of the persons' means (persons with nothing scored left out).
pub fn overall_mean(people: &[PersonScore]) -> Option<f64> {
    mean(
        &people
            .iter()
            .filter_map(PersonScore::mean)
            .collect::<Vec<_>>(),
    )
}

fn mean(values: &[f64]) -> Option<f64> {
    (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64)
}

/// The mono8 mask of a render: 255 where its opacity is at least ½.
pub fn render_mask(out: &RenderOutput) -> GrayImage {
    let data = out
        .alpha
        .iter()
        .map(|a| if *a >= 0.5 { 255 } else { 0 })
        .collect();
    GrayImage::from_raw(out.width, out.height, data).expect("alpha holds H × W values")
}

/// The posed template's landmarks projected by `camera`, all seen.
pub fn projected_landmarks(
    template: &BodyTemplate,
    pose: &Pose,
    camera: &Camera,
) -> Result<[Landmark; BODY_LANDMARKS], PoseSolveError> {
    let world = template_landmarks(template, pose)?;
    let from_world = camera.camera_from_world();
    Ok(world.map(|p| {
        let c = from_world.transform_point3(p);
        Landmark {
            position: camera.project_camera_point(c).extend(c.z),
            visibility: 1.0,
            presence: 1.0,
        }
    }))
}

/// Scores one photo against a render of the avatar: `render` is the avatar in the photo's
/// pose, `render_landmarks` what perception read in it. The photo's regions come from
/// `photo_landmarks` (none: nothing shown) and `photo_mask`.
pub fn score_view(
    photo: &RgbImage,
    photo_mask: &GrayImage,
    photo_landmarks: Option<&[Landmark; BODY_LANDMARKS]>,
    render: &RgbImage,
    render_mask: &GrayImage,
    render_landmarks: &[Landmark; BODY_LANDMARKS],
    config: &RegionConfig,
) -> ViewPicture {
    let nothing: Sides = [[false; 2]; 6];
    let photo_map = match photo_landmarks {
        Some(l) => photo_regions(l, photo_mask, config),
        None => region_map(render_landmarks, photo_mask, nothing, config),
    };
    let render_map = region_map(render_landmarks, render_mask, photo_map.sides, config);
    let everywhere = GrayImage::from_pixel(render.width(), render.height(), image::Luma([255]));
    let render_shapes = region_map(render_landmarks, &everywhere, photo_map.sides, config);
    let regions = compare_regions(
        photo,
        &photo_map,
        render,
        &render_map,
        &render_shapes,
        config,
    );
    ViewPicture {
        photo: photo.clone(),
        photo_mask: photo_mask.clone(),
        photo_map,
        render: render.clone(),
        render_mask: render_mask.clone(),
        render_map,
        regions,
    }
}

/// Reconstructs one person from all their photos and scores each photo against the avatar
/// rendered in its pose; with held-out photos in the manifest, the avatar is made from the
/// others and only the held-out ones are scored. Photos in which nobody is found (and no mask
/// is given) are skipped; a person with no photo left has no views.
pub fn score_person(
    recon: &mut Reconstructor,
    networks: &Arc<PoseNetworks>,
    person: &ManifestPerson,
    config: &EvalPhotosConfig,
) -> Result<(PersonScore, Vec<ViewPicture>), EvalPhotosError> {
    let prep = preprocess_config(recon);
    let mut views: Vec<PhotoView> = Vec::new();
    let mut paths = Vec::new();
    let mut heldout = Vec::new();
    let mut skipped = Vec::new();
    for v in &person.views {
        match photo_view(
            &v.photo,
            v.mask.as_deref(),
            v.person.as_ref(),
            networks,
            recon.template(),
            &prep,
        )? {
            Some(view) => {
                views.push(view);
                paths.push(v.photo.clone());
                heldout.push(v.heldout);
            }
            None => skipped.push((v.photo.clone(), "no person found".to_string())),
        }
    }
    let mut score = PersonScore {
        name: person.name.clone(),
        note: person.note.clone(),
        views: Vec::new(),
        skipped,
        refinement: None,
    };
    if views.is_empty() {
        return Ok((score, Vec::new()));
    }
    let any_heldout = heldout.iter().any(|h| *h);
    let inputs: Vec<PhotoView> = views
        .iter()
        .zip(&heldout)
        .filter(|(_, h)| !**h)
        .map(|(v, _)| v.clone())
        .collect();
    if inputs.is_empty() {
        return Ok((score, Vec::new()));
    }
    let mut avatar = reconstruct_photos(recon, &inputs)?;
    let template = recon.template();
    if let Some(colours) = &config.photo_colours {
        colour_from_views(&mut avatar, template, &inputs, colours);
    }
    if let Some(refine) = &config.refine {
        let fit = refine_photos(
            &avatar,
            template,
            &inputs,
            refine,
            &PhotoCameraConfig::default(),
            |p| {
                tracing::debug!(person = %person.name, ?p, "refining");
                true
            },
        )?;
        score.refinement = Some(match fit.refined {
            Some(done) => {
                let r = &done.report;
                let summary = format!(
                    "{} steps over {} photos ({:?}), held-out photo loss {:.4} → {:.4}, {}",
                    r.iterations,
                    r.views_fitted,
                    r.stop,
                    r.held.0,
                    r.held.1,
                    if r.improved { "kept" } else { "not kept" }
                );
                avatar = done.avatar;
                summary
            }
            None => format!(
                "not refined: {}",
                fit.skipped.unwrap_or_else(|| "no fit".into())
            ),
        });
    }
    let stage = FrontStage::new(&avatar, config.render_size);
    let mut pictures = Vec::new();
    for ((view, path), held) in views.iter().zip(paths).zip(heldout) {
        if any_heldout && !held {
            continue;
        }
        let pose = view.pose.clone().unwrap_or_else(Pose::identity);
        let out = stage.render(&avatar, template, &pose, 0, 1)?;
        let render = out.to_rgb8();
        let mask = render_mask(&out);
        let (landmarks, source) = match perceive_person(networks, &render, &PersonHint::Best)? {
            Some(p) => (p.landmarks.image, RenderLandmarks::Perception),
            None => (
                projected_landmarks(template, &pose, &stage.camera(0, 1))?,
                RenderLandmarks::Template,
            ),
        };
        let picture = score_view(
            &view.image,
            &view.mask,
            view.perceived.as_ref().map(|p| &p.landmarks.image),
            &render,
            &mask,
            &landmarks,
            &config.regions,
        );
        score.views.push(ViewScore {
            photo: path,
            mask: view.mask_source,
            person_found: view.perceived.is_some(),
            posed: view.pose.is_some(),
            render_landmarks: source,
            regions: picture.regions.clone(),
        });
        pictures.push(picture);
    }
    Ok((score, pictures))
}
