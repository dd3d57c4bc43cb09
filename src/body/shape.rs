//! Shape variation of the MakeHuman template: a height scale (whole body) and a girth scale
//! (x and z on top of height). Synthetic people are made with it and the node applies the
//! same shape when a `BodyShape` message names `makehuman-cc0`.

use super::BodyTemplate;
use glam::Vec3;
use std::ops::RangeInclusive;

/// Accepted range of each MakeHuman shape coefficient.
pub const MAKEHUMAN_SHAPE_RANGE: RangeInclusive<f32> = 0.5..=2.0;

/// Height and girth scale of the MakeHuman template; `[height_scale, girth_scale]` in
/// `BodyShape.shape_params`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MakeHumanShape {
    /// Scales the whole body.
    pub height_scale: f32,
    /// Scales x and z (on top of `height_scale`).
    pub girth_scale: f32,
}

impl Default for MakeHumanShape {
    fn default() -> Self {
        Self {
            height_scale: 1.0,
            girth_scale: 1.0,
        }
    }
}

impl MakeHumanShape {
    /// The shape from `[height_scale, girth_scale]`; `None` unless there are exactly two
    /// finite values in [`MAKEHUMAN_SHAPE_RANGE`].
    pub fn from_params(params: &[f32]) -> Option<Self> {
        match params {
            [h, g] if [h, g].iter().all(|v| MAKEHUMAN_SHAPE_RANGE.contains(*v)) => Some(Self {
                height_scale: *h,
                girth_scale: *g,
            }),
            _ => None,
        }
    }

    /// `[height_scale, girth_scale]`.
    pub fn params(&self) -> [f32; 2] {
        [self.height_scale, self.girth_scale]
    }

    /// Per-axis scale of canonical positions (the ground plane and the feet centre stay put).
    pub fn axis_scale(&self) -> Vec3 {
        let xz = self.girth_scale * self.height_scale;
        Vec3::new(xz, self.height_scale, xz)
    }

    /// Scales the template's vertices and joints in place.
    pub fn apply(&self, template: &mut BodyTemplate) {
        let scale = self.axis_scale();
        for v in &mut template.vertices {
            *v *= scale;
        }
        for j in &mut template.skeleton.joints {
            *j *= scale;
        }
    }

    /// A shaped copy of `template`.
    pub fn shaped(&self, template: &BodyTemplate) -> BodyTemplate {
        let mut t = template.clone();
        self.apply(&mut t);
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn height_scale_scales_the_template_height() {
        let base = BodyTemplate::load_default().unwrap();
        let shape = MakeHumanShape {
            height_scale: 1.2,
            girth_scale: 0.8,
        };
        let shaped = shape.shaped(&base);
        let ratio = shaped.height() / base.height();
        assert!((ratio - 1.2).abs() < 1e-4, "{ratio}");
    }

    #[test]
    fn params_outside_the_range_or_of_wrong_length_are_refused() {
        assert!(MakeHumanShape::from_params(&[1.0, 1.1]).is_some());
        assert!(MakeHumanShape::from_params(&[2.5, 1.0]).is_none());
        assert!(MakeHumanShape::from_params(&[1.0, f32::NAN]).is_none());
        assert!(MakeHumanShape::from_params(&[1.0]).is_none());
        assert!(MakeHumanShape::from_params(&[1.0, 1.0, 1.0]).is_none());
    }
}
