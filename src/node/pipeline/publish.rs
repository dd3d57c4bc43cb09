//! Results to the outputs: each person's statuses (on every state change, and again when the
//! rejection counts change), the person masks perception made, and, at the render and preview
//! rates, every person's frames and the avatar preview.

use super::perceive::PersonSeen;
use super::Pipeline;
use crate::msgs::ReconstructionStatus;
use crate::node::inputs::CameraFrame;
use crate::node::outputs::{status_message, Publisher};
use image::GrayImage;
use std::time::Duration;

/// Shortest time between statuses republished only because the rejection counts changed.
const STATUS_REFRESH: Duration = Duration::from_secs(1);

impl Pipeline {
    /// Publishes `person`'s status.
    pub(super) fn publish_status(
        &mut self,
        person: &str,
        revision: u64,
        latency_ms: f64,
        state: u8,
        message: impl Into<String>,
    ) {
        let mut msg = status_message(
            person,
            self.views_held_by(person),
            revision,
            latency_ms,
            self.stats.last_render_ms,
            state,
            message,
            0,
        );
        (msg.rejected_reasons, msg.rejected_counts) = self.rejection_fields();
        self.send_status(msg);
    }

    fn send_status(&mut self, msg: ReconstructionStatus) {
        if self.outputs.live() {
            self.outputs.status(msg.clone());
            // A released person's last status is not kept (nor are they made again).
            if let Some(state) = self.persons.get_mut(&msg.person_id) {
                state.last_status = Some(msg);
            }
        }
    }

    /// Republishes the statuses (the last ones, or an idle one for the configured person
    /// before any) when the rejection counts changed, at most once per [`STATUS_REFRESH`], so
    /// they show without a state change.
    pub(super) fn refresh_status(&mut self, now: Duration) {
        if !self.outputs.live() || now < self.status_refresh_due {
            return;
        }
        let (reasons, counts) = self.rejection_fields();
        let mut last: Vec<ReconstructionStatus> = self
            .persons
            .values()
            .filter_map(|p| p.last_status.clone())
            .collect();
        if last.is_empty() && !counts.is_empty() {
            let person = self.default_person.clone();
            let views = self.views_held_by(&person);
            let state = if views == 0 {
                ReconstructionStatus::STATE_IDLE
            } else {
                ReconstructionStatus::STATE_WAITING
            };
            last.push(status_message(
                &person,
                views,
                self.revision_of(&person),
                0.0,
                self.stats.last_render_ms,
                state,
                "",
                0,
            ));
        }
        let mut sent = false;
        for mut msg in last {
            if msg.rejected_counts == counts && msg.rejected_reasons == reasons {
                continue;
            }
            (msg.rejected_reasons, msg.rejected_counts) = (reasons.clone(), counts.clone());
            self.send_status(msg);
            sent = true;
        }
        if sent {
            self.status_refresh_due = now + STATUS_REFRESH;
        }
    }

    /// The rejection counts as `ReconstructionStatus` carries them.
    fn rejection_fields(&self) -> (Vec<String>, Vec<u64>) {
        self.rejections()
            .nonzero()
            .map(|(r, n)| (r.as_str().to_owned(), n))
            .unzip()
    }

    /// Publishes the persons' masks perception made of `frame`, as one camera mask
    /// (`outputs.masks`).
    pub(super) fn publish_mask(&self, frame: &CameraFrame, people: &[PersonSeen]) {
        if self.publish_masks && self.outputs.live() {
            let mask = union_mask(people, frame.image.width(), frame.image.height());
            self.outputs
                .mask(&frame.topic, &mask, frame.stamp_ns, &frame.frame_id);
        }
    }

    /// Renders the frames and poses the preview when their periods are due (for live outputs).
    pub(super) fn publish_due(&mut self, now: Duration, clock: &impl Fn() -> Duration) {
        if let (Some(period), true) = (self.render_period, self.outputs.live()) {
            if self.any_avatar() && now >= self.next_render {
                let started = clock();
                self.publish_frames(now);
                let took = clock().saturating_sub(started);
                self.next_render = now + period;
                self.note_render_time(took, period);
            }
        }
        if let (Some(period), true) = (self.preview_period, self.outputs.live()) {
            if self.any_avatar() && now >= self.next_preview {
                self.publish_preview(now);
                self.next_preview = now + period;
            }
        }
    }

