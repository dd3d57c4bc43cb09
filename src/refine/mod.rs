//! Refinement: the avatar the network made, fitted to the views the person was seen in.
//!
//! Starting from the network's canonical Gaussians, a fit moves each Gaussian's centre
//! (pulled back towards where the network put it), scales, orientation, opacity and albedo so
//! that the avatar, posed as the person stood in each view and rendered through that view's
//! camera, shows the person's colours inside their mask and covers the mask and nothing else
//! ([`loss`]). Gradients come from the rasteriser's backward pass ([`crate::splat::grad`]),
//! through linear blend skinning to the canonical Gaussians, and Adam takes the steps
//! ([`params`]). Gaussians grow where the silhouettes ask for more than the body template
//! gives (skirts, coats, hair: [`growth`]).
//!
//! Views whose camera and pose were fitted rather than measured (photos) can also have a
//! rigid correction of the posed body in each view's camera frame fitted alongside
//! ([`RefineConfig::correct_views`], [`correction`]).
//!
//! Never worse than its start: one view is held out of the fit, the fit stops when the held
//! view's loss stops falling, and the parameters that scored best on it are kept; when none
//! beat the network's avatar, the network's avatar is returned unchanged.

mod correction;
mod growth;
mod light;
mod loss;
mod params;
pub mod photos;
mod skinning;
mod smooth;
mod view;

pub use loss::ViewLoss;
pub use view::RefineView;

use crate::avatar::{Avatar, AvatarError};
use crate::splat::grad::{self, FrameGrads};
use crate::splat::{Rasterizer, RenderOptions, RenderOutput};
use glam::Vec3;
use params::{Adam, ParamGrads, Params, Rates};
use std::time::{Duration, Instant};

/// Why a fit cannot run.
#[derive(Debug, thiserror::Error)]
pub enum RefineError {
    /// A view is unusable.
    #[error("refine: view `{view}`: {why}")]
    View {
        /// The view's name.
        view: String,
        /// What is wrong with it.
        why: String,
    },
    /// The fitted Gaussians do not make an avatar (a bug: the fit keeps them valid).
    #[error("refine: {0}")]
    Avatar(#[from] AvatarError),
}

/// Settings of a fit.
#[derive(Debug, Clone, PartialEq)]
pub struct RefineConfig {
    /// Wall-clock time a fit may take.
    pub budget: Duration,
    /// Most optimiser steps.
    pub max_iterations: usize,
    /// Most Gaussians the avatar may grow to.
    pub max_gaussians: usize,
    /// Longest side (pixels) of each view's crop.
    pub max_side: u32,
    /// Fewest views to fit to (one of them is held out to stop the fit in time).
    pub min_views: usize,
    /// Weight of the silhouette term against the photometric one.
    pub silhouette_weight: f32,
    /// Weight of the pull of each centre back to its anchor (per `(2 cm)²` of offset, averaged
    /// over the Gaussians).
    pub anchor_weight: f32,
    /// Weight of the albedo prior (neighbouring Gaussians share a colour, [`smooth`]) when
    /// the light is fitted.
    pub albedo_weight: f32,
    /// Steps between checks of the held-out view.
    pub check_every: usize,
    /// Checks without a better held-out loss after which the fit stops.
    pub patience: usize,
    /// Grow Gaussians where the silhouettes ask for them.
    pub grow: bool,
    /// Views rendered per optimiser step (taken in turn).
    pub views_per_step: usize,
    /// Fit a rigid correction of the posed body in each fitted view's camera frame (image
    /// shift, scale and a small rotation; for views whose camera and pose were fitted, not
    /// measured). The held-out view keeps the camera it was given.
    pub correct_views: bool,
}

impl Default for RefineConfig {
    fn default() -> Self {
        Self {
            budget: Duration::from_secs(10),
            max_iterations: 500,
            max_gaussians: 60_000,
            max_side: 256,
            min_views: 3,
            silhouette_weight: 1.0,
            anchor_weight: 0.05,
            albedo_weight: 0.3,
            check_every: 10,
            patience: 6,
            grow: true,
            views_per_step: 1,
            correct_views: false,
        }
    }
}

/// Why a fit ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Stop {
    /// Fewer views than [`RefineConfig::min_views`]: nothing was fitted.
    #[default]
    TooFewViews,
    /// The held-out view's loss stopped falling.
    Converged,
    /// [`RefineConfig::budget`] ran out.
    Budget,
    /// [`RefineConfig::max_iterations`] were taken.
    Iterations,
    /// The caller asked it to stop (a new view arrived).
    Cancelled,
}

