//! Shading taken out of the colours photos show: a key light fitted to how the photos'
//! brightness follows the avatar's surface normals, then divided out, so that the avatar carries
//! its garments' own colours rather than the light they stood in.
//!
//! The model, in each set of views that share a world frame (calibrated views and their
//! pose-topic poses; else one view alone): a colour seen at a point with posed normal `n` is the
//! point's albedo times `1 + max(0, n · k)`, ambient plus one directional key light whose
//! direction and strength relative to the ambient are `k`. Albedo is taken to be constant over
//! a group of Gaussians (body part × height band × hue, [`ShadedSample::group`]) up to robust
//! residuals (prints, stripes), and each view may be exposed differently (a per-view offset,
//! pulled towards the others). `k` is searched over directions and strengths for the smallest
//! mean absolute log-luminance residual; a fit that explains no more than
//! [`MIN_GAIN`] of the residual of no light at all is dropped.
//!
//! The key light's strength is then fitted per colour channel along the same direction (a key
//! light warmer or cooler than the ambient light). Removing the light ([`KeyLight::gain`])
//! scales each seen colour channel by `(1 + s) / (1 + s · max(0, n · k̂))`: every point as it
//! would look facing the key light, so shadowed sides are lifted to their lit sides' level and
//! colour, and the avatar has one brightness all round; each view's fitted exposure offset
//! ([`KeyLight::exposure`]) is divided out with it.

use glam::Vec3;

/// One photo's view of one Gaussian.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShadedSample {
    /// Group of Gaussians taken to share an albedo.
    pub group: u32,
    /// The view (exposure offset) it was seen in.
    pub view: u32,
    /// Its posed unit normal, in the views' shared frame.
    pub normal: Vec3,
    /// The colour seen (sRGB, 0–1).
    pub colour: Vec3,
    /// How much of the key light reaches it (0 in a cast shadow, else 1).
    pub lit: f32,
}

/// A fitted key light: shading `1 + max(0, n · key)` in luminance, and per colour channel `c`
/// `1 + strength[c] · max(0, n · key / |key|)` (a key light of another colour than the
/// ambient one).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct KeyLight {
    /// Direction towards the light times its strength relative to the ambient light.
    pub key: Vec3,
    /// Strength relative to the ambient light per colour channel.
    pub strength: Vec3,
    /// Mean absolute log-luminance residual with this light, and with none.
    pub residual: (f32, f32),
    /// Each view's exposure offset (log luminance, by [`ShadedSample::view`]) in the fit.
    pub exposure: Vec<f32>,
}

/// Least share of the no-light residual a light must explain to be kept.
pub const MIN_GAIN: f32 = 0.03;

/// Strongest key light searched (times the ambient light).
const MAX_STRENGTH: f32 = 4.0;

/// Most samples the search looks at (spread evenly over the input).
const MAX_SAMPLES: usize = 3000;

/// Smallest group (samples) whose albedo is fitted; smaller groups are left out of the fit.
const MIN_GROUP: usize = 6;

impl KeyLight {
    /// No light: shading 1 everywhere.
    pub fn none() -> Self {
        Self::default()
    }

    /// Shading at unit normal `n`.
    pub fn shading(&self, n: Vec3) -> f32 {
        1.0 + n.dot(self.key).max(0.0)
    }

    /// Per-channel factor that takes a colour seen at normal `n` to the colour of the same
    /// surface facing the light.
    pub fn gain(&self, n: Vec3) -> Vec3 {
        self.gain_lit(n, 1.0)
    }

    /// [`Self::gain`] for a point that `lit` of the key light reaches (0 in a cast shadow).
    pub fn gain_lit(&self, n: Vec3, lit: f32) -> Vec3 {
        let facing = n.dot(self.key.normalize_or_zero()).max(0.0) * lit;
        (Vec3::ONE + self.strength) / (Vec3::ONE + self.strength * facing)
    }
}

