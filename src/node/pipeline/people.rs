//! Perception results to persons: each person perceived in a frame goes to their [`Person`]
//! (made when first seen; with tracking, released when the tracker lets go of them), with
//! their view for the frame store when their camera is routed to perception; cluster
//! membership hands persons to this node or away from it.

use super::perceive::{PerceivedFrame, Task};
use super::person::{Person, PosePath};
use super::Pipeline;
use crate::node::frame_store::{thumbnail_embedding, InsertOutcome, View};
use crate::node::inputs::CameraFrame;
use crate::node::rejections::RejectReason;
use crate::reconstruct::photo_colours::ViewEvidence;
use crate::reconstruct::preprocess::{preprocess, Subject};
use image::GrayImage;
use std::sync::Arc;
use std::time::Duration;

/// Side of the thumbnail grid used as the frame-store embedding (cheap, no network pass).
const EMBEDDING_GRID: u32 = 12;
/// How often the pipeline looks for perception results while perception is busy.
const PERCEPTION_POLL: Duration = Duration::from_millis(5);

/// What perception saw of a person in one frame, as the frame store takes it.
pub(super) struct StoreInput {
    /// The person's mask over the frame (`None`: the whole frame).
    pub(super) mask: Option<Arc<GrayImage>>,
    /// Their landmarks and mask for the colours (`perception.colours_from_views`).
    pub(super) evidence: Option<Arc<ViewEvidence>>,
    /// How much of their box others covered ([`View::hidden`]).
    pub(super) hidden: f32,
}

impl StoreInput {
    /// The whole frame, nothing perceived.
    pub(super) fn whole_frame() -> Self {
        Self {
            mask: None,
            evidence: None,
            hidden: 0.0,
        }
    }
}

impl Pipeline {
    /// Handles the frames perception has finished.
    pub(super) fn take_perceived(&mut self, now: Duration) {
        let Some(perception) = self.perception.as_mut() else {
            return;
        };
        for done in perception.take_results() {
            self.on_perceived(done, now);
        }
        self.perception_due = now + PERCEPTION_POLL;
    }

    /// A perceived frame: the persons' masks are published (together, one camera mask), each
    /// person's landmarks update their camera pose and body height, and frames perceived for
    /// the store go on to each person's frame store cropped by their mask: perception's, or the
    /// mask topic's the person was read inside (with nobody found, perception's frames go no
    /// further; a mask topic's go on without what perception reads).
    fn on_perceived(&mut self, done: PerceivedFrame, now: Duration) {
        let PerceivedFrame {
            frame,
            people,
            tracked,
            task,
            took,
        } = done;
        self.stats.perceived += 1;
        self.stats.perception_times.record(took);
        let given_mask = matches!(task, Task::Within(_));
        if !given_mask {
            // A topic's mask is the user's own: it is not published again.
            self.publish_mask(&frame, &people);
        }
        if self.tracking {
            self.release_untracked(&tracked);
        }
        let to_store = task.stores();
        if people.is_empty() && to_store {
            if let Task::Within(mask) = task {
                // The mask topic says where the person is: the frame goes on cropped by it,
                // without what perception would have read.
                tracing::debug!(topic = %frame.topic, "nobody read inside the given mask");
                let person = self.default_person.clone();
                let seen = StoreInput {
                    mask: Some(mask),
                    evidence: None,
                    hidden: 0.0,
                };
                self.on_frame(frame, seen, &person, now);
                return;
            }
            self.stats.no_person += 1;
            tracing::debug!(topic = %frame.topic, "no person in the frame: not stored");
        }
        for seen in people {
            // Persons another cluster member reconstructs are followed too (views, pose,
            // height), so that they can be handed over at once.
            let person = seen.id.unwrap_or_else(|| self.default_person.clone());
            if self.tracking && !tracked.contains(&person) {
                // Dropped by the tracker in this very frame (past tracking.max_persons).
                continue;
            }
            self.person_mut(&person);
            if seen.someone_else {
                self.someone_else_in(&frame.topic, &person, now);
            }
            self.on_camera_landmarks(&person, &frame, &seen.world, now);
            self.on_calibrated_landmarks(&person, &frame, &seen.image, now);
            if to_store {
                if given_mask {
                    self.stats.read_in_given_masks += 1;
                } else {
                    self.stats.perception_masked += 1;
                }
                let evidence = self.colours_from_views.then(|| {
                    let evidence =
                        ViewEvidence::new(&frame.image, &seen.mask, &seen.image, &seen.world);
                    Arc::new(match self.calibrated_view(&person, &frame) {
                        Some((camera, pose)) => {
                            self.stats.calibrated_views += 1;
                            evidence.with_calibration(camera, pose)
                        }
                        None => evidence,
                    })
                });
                let seen_as = StoreInput {
                    mask: Some(seen.mask),
                    evidence,
                    hidden: seen.hidden,
                };
                self.on_frame(frame.clone(), seen_as, &person, now);
            }
        }
    }

