//! Work that runs for one person. Today that is the network's reconstruction of their avatar
//! from the views they hold; refinement of the avatar between reruns belongs here too. A job
//! takes a copy of what it reads (the views, the body shape) when it starts, so it holds no
//! borrow of the person: their pose path and frame store go on taking frames while it works,
//! and the job could as well run on a worker thread.

use crate::avatar::Avatar;
use crate::config::Delight;
use crate::node::frame_store::ViewSet;
use crate::node::scheduler::Job;
use crate::reconstruct::photo_colours::{colour_from_evidence, ViewEvidence};
use crate::reconstruct::preprocess::Preprocessed;
use crate::reconstruct::shape::AcceptedShape;
use crate::reconstruct::{ReconstructError, Reconstructor};

/// A reconstruction of one person's avatar from the views they held when it started.
pub struct Reconstruction {
    /// What the scheduler started (person, revision, set version).
    pub job: Job,
    /// The views, as held when the job started.
    pub views: ViewSet,
    /// The body shape to reconstruct with (`None`: the template as shipped).
    pub shape: Option<AcceptedShape>,
}

impl Reconstruction {
    /// Runs the network on the views with the person's shape; with `colours`, recolours the
    /// avatar from what perception saw in each view (`perception.colours_from_views`), with a
    /// fitted key light divided out as that setting says (`perception.delight`).
    pub fn run(
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

    /// Views the avatar is built from.
    pub fn view_count(&self) -> usize {
        self.views.views.len()
    }

    /// Stamp of the newest view (ns since the epoch; 0 without views).
    pub fn stamp_ns(&self) -> i64 {
        self.views
            .views
            .iter()
            .map(|v| v.stamp_ns)
            .max()
            .unwrap_or(0)
    }
}