/// Evenly spread unit directions (a Fibonacci sphere).
fn directions(count: usize) -> Vec<Vec3> {
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    (0..count)
        .map(|i| {
            let y = 1.0 - 2.0 * (i as f32 + 0.5) / count as f32;
            let r = (1.0 - y * y).max(0.0).sqrt();
            let a = golden * i as f32;
            Vec3::new(r * a.cos(), y, r * a.sin())
        })
        .collect()
}

/// Reusable buffers of the residual evaluation.
struct Fitter<'a> {
    samples: &'a [ShadedSample],
    logs: Vec<f32>,
    groups: usize,
    views: usize,
    residual: Vec<f32>,
    by_group: Vec<Vec<f32>>,
    by_view: Vec<Vec<f32>>,
    group_offset: Vec<f32>,
    view_offset: Vec<f32>,
}

fn median(v: &mut [f32]) -> f32 {
    if v.is_empty() {
        return 0.0;
    }
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f32::total_cmp).1
}

impl<'a> Fitter<'a> {
    /// A fitter of the luminance of `samples` (`channel` None) or of one colour channel.
    fn new(samples: &'a [ShadedSample], channel: Option<usize>) -> Self {
        let groups = samples
            .iter()
            .map(|s| s.group as usize + 1)
            .max()
            .unwrap_or(0);
        let views = samples
            .iter()
            .map(|s| s.view as usize + 1)
            .max()
            .unwrap_or(0);
        Self {
            samples,
            logs: samples
                .iter()
                .map(|s| channel.map_or(luminance(s.colour), |c| s.colour[c]))
                .map(|v| v.max(0.02).ln())
                .collect(),
            groups,
            views,
            residual: vec![0.0; samples.len()],
            by_group: vec![Vec::new(); groups],
            by_view: vec![Vec::new(); views],
            group_offset: vec![0.0; groups],
            view_offset: vec![0.0; views],
        }
    }

    /// Mean absolute residual of log luminance with light `key`, after per-group albedos and
    /// per-view exposures (two rounds of medians; exposures halved towards none).
    fn cost(&mut self, key: Vec3) -> f32 {
        for (r, (s, y)) in self
            .residual
            .iter_mut()
            .zip(self.samples.iter().zip(&self.logs))
        {
            *r = y - (1.0 + s.normal.dot(key).max(0.0) * s.lit).ln();
        }
        self.view_offset.iter_mut().for_each(|v| *v = 0.0);
        for _ in 0..2 {
            self.by_group.iter_mut().for_each(Vec::clear);
            for (s, r) in self.samples.iter().zip(&self.residual) {
                self.by_group[s.group as usize].push(r - self.view_offset[s.view as usize]);
            }
            for (o, g) in self.group_offset.iter_mut().zip(&mut self.by_group) {
                *o = median(g);
            }
            self.by_view.iter_mut().for_each(Vec::clear);
            for (s, r) in self.samples.iter().zip(&self.residual) {
                self.by_view[s.view as usize].push(r - self.group_offset[s.group as usize]);
            }
            for (o, v) in self.view_offset.iter_mut().zip(&mut self.by_view) {
                *o = 0.5 * median(v);
            }
        }
        let total: f32 = self
            .samples
            .iter()
            .zip(&self.residual)
            .map(|(s, r)| {
                (r - self.group_offset[s.group as usize] - self.view_offset[s.view as usize]).abs()
            })
            .sum();
        total / self.samples.len().max(1) as f32
    }
}