    /// A frame of `person` (cropped by their mask, else whole; with what perception saw of
    /// them), preprocessed for the network, into their frame store.
    pub(super) fn on_frame(
        &mut self,
        frame: CameraFrame,
        seen: StoreInput,
        person: &str,
        now: Duration,
    ) {
        let StoreInput {
            mask,
            evidence,
            hidden,
        } = seen;
        self.person_mut(person);
        let subject = mask.as_deref().map_or(Subject::FullFrame, Subject::Mask);
        let image = match preprocess(&frame.image, subject, &self.preprocess) {
            Ok(image) => Arc::new(image),
            Err(e) => {
                self.stats.rejected += 1;
                self.stats.rejections.add(RejectReason::Frame);
                tracing::warn!(topic = %frame.topic, "frame rejected: {e}");
                return;
            }
        };
        let frame_id = self.next_frame_id;
        self.next_frame_id += 1;
        let view = View {
            frame_id,
            camera: frame.topic,
            stamp_ns: frame.stamp_ns,
            arrival: frame.arrival,
            embedding: thumbnail_embedding(&image, EMBEDDING_GRID),
            image,
            evidence,
            hidden,
        };
        let outcome = self.person_mut(person).add_view(view, now);
        if outcome.changed() {
            // A fit in flight stops: a new network avatar is due.
            self.refine_news
                .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        }
        match outcome {
            InsertOutcome::Dropped { .. } => self.stats.duplicates += 1,
            InsertOutcome::DroppedHidden => {}
            InsertOutcome::AddedEvicting { evicted } => self.network.forget(evicted),
            InsertOutcome::Replaced { replaced, .. } => self.network.forget(replaced),
            InsertOutcome::Added => {}
        }
    }

    /// `camera`'s tracker took up someone other than the person it followed (one person
    /// followed): the views it gave `person` show the one before, and are dropped, so that the
    /// next avatar is made of the new person's views.
    fn someone_else_in(&mut self, camera: &str, person: &str, now: Duration) {
        let dropped = self.person_mut(person).drop_camera(camera, now);
        for frame_id in &dropped {
            self.network.forget(*frame_id);
        }
        self.stats.views_of_another += dropped.len() as u64;
        tracing::info!(
            camera,
            person,
            views = dropped.len(),
            "the camera follows someone else now: its views of the one before dropped"
        );
    }

    /// `person`, made when first seen: with tracking, this node reconstructs them when
    /// `cluster` gives them to it.
    pub(super) fn person_mut(&mut self, person: &str) -> &mut Person {
        if !self.persons.contains_key(person) {
            let owned = !self.tracking || self.membership.owns(person);
            let setup = &self.setup;
            let pose = PosePath::new(setup.source, setup.estimator.clone());
            self.stats.persons_started += 1;
            if self.tracking {
                tracing::info!(person, reconstructed_here = owned, "tracking a new person");
            }
            let made = Person::new(setup.limits.clone(), setup.schedule.clone(), pose, owned);
            self.persons.insert(person.to_owned(), made);
        }
        self.persons.get_mut(person).expect("inserted above")
    }

    /// The person a pose or shape message is for: its `person_id`, or the configured person
    /// when it has none and nobody is tracked; `None` when no followed person has that id.
    pub(super) fn addressee(&self, person_id: &str) -> Option<String> {
        match (person_id.is_empty(), self.tracking) {
            (true, false) => Some(self.default_person.clone()),
            (true, true) => None,
            (false, false) => (person_id == self.default_person).then(|| person_id.to_owned()),
            (false, true) => self
                .persons
                .contains_key(person_id)
                .then(|| person_id.to_owned()),
        }
    }

    /// Lets go of tracked persons the tracker no longer holds: their views, schedule and
    /// avatar (their avatar was published; it is no longer rendered).
    fn release_untracked(&mut self, tracked: &[String]) {
        let gone: Vec<String> = self
            .persons
            .keys()
            .filter(|p| !tracked.contains(p))
            .cloned()
            .collect();
        for person in gone {
            let released = self.persons.remove(&person).expect("listed above");
            for frame_id in released.frame_ids() {
                self.network.forget(frame_id);
            }
            self.stats.persons_released += 1;
            tracing::info!(person, "person no longer tracked: released");
        }
    }

    /// After a change of the alive members: persons handed to this node are scheduled (their
    /// views are already held), persons handed away stop being reconstructed here.
    pub(super) fn reassign(&mut self, now: Duration) {
        for (person, state) in &mut self.persons {
            let owned = self.membership.owns(person);
            if state.owned() == owned {
                continue;
            }
            if owned {
                tracing::info!(person, "person handed to this node");
            } else {
                tracing::info!(person, "person handed to another cluster member");
            }
            state.hand_over(owned, now);
        }
    }
}
