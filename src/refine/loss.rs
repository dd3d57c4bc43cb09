//! The image loss of one view and its gradient with respect to the rendered frame.
//!
//! The frame is rendered over black, so its colour `C` is premultiplied by its alpha `A`.
//! - Photometric, inside the person's mask `m`: `Σ m · ρ(C − A · I) / Σ m` over the channels,
//!   `ρ` the Charbonnier penalty `√(x² + ε²) − ε`: a pixel the avatar does not cover costs
//!   nothing here (the silhouette asks for it), and one it covers costs the difference of its
//!   colour from the photo's.
//! - Silhouette: `λ · Σ (A − m)² / P` over all `P` pixels of the view.

use super::view::RefineView;
use crate::splat::RenderOutput;

/// Smoothing of the Charbonnier penalty (colour units).
const EPSILON: f32 = 0.01;

/// The loss of one view.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ViewLoss {
    /// Photometric part.
    pub photometric: f32,
    /// Silhouette part (weighted).
    pub silhouette: f32,
}

impl ViewLoss {
    /// Photometric plus silhouette.
    pub fn total(&self) -> f32 {
        self.photometric + self.silhouette
    }
}

/// The loss of `out` (rendered over black) against `view`, and when `grads` is given its
/// gradient with respect to the frame's rgb and alpha (resized and overwritten).
pub(crate) fn view_loss(
    view: &RefineView,
    out: &RenderOutput,
    silhouette_weight: f32,
    grads: Option<(&mut Vec<f32>, &mut Vec<f32>)>,
) -> ViewLoss {
    let p = view.pixels();
    let masked: f32 = view.mask.iter().sum::<f32>().max(1.0);
    let mut photometric = 0.0f64;
    let mut silhouette = 0.0f64;
    let (mut d_rgb, mut d_alpha) = match grads {
        Some((r, a)) => {
            r.clear();
            r.resize(3 * p, 0.0);
            a.clear();
            a.resize(p, 0.0);
            (Some(r), Some(a))
        }
        None => (None, None),
    };
    let sil_scale = silhouette_weight / p as f32;
    for i in 0..p {
        let m = view.mask[i];
        let a = out.alpha[i];
        let mut d_a = 0.0;
        if m > 0.0 {
            for c in 0..3 {
                let target = view.rgb[3 * i + c];
                let r = out.rgb[3 * i + c] - a * target;
                let root = (r * r + EPSILON * EPSILON).sqrt();
                photometric += (m * (root - EPSILON)) as f64;
                let d = m * r / root / masked;
                if let Some(g) = d_rgb.as_deref_mut() {
                    g[3 * i + c] = d;
                }
                d_a -= d * target;
            }
        }
        let e = a - m;
        silhouette += (e * e) as f64;
        d_a += 2.0 * e * sil_scale;
        if let Some(g) = d_alpha.as_deref_mut() {
            g[i] = d_a;
        }
    }
    ViewLoss {
        photometric: (photometric / masked as f64) as f32,
        silhouette: (silhouette as f32) * sil_scale,
    }
}

/// How far the frame `out` (rendered over black) is from what `view` shows, as the held-out
/// views of an evaluation are scored: the mean squared error of the render composited over
/// white and over black against the photo's person (by its mask) composited over the same,
/// averaged. Unlike [`view_loss`] it prices an uncovered part of the person and a covered part
/// of the background alike, as a held-out PSNR does.
pub(crate) fn composite_error(view: &RefineView, out: &RenderOutput) -> f32 {
    let p = view.pixels();
    let mut sum = 0.0f64;
    for i in 0..p {
        let (m, a) = (view.mask[i], out.alpha[i]);
        for c in 0..3 {
            let person = m * view.rgb[3 * i + c];
            let black = out.rgb[3 * i + c] - person;
            let white = black + m - a;
            sum += (0.5 * (black * black + white * white)) as f64;
        }
    }
    (sum / (3 * p.max(1)) as f64) as f32
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::splat::{Camera, Intrinsics};
    use glam::Vec3;

    fn view(rgb: Vec<f32>, mask: Vec<f32>) -> RefineView {
        RefineView {
            name: "v".into(),
            camera: Camera::look_at(
                Vec3::Z,
                Vec3::ZERO,
                Vec3::Y,
                Intrinsics::from_fov_y(2, 1, 0.5),
            ),
            rgb,
            mask,
            skinning: Vec::new(),
            exposure: 0.0,
        }
    }

    fn frame(rgb: Vec<f32>, alpha: Vec<f32>) -> RenderOutput {
        RenderOutput {
            width: 2,
            height: 1,
            rgb,
            alpha,
            ..RenderOutput::default()
        }
    }

    /// A render that is the photo inside the mask and empty outside costs nothing.
    #[test]
    fn the_photo_itself_costs_nothing() {
        let v = view(vec![0.2, 0.4, 0.6, 0.9, 0.9, 0.9], vec![1.0, 0.0]);
        let out = frame(vec![0.2, 0.4, 0.6, 0.0, 0.0, 0.0], vec![1.0, 0.0]);
        let loss = view_loss(&v, &out, 1.0, None);
        assert!(loss.total() < 1e-6, "{loss:?}");
        // Covering the background, or leaving the person bare, costs.
        let out = frame(vec![0.0; 6], vec![0.0, 1.0]);
        assert!(view_loss(&v, &out, 1.0, None).silhouette > 0.9);
    }

    /// The frame gradients match finite differences of the loss.
    #[test]
    fn frame_gradients_match_finite_differences() {
        let v = view(vec![0.2, 0.4, 0.6, 0.9, 0.1, 0.5], vec![1.0, 0.6]);
        let out = frame(vec![0.3, 0.1, 0.5, 0.2, 0.3, 0.1], vec![0.7, 0.4]);
        let (mut gr, mut ga) = (Vec::new(), Vec::new());
        view_loss(&v, &out, 0.7, Some((&mut gr, &mut ga)));
        let h = 1e-3;
        assert_eq!((gr.len(), ga.len()), (6, 2));
        for (k, g) in gr.iter().enumerate() {
            let (mut a, mut b) = (out.clone(), out.clone());
            a.rgb[k] += h;
            b.rgb[k] -= h;
            let n = (view_loss(&v, &a, 0.7, None).total() - view_loss(&v, &b, 0.7, None).total())
                / (2.0 * h);
            assert!((n - g).abs() < 1e-3, "rgb {k}: {n} vs {g}");
        }
        for (k, g) in ga.iter().enumerate() {
            let (mut a, mut b) = (out.clone(), out.clone());
            a.alpha[k] += h;
            b.alpha[k] -= h;
            let n = (view_loss(&v, &a, 0.7, None).total() - view_loss(&v, &b, 0.7, None).total())
                / (2.0 * h);
            assert!((n - g).abs() < 1e-3, "alpha {k}: {n} vs {g}");
        }
    }
}
