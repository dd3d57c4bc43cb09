//! Reconstruction quality: image metrics and the held-out-view evaluation behind `lhmpp eval`.
//! [`perception`]: camera-only perception scored against synthetic ground truth
//! (`lhmpp eval-perception`).

pub mod heldout;
pub mod metrics;
pub mod perception;