/// What a fit did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RefineReport {
    /// Optimiser steps taken.
    pub iterations: usize,
    /// Views fitted to (the held-out one not counted).
    pub views_fitted: usize,
    /// The view held out to stop the fit.
    pub held_view: Option<String>,
    /// Mean loss over the fitted views at the start and at the end.
    pub loss: (f32, f32),
    /// The held-out view's loss at the start and at its best.
    pub held: (f32, f32),
    /// Step at which the held-out view scored best (0: the network's avatar).
    pub best_iteration: usize,
    /// Gaussians before and after.
    pub gaussians: (usize, usize),
    /// Gaussians added by growth (in the kept parameters).
    pub grown: usize,
    /// Wall-clock time taken.
    pub elapsed: Duration,
    /// Whether the fitted avatar replaced the network's (it beat it on the held-out view).
    pub improved: bool,
    /// Why it ended.
    pub stop: Stop,
    /// Time spent in each part of the steps.
    pub times: StageTimes,
    /// Each check of the held-out view: (seconds since the fit began, its loss).
    pub trace: Vec<(f64, f32)>,
    /// Per fitted view, the correction fitted at the end (with
    /// [`RefineConfig::correct_views`]).
    pub corrections: Vec<CorrectionReport>,
}

/// The correction fitted to one view ([`RefineConfig::correct_views`]).
#[derive(Debug, Clone, PartialEq)]
pub struct CorrectionReport {
    /// The view's name.
    pub view: String,
    /// Translation of the body in the camera's optical frame (metres: x right, y down, z away).
    pub translation: Vec3,
    /// Angle of its rotation, degrees.
    pub degrees: f32,
}

impl RefineReport {
    /// Seconds the fit took to reach `share` (0..=1) of the held-out gain it finally kept;
    /// `None` when it kept nothing.
    pub fn time_to_gain(&self, share: f32) -> Option<f64> {
        let gain = self.held.0 - self.held.1;
        if !self.improved || gain <= 0.0 {
            return None;
        }
        let target = self.held.0 - share * gain;
        self.trace
            .iter()
            .find(|(_, held)| *held <= target)
            .map(|(t, _)| *t)
    }
}

/// Seconds spent in each part of a fit's steps.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StageTimes {
    /// Posing the Gaussians for each view.
    pub pose: f64,
    /// The forward render.
    pub render: f64,
    /// The image loss and its frame gradients.
    pub loss: f64,
    /// The rasteriser's backward pass.
    pub backward: f64,
    /// The chain rule through posing, regularisation and the optimiser step.
    pub update: f64,
    /// Checks of the held-out view.
    pub check: f64,
}

/// A progress report at each check of the held-out view; returning `false` stops the fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Progress {
    /// Steps taken.
    pub iteration: usize,
    /// Mean loss over the fitted views.
    pub loss: f32,
    /// The held-out view's loss.
    pub held: f32,
    /// Gaussians now.
    pub gaussians: usize,
}

/// What the light is fitted from: the key light the views' colours were de-lit by (the
/// avatar's colours are albedo in its convention) and each Gaussian's canonical normal
/// ([`crate::reconstruct::surface::canonical_normals`]). Each view's exposure is
/// [`RefineView::exposure`].
#[derive(Debug, Clone)]
pub struct LightStart {
    /// The key light fitted to the views' colours (none: a light from above in front).
    pub key: crate::reconstruct::delight::KeyLight,
    /// Per Gaussian of the avatar, its canonical normal.
    pub normals: Vec<Vec3>,
}

/// The fitted avatar and what the fit did.
#[derive(Debug, Clone)]
pub struct Refined {
    /// The avatar (the input one when the fit did not beat it).
    pub avatar: Avatar,
    /// What the fit did.
    pub report: RefineReport,
}

