//! Pose specs accepted on command lines: `rest`, `tpose`, `walk:F` and `walk:A..B`.

use super::{tpose, walk_pose};
use crate::body::{BodyError, Pose};

/// A parsed pose spec.
#[derive(Debug, Clone, PartialEq)]
pub enum PoseSpec {
    /// The canonical rest pose.
    Rest,
    /// The T-pose.
    TPose,
    /// Walk-cycle frames `start..end` (end exclusive; one frame is `f..f+1`).
    Walk {
        /// First frame.
        start: u32,
        /// One past the last frame.
        end: u32,
    },
}

impl PoseSpec {
    /// Parses `rest`, `tpose`, `walk:12` or `walk:0..60`.
    pub fn parse(spec: &str) -> Result<Self, BodyError> {
        let err = |m: &str| BodyError::PoseSpec {
            spec: spec.to_string(),
            message: m.to_string(),
        };
        let frame = |s: &str| {
            s.trim()
                .parse::<u32>()
                .map_err(|_| err("frames are whole numbers"))
        };
        match spec.trim() {
            "rest" => Ok(Self::Rest),
            "tpose" => Ok(Self::TPose),
            s => {
                let rest = s
                    .strip_prefix("walk:")
                    .ok_or_else(|| err("expected rest, tpose, walk:F or walk:A..B"))?;
                match rest.split_once("..") {
                    Some((a, b)) => {
                        let (start, end) = (frame(a)?, frame(b)?);
                        if end <= start {
                            return Err(err("empty frame range"));
                        }
                        Ok(Self::Walk { start, end })
                    }
                    None => {
                        let f = frame(rest)?;
                        Ok(Self::Walk {
                            start: f,
                            end: f + 1,
                        })
                    }
                }
            }
        }
    }

    /// The poses the spec names, in order.
    pub fn poses(&self) -> Vec<Pose> {
        match self {
            Self::Rest => vec![Pose::identity()],
            Self::TPose => vec![tpose()],
            Self::Walk { start, end } => (*start..*end).map(|f| walk_pose(f as f32)).collect(),
        }
    }
}

/// Parses a pose spec and returns its poses.
pub fn parse_pose_spec(spec: &str) -> Result<Vec<Pose>, BodyError> {
    Ok(PoseSpec::parse(spec)?.poses())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn specs_parse_into_frames() {
        assert_eq!(PoseSpec::parse("rest").unwrap(), PoseSpec::Rest);
        assert_eq!(
            PoseSpec::parse("walk:12").unwrap(),
            PoseSpec::Walk { start: 12, end: 13 }
        );
        assert_eq!(
            PoseSpec::parse("walk:0..60").unwrap(),
            PoseSpec::Walk { start: 0, end: 60 }
        );
    }

    #[test]
    fn bad_specs_are_errors_quoting_the_spec() {
        for bad in ["run:3", "walk:x", "walk:5..5", ""] {
            let e = PoseSpec::parse(bad).unwrap_err().to_string();
            assert!(e.contains(&format!("`{bad}`")), "{e}");
        }
    }
}
