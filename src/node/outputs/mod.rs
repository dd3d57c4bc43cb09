//! The one place results leave the node: every avatar revision, status, rendered frame,
//! preview and end-of-replay animation frame goes through a [`Publisher`], and a [`Fanout`]
//! hands them to all of the node's outputs at once: ROS 2 messages ([`ros`]), iceoryx2 shared
//! memory ([`shm`]), the live page ([`web`]) and files on disk ([`files`]); the person masks
//! and the pose perception reads from the cameras go out the same way.
//!
//! Outputs differ in what they take: the live ones ([`Publisher::live`]: ROS 2, shared memory,
//! the live page) take statuses, rendered frames and previews; the files take the avatars and the animation
//! frames ([`Publisher::animation`]). The pipeline renders and poses only for outputs that take
//! the result. Failures are each output's to log: an output never stops the pipeline.

pub mod disk;
pub mod files;
pub mod ros;
pub mod shm;
pub mod web;

pub use disk::DiskUsage;
pub use files::{FileOutputs, Retention};
pub use ros::{avatar_message, compact_message, frame_message, status_message, RosPublisher};
pub use shm::ShmOutputs;
pub use web::WebPublisher;

use crate::avatar::Avatar;
use crate::compact::CompactAvatar;
use crate::msgs::{BodyPose, ReconstructionStatus};
use crate::node::pipeline::RenderedFrame;
use crate::splat::{Gaussians, PlyError};
use image::GrayImage;
use std::path::PathBuf;
use std::sync::OnceLock;

/// An output failed; names the file or the message.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// Writing a PLY failed.
    #[error(transparent)]
    Ply(#[from] PlyError),
    /// Writing a PNG or creating a directory failed.
    #[error("{path}: {message}")]
    File {
        /// File or directory.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// A message could not be built.
    #[error("message: {0}")]
    Message(#[from] crate::msgs::MsgError),
    /// The compact avatar could not be encoded.
    #[error("compact avatar: {0}")]
    Compact(String),
}

/// A new avatar revision as handed to the outputs.
pub struct AvatarUpdate<'a> {
    /// Person id.
    pub person: &'a str,
    /// Revision number.
    pub revision: u64,
    /// Views it was built from.
    pub views_used: usize,
    /// Stamp of the newest view (ns since the epoch).
    pub stamp_ns: i64,
    /// The avatar.
    pub avatar: &'a Avatar,
    /// The body template whose skeleton the skinning refers to.
    pub template: &'a crate::body::BodyTemplate,
    /// Shape coefficients of the avatar's body model (empty: the unshaped template).
    pub shape_params: &'a [f32],
    /// Whether the Gaussians' RGB is display-ready (false: latent, see `neural_renderer`).
    pub rgb_display_ready: bool,
    /// The neural renderer that decodes a latent RGB avatar (empty when display-ready).
    pub neural_renderer: &'a str,
    /// The compact form, encoded by the first output that asks ([`AvatarUpdate::compact`]).
    pub compact: CompactOnce,
}

/// A compact avatar encoded at most once per update, for every output that sends it.
#[derive(Default)]
pub struct CompactOnce(OnceLock<Result<CompactAvatar, String>>);

impl AvatarUpdate<'_> {
    /// The compact form of the avatar (SPZ + skin), encoded on first use; the error text
    /// when it cannot be encoded.
    pub fn compact(&self) -> Result<&CompactAvatar, &str> {
        self.compact
            .0
            .get_or_init(|| CompactAvatar::encode(self.avatar).map_err(|e| e.to_string()))
            .as_ref()
            .map_err(|e| e.as_str())
    }
}

/// One output of the node (ROS 2, shared memory, files).
/// Failures are the output's to log: publishing never stops the pipeline.
pub trait Publisher {
    /// Publishes a new avatar revision.
    fn avatar(&self, update: &AvatarUpdate<'_>);
    /// Publishes the reconstruction status.
    fn status(&self, msg: ReconstructionStatus);
    /// Publishes a rendered frame of `person`'s avatar from virtual camera `camera`.
    fn frame(&self, person: &str, camera: usize, frame: &RenderedFrame, stamp_ns: i64);
    /// Publishes the avatar preview: the Gaussians posed at the latest BodyPose.
    fn preview(&self, _posed: &Gaussians, _stamp_ns: i64) {}
    /// Publishes the person mask perception made of a frame of camera `camera` (resolved
    /// topic): mono8, 255 = person, with the frame's stamp and optical frame.
    fn mask(&self, _camera: &str, _mask: &GrayImage, _stamp_ns: i64, _frame_id: &str) {}
    /// Publishes the pose read from the cameras.
    fn pose(&self, _pose: &BodyPose) {}
    /// A pose accepted from the pose topic for `person` (it animates their avatar; the
    /// message's own `person_id` may be empty): outputs that show the avatar take it; the ROS 2
    /// output does not send it back.
    fn topic_pose(&self, _person: &str, _pose: &BodyPose) {}
    /// Whether this output takes the live stream: statuses, rendered frames and previews
    /// (true by default). The pipeline renders frames, poses previews and sends statuses only
    /// when some output does.
    fn live(&self) -> bool {
        true
    }
    /// Starts storing an end-of-replay animation; `None` (the default) when this output
    /// stores none. The pipeline renders the animation only when some output stores it.
    fn animation(&self) -> Option<Box<dyn Animation + '_>> {
        None
    }
    /// What this output wrote to and removed from disk so far (`None`: it writes no files).
    fn disk_usage(&self) -> Option<DiskUsage> {
        None
    }
}

