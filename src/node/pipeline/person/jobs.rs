//! Work that runs for one person, beside their pose path: the network's reconstruction of
//! their avatar from the views they hold, then its refinement against those views
//! ([`super::refinement`]). A job takes a copy of what it reads (the views, the body shape, and
//! for a refinement the current avatar, which is shared) when it starts, so it holds no borrow
//! of the person: their pose path and frame store go on taking frames while it works. The
//! pipeline runs it on its jobs lane (a thread of its own when live, see
//! `node::pipeline::lane`) and takes its result back as a message; a job must not assume it
//! runs on the pipeline's thread.

use crate::avatar::Avatar;
use crate::config::Delight;
use crate::node::frame_store::ViewSet;
use crate::node::scheduler::Job;
use crate::reconstruct::delight::KeyLight;
use crate::reconstruct::photo_colours::{colour_from_evidence, ViewEvidence};
use crate::reconstruct::preprocess::Preprocessed;
use crate::reconstruct::shape::AcceptedShape;
use crate::reconstruct::{ReconstructError, Reconstructor};

/// A kind of job that runs for one person on the network all persons share, beside their
/// pose path, and makes a new revision of their avatar. To add a kind (refinement between
/// network reruns, say): a struct holding copies of what it reads, this trait, and the
/// [`Person`](super::Person) step that makes it when due; the pipeline's jobs lane runs any
/// kind alike, publishes its avatar and hands it back to the person as their latest.
pub trait PersonJob: Send + 'static {
    /// What the scheduler started (person, revision, set version).
    fn job(&self) -> &Job;
    /// Makes the avatar on `recon` (the shared network, held by this job while it runs); with
    /// `colours`, recolours it from the views (`perception.colours_from_views`).
    fn run(
        &self,
        recon: &mut Reconstructor,
        colours: Option<Delight>,
    ) -> Result<Made, ReconstructError>;
    /// The views it reads.
    fn views(&self) -> &ViewSet;
    /// The revision its refinement publishes under, when the avatar is to be refined against
    /// the views after it is made ([`super::Refinement`]).
    fn refined_revision(&self) -> Option<u64>;
    /// Whether it remakes the person's current avatar from the same views (only its
    /// refinement is new, and only that is published).
    fn remakes_current(&self) -> bool;
    /// Views the avatar is built from.
    fn view_count(&self) -> usize;
    /// Stamp of the newest view it reads (ns since the epoch; 0 without views).
    fn stamp_ns(&self) -> i64;
}

/// The network's avatar and the key light its colours were de-lit by (when they were).
pub struct Made {
    /// The avatar.
    pub avatar: Avatar,
    /// The key light divided out of the views' colours, its exposures in the order of the
    /// views holding evidence.
    pub light: Option<KeyLight>,
}

/// A reconstruction of one person's avatar from the views they held when it started.
pub struct Reconstruction {
    /// What the scheduler started (person, revision, set version).
    pub job: Job,
    /// The views, as held when the job started.
    pub views: ViewSet,
    /// The body shape to reconstruct with (`None`: the template as shipped).
    pub shape: Option<AcceptedShape>,
    /// The revision the refined avatar is published under (`None`: no refinement).
    pub refined_revision: Option<u64>,
    /// It remakes the current avatar from the same views, to refine it.
    pub remakes_current: bool,
}

impl PersonJob for Reconstruction {
    fn job(&self) -> &Job {
        &self.job
    }

    /// Runs the network on the views with the person's shape; with `colours`, recolours the
    /// avatar from what perception saw in each view (`perception.colours_from_views`), with a
    /// fitted key light divided out as that setting says (`perception.delight`).
    fn run(
        &self,
        recon: &mut Reconstructor,
        colours: Option<Delight>,
    ) -> Result<Made, ReconstructError> {
        let views: Vec<(u64, &Preprocessed)> = self
            .views
            .views
            .iter()
            .map(|v| (v.frame_id, v.image.as_ref()))
            .collect();
        recon.use_shape(self.shape.clone())?;
        let mut avatar = recon.reconstruct(&views)?;
        let mut light = None;
        if let Some(delight) = colours {
            let seen: Vec<&ViewEvidence> = self
                .views
                .views
                .iter()
                .filter_map(|v| v.evidence.as_deref())
                .collect();
            let report = colour_from_evidence(&mut avatar, recon.template(), &seen, delight);
            if delight != Delight::Never {
                light = Some(report.lights.into_iter().next().unwrap_or_default());
            }
        }
        Ok(Made { avatar, light })
    }

    fn views(&self) -> &ViewSet {
        &self.views
    }

    fn refined_revision(&self) -> Option<u64> {
        self.refined_revision
    }

    fn remakes_current(&self) -> bool {
        self.remakes_current
    }

    fn view_count(&self) -> usize {
        self.views.views.len()
    }

    fn stamp_ns(&self) -> i64 {
        self.views
            .views
            .iter()
            .map(|v| v.stamp_ns)
            .max()
            .unwrap_or(0)
    }
}
