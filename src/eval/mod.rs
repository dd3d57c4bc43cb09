//! Reconstruction quality: image metrics and the held-out-view evaluation behind `lhmpp eval`.

pub mod metrics;
