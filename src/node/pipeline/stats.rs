//! The pipeline's run counters.

use crate::node::rejections::Rejections;
use crate::node::timings::Timings;
use std::collections::VecDeque;

/// Latencies kept for the summary.
const LATENCIES_KEPT: usize = 256;

/// Counters of one run, printed at the end and used by tests.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PipelineStats {
    /// Camera frames received.
    pub frames: u64,
    /// Frames rejected (preprocessing failed).
    pub rejected: u64,
    /// Frames dropped as near-duplicates of held views.
    pub duplicates: u64,
    /// Frames cropped to the person by a mask of the same stamp (the rest: whole frames).
    pub masked: u64,
    /// Reconstructions run.
    pub reconstructions: u64,
    /// Reconstructions that failed.
    pub failures: u64,
    /// Latest latencies (last frame arrival → avatar published), milliseconds.
    pub latencies_ms: VecDeque<f64>,
    /// Reconstruction run times, milliseconds (same window).
    pub run_times_ms: VecDeque<f64>,
    /// Rendered frames produced.
    pub rendered_frames: u64,
    /// Render periods skipped because rendering a batch took longer than the period of
    /// `outputs.render_rate_hz` (the newest pose wins; per virtual camera).
    pub frames_dropped: u64,
    /// Per-frame render time of the last rendered batch, milliseconds (0: none yet).
    pub last_render_ms: f64,
    /// Body shapes accepted (changes of the shape in use).
    pub shapes_applied: u64,
    /// Body shapes rejected (wrong model, length or values).
    pub shapes_rejected: u64,
    /// Live camera frames' waits in the input queue (arrival → taken by the pipeline).
    pub queue_waits: Timings,
    /// Camera frames' age when taken (`header.stamp` → taken), recorded only for stamps of
    /// the last 10 minutes by this machine's clock (live streams, not replayed bags).
    pub frame_ages: Timings,
    /// Newest frame's arrival → avatar published, over the whole run.
    pub latencies: Timings,
    /// Input messages rejected by the pipeline's checks and reported to it by the bag replay
    /// ([`super::Pipeline::reject`]), by reason; [`super::Pipeline::rejections`] adds the live inputs'.
    pub rejections: Rejections,
    /// Frames camera-only perception ran on.
    pub perceived: u64,
    /// Frames cropped by a mask from perception.
    pub perception_masked: u64,
    /// Frames whose person perception read inside the mask a mask topic gave (their pose,
    /// camera fit and colours as camera-only perception gives them).
    pub read_in_given_masks: u64,
    /// Of the views perception read, those kept with their calibrated camera and the pose topic's pose, whose
    /// colours are projected through that camera (`perception.colours_from_views`).
    pub calibrated_views: u64,
    /// Perceived frames that showed nobody (they never reach the frame store).
    pub no_person: u64,
    /// Time perception took per frame.
    pub perception_times: Timings,
    /// Poses read from the cameras.
    pub camera_poses: u64,
    /// A camera frame's stamp → the pose read from it published, for stamps of the last 10
    /// minutes by this machine's clock (live streams).
    pub pose_ages: Timings,
    /// Views dropped because their camera took up someone else (one person followed).
    pub views_of_another: u64,
    /// Persons the pipeline started following (1 without tracking once a frame arrived).
    pub persons_started: u64,
    /// Tracked persons let go (the tracker forgot or dropped them), with their views.
    pub persons_released: u64,
    /// Refinements run (`refine.enabled`), and those whose avatar was kept (it beat the
    /// network's on the view held out of the fit).
    pub refinements: u64,
    /// Refined avatars published.
    pub refinements_kept: u64,
    /// Optimiser steps over all refinements.
    pub refine_steps: u64,
}

impl PipelineStats {
    /// Counts a finished reconstruction: its latency (newest frame's arrival → published) and
    /// run time.
    pub(super) fn reconstructed(&mut self, latency: std::time::Duration, run: std::time::Duration) {
        push_bounded(&mut self.latencies_ms, latency.as_secs_f64() * 1e3);
        self.latencies.record(latency);
        push_bounded(&mut self.run_times_ms, run.as_secs_f64() * 1e3);
        self.reconstructions += 1;
    }
}

impl PipelineStats {
    /// Counts a refinement.
    pub(super) fn refined(&mut self, report: &crate::refine::RefineReport) {
        self.refinements += 1;
        self.refinements_kept += u64::from(report.improved);
        self.refine_steps += report.iterations as u64;
    }
}

fn push_bounded(q: &mut VecDeque<f64>, v: f64) {
    q.push_back(v);
    while q.len() > LATENCIES_KEPT {
        q.pop_front();
    }
}
