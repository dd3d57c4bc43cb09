//! Reconstruction quality: image metrics and the held-out-view evaluation behind `lhmpp eval`.
//! [`perception`]: camera-only perception scored against synthetic ground truth
//! (`lhmpp eval-perception`). [`photos`]: the avatar's colours against real photos, region by
//! region with CIEDE2000 (`lhmpp eval-photos`). [`tracking`]: person ids on crowd scenes
//! (`lhmpp eval-tracking`); [`id_tracks`]: the same ids on a calibrated bag without truth
//! (real video, `--no-truth`); [`following`]: the one-person mode's finds on the same bags
//! (`--one-person`). [`crowd`]: each tracked person's avatar against their own
//! true person, beside the avatar made of that person alone (`lhmpp eval-crowd`).

pub mod crowd;
pub mod following;
pub mod heldout;
pub mod id_tracks;
pub mod metrics;
pub mod perception;
pub mod photos;
pub mod tracking;