/// Fits `avatar` to `views` (see the module doc), with the light the views were taken in when
/// `light` is given (the avatar's colours then stay albedo), else with the colours as seen.
/// `on_check` sees each check of the held-out view and can stop the fit by returning `false`.
pub fn refine(
    avatar: &Avatar,
    views: Vec<RefineView>,
    light: Option<LightStart>,
    config: &RefineConfig,
    mut on_check: impl FnMut(&Progress) -> bool,
) -> Result<Refined, RefineError> {
    let start = Instant::now();
    let mut report = RefineReport {
        gaussians: (avatar.canonical.len(), avatar.canonical.len()),
        ..RefineReport::default()
    };
    if views.len() < config.min_views.max(2) || avatar.canonical.is_empty() {
        report.elapsed = start.elapsed();
        return Ok(Refined {
            avatar: avatar.clone(),
            report,
        });
    }
    for v in &views {
        if let Err(e) = avatar.check_matrices(&v.skinning) {
            return Err(RefineError::View {
                view: v.name.clone(),
                why: e.to_string(),
            });
        }
    }
    if let Some(l) = &light {
        if l.normals.len() != avatar.canonical.len() {
            return Err(RefineError::View {
                view: "all".into(),
                why: format!(
                    "{} normals for {} Gaussians",
                    l.normals.len(),
                    avatar.canonical.len()
                ),
            });
        }
    }
    let held = held_out_view(avatar, &views);
    tracing::debug!(held, name = %views[held].name, "held-out view");
    report.held_view = Some(views[held].name.clone());
    report.views_fitted = views.len() - 1;
    let mut fit = Fit::new(avatar, views, light, held, config);
    let held_start = fit.held_loss();
    let loss_start = fit.step(false).0;
    report.loss = (loss_start, loss_start);
    report.held = (held_start, held_start);
    let mut best = (held_start, 0, fit.params.clone(), 0usize);
    let mut since_best = 0;
    let mut grown = 0usize;
    report.stop = Stop::Iterations;
    for it in 1..=config.max_iterations {
        // The schedule follows the steps; the budget only cuts the fit short.
        let progress = it as f32 / config.max_iterations.max(1) as f32;
        fit.set_rates(progress);
        let (loss, _) = fit.step(true);
        report.loss.1 = loss;
        report.iterations = it;
        if config.grow && growth::due(it, progress) {
            grown += fit.grow(config.max_gaussians);
        }
        if it % config.check_every == 0 {
            let held_loss = fit.held_loss();
            report
                .trace
                .push((start.elapsed().as_secs_f64(), held_loss));
            let keep_going = on_check(&Progress {
                iteration: it,
                loss,
                held: held_loss,
                gaussians: fit.params.len(),
            });
            if held_loss < best.0 {
                best = (held_loss, it, fit.params.clone(), grown);
                since_best = 0;
            } else {
                since_best += 1;
            }
            if !keep_going {
                report.stop = Stop::Cancelled;
                break;
            }
            if since_best >= config.patience {
                report.stop = Stop::Converged;
                break;
            }
        }
        if start.elapsed() >= config.budget {
            report.stop = Stop::Budget;
            break;
        }
    }
    let (held_best, best_it, params, best_grown) = best;
    report.held.1 = held_best;
    report.best_iteration = best_it;
    report.improved = best_it > 0;
    let avatar = if report.improved {
        report.grown = best_grown;
        Avatar::new(
            params.gaussians(),
            params.skin.clone(),
            avatar.body_model.clone(),
        )?
    } else {
        avatar.clone()
    };
    report.gaussians.1 = avatar.canonical.len();
    if let Some(l) = &fit.light {
        tracing::debug!(light = ?l.summary(), "fitted light");
    }
    report.corrections = fit
        .corrections
        .iter()
        .zip(&fit.views)
        .filter_map(|(c, v)| {
            let c = c.as_ref()?;
            Some(CorrectionReport {
                view: v.name.clone(),
                translation: c.translation,
                degrees: c.rotation.to_scaled_axis().length().to_degrees(),
            })
        })
        .collect();
    report.times = fit.times;
    report.elapsed = start.elapsed();
    Ok(Refined { avatar, report })
}

