//! The One-Euro filter (Casiez, Roussel, Vogel, CHI 2012) on 3D points.
//!
//! An exponential low-pass whose cutoff rises with speed: `cutoff = min_cutoff + beta·|ẋ|`,
//! the speed `ẋ` itself low-passed at `d_cutoff`. Slow motion is smoothed hard (jitter
//! goes), fast motion passes with little lag. Here it runs on landmark positions rather than
//! on bone rotations: the noise is in the landmarks, a position's speed is a meaningful
//! "how fast is this moving" in metres per second, and the solver stays a function of one
//! (filtered) frame, without averaging rotations across twist flips. The speed is the
//! length of the 3D velocity, so one cutoff serves all three coordinates of a point.

use glam::Vec3;
use std::f64::consts::TAU;

/// Filter parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OneEuroConfig {
    /// Cutoff at rest, Hz.
    pub min_cutoff: f64,
    /// Cutoff increase per unit of speed, Hz per (metre per second).
    pub beta: f64,
    /// Cutoff of the speed estimate, Hz.
    pub d_cutoff: f64,
}

impl Default for OneEuroConfig {
    /// 1 Hz at rest, +4 Hz per m/s, speed at 1 Hz: for world landmarks at camera rates.
    fn default() -> Self {
        Self {
            min_cutoff: 1.0,
            beta: 4.0,
            d_cutoff: 1.0,
        }
    }
}

/// Smoothing factor of a first-order low-pass with `cutoff` (Hz) over `dt` seconds.
fn alpha(cutoff: f64, dt: f64) -> f32 {
    let tau = 1.0 / (TAU * cutoff.max(1e-9));
    (1.0 / (1.0 + tau / dt)) as f32
}

/// A One-Euro filter over one 3D point.
#[derive(Debug, Clone, PartialEq)]
pub struct OneEuroFilter {
    config: OneEuroConfig,
    /// Time, filtered value and filtered velocity of the last sample.
    state: Option<(f64, Vec3, Vec3)>,
}

impl OneEuroFilter {
    /// A filter that has seen nothing yet.
    pub fn new(config: OneEuroConfig) -> Self {
        Self {
            config,
            state: None,
        }
    }

    /// Filters sample `x` taken at `t` seconds. The first sample passes unchanged; a sample
    /// not later than the previous one is ignored and the previous output returned.
    pub fn filter(&mut self, t: f64, x: Vec3) -> Vec3 {
        let Some((t0, x0, dx0)) = self.state else {
            self.state = Some((t, x, Vec3::ZERO));
            return x;
        };
        let dt = t - t0;
        if dt <= 0.0 || !dt.is_finite() {
            return x0;
        }
        let dx = (x - x0) / dt as f32;
        let dx = dx0.lerp(dx, alpha(self.config.d_cutoff, dt));
        let cutoff = self.config.min_cutoff + self.config.beta * f64::from(dx.length());
        let out = x0.lerp(x, alpha(cutoff, dt));
        self.state = Some((t, out, dx));
        out
    }

    /// The last output, if any.
    pub fn value(&self) -> Option<Vec3> {
        self.state.map(|(_, x, _)| x)
    }

    /// Forgets the past: the next sample passes unchanged.
    pub fn reset(&mut self) {
        self.state = None;
    }
}
