//! The shared-memory output: [`ShmOutputs`] publishes avatars and rendered frames as iceoryx2
//! services. Failures are logged; they never stop the pipeline.

use super::{AvatarUpdate, Publisher};
use crate::msgs::ReconstructionStatus;
use crate::node::pipeline::RenderedFrame;
use crate::splat::sh_dc_to_rgb;
use crate::transport::{
    AvatarView, FrameShape, PayloadBody, ShmError, ShmNode, ShmOptions, ShmPublisher, Stamp,
};
use std::collections::VecDeque;
use std::sync::Mutex;

/// Publishes avatars and rendered frames over iceoryx2 (layout: `docs/shm-layout.md`), one
/// set of services per person; a tracked person's are made at their first avatar or frame,
/// and only the most recently used persons' are kept.
pub struct ShmOutputs {
    node: ShmNode,
    virtual_cameras: u32,
    /// Persons whose services are kept.
    kept: usize,
    /// Services by person, most recently used last.
    persons: Mutex<VecDeque<(String, PersonServices)>>,
}

/// One person's services.
struct PersonServices {
    avatar: ShmPublisher,
    frames: Vec<ShmPublisher>,
}

impl PersonServices {
    fn new(node: &ShmNode, person: &str, virtual_cameras: u32) -> Result<Self, ShmError> {
        Ok(Self {
            avatar: node.avatar_publisher(person)?,
            frames: (0..virtual_cameras)
                .map(|i| node.frame_publisher(person, &format!("cam{i}")))
                .collect::<Result<Vec<_>, _>>()?,
        })
    }
}

impl ShmOutputs {
    /// Services `lhmpp/<person>/avatar` and `lhmpp/<person>/frame/cam<i>` for each virtual
    /// camera, made now for `person` and at first use for other (tracked) persons, keeping
    /// the `kept` most recently used persons' services.
    pub fn new(person: &str, virtual_cameras: u32, kept: usize) -> Result<Self, ShmError> {
        let node = ShmNode::new(&format!("lhmpp_{person}"), ShmOptions::default())?;
        let first = PersonServices::new(&node, person, virtual_cameras)?;
        Ok(Self {
            node,
            virtual_cameras,
            kept: kept.max(1),
            persons: Mutex::new(VecDeque::from([(person.to_owned(), first)])),
        })
    }

    /// Names of the services published on.
    pub fn services(&self) -> Vec<String> {
        let persons = self.persons.lock().unwrap_or_else(|e| e.into_inner());
        persons
            .iter()
            .flat_map(|(_, s)| std::iter::once(&s.avatar).chain(&s.frames))
            .map(|p| p.service().to_owned())
            .collect()
    }

    /// Runs `f` on `person`'s services (made when needed); errors are logged.
    fn with_person(&self, person: &str, f: impl FnOnce(&PersonServices)) {
        let mut persons = self.persons.lock().unwrap_or_else(|e| e.into_inner());
        let entry = match persons.iter().position(|(p, _)| p == person) {
            Some(at) => persons.remove(at).expect("index found above"),
            None => match PersonServices::new(&self.node, person, self.virtual_cameras) {
                Ok(made) => (person.to_owned(), made),
                Err(e) => {
                    tracing::warn!(person, "shared-memory services: {e}");
                    return;
                }
            },
        };
        f(&entry.1);
        persons.push_back(entry);
        while persons.len() > self.kept {
            persons.pop_front();
        }
    }
}

impl Publisher for ShmOutputs {
    fn avatar(&self, u: &AvatarUpdate<'_>) {
        let g = &u.avatar.canonical;
        let positions: Vec<[f32; 3]> = g.positions.iter().map(|p| p.to_array()).collect();
        let scales: Vec<[f32; 3]> = g.scales.iter().map(|s| s.to_array()).collect();
        let rotations: Vec<[f32; 4]> = g.rotations.iter().map(|q| [q.w, q.x, q.y, q.z]).collect();
        let colours: Vec<f32> = (0..g.len())
            .flat_map(|i| sh_dc_to_rgb(g.sh_of(i)[0]).to_array())
            .collect();
        let view = AvatarView {
            positions: &positions,
            scales: &scales,
            rotations: &rotations,
            opacities: &g.opacities,
            sh_coeffs: 1,
            colours: &colours,
            bones: &u.avatar.skin.bones,
            weights: &u.avatar.skin.weights,
            rgb_latent: !u.rgb_display_ready,
        };
        self.with_person(u.person, |s| {
            if let Err(e) = s
                .avatar
                .publish(Stamp::now(u.revision), &PayloadBody::Avatar(view))
            {
                tracing::warn!("{e}");
            }
        });
    }
    fn status(&self, _msg: ReconstructionStatus) {}
    /// Converts the render straight into a loaned shared-memory sample (no intermediate
    /// image) and sends it; the frame sequence number is the render stamp.
    fn frame(&self, person: &str, camera: usize, frame: &RenderedFrame, stamp_ns: i64) {
        self.with_person(person, |s| {
            if let Some(publisher) = s.frames.get(camera) {
                send_frame(publisher, frame, stamp_ns);
            }
        });
    }
}

/// Converts the render straight into a loaned sample of `publisher` and sends it.
fn send_frame(publisher: &ShmPublisher, frame: &RenderedFrame, stamp_ns: i64) {
    let stamp = Stamp {
        revision: stamp_ns as u64,
        timestamp_ns: crate::transport::layout::unix_time_ns(),
    };
    let sent = publisher
        .loan_frame(stamp, FrameShape::rgb8(frame.width(), frame.height()))
        .and_then(|mut loan| {
            frame.write_rgb8(loan.pixels_mut());
            loan.set_timestamp_ns(crate::transport::layout::unix_time_ns());
            loan.send()
        });
    if let Err(e) = sent {
        tracing::warn!("{e}");
    }
}
