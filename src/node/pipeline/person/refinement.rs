//! Background work for one person after the network made their avatar: the avatar fitted to
//! the views it was made from ([`crate::refine`]). The fit takes a copy of what it reads (the
//! views cropped around the person, their poses, the light the colours were de-lit by), so it
//! holds no borrow of the person, and stops as soon as its caller says a new view arrived.

use crate::avatar::Avatar;
use crate::body::BodyTemplate;
use crate::node::frame_store::ViewSet;
use crate::reconstruct::delight::KeyLight;
use crate::reconstruct::surface::canonical_normals;
use crate::refine::{refine, LightStart, RefineConfig, RefineError, RefineView, Refined};

/// A fit of one avatar to the calibrated views it was made from, ready to run.
pub struct Refinement {
    views: Vec<RefineView>,
    light: Option<LightStart>,
    config: RefineConfig,
}

impl Refinement {
    /// The fit of `avatar` (built on `template`) to those of `views` whose camera and pose are
    /// known ([`crate::reconstruct::photo_colours::ViewEvidence::calibration`]), with `light`
    /// (the key light the avatar's colours were de-lit by, its exposures in the order of the
    /// views holding evidence) as the fit's starting light. `None` when fewer views than the
    /// fit needs are calibrated.
    pub fn prepare(
        avatar: &Avatar,
        template: &BodyTemplate,
        views: &ViewSet,
        light: Option<&KeyLight>,
        config: &RefineConfig,
    ) -> Option<Self> {
        let mut fitted = Vec::new();
        let seen = views.views.iter().filter_map(|v| v.evidence.as_deref());
        for (i, evidence) in seen.enumerate() {
            let Some((camera, pose)) = &evidence.calibration else {
                continue;
            };
            let skinning = template.skeleton.skinning_matrices(pose);
            match RefineView::new(
                format!("view {i}"),
                &evidence.frame,
                &evidence.mask,
                *camera,
                skinning,
                config.max_side,
            ) {
                Ok(mut view) => {
                    if let Some(l) = light {
                        view.exposure = l.exposure.get(i).copied().unwrap_or(0.0);
                    }
                    fitted.push(view);
                }
                Err(e) => tracing::debug!("refinement skips a view: {e}"),
            }
        }
        if fitted.len() < config.min_views {
            return None;
        }
        let light = light.map(|key| LightStart {
            key: key.clone(),
            normals: canonical_normals(avatar, template).0,
        });
        Some(Self {
            views: fitted,
            light,
            config: config.clone(),
        })
    }

    /// Fits `avatar`; stops early (keeping the best so far) once `cancelled` says so, which is
    /// asked at each check of the held-out view.
    pub fn run(
        self,
        avatar: &Avatar,
        cancelled: impl Fn() -> bool,
    ) -> Result<Refined, RefineError> {
        refine(avatar, self.views, self.light, &self.config, |p| {
            tracing::trace!(?p, "refining");
            !cancelled()
        })
    }
}
