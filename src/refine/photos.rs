//! Refinement of an avatar made from photos (`lhmpp avatar --refine`, `lhmpp eval-photos
//! --refine`): no photo has a measured camera or pose, so each gets the pinhole camera its
//! landmarks place ([`crate::reconstruct::photo_camera`]) in the pose solved from them
//! ([`crate::reconstruct::photos::photo_pose`]), and the fit corrects each fitted photo's
//! camera as it goes ([`super::RefineConfig::correct_views`]). The photos are fitted as they
//! are lit (their colours are compared as seen: no light model), and like every fit one photo
//! is held out to stop it, so it needs [`super::RefineConfig::min_views`] photos with a camera
//! (three by default); with fewer the avatar is left as the network and the photos' colours
//! made it, since nothing would tell a fit that learns the photos it sees from one that
//! overfits them.

use super::{refine, Progress, RefineConfig, RefineError, RefineView, Refined};
use crate::avatar::Avatar;
use crate::body::BodyTemplate;
use crate::reconstruct::photo_camera::{photo_camera, PhotoCamera, PhotoCameraConfig};
use crate::reconstruct::photos::PhotoView;

/// What [`refine_photos`] did.
#[derive(Debug, Clone)]
pub struct PhotoRefinement {
    /// The fit, when there were enough photos to run it.
    pub refined: Option<Refined>,
    /// Per photo (by its stem), the camera placed, or why none was.
    pub cameras: Vec<(String, Result<PhotoCamera, String>)>,
    /// Why no fit ran, when none did.
    pub skipped: Option<String>,
}

/// The photo as a view to fit to: its placed camera, its pose, its crop around the mask.
fn photo_refine_view(
    view: &PhotoView,
    template: &BodyTemplate,
    camera: &PhotoCameraConfig,
    max_side: u32,
) -> Result<(RefineView, PhotoCamera), String> {
    let (Some(perceived), Some(pose)) = (&view.perceived, &view.pose) else {
        return Err("perception found nobody, so no pose and no camera".into());
    };
    let placed = photo_camera(
        template,
        pose,
        &perceived.landmarks.image,
        view.image.dimensions(),
        camera,
    )
    .map_err(|e| e.to_string())?;
    let skinning = template
        .skeleton
        .try_skinning_matrices(pose)
        .map_err(|e| e.to_string())?;
    let fitted = RefineView::new(
        view.stem.clone(),
        &view.image,
        &view.mask,
        placed.camera,
        skinning,
        max_side,
    )
    .map_err(|e| e.to_string())?;
    Ok((fitted, placed))
}

/// Fits `avatar` (made from `views` on `template`'s skeleton) to the photos (see the module
/// doc). `config` is the fit's (its `correct_views` is turned on here); `on_check` sees each
/// check of the held-out photo and can stop the fit.
pub fn refine_photos(
    avatar: &Avatar,
    template: &BodyTemplate,
    views: &[PhotoView],
    config: &RefineConfig,
    camera: &PhotoCameraConfig,
    on_check: impl FnMut(&Progress) -> bool,
) -> Result<PhotoRefinement, RefineError> {
    let mut fitted = Vec::new();
    let mut cameras = Vec::new();
    for v in views {
        match photo_refine_view(v, template, camera, config.max_side) {
            Ok((view, placed)) => {
                fitted.push(view);
                cameras.push((v.stem.clone(), Ok(placed)));
            }
            Err(why) => {
                tracing::warn!(photo = %v.stem, "not refined against: {why}");
                cameras.push((v.stem.clone(), Err(why)));
            }
        }
    }
    let needed = config.min_views.max(2);
    if fitted.len() < needed {
        return Ok(PhotoRefinement {
            refined: None,
            cameras,
            skipped: Some(format!(
                "{} photo(s) with a camera; a fit needs {needed} (one is held out to stop it)",
                fitted.len()
            )),
        });
    }
    let config = RefineConfig {
        correct_views: true,
        ..config.clone()
    };
    let refined = refine(avatar, fitted, None, &config, on_check)?;
    Ok(PhotoRefinement {
        refined: Some(refined),
        cameras,
        skipped: None,
    })
}