/// The view held out of the fit: the one whose camera sits nearest another view's (seen from
/// the avatar's centre), so that the views fitted cover the person as well as they can.
fn held_out_view(avatar: &Avatar, views: &[RefineView]) -> usize {
    let g = &avatar.canonical.positions;
    let centre = g.iter().copied().sum::<Vec3>() / g.len().max(1) as f32;
    let dirs: Vec<Vec3> = views
        .iter()
        .map(|v| (v.camera.center() - centre).normalize_or_zero())
        .collect();
    let crowding = |i: usize| {
        dirs.iter()
            .enumerate()
            .filter(|(j, _)| *j != i)
            .map(|(_, d)| d.dot(dirs[i]))
            .fold(f32::MIN, f32::max)
    };
    // The newest view among the most crowded ones (ties go to the last).
    (0..views.len())
        .max_by(|&a, &b| crowding(a).total_cmp(&crowding(b)).then(a.cmp(&b)))
        .unwrap_or(0)
}

/// Learning rate of the light's parameters.
const LIGHT_RATE: f32 = 0.02;
/// Steps between updates of the cast shadows.
const SHADOW_EVERY: usize = 50;

/// A step through `n` views that visits all of them, spread out: about 0.4 n, coprime with n.
fn stride(n: usize) -> usize {
    fn gcd(a: usize, b: usize) -> usize {
        if b == 0 {
            a
        } else {
            gcd(b, a % b)
        }
    }
    let mut s = (n * 2 / 5).max(1);
    while gcd(s, n) != 1 {
        s += 1;
    }
    s
}

/// The state of one fit.
struct Fit<'a> {
    config: &'a RefineConfig,
    params: Params,
    adam: Adam,
    rates: Rates,
    views: Vec<RefineView>,
    held: usize,
    /// Per view, each Gaussian's blended bone transform and rotation.
    transforms: Vec<Vec<(glam::Affine3A, glam::Quat)>>,
    /// The fitted light, when the light is modelled.
    light: Option<light::Light>,
    light_adam: light::LightAdam,
    /// Per view, whether the key light reaches each Gaussian (refreshed as the fit goes).
    lit: Vec<Vec<f32>>,
    /// Per Gaussian, the summed screen-space gradient norms and the views that saw it (the
    /// growth signal since the last growth).
    grad_2d: Vec<f32>,
    seen: Vec<u32>,
    rasterizer: Rasterizer,
    out: RenderOutput,
    d_rgb: Vec<f32>,
    d_alpha: Vec<f32>,
    initial_rates: Rates,
    times: StageTimes,
    /// Steps since the cast shadows were last worked out.
    shadow_age: usize,
    /// Neighbouring Gaussians (the albedo prior's pairs), rebuilt after growth.
    pairs: Vec<(u32, u32)>,
    /// Next place in the visiting order of the fitted views.
    cursor: usize,
    /// Each view's latest loss.
    last_loss: Vec<f32>,
    /// Per view, its correction ([`RefineConfig::correct_views`]; never the held-out view's).
    corrections: Vec<Option<correction::ViewCorrection>>,
}

impl<'a> Fit<'a> {
    fn new(
        avatar: &Avatar,
        views: Vec<RefineView>,
        light: Option<LightStart>,
        held: usize,
        config: &'a RefineConfig,
    ) -> Self {
        let params = Params::from_avatar(avatar);
        let transforms: Vec<_> = views
            .iter()
            .map(|v| crate::avatar::blend_rows(&params.skin, &v.skinning))
            .collect();
        let exposures: Vec<f32> = views.iter().map(|v| v.exposure).collect();
        let light = light.map(|l| light::Light::new(&l.key, &exposures, l.normals));
        let rates = Rates {
            position: 1e-3,
            log_scale: 1e-2,
            rotation: 5e-3,
            opacity_logit: 5e-2,
            colour: 1e-2,
        };
        let n = params.len();
        let count = views.len();
        let corrections = views
            .iter()
            .zip(&transforms)
            .enumerate()
            .map(|(v, (view, t))| {
                if !config.correct_views || v == held {
                    return None;
                }
                let centre = params
                    .position
                    .iter()
                    .zip(t)
                    .map(|(x, (a, _))| a.transform_point3(*x))
                    .sum::<Vec3>()
                    / n.max(1) as f32;
                let pivot = view.camera.camera_from_world().transform_point3(centre);
                Some(correction::ViewCorrection::new(pivot))
            })
            .collect();
        Self {
            corrections,
            last_loss: vec![0.0; count],
            config,
            params,
            adam: Adam::default(),
            rates,
            views,
            held,
            transforms,
            light,
            light_adam: light::LightAdam::default(),
            lit: Vec::new(),
            grad_2d: vec![0.0; n],
            seen: vec![0; n],
            rasterizer: Rasterizer::new(),
            out: RenderOutput::default(),
            d_rgb: Vec::new(),
            d_alpha: Vec::new(),
            initial_rates: rates,
            times: StageTimes::default(),
            cursor: 0,
            shadow_age: 0,
            pairs: Vec::new(),
        }
    }

