//! `lhmpp_msgs/msg/BodyShape`: a person's body-shape coefficients for a named body model.

use super::message::ros_message;
use super::Header;
use serde::{Deserialize, Serialize};

/// `lhmpp_msgs/msg/BodyShape`. What `shape_params` means depends on `body_model`
/// (see `msg/msg/BodyShape.msg`).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct BodyShape {
    /// Time the shape was estimated.
    pub header: Header,
    /// Tracked person.
    pub person_id: String,
    /// Body model, `makehuman-cc0` or `smplx`.
    pub body_model: String,
    /// Shape coefficients of the body model.
    pub shape_params: Vec<f32>,
}
ros_message!(
    BodyShape,
    "lhmpp_msgs",
    "BodyShape",
    include_str!("../../msg/msg/BodyShape.msg")
);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::RosMessage;

    #[test]
    fn shape_survives_the_cdr_round_trip() {
        let msg = BodyShape {
            person_id: "p1".into(),
            body_model: "makehuman-cc0".into(),
            shape_params: vec![1.05, 0.95],
            ..Default::default()
        };
        let bytes = msg.encode_cdr();
        assert_eq!(BodyShape::decode_cdr(&bytes).unwrap(), msg);
    }
}
