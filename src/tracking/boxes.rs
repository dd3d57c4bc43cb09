//! Axis-aligned person boxes in frame pixels.

/// A box in frame pixels: `min` is the top-left corner, `max` the bottom-right.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoxPx {
    /// Top-left corner (x, y).
    pub min: [f32; 2],
    /// Bottom-right corner (x, y).
    pub max: [f32; 2],
}

impl BoxPx {
    /// The box from its corners, in any order.
    pub fn new(a: [f32; 2], b: [f32; 2]) -> Self {
        Self {
            min: [a[0].min(b[0]), a[1].min(b[1])],
            max: [a[0].max(b[0]), a[1].max(b[1])],
        }
    }

    /// Area in square pixels.
    pub fn area(&self) -> f32 {
        (self.max[0] - self.min[0]).max(0.0) * (self.max[1] - self.min[1]).max(0.0)
    }

    /// Centre (x, y).
    pub fn center(&self) -> [f32; 2] {
        [
            0.5 * (self.min[0] + self.max[0]),
            0.5 * (self.min[1] + self.max[1]),
        ]
    }

    /// Area shared with `other`, square pixels.
    pub fn intersection(&self, other: &BoxPx) -> f32 {
        let w = (self.max[0].min(other.max[0]) - self.min[0].max(other.min[0])).max(0.0);
        let h = (self.max[1].min(other.max[1]) - self.min[1].max(other.min[1])).max(0.0);
        w * h
    }

    /// Intersection over union with `other` (0 when either is empty).
    pub fn iou(&self, other: &BoxPx) -> f32 {
        let inter = self.intersection(other);
        let union = self.area() + other.area() - inter;
        if union > 0.0 {
            inter / union
        } else {
            0.0
        }
    }

    /// The box moved by `velocity` (pixels per second) for `seconds`.
    pub fn moved(&self, velocity: [f32; 2], seconds: f32) -> BoxPx {
        let (dx, dy) = (velocity[0] * seconds, velocity[1] * seconds);
        BoxPx {
            min: [self.min[0] + dx, self.min[1] + dy],
            max: [self.max[0] + dx, self.max[1] + dy],
        }
    }
}