    /// Learning rates at `progress` (0–1) through the steps: positions decay tenfold.
    fn set_rates(&mut self, progress: f32) {
        let r = self.initial_rates;
        self.rates = Rates {
            position: r.position * 0.1f32.powf(progress),
            ..r
        };
    }

    fn options() -> RenderOptions {
        RenderOptions {
            background: Vec3::ZERO,
            ..RenderOptions::default()
        }
    }

    /// The loss of the held-out view now.
    fn held_loss(&mut self) -> f32 {
        let clock = Instant::now();
        let shading = self.shading(self.held);
        let posed = skinning::pose(&self.params, &self.transforms[self.held], &shading);
        let view = &self.views[self.held];
        self.rasterizer
            .render_into(&posed, &view.camera, &Self::options(), &mut self.out);
        let loss = loss::composite_error(view, &self.out);
        self.times.check += clock.elapsed().as_secs_f64();
        loss
    }

    /// With `apply`, one optimiser step on the next [`RefineConfig::views_per_step`] fitted
    /// views; without, the loss of every fitted view. Returns the mean of each fitted view's
    /// latest loss.
    fn step(&mut self, apply: bool) -> (f32, ParamGrads) {
        let n = self.params.len();
        let mut grads = ParamGrads::zeros(n);
        let fitted = (0..self.views.len())
            .filter(|v| *v != self.held)
            .collect::<Vec<_>>();
        let batch: Vec<usize> = if apply {
            let k = self.config.views_per_step.clamp(1, fitted.len());
            (0..k)
                .map(|_| {
                    // A stride coprime with the count visits the views in a spread-out order.
                    let v = fitted[self.cursor % fitted.len()];
                    self.cursor += stride(fitted.len());
                    v
                })
                .collect()
        } else {
            fitted.clone()
        };
        let share = 1.0 / batch.len() as f32;
        let options = Self::options();
        let mut light_grads = self
            .light
            .as_ref()
            .map(|l| l.zero_grads())
            .unwrap_or_default();
        for &v in &batch {
            let mut clock = Instant::now();
            let mut lap = |t: &mut f64| {
                *t += clock.elapsed().as_secs_f64();
                clock = Instant::now();
            };
            let shading = self.shading(v);
            let mut posed = skinning::pose(&self.params, &self.transforms[v], &shading);
            let view = &self.views[v];
            let moved = self.corrections[v]
                .as_ref()
                .map(|c| c.apply(&view.camera, &mut posed));
            lap(&mut self.times.pose);
            grad::forward(
                &mut self.rasterizer,
                &posed,
                &view.camera,
                &options,
                &mut self.out,
            );
            lap(&mut self.times.render);
            let loss = loss::view_loss(
                view,
                &self.out,
                self.config.silhouette_weight,
                Some((&mut self.d_rgb, &mut self.d_alpha)),
            );
            self.last_loss[v] = loss.total();
            lap(&mut self.times.loss);
            if !apply {
                continue;
            }
            for d in self.d_rgb.iter_mut().chain(self.d_alpha.iter_mut()) {
                *d *= share;
            }
            let frame = FrameGrads {
                rgb: &self.d_rgb,
                alpha: &self.d_alpha,
            };
            let mut g = grad::backward(&self.rasterizer, &posed, &view.camera, &options, frame)
                .expect("the frame and Gaussians of the forward just run");
            lap(&mut self.times.backward);
            if let (Some(c), Some(moved)) = (self.corrections[v].as_mut(), moved) {
                let d = c.gradient(&view.camera, &posed, &g);
                c.step(d);
                correction::pull_back(&moved, &mut g);
            }
            skinning::accumulate(&self.params, &self.transforms[v], &shading, &g, &mut grads);
            if let Some(l) = &self.light {
                l.accumulate(
                    v,
                    &self.transforms[v],
                    &self.lit[v],
                    &self.params.colour,
                    &g.colours,
                    &mut light_grads,
                );
            }
            for (i, m) in g.means_2d.iter().enumerate() {
                let norm = (m[0] * m[0] + m[1] * m[1]).sqrt();
                if norm > 0.0 {
                    self.grad_2d[i] += norm;
                    self.seen[i] += 1;
                }
            }
            lap(&mut self.times.update);
        }
        if apply {
            let clock = Instant::now();
            self.shadow_age += 1;
            self.regularise(&mut grads);
            self.adam.step(&mut self.params, &grads, &self.rates);
            if let Some(l) = &mut self.light {
                let factor = l.step(&light_grads, &mut self.light_adam, LIGHT_RATE, &fitted);
                for c in &mut self.params.colour {
                    *c = (*c * factor).clamp(Vec3::ZERO, Vec3::ONE);
                }
            }
            self.times.update += clock.elapsed().as_secs_f64();
        }
        let total = fitted.iter().map(|v| self.last_loss[*v]).sum::<f32>() / fitted.len() as f32;
        (total, grads)
    }

