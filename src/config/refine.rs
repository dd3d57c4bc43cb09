//! The `refine` section: fitting each avatar to the views it was made from, between network
//! reruns ([`crate::refine`]).

use serde::{Deserialize, Serialize};
use std::ops::RangeInclusive;
use std::time::Duration;

/// Refinement settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RefineSettings {
    /// Fit each avatar to its views after each network reconstruction.
    pub enabled: bool,
    /// Wall-clock milliseconds one fit may take, in [`RefineSettings::BUDGET_MS`].
    pub budget_ms: u64,
    /// Most Gaussians an avatar may grow to, in [`RefineSettings::MAX_GAUSSIANS`].
    pub max_gaussians: usize,
    /// Longest side (pixels) each view is fitted at, in [`RefineSettings::MAX_SIDE`].
    pub max_side: u32,
    /// Most optimiser steps of one fit, in [`RefineSettings::MAX_ITERATIONS`].
    pub max_iterations: usize,
}

impl RefineSettings {
    /// Accepted `refine.budget_ms` values.
    pub const BUDGET_MS: RangeInclusive<u64> = 100..=600_000;
    /// Accepted `refine.max_gaussians` values.
    pub const MAX_GAUSSIANS: RangeInclusive<usize> = 1_000..=2_000_000;
    /// Accepted `refine.max_iterations` values.
    pub const MAX_ITERATIONS: RangeInclusive<usize> = 1..=100_000;
    /// Accepted `refine.max_side` values.
    pub const MAX_SIDE: RangeInclusive<u32> = 32..=1024;

    /// The fit's settings.
    pub fn fit_config(&self) -> crate::refine::RefineConfig {
        crate::refine::RefineConfig {
            budget: Duration::from_millis(self.budget_ms),
            max_gaussians: self.max_gaussians,
            max_side: self.max_side,
            max_iterations: self.max_iterations,
            ..crate::refine::RefineConfig::default()
        }
    }
}

impl Default for RefineSettings {
    fn default() -> Self {
        let c = crate::refine::RefineConfig::default();
        Self {
            enabled: true,
            budget_ms: c.budget.as_millis() as u64,
            max_gaussians: c.max_gaussians,
            max_side: c.max_side,
            max_iterations: c.max_iterations,
        }
    }
}
