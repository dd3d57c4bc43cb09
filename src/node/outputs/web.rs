//! The live page's output: [`WebPublisher`] hands each avatar revision (its compact form with
//! the skeleton), status and pose to the page's state ([`crate::web::LiveState`]), which the
//! page's server sends to the browsers connected.

use super::{AvatarUpdate, Publisher};
use crate::msgs::{BodyPose, ReconstructionStatus};
use crate::node::pipeline::RenderedFrame;
use crate::web::protocol::{avatar_frame, pose_json, status_json, AvatarHeader};
use crate::web::LiveState;
use std::sync::Arc;

/// Publishes to the live page.
pub struct WebPublisher(pub Arc<LiveState>);

impl Publisher for WebPublisher {
    fn avatar(&self, u: &AvatarUpdate<'_>) {
        let blobs = match u.compact() {
            Ok(b) => b,
            Err(e) => {
                tracing::error!(person = u.person, "live page: compact avatar: {e}");
                return;
            }
        };
        let skeleton = &u.template.skeleton;
        let header = AvatarHeader {
            person: u.person.to_owned(),
            revision: u.revision,
            views_used: u.views_used,
            body_model: u.avatar.body_model.clone(),
            rgb_display_ready: u.rgb_display_ready,
            bone_names: skeleton.bone_names.clone(),
            bone_parents: skeleton
                .parents
                .iter()
                .map(|p| p.map_or(-1, |i| i as i32))
                .collect(),
            bone_rest: skeleton.joints.iter().flat_map(|j| j.to_array()).collect(),
            gaussians_bytes: blobs.gaussians.len(),
            skin_bytes: blobs.skin.len(),
        };
        self.0.set_avatar(
            u.person,
            avatar_frame(&header, &blobs.gaussians, &blobs.skin),
        );
    }

    fn status(&self, msg: ReconstructionStatus) {
        self.0.set_status(&msg.person_id, status_json(&msg));
    }

    fn frame(&self, _person: &str, _camera: usize, _frame: &RenderedFrame, _stamp_ns: i64) {}

    fn pose(&self, pose: &BodyPose) {
        self.0
            .set_pose(&pose.person_id, pose_json(&pose.person_id, pose));
    }

    fn topic_pose(&self, person: &str, pose: &BodyPose) {
        self.0.set_pose(person, pose_json(person, pose));
    }
}