/// The key light that best explains `samples` (see the module docs); [`KeyLight::none`] when
/// there are too few samples or no light explains enough. With `near`, the search starts from
/// that light (a fit of the same views) instead of every direction and strength.
pub fn fit_key_light(samples: &[ShadedSample], near: Option<Vec3>) -> KeyLight {
    // Keep groups large enough to tell light from albedo, then thin evenly.
    let groups = samples
        .iter()
        .map(|s| s.group as usize + 1)
        .max()
        .unwrap_or(0);
    let mut counts = vec![0usize; groups];
    for s in samples {
        counts[s.group as usize] += 1;
    }
    let kept: Vec<ShadedSample> = samples
        .iter()
        .filter(|s| counts[s.group as usize] >= MIN_GROUP)
        .copied()
        .collect();
    if kept.len() < 4 * MIN_GROUP {
        return KeyLight::none();
    }
    let step = kept.len().div_ceil(MAX_SAMPLES);
    let thinned: Vec<ShadedSample> = kept.iter().step_by(step).copied().collect();
    let mut fitter = Fitter::new(&thinned, None);
    debug_assert!(fitter.groups > 0 && fitter.views > 0);
    let unlit = fitter.cost(Vec3::ZERO);
    let mut best = (unlit, Vec3::ZERO);
    let strengths = [0.25, 0.5, 0.8, 1.2, 1.7, 2.4, 3.2, MAX_STRENGTH];
    match near {
        // The refinement below searches around `near` even where `near` itself explains less
        // than no light; the bar stays the no-light residual then.
        Some(key) if key != Vec3::ZERO => best = (best.0.min(fitter.cost(key)), key),
        _ => {
            for d in directions(64) {
                for s in strengths {
                    let c = fitter.cost(d * s);
                    if c < best.0 {
                        best = (c, d * s);
                    }
                }
            }
        }
    }
    // Refine around the best: nearby directions, finer strengths.
    for round in 0..2 {
        let spread = if round == 0 { 0.2 } else { 0.08 };
        let centre = best.1;
        if centre == Vec3::ZERO {
            break;
        }
        let (dir, strength) = (centre.normalize(), centre.length());
        for d in directions(24) {
            let candidate = (dir + d * spread).normalize();
            for f in [0.8, 0.9, 1.0, 1.1, 1.25] {
                let key = candidate * (strength * f).min(MAX_STRENGTH);
                let c = fitter.cost(key);
                if c < best.0 {
                    best = (c, key);
                }
            }
        }
    }
    if best.0 > (1.0 - MIN_GAIN) * unlit {
        return KeyLight {
            residual: (unlit, unlit),
            ..KeyLight::none()
        };
    }
    // Each channel's strength along the fitted direction.
    let (dir, strength) = (best.1.normalize(), best.1.length());
    let mut strengths = Vec3::splat(strength);
    for c in 0..3 {
        let mut channel = Fitter::new(&thinned, Some(c));
        let mut best_c = (f32::MAX, strength);
        for f in [0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.12, 1.25, 1.4, 1.6, 1.8] {
            let s = (strength * f).min(MAX_STRENGTH);
            let cost = channel.cost(dir * s);
            if cost < best_c.0 {
                best_c = (cost, s);
            }
        }
        strengths[c] = best_c.1;
    }
    fitter.cost(best.1);
    KeyLight {
        key: best.1,
        strength: strengths,
        residual: (best.0, unlit),
        exposure: fitter.view_offset.clone(),
    }
}

/// Hue bin of an sRGB colour (0–1): 0 for greys, else 1..=6 by hue sextant.
pub fn hue_bin(c: Vec3) -> u32 {
    let (hi, lo) = (c.max_element(), c.min_element());
    if hi - lo < 0.12 * hi.max(0.05) + 0.02 {
        return 0;
    }
    let d = hi - lo;
    let h = if hi == c.x {
        ((c.y - c.z) / d).rem_euclid(6.0)
    } else if hi == c.y {
        (c.z - c.x) / d + 2.0
    } else {
        (c.x - c.y) / d + 4.0
    };
    1 + (h.floor() as u32).min(5)
}