    /// Poses the avatar (the configured person's; with tracking, the first tracked person's
    /// that has one) at the pose its frames use and hands it to the publishers' preview.
    fn publish_preview(&self, now: Duration) {
        let Some(person) = self.persons.values().find(|p| p.current().is_some()) else {
            return;
        };
        if !self.outputs.live() {
            return;
        }
        if let Some(posed) = person.posed(now) {
            self.outputs.preview(&posed, super::unix_now_ns());
        }
    }

    /// Renders every person's latest avatar from every virtual camera at the pose their
    /// frames use and hands the frames to the outputs.
    fn publish_frames(&mut self, now: Duration) {
        if !self.outputs.live() {
            return;
        }
        let started = std::time::Instant::now();
        let stamp = super::unix_now_ns();
        let mut count = 0;
        for (id, person) in &self.persons {
            let Some(frames) = person.render(now, &self.cameras, &mut self.frames) else {
                continue;
            };
            for (i, f) in frames.iter().enumerate() {
                self.outputs.frame(id, i, f, stamp);
            }
            count += frames.len();
        }
        self.stats.last_render_ms = started.elapsed().as_secs_f64() * 1e3 / count.max(1) as f64;
        self.stats.rendered_frames += count as u64;
    }

    /// Counts the render periods a batch that took `took` skipped (the next batch starts when
    /// this one ends: the newest pose wins) and says so once, in the log and the status.
    fn note_render_time(&mut self, took: Duration, period: Duration) {
        let periods = took.as_secs_f64() / period.as_secs_f64();
        if periods <= 1.0 {
            return;
        }
        self.drop_debt += periods - 1.0;
        let whole = self.drop_debt.floor();
        self.drop_debt -= whole;
        let with_avatar: Vec<(String, u64)> = self
            .persons
            .iter()
            .filter(|(_, p)| p.current().is_some())
            .map(|(id, p)| (id.clone(), p.revision()))
            .collect();
        let rendered = self.cameras.cameras().len() * with_avatar.len();
        self.stats.frames_dropped += whole as u64 * rendered as u64;
        if self.slow_render_noted {
            return;
        }
        self.slow_render_noted = true;
        let achieved = 1.0 / took.as_secs_f64();
        let message = format!(
            "rendering holds {achieved:.2} Hz per camera, below outputs.render_rate_hz {:.2} \
             ({:.0} ms per batch of {} frame(s), {} renderer): frames drop, the newest pose \
             wins",
            self.render_rate_hz,
            took.as_secs_f64() * 1e3,
            rendered,
            if self.frames.is_neural() {
                "neural"
            } else {
                "gaussians"
            },
        );
        tracing::warn!("{message}");
        for (person, revision) in with_avatar {
            self.publish_status(
                &person,
                revision,
                0.0,
                ReconstructionStatus::STATE_IDLE,
                message.clone(),
            );
        }
    }

    /// Renders a short animation of each person's latest avatar from every virtual camera and
    /// hands it to the outputs that store it (the files write
    /// `frames/<person>_cam<i>_<f>.png`); nothing is rendered when none does. The animation
    /// replays the poses read from the cameras when they drove the avatar (every one kept, up
    /// to the last 240), else `frames` frames of the built-in walk cycle. Returns the frames
    /// stored.
    pub fn write_animation(&mut self, frames: usize) -> usize {
        if !self.any_avatar() {
            return 0;
        }
        let Some(mut animation) = self.outputs.animation() else {
            return 0;
        };
        let mut written = 0;
        for (id, person) in &self.persons {
            if person.current().is_none() {
                continue;
            }
            for (f, pose) in person.animation(frames).iter().enumerate() {
                let started = std::time::Instant::now();
                let Some(images) = person.render_at(pose, &self.cameras, &mut self.frames) else {
                    continue;
                };
                self.stats.last_render_ms =
                    started.elapsed().as_secs_f64() * 1e3 / images.len().max(1) as f64;
                for (c, image) in images.iter().enumerate() {
                    let name = format!("{id}_cam{c}_{f:03}");
                    written += usize::from(animation.frame(&name, image));
                }
            }
        }
        animation.finish();
        self.stats.rendered_frames += written as u64;
        written
    }
}

/// The persons' masks of one frame as one mask (the brightest value per pixel); an empty mask
/// when nobody was found.
fn union_mask(people: &[PersonSeen], width: u32, height: u32) -> GrayImage {
    let mut out = GrayImage::new(width, height);
    for p in people {
        if p.mask.dimensions() != (width, height) {
            continue;
        }
        for (o, m) in out.iter_mut().zip(p.mask.iter()) {
            *o = (*o).max(*m);
        }
    }
    out
}
