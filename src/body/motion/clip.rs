//! Keyframed FK channels (Blender F-curves) and their Bézier evaluation.

use serde::{Deserialize, Serialize};

/// Which pose-bone property a channel animates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ChannelProperty {
    /// Euler angle (XYZ order, radians) in the bone's local rest axes.
    RotationEuler,
    /// Translation in the bone's local rest axes (metres).
    Location,
}

/// One F-curve: keys `[frame, value, left_handle_frame, left_handle_value,
/// right_handle_frame, right_handle_value]` sorted by frame (Blender's absolute handles).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Channel {
    /// Animated bone.
    pub bone: String,
    /// Animated property.
    pub property: ChannelProperty,
    /// Component (0 = x, 1 = y, 2 = z).
    pub axis: usize,
    /// Bézier keys.
    pub keys: Vec<[f32; 6]>,
}

/// A looping keyframed clip of FK channels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KeyframeClip {
    /// Where the keys come from.
    pub source: String,
    /// What the clip contains and how it is used.
    pub note: String,
    /// Loop length in frames (the last key equals the first one period later).
    pub period_frames: f32,
    /// The channels.
    pub channels: Vec<Channel>,
}

impl Channel {
    /// Value at `frame`: cubic Bézier between neighbouring keys, held outside the key range.
    pub fn evaluate(&self, frame: f32) -> f32 {
        let keys = &self.keys;
        match keys.len() {
            0 => return 0.0,
            1 => return keys[0][1],
            _ => {}
        }
        if frame <= keys[0][0] {
            return keys[0][1];
        }
        let last = keys[keys.len() - 1];
        if frame >= last[0] {
            return last[1];
        }
        let i = keys.partition_point(|k| k[0] <= frame) - 1;
        let (a, b) = (keys[i], keys[i + 1]);
        bezier_segment(
            [a[0], a[1]],
            [a[4], a[5]],
            [b[2], b[3]],
            [b[0], b[1]],
            frame,
        )
    }

    /// Mean change of value per frame from the first to the last key (0 for one key).
    pub fn drift_per_frame(&self) -> f32 {
        match (self.keys.first(), self.keys.last()) {
            (Some(a), Some(b)) if b[0] > a[0] => (b[1] - a[1]) / (b[0] - a[0]),
            _ => 0.0,
        }
    }
}

/// Evaluates the Bézier segment `p0, p1, p2, p3` (points `(frame, value)`) at `frame`: solves
/// the frame polynomial for the curve parameter by bisection (Blender keeps handles inside the
/// segment, so it is monotonic) and returns the value there.
fn bezier_segment(p0: [f32; 2], p1: [f32; 2], p2: [f32; 2], p3: [f32; 2], frame: f32) -> f32 {
    // Handles are clamped into the segment as Blender does, keeping frame(t) monotonic.
    let x1 = p1[0].clamp(p0[0], p3[0]);
    let x2 = p2[0].clamp(p0[0], p3[0]);
    let cubic = |a: f32, b: f32, c: f32, d: f32, t: f32| {
        let s = 1.0 - t;
        s * s * s * a + 3.0 * s * s * t * b + 3.0 * s * t * t * c + t * t * t * d
    };
    let (mut lo, mut hi) = (0.0f32, 1.0f32);
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if cubic(p0[0], x1, x2, p3[0], mid) < frame {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    cubic(p0[1], p1[1], p2[1], p3[1], 0.5 * (lo + hi))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn linear_channel() -> Channel {
        // Handles on the straight line between the keys make the curve linear.
        Channel {
            bone: "b".into(),
            property: ChannelProperty::RotationEuler,
            axis: 0,
            keys: vec![
                [0.0, 0.0, -1.0, -0.1, 1.0, 0.1],
                [3.0, 0.3, 2.0, 0.2, 4.0, 0.4],
            ],
        }
    }

    #[test]
    fn bezier_with_collinear_handles_interpolates_linearly() {
        let c = linear_channel();
        for f in [0.5f32, 1.0, 1.5, 2.9] {
            assert!((c.evaluate(f) - 0.1 * f).abs() < 1e-5, "{f}");
        }
    }

    #[test]
    fn values_hold_outside_the_keys_and_hit_keys_exactly() {
        let c = linear_channel();
        assert_eq!(c.evaluate(-5.0), 0.0);
        assert_eq!(c.evaluate(10.0), 0.3);
        assert!((c.evaluate(3.0) - 0.3).abs() < 1e-6);
    }

    #[test]
    fn flat_handles_ease_in_and_out() {
        let c = Channel {
            keys: vec![
                [0.0, 0.0, -1.0, 0.0, 1.0, 0.0],
                [3.0, 1.0, 2.0, 1.0, 4.0, 1.0],
            ],
            ..linear_channel()
        };
        let quarter = c.evaluate(0.75);
        assert!(quarter < 0.25 && quarter > 0.0, "{quarter}");
        assert!((c.evaluate(1.5) - 0.5).abs() < 1e-5);
    }
}