/// Luminance of an sRGB colour (0–1), Rec. 709 weights.
pub fn luminance(c: Vec3) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Samples of a lit cylinder-ish body: six rings of points with normals all round, albedo
    /// per ring, seen from one view per `exposure` each seeing the half facing it.
    fn lit_samples(key: Vec3, warm: Vec3, exposure: &[f32]) -> Vec<ShadedSample> {
        let views = exposure.len();
        let mut out = Vec::new();
        for g in 0..6u32 {
            let albedo = 0.2 + 0.12 * g as f32;
            for i in 0..60 {
                let a = i as f32 / 60.0 * std::f32::consts::TAU;
                let tilt = ((i * 7) % 11) as f32 / 11.0 - 0.5;
                let n = Vec3::new(a.sin(), 0.6 * tilt, a.cos()).normalize();
                for (v, gain) in exposure.iter().enumerate() {
                    let b = v as f32 / views as f32 * std::f32::consts::TAU;
                    let eye = Vec3::new(b.sin(), 0.0, b.cos());
                    if n.dot(eye) <= 0.1 {
                        continue;
                    }
                    let shade = Vec3::ONE + warm * n.dot(key).max(0.0);
                    let colour = Vec3::splat(albedo) * shade * 0.4 * gain;
                    out.push(ShadedSample {
                        group: g,
                        view: v as u32,
                        normal: n,
                        colour,
                        lit: 1.0,
                    });
                }
            }
        }
        out
    }

    #[test]
    fn a_key_light_is_found_and_divided_out() {
        let key = Vec3::new(0.6, 0.5, 0.4).normalize() * 1.8;
        let exposure = [1.0, 0.9, 1.1, 1.0, 0.95, 1.05, 1.0, 0.9];
        let warm = Vec3::new(1.2, 1.0, 0.75);
        let samples = lit_samples(key, warm, &exposure);
        let fit = fit_key_light(&samples, None);
        assert!(
            (fit.key - key).length() < 0.3,
            "fitted {:?}, true {key:?}",
            fit.key
        );
        assert!(fit.residual.0 < 0.5 * fit.residual.1, "{:?}", fit.residual);
        // Each view's exposure is partly divided out: the spread between views shrinks.
        let corrected: Vec<f32> = exposure
            .iter()
            .zip(&fit.exposure)
            .map(|(e, offset)| e * (-offset).exp())
            .collect();
        let spread = |v: &[f32]| {
            v.iter().cloned().fold(f32::MIN, f32::max) / v.iter().cloned().fold(f32::MAX, f32::min)
        };
        assert!(
            spread(&corrected) < spread(&exposure) - 0.05,
            "exposures {exposure:?} corrected to {corrected:?}"
        );
        // The shadowed side is lifted to the lit side's level and colour.
        let lit = key.normalize();
        let dark = -lit;
        let seen_lit = Vec3::ONE + warm * key.length();
        let seen_dark = Vec3::ONE;
        let ratio = (seen_lit * fit.gain(lit)) / (seen_dark * fit.gain(dark));
        assert!(
            (ratio - Vec3::ONE).abs().max_element() < 0.15,
            "lit / dark after: {ratio}"
        );
    }

    #[test]
    fn unlit_samples_keep_no_light() {
        let samples = lit_samples(Vec3::ZERO, Vec3::ONE, &[1.0; 8]);
        let fit = fit_key_light(&samples, None);
        assert_eq!(fit.key, Vec3::ZERO);
        assert_eq!(fit.gain(Vec3::X), Vec3::ONE);
    }

    #[test]
    fn hue_bins_split_colours_and_keep_greys_together() {
        assert_eq!(hue_bin(Vec3::splat(0.5)), 0);
        assert_eq!(hue_bin(Vec3::splat(0.05)), 0);
        assert_ne!(
            hue_bin(Vec3::new(0.8, 0.1, 0.1)),
            hue_bin(Vec3::new(0.1, 0.1, 0.8))
        );
        // Shading keeps the hue.
        let c = Vec3::new(0.6, 0.3, 0.2);
        assert_eq!(hue_bin(c), hue_bin(c * 0.4));
    }
}
