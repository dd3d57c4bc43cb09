//! Work that runs for one person, beside their pose path. Today that is the network's
//! reconstruction of their avatar from the views they hold; refinement of the avatar between
//! reruns belongs here too. A job takes a copy of what it reads (the views, the body shape, and
//! for a refinement the current avatar, which is shared) when it starts, so it holds no borrow
//! of the person: their pose path and frame store go on taking frames while it works. The
//! pipeline runs it on its jobs lane (a thread of its own when live, see
//! `node::pipeline::lane`) and takes its result back as a message; a job must not assume it
//! runs on the pipeline's thread.

use crate::avatar::Avatar;
use crate::config::Delight;
use crate::node::frame_store::ViewSet;
use crate::node::scheduler::Job;
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
    ) -> Result<Avatar, ReconstructError>;
    /// Views the avatar is built from.
    fn view_count(&self) -> usize;
    /// Stamp of the newest view it reads (ns since the epoch; 0 without views).
    fn stamp_ns(&self) -> i64;
}

/// A reconstruction of one person's avatar from the views they held when it started.
pub struct Reconstruction {
    /// What the scheduler started (person, revision, set version).
    pub job: Job,
    /// The views, as held when the job started.
    pub views: ViewSet,
    /// The body shape to reconstruct with (`None`: the template as shipped).
    pub shape: Option<AcceptedShape>,
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
    ) -> Result<Avatar, ReconstructError> {
        let views: Vec<(u64, &Preprocessed)> = self
            .views
            .views
            .iter()
            .map(|v| (v.frame_id, v.image.as_ref()))
            .collect();
        recon.use_shape(self.shape.clone())?;
        let mut avatar = recon.reconstruct(&views)?;
        if let Some(delight) = colours {
            let seen: Vec<&ViewEvidence> = self
                .views
                .views
                .iter()
                .filter_map(|v| v.evidence.as_deref())
                .collect();
            colour_from_evidence(&mut avatar, recon.template(), &seen, delight);
        }
        Ok(avatar)
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
