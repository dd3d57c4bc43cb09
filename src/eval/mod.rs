//! Reconstruction quality: image metrics and the held-out-view evaluation behind `lhmpp eval`.
//! [`perception`]: camera-only perception scored against synthetic ground truth
//! (`lhmpp eval-perception`). [`photos`]: the avatar's colours against real photos, region by
//! region with CIEDE2000 (`lhmpp eval-photos`). [`tracking`]: person ids on crowd scenes
//! (`lhmpp eval-tracking`).

pub mod heldout;
pub mod metrics;
pub mod perception;
pub mod photos;
pub mod tracking;
