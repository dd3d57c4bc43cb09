//! What the Gaussian head's RGB of a loaded network is: colours to display, or a latent
//! intermediate that only the network's neural renderer turns into images.
//!
//! The released LHMPP-700M (and LHMPPS-700M) checkpoint was trained without supervising the
//! Gaussians' RGB against images (aigc3d/LHM-plusplus#2: exported colours look "negative");
//! the official app splats the 128 latent feature channels and decodes them with the DPT head
//! (`neural_renderer.type: patch_4dptonly`, reference §1.3 (i)). The newer GS-supervised
//! releases and this project's own presets, whose embedded default is trained on its Gaussian
//! RGB, have display-ready colours. The GS-supervised releases are LHMPP-700M-PixelShuffle
//! (`mlp_pixelshuffle` renderer) and LHMPP-700M-SMPLX-FREE (`patch_4dptonly` renderer like
//! LHMPP-700M, but trained with the betas `shape_head`): upstream's
//! `GS_RENDER_SUPPORTED_MODEL_NAMES` in `core/utils/model_card.py` lists exactly these two.

/// The official `neural_renderer.type` of the checkpoints whose RGB is latent (LHMPP-700M).
pub const LATENT_RGB_RENDERER_TYPE: &str = "patch_4dptonly";
/// The official `neural_renderer.type` of LHMPPS-700M, whose RGB is latent too.
pub const LATENT_RGB_SHARED_RENDERER_TYPE: &str = "patch_dptonly";

/// What the `r g b` of the predicted Gaussians mean.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RgbKind {
    /// Colours in [0, 1], supervised against images: splatting them gives frames.
    DisplayReady,
    /// An unsupervised intermediate of the network: frames need the neural renderer.
    Latent,
}

impl RgbKind {
    /// Whether the RGB can be shown (or exported as colours) as it is.
    pub fn display_ready(self) -> bool {
        self == Self::DisplayReady
    }

    /// The RGB of a network built from a preset (a single safetensors file, random weights or
    /// the embedded default): `lhmpp-700m` has the layout of the released, RGB-unsupervised
    /// checkpoint; our own presets are trained (or meant to be trained) on their RGB.
    pub fn of_preset(preset: &str) -> Self {
        // `lhmpp-700m-pixelshuffle` and `lhmpp-700m-smplx-free` are GS-supervised.
        match preset {
            "lhmpp-700m" | "lhmpp_700m" | "700m" => Self::Latent,
            _ => Self::DisplayReady,
        }
    }

    /// The RGB of a hub-folder checkpoint with this official `neural_renderer.type`:
    /// `patch_4dptonly` (LHMPP-700M, LHMPPS-700M) is latent, the GS-supervised variants'
    /// renderers (e.g. `mlp_pixelshuffle`) are display-ready.
    pub fn of_official_renderer(kind: &str) -> Self {
        Self::of_hub(kind, false)
    }

    /// The RGB of a hub-folder checkpoint with this `neural_renderer.type` that does
    /// (`shape_head`: true) or does not carry the betas `shape_head` of the GS-supervised
    /// releases: `patch_4dptonly` / `patch_dptonly` without it (LHMPP-700M, LHMPPS-700M) is
    /// latent; with it
    /// (LHMPP-700M-SMPLX-FREE), and every other renderer (`mlp_pixelshuffle`), display-ready.
    pub fn of_hub(kind: &str, shape_head: bool) -> Self {
        if (kind == LATENT_RGB_RENDERER_TYPE || kind == LATENT_RGB_SHARED_RENDERER_TYPE)
            && !shape_head
        {
            Self::Latent
        } else {
            Self::DisplayReady
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn released_layout_is_latent_and_ours_display_ready() {
        assert_eq!(RgbKind::of_preset("lhmpp-700m"), RgbKind::Latent);
        for p in [
            "tiny",
            "s",
            "m",
            "l",
            "lhmpp-700m-pixelshuffle",
            "lhmpp-700m-smplx-free",
        ] {
            assert_eq!(RgbKind::of_preset(p), RgbKind::DisplayReady, "{p}");
        }
        assert_eq!(
            RgbKind::of_official_renderer("patch_4dptonly"),
            RgbKind::Latent
        );
        assert_eq!(
            RgbKind::of_official_renderer("mlp_pixelshuffle"),
            RgbKind::DisplayReady
        );
        assert!(!RgbKind::Latent.display_ready());
        assert_eq!(
            RgbKind::of_preset("lhmpp-700m-smplx-free"),
            RgbKind::DisplayReady
        );
        assert_eq!(
            RgbKind::of_hub("patch_4dptonly", true),
            RgbKind::DisplayReady
        );
        assert_eq!(
            RgbKind::of_hub("mlp_pixelshuffle", true),
            RgbKind::DisplayReady
        );
        assert_eq!(RgbKind::of_hub("patch_4dptonly", false), RgbKind::Latent);
        assert_eq!(RgbKind::of_hub("patch_dptonly", false), RgbKind::Latent);
    }
}
