//! Checking `BodyShape` messages against the body model the node reconstructs with: a shape
//! is accepted only for that model, with the right number of finite, in-range coefficients.

use crate::body::official::SMPLX_MODEL_ID;
use crate::body::{MakeHumanShape, MAKEHUMAN_MODEL_ID, MAKEHUMAN_SHAPE_RANGE};
use crate::msgs::BodyShape;
use std::ops::RangeInclusive;

/// `BodyShape.body_model` of SMPL-X betas (the node's SMPL-X prior body accepts them).
pub const SMPLX_SHAPE_MODEL: &str = "smplx";
/// Most SMPL-X betas accepted (the model's full shape space).
pub const SMPLX_MAX_BETAS: usize = 300;
/// Accepted range of each SMPL-X beta (standard deviations of the shape space).
pub const SMPLX_BETA_RANGE: RangeInclusive<f32> = -10.0..=10.0;

/// A shape the node accepted.
#[derive(Debug, Clone, PartialEq)]
pub enum AcceptedShape {
    /// Height and girth scale of the MakeHuman template.
    MakeHuman(MakeHumanShape),
    /// SMPL-X betas (carried in the avatar message; not applied to the prior).
    SmplxBetas(Vec<f32>),
}

impl AcceptedShape {
    /// Body-model id the coefficients belong to.
    pub fn body_model(&self) -> &'static str {
        match self {
            Self::MakeHuman(_) => MAKEHUMAN_MODEL_ID,
            Self::SmplxBetas(_) => SMPLX_SHAPE_MODEL,
        }
    }

    /// The coefficients as `BodyShape.shape_params` / `GaussianAvatar.shape_params` carry them.
    pub fn params(&self) -> Vec<f32> {
        match self {
            Self::MakeHuman(s) => s.params().to_vec(),
            Self::SmplxBetas(b) => b.clone(),
        }
    }
}

/// Why a `BodyShape` message was rejected; each names the topic and the field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ShapeError {
    /// `body_model` is not a model the node knows.
    #[error("{topic}: body_model `{model}` is not `makehuman-cc0` or `smplx`")]
    UnknownModel {
        /// Topic of the message.
        topic: String,
        /// The model named.
        model: String,
    },
    /// `body_model` is known but not the one the node reconstructs with.
    #[error("{topic}: body_model `{model}` does not match the node's body model `{node_model}`")]
    OtherModel {
        /// Topic of the message.
        topic: String,
        /// The model named.
        model: String,
        /// The node's model.
        node_model: String,
    },
    /// `shape_params` has the wrong number of values.
    #[error("{topic}: shape_params has {got} values; body_model `{model}` needs {expected}")]
    Length {
        /// Topic of the message.
        topic: String,
        /// The model named.
        model: String,
        /// What the model needs.
        expected: String,
        /// Values given.
        got: usize,
    },
    /// A coefficient is NaN or infinite, or outside the model's range.
    #[error("{topic}: shape_params[{index}] = {value} is not a finite value in {range}")]
    Value {
        /// Topic of the message.
        topic: String,
        /// Index of the coefficient.
        index: usize,
        /// Its value.
        value: f32,
        /// The accepted range.
        range: String,
    },
}

/// The `BodyShape.body_model` a node whose avatars use body model `node_model` accepts.
pub fn shape_model_of(node_model: &str) -> &str {
    match node_model {
        SMPLX_MODEL_ID => SMPLX_SHAPE_MODEL,
        other => other,
    }
}

/// Checks `msg` (received on `topic`) for a node whose avatars use body model `node_model`
/// (`makehuman-cc0`, or the SMPL-X prior, which takes `smplx` betas).
pub fn check_shape(
    topic: &str,
    msg: &BodyShape,
    node_model: &str,
) -> Result<AcceptedShape, ShapeError> {
    let model = msg.body_model.as_str();
    let (range, expected) = match model {
        MAKEHUMAN_MODEL_ID => (MAKEHUMAN_SHAPE_RANGE, "2 ([height_scale, girth_scale])"),
        SMPLX_SHAPE_MODEL => (SMPLX_BETA_RANGE, "1 to 300 betas"),
        _ => {
            return Err(ShapeError::UnknownModel {
                topic: topic.to_owned(),
                model: model.to_owned(),
            })
        }
    };
    if model != shape_model_of(node_model) {
        return Err(ShapeError::OtherModel {
            topic: topic.to_owned(),
            model: model.to_owned(),
            node_model: shape_model_of(node_model).to_owned(),
        });
    }
    let p = &msg.shape_params;
    let length_ok = match model {
        MAKEHUMAN_MODEL_ID => p.len() == 2,
        _ => (1..=SMPLX_MAX_BETAS).contains(&p.len()),
    };
    if !length_ok {
        return Err(ShapeError::Length {
            topic: topic.to_owned(),
            model: model.to_owned(),
            expected: expected.to_owned(),
            got: p.len(),
        });
    }
    if let Some((index, &value)) = p.iter().enumerate().find(|(_, v)| !range.contains(*v)) {
        return Err(ShapeError::Value {
            topic: topic.to_owned(),
            index,
            value,
            range: format!("{}..={}", range.start(), range.end()),
        });
    }
    Ok(match model {
        MAKEHUMAN_MODEL_ID => AcceptedShape::MakeHuman(MakeHumanShape {
            height_scale: p[0],
            girth_scale: p[1],
        }),
        _ => AcceptedShape::SmplxBetas(p.clone()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn msg(model: &str, params: &[f32]) -> BodyShape {
        BodyShape {
            body_model: model.into(),
            shape_params: params.to_vec(),
            ..Default::default()
        }
    }

    #[test]
    fn makehuman_scales_in_range_are_accepted() {
        let s = check_shape("/s", &msg("makehuman-cc0", &[1.1, 0.9]), "makehuman-cc0").unwrap();
        assert_eq!(s.params(), vec![1.1, 0.9]);
        assert_eq!(s.body_model(), "makehuman-cc0");
    }

    #[test]
    fn rejections_name_the_topic_and_the_field() {
        let node = "makehuman-cc0";
        let cases = [
            (msg("smpl", &[1.0, 1.0]), "body_model `smpl`"),
            (msg("smplx", &[0.1]), "does not match the node's body model"),
            (msg(node, &[1.0]), "shape_params has 1 values"),
            (msg(node, &[1.0, f32::NAN]), "shape_params[1] = NaN"),
            (msg(node, &[2.5, 1.0]), "shape_params[0] = 2.5"),
            (msg(node, &[1.0, 0.4]), "0.5..=2"),
        ];
        for (m, expected) in cases {
            let e = check_shape("/lhmpp/body_shape", &m, node)
                .unwrap_err()
                .to_string();
            assert!(
                e.contains(expected) && e.starts_with("/lhmpp/body_shape"),
                "{e}"
            );
        }
    }

    #[test]
    fn smplx_betas_are_accepted_for_the_smplx_prior_and_bounded() {
        let betas: Vec<f32> = (0..10).map(|i| i as f32 * 0.1 - 0.5).collect();
        let s = check_shape("/s", &msg("smplx", &betas), SMPLX_MODEL_ID).unwrap();
        assert_eq!(s, AcceptedShape::SmplxBetas(betas));
        for bad in [
            msg("smplx", &[]),
            msg("smplx", &[11.0]),
            msg("smplx", &[0.0; 301]),
            msg("makehuman-cc0", &[1.0, 1.0]),
        ] {
            assert!(check_shape("/s", &bad, SMPLX_MODEL_ID).is_err(), "{bad:?}");
        }
    }
}
