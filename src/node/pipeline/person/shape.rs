//! A person's body shape: the one their reconstructions use, where it came from, and the
//! height read from their calibrated views.

use crate::node::pipeline::calibration::HeightReading;
use crate::reconstruct::shape::AcceptedShape;

/// The body shape a person is reconstructed with.
#[derive(Default)]
pub struct ShapeState {
    /// The shape in use (`None`: the template as shipped).
    shape: Option<AcceptedShape>,
    /// Whether the shape topic has given the shape (it then wins over the views).
    from_topic: bool,
    /// Shape changes so far (part of the reconstruction's input version).
    changes: u64,
    /// The body height read from the person's calibrated views.
    pub heights: HeightReading,
}

impl ShapeState {
    /// The shape in use.
    pub fn shape(&self) -> Option<&AcceptedShape> {
        self.shape.as_ref()
    }

    /// Shape changes so far.
    pub fn changes(&self) -> u64 {
        self.changes
    }

    /// Whether the shape topic gave the shape.
    pub fn topic_gave_it(&self) -> bool {
        self.from_topic
    }

    /// The shape topic gives the shape from now on (it wins over the views).
    pub fn given_by_topic(&mut self) {
        self.from_topic = true;
    }

    /// Uses `shape` from now on; whether it changed.
    pub fn set(&mut self, shape: AcceptedShape) -> bool {
        if self.shape.as_ref() == Some(&shape) {
            return false;
        }
        self.shape = Some(shape);
        self.changes += 1;
        true
    }
}