    /// Per Gaussian, the light view `v` shows it in (empty without a light model); the
    /// cast shadows are worked out again every [`SHADOW_EVERY`] steps.
    fn shading(&mut self, v: usize) -> Vec<Vec3> {
        let Some(light) = &self.light else {
            return Vec::new();
        };
        if self.lit.is_empty() || self.shadow_age >= SHADOW_EVERY {
            self.lit = self
                .transforms
                .iter()
                .map(|t| {
                    let posed: Vec<Vec3> = self
                        .params
                        .position
                        .iter()
                        .zip(t)
                        .map(|(x, (a, _))| a.transform_point3(*x))
                        .collect();
                    light.lit(&posed, t)
                })
                .collect();
            self.shadow_age = 0;
        }
        light.shading(v, &self.transforms[v], &self.lit[v])
    }

    /// Adds the pull of each centre towards its anchor, and with a fitted light the albedo
    /// prior, to `grads`.
    fn regularise(&mut self, grads: &mut ParamGrads) {
        if self.light.is_some() && self.config.albedo_weight > 0.0 {
            if self.pairs.is_empty() {
                self.pairs = smooth::neighbour_pairs(&self.params.anchor);
            }
            smooth::albedo_prior(
                &self.params.colour,
                &self.pairs,
                self.config.albedo_weight,
                &mut grads.colour,
            );
        }
        const REACH: f32 = 0.02;
        let w = 2.0 * self.config.anchor_weight / (self.params.len() as f32 * REACH * REACH);
        for ((g, x), a) in grads
            .position
            .iter_mut()
            .zip(&self.params.position)
            .zip(&self.params.anchor)
        {
            *g += (*x - *a) * w;
        }
    }

    /// Grows Gaussians where the screen-space gradients say the silhouette or colours ask for
    /// more; returns how many were added.
    fn grow(&mut self, max_gaussians: usize) -> usize {
        let added = growth::densify(
            &mut self.params,
            &mut self.adam,
            &self.grad_2d,
            &self.seen,
            max_gaussians,
        );
        for (parent, _) in &added {
            for t in &mut self.transforms {
                t.push(t[*parent]);
            }
            for l in &mut self.lit {
                l.push(l[*parent]);
            }
            if let Some(light) = &mut self.light {
                light.normals.push(light.normals[*parent]);
            }
        }
        let n = self.params.len();
        self.grad_2d = vec![0.0; n];
        self.seen = vec![0; n];
        if !added.is_empty() {
            self.pairs.clear();
        }
        added.len()
    }
}