/// The frames of one end-of-replay animation, stored as they are rendered.
pub trait Animation {
    /// Stores frame `name` (`<person>_cam<i>_<frame>`); whether it was stored.
    fn frame(&mut self, name: &str, frame: &RenderedFrame) -> bool;
    /// Ends the animation; logs what could not be stored.
    fn finish(self: Box<Self>);
}

/// Several outputs behind one, in order.
#[derive(Default)]
pub struct Fanout(pub Vec<Box<dyn Publisher>>);

impl Fanout {
    /// Replaces the live outputs (ROS 2, shared memory) with `publisher`, keeping the others
    /// (the files) first, in their order.
    pub fn replace_live(&mut self, publisher: Option<Box<dyn Publisher>>) {
        self.0.retain(|p| !p.live());
        self.0.extend(publisher);
    }
}

impl Publisher for Fanout {
    fn avatar(&self, update: &AvatarUpdate<'_>) {
        self.0.iter().for_each(|p| p.avatar(update));
    }
    fn status(&self, msg: ReconstructionStatus) {
        self.0.iter().for_each(|p| p.status(msg.clone()));
    }
    fn frame(&self, person: &str, camera: usize, frame: &RenderedFrame, stamp_ns: i64) {
        self.0
            .iter()
            .for_each(|p| p.frame(person, camera, frame, stamp_ns));
    }
    fn preview(&self, posed: &Gaussians, stamp_ns: i64) {
        self.0.iter().for_each(|p| p.preview(posed, stamp_ns));
    }
    fn mask(&self, camera: &str, mask: &GrayImage, stamp_ns: i64, frame_id: &str) {
        self.0
            .iter()
            .for_each(|p| p.mask(camera, mask, stamp_ns, frame_id));
    }
    fn pose(&self, pose: &BodyPose) {
        self.0.iter().for_each(|p| p.pose(pose));
    }
    fn topic_pose(&self, person: &str, pose: &BodyPose) {
        self.0.iter().for_each(|p| p.topic_pose(person, pose));
    }
    fn live(&self) -> bool {
        self.0.iter().any(|p| p.live())
    }
    fn disk_usage(&self) -> Option<DiskUsage> {
        self.0.iter().find_map(|p| p.disk_usage())
    }
    fn animation(&self) -> Option<Box<dyn Animation + '_>> {
        let stores: Vec<_> = self.0.iter().filter_map(|p| p.animation()).collect();
        (!stores.is_empty()).then(|| Box::new(FanoutAnimation(stores)) as Box<dyn Animation + '_>)
    }
}

/// An animation stored by several outputs.
struct FanoutAnimation<'a>(Vec<Box<dyn Animation + 'a>>);

impl Animation for FanoutAnimation<'_> {
    /// Stored when at least one output stored it.
    fn frame(&mut self, name: &str, frame: &RenderedFrame) -> bool {
        self.0
            .iter_mut()
            .fold(false, |stored, a| a.frame(name, frame) | stored)
    }
    fn finish(self: Box<Self>) {
        self.0.into_iter().for_each(|a| a.finish());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A live output that takes everything and does nothing.
    struct Live;

    impl Publisher for Live {
        fn avatar(&self, _update: &AvatarUpdate<'_>) {}
        fn status(&self, _msg: ReconstructionStatus) {}
        fn frame(&self, _: &str, _camera: usize, _frame: &RenderedFrame, _stamp_ns: i64) {}
    }

    #[test]
    fn replacing_the_live_publishers_keeps_the_files() {
        let tmp = tempfile::tempdir().unwrap();
        let files = FileOutputs::new(tmp.path(), Retention::EVERYTHING).unwrap();
        let mut outputs = Fanout(vec![Box::new(files)]);
        assert!(!outputs.live(), "files take no live stream");
        assert!(outputs.animation().is_some(), "files store the animation");
        outputs.replace_live(Some(Box::new(Live)));
        assert!(outputs.live());
        assert_eq!(outputs.0.len(), 2);
        outputs.replace_live(Some(Box::new(Fanout(vec![Box::new(Live), Box::new(Live)]))));
        assert_eq!(outputs.0.len(), 2);
        assert!(!outputs.0[0].live(), "the files stay first");
        outputs.replace_live(None);
        assert!(!outputs.live());
        assert!(outputs.animation().is_some());
    }

    #[test]
    fn nothing_stores_the_animation_without_files() {
        assert!(Fanout::default().animation().is_none());
        assert!(Fanout(vec![Box::new(Live)]).animation().is_none());
        assert!(!Fanout::default().live());
    }
}
