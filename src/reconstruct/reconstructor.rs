//! The reconstruction step: owns the network, the per-view token cache and the
//! anchor points on the body template (shaped by the latest accepted body shape), and turns a
//! set of held views into an [`Avatar`].

use super::part_rules::apply_part_rules;
use super::preprocess::Preprocessed;
use super::shape::AcceptedShape;
use crate::avatar::Avatar;
use crate::body::official::{OfficialPrior, PriorPaths, SMPLX_MODEL_ID};
use crate::body::{BodyTemplate, SkinWeights, MAKEHUMAN_MODEL_ID};
use crate::config::{ComputeDevice, ModelConfig};
use crate::model::cache::ViewTokenCache;
use crate::model::checkpoint::seeded_var_builder;
use crate::model::default_weights::{
    default_var_builder, WeightsSource, DEFAULT_CHECKPOINT_PATH, DEFAULT_PRESET,
    RANDOM_WEIGHTS_SEED,
};
use crate::model::dpt::{DptConfig, NeuralRenderer};
use crate::model::hub::load_checkpoint;
use crate::model::rgb_kind::LATENT_RGB_RENDERER_TYPE;
use crate::model::{Lhmpp, LhmppConfig, RgbKind};
use crate::splat::Gaussians;
use candle_core::{DType, Device, Tensor};
use glam::{Quat, Vec3};
use std::path::Path;

/// A reconstruction problem, naming the input that caused it.
#[derive(Debug, thiserror::Error)]
pub enum ReconstructError {
    /// The model preset or checkpoint is unusable.
    #[error("model: {0}")]
    Model(String),
    /// The body template failed to load.
    #[error(transparent)]
    Body(#[from] crate::body::BodyError),
    /// A tensor operation failed.
    #[error("network: {0}")]
    Candle(#[from] candle_core::Error),
    /// The predicted Gaussians are inconsistent.
    #[error(transparent)]
    Avatar(#[from] crate::avatar::AvatarError),
    /// The predicted Gaussians are inconsistent.
    #[error(transparent)]
    Gaussians(#[from] crate::splat::GaussianError),
    /// A view needed for the reconstruction is no longer available.
    #[error("view {0} is not in the token cache and has no image")]
    MissingView(u64),
    /// No view to reconstruct from.
    #[error("no views")]
    NoViews,
}

/// Opens the compute device named in the config.
pub fn select_device(device: ComputeDevice) -> Result<Device, ReconstructError> {
    let Some(index) = device.cuda_index() else {
        return Ok(Device::Cpu);
    };
    if !candle_core::utils::cuda_is_available() {
        return Err(ReconstructError::Model(format!(
            "device `{device}`: this binary was built without the `cuda` feature (see scripts/build-cuda)"
        )));
    }
    Device::new_cuda(index).map_err(|e| ReconstructError::Model(format!("device `{device}`: {e}")))
}

/// Network + token cache + anchor points.
pub struct Reconstructor {
    model: Lhmpp,
    cfg: LhmppConfig,
    device: Device,
    cache: ViewTokenCache,
    template: BodyTemplate,
    skin: SkinWeights,
    prior: Option<OfficialPrior>,
    anchor_positions: Tensor,
    anchor_normals: Tensor,
    weights: String,
    /// The unshaped MakeHuman template (shapes are applied to it); `None` with the prior.
    base_template: Option<BodyTemplate>,
    num_points: usize,
    seed: u64,
    /// `model.checkpoint` as configured (names the weights in `neural_renderer_id`).
    checkpoint: String,
    shape: Option<AcceptedShape>,
    betas_noted: bool,
    /// The betas the network's shape head predicted at the last reconstruction, as a SMPL-X
    /// shape (only with the SMPL-X prior body).
    predicted_shape: Option<AcceptedShape>,
    /// The official `neural_renderer.type` of the network (`patch_4dptonly` for presets).
    renderer_kind: String,
    rgb_kind: RgbKind,
    checkpoint_kind: String,
    /// Most views the network reads ([`ModelConfig::network_views`]).
    network_views: usize,
}

impl Reconstructor {
    /// Builds the network (checkpoint or embedded default), samples the anchors on the template.
    /// `max_views` bounds the token cache.
    pub fn new(config: &ModelConfig, max_views: usize) -> Result<Self, ReconstructError> {
        let mut cfg = LhmppConfig::preset(&config.preset)
            .map_err(|e| ReconstructError::Model(e.to_string()))?;
        let device = select_device(config.device)?;
        let dtype = config.dtype.candle();
        // The prior first: a missing prior file fails before gigabytes of weights are read.
        let official = cfg.preset == "lhmpp-700m"
            || (!config.checkpoint.is_empty() && Path::new(&config.checkpoint).is_dir());
        let prior = load_prior(config, official, &cfg.preset)?;
        let source = WeightsSource::parse(&config.checkpoint).ok_or_else(|| {
            ReconstructError::Model(format!(
                "model.checkpoint `{}`: expected a path, `random` or `random:SEED`",
                config.checkpoint
            ))
        })?;
        let mut renderer_type: Option<String> = None;
        let mut shape_head = false;
        let (vb, weights) = match source {
            WeightsSource::Embedded if cfg.preset == DEFAULT_PRESET => {
                let (default_cfg, vb) = default_var_builder(dtype, &device)
                    .map_err(|e| ReconstructError::Model(e.to_string()))?;
                cfg = default_cfg;
                (
                    vb,
                    format!(
                        "embedded default ({DEFAULT_CHECKPOINT_PATH}, trained on synthetic people)"
                    ),
                )
            }
            WeightsSource::Embedded => {
                tracing::warn!(
                    "preset `{}` has no trained default: using seeded random weights (seed \
                     {RANDOM_WEIGHTS_SEED}); set model.checkpoint to real weights",
                    cfg.preset
                );
                (
                    seeded_var_builder(RANDOM_WEIGHTS_SEED, dtype, &device),
                    format!("seeded random weights, seed {RANDOM_WEIGHTS_SEED} (no trained default for `{}`)", cfg.preset),
                )
            }
            WeightsSource::Random(seed) => (
                seeded_var_builder(seed, dtype, &device),
                format!("seeded random weights, seed {seed}"),
            ),
            WeightsSource::Path(path) => {
                let loaded = load_checkpoint(Path::new(&path), &cfg, dtype, &device)
                    .map_err(|e| ReconstructError::Model(e.to_string()))?;
                cfg = loaded.config;
                renderer_type = loaded.neural_renderer_type;
                shape_head = loaded.shape_head;
                (loaded.var_builder, loaded.description)
            }
        };
        let (rgb_kind, checkpoint_kind) = match &renderer_type {
            Some(kind) => (
                RgbKind::of_hub(kind, shape_head),
                match RgbKind::of_hub(kind, shape_head) {
                    RgbKind::Latent => format!(
                        "hub folder with neural_renderer.type `{kind}` (LHMPP-700M / \
                         LHMPPS-700M, Gaussian RGB never supervised against images)"
                    ),
                    RgbKind::DisplayReady if shape_head => format!(
                        "hub folder with neural_renderer.type `{kind}` and a shape_head \
                         (GS-supervised LHMPP-700M-PixelShuffle / -SMPLX-FREE)"
                    ),
                    RgbKind::DisplayReady => {
                        format!("hub folder with neural_renderer.type `{kind}`")
                    }
                },
            ),
            None => {
                let rgb = RgbKind::of_preset(&cfg.preset);
                let kind = match rgb {
                    RgbKind::Latent => format!(
                        "preset `{}` (the released LHMPP-700M layout, Gaussian RGB never \
                         supervised against images)",
                        cfg.preset
                    ),
                    RgbKind::DisplayReady => format!("preset `{}`", cfg.preset),
                };
                (rgb, kind)
            }
        };
        let model = Lhmpp::new(&cfg, vb)?;
        let base_template = match &prior {
            Some(_) => None,
            None => Some(BodyTemplate::load_default()?),
        };
        let (template, positions, normals, skin) = match &prior {
            Some(p) => (
                p.template.clone(),
                p.query_points.clone(),
                p.query_normals.clone(),
                p.skin.clone(),
            ),
            None => {
                let template = base_template.clone().unwrap_or_default();
                let anchors = template.sample_anchors(config.num_points, config.seed);
                (template, anchors.positions, anchors.normals, anchors.skin)
            }
        };
        let (anchor_positions, anchor_normals) =
            anchor_tensors(&positions, &normals, dtype, &device)?;
        Ok(Self {
            model,
            cfg,
            device,
            cache: ViewTokenCache::new(max_views + 4),
            template,
            skin,
            prior,
            anchor_positions,
            anchor_normals,
            weights,
            base_template,
            num_points: config.num_points,
            seed: config.seed,
            checkpoint: match config.checkpoint.as_str() {
                "" => "embedded".to_string(),
                other => other.to_string(),
            },
            shape: None,
            betas_noted: false,
            network_views: config.network_views(),
            predicted_shape: None,
            renderer_kind: renderer_type
                .clone()
                .unwrap_or_else(|| LATENT_RGB_RENDERER_TYPE.to_string()),
            rgb_kind,
            checkpoint_kind,
        })
    }

    /// What the predicted Gaussians' RGB is: display-ready colours, or the latent intermediate
    /// of the released LHMPP-700M / LHMPPS-700M checkpoints (preset `lhmpp-700m`, or a hub
    /// folder whose `neural_renderer.type` is `patch_4dptonly`), which only the neural
    /// renderer turns into images.
    pub fn rgb_kind(&self) -> RgbKind {
        self.rgb_kind
    }

    /// The checkpoint's kind in words (for logs and warnings), e.g. "preset `tiny`".
    pub fn checkpoint_kind(&self) -> &str {
        &self.checkpoint_kind
    }

    /// Feature channels of the predicted Gaussians (`gs_head.gs_query_dim`).
    pub fn feature_channels(&self) -> usize {
        self.cfg.gs_head.gs_query_dim
    }

    /// Channels of the background feature splatted behind the avatar
    /// (`renderer.background_embedding`: 128 for the official layout).
    pub fn background_channels(&self) -> usize {
        self.cfg.gs_head.background_width()
    }

    /// The neural renderer's config (`neural_renderer.*`).
    pub fn neural_renderer_config(&self) -> &DptConfig {
        &self.cfg.neural_renderer
    }

    /// A clone of the network's neural renderer (its tensors are shared, not copied), on the
    /// model's device.
    pub fn neural_renderer(&self) -> NeuralRenderer {
        self.model.neural_renderer().clone()
    }

    /// The background feature the official renderer splats behind a white background
    /// (`background_embedding[int(1.0 / 0.5)]`, index 2): `[gs_query_dim]`, model dtype and
    /// device.
    pub fn white_background_feature(&self) -> Result<Tensor, ReconstructError> {
        Ok(self.model.gs_head().background_feature(1.0)?)
    }

    /// The id a subscriber needs to render this network's avatars when their RGB is not
    /// display-ready: `<official neural_renderer.type>@<model.checkpoint>`; empty when the RGB
    /// is display-ready.
    pub fn neural_renderer_id(&self) -> String {
        match self.rgb_kind {
            RgbKind::DisplayReady => String::new(),
            RgbKind::Latent => format!("{}@{}", self.renderer_kind, self.checkpoint),
        }
    }

    /// Body-model id of the avatars this reconstructor makes (what a body shape must name).
    pub fn body_model(&self) -> &'static str {
        match self.prior {
            Some(_) => SMPLX_MODEL_ID,
            None => MAKEHUMAN_MODEL_ID,
        }
    }

    /// The shape in use: the shape topic's; else, for a network with a shape head (the
    /// GS-supervised LHMPP-700M-PixelShuffle / -SMPLX-FREE) on the SMPL-X prior, the betas it
    /// predicted at the last reconstruction (the official `use_pred_shape_for_render`); `None`:
    /// the template as shipped.
    pub fn shape(&self) -> Option<&AcceptedShape> {
        self.shape.as_ref().or(self.predicted_shape.as_ref())
    }

    /// The betas the network's shape head predicted at the last reconstruction (SMPL-X prior
    /// only; carried like the shape topic's betas, not applied to the prior body).
    pub fn predicted_betas(&self) -> Option<&[f32]> {
        match &self.predicted_shape {
            Some(AcceptedShape::SmplxBetas(b)) => Some(b),
            _ => None,
        }
    }

    /// Uses `shape` from the next reconstruction on: a MakeHuman shape rescales the template
    /// (as synthetic people are made) and resamples the anchors on it with the same seed;
    /// SMPL-X betas are only carried along (applying them to the prior is not implemented).
    /// Returns false when `shape` is already in use. `shape` must be for [`Self::body_model`].
    pub fn set_shape(&mut self, shape: AcceptedShape) -> Result<bool, ReconstructError> {
        if self.shape.as_ref() == Some(&shape) {
            return Ok(false);
        }
        match (&shape, &self.base_template) {
            (AcceptedShape::MakeHuman(s), Some(base)) => {
                let template = s.shaped(base);
                self.use_template(template)?;
            }
            (AcceptedShape::SmplxBetas(_), None) => {
                if !self.betas_noted {
                    self.betas_noted = true;
                    tracing::warn!(
                        "SMPL-X betas are carried in the avatar message but not applied to the \
                         body prior (the prior stays the neutral shape)"
                    );
                }
            }
            _ => {
                return Err(ReconstructError::Model(format!(
                    "a `{}` shape cannot be applied to a `{}` body",
                    shape.body_model(),
                    self.body_model()
                )))
            }
        }
        self.shape = Some(shape);
        Ok(true)
    }

    /// Uses `shape` from the next reconstruction on, or the template as shipped for `None`
    /// (one network serving several people switches between their shapes); returns whether
    /// anything changed.
    pub fn use_shape(&mut self, shape: Option<AcceptedShape>) -> Result<bool, ReconstructError> {
        match shape {
            Some(shape) => self.set_shape(shape),
            None if self.shape.is_none() => Ok(false),
            None => {
                if let Some(base) = self.base_template.clone() {
                    self.use_template(base)?;
                }
                self.shape = None;
                Ok(true)
            }
        }
    }

    /// Reconstructs on `template` from now on: the anchors resampled on it with the same seed.
    fn use_template(&mut self, template: BodyTemplate) -> Result<(), ReconstructError> {
        let anchors = template.sample_anchors(self.num_points, self.seed);
        let (p, n) = anchor_tensors(
            &anchors.positions,
            &anchors.normals,
            self.anchor_positions.dtype(),
            &self.device,
        )?;
        self.anchor_positions = p;
        self.anchor_normals = n;
        self.skin = anchors.skin;
        self.template = template;
        Ok(())
    }

    /// Anchor positions in the canonical frame (metres), as the network receives them.
    pub fn anchor_positions(&self) -> Result<Vec<Vec3>, ReconstructError> {
        let rows = self
            .anchor_positions
            .to_dtype(DType::F32)?
            .to_vec2::<f32>()?;
        Ok(rows.iter().map(|r| Vec3::new(r[0], r[1], r[2])).collect())
    }

    /// Encoder input size (height, width) that preprocessing must produce.
    pub fn input_size(&self) -> (u32, u32) {
        (self.cfg.image_height as u32, self.cfg.image_width as u32)
    }

    /// Where the weights came from (for logs).
    pub fn weights(&self) -> &str {
        &self.weights
    }

    /// The body template the avatars are bound to.
    pub fn template(&self) -> &BodyTemplate {
        &self.template
    }

    /// Views encoded so far (cache misses), for logs and tests of token reuse.
    pub fn encode_count(&self) -> usize {
        self.cache.encode_count()
    }

    fn image_tensor(&self, image: &Preprocessed) -> Result<Tensor, ReconstructError> {
        let t = Tensor::from_vec(
            image.chw.clone(),
            (3, image.height as usize, image.width as usize),
            &self.device,
        )?;
        Ok(t.to_dtype(self.anchor_positions.dtype())?)
    }

    /// Encodes a view once (cached by `frame_id`) and returns its embedding for the frame
    /// store: the mean image token, L2-normalised.
    pub fn encode(
        &mut self,
        frame_id: u64,
        image: &Preprocessed,
    ) -> Result<Vec<f32>, ReconstructError> {
        let t = self.image_tensor(image)?;
        let tokens = self.cache.get_or_encode(&self.model, frame_id, &t)?;
        let mean = tokens
            .patch_tokens
            .mean(0)?
            .to_dtype(DType::F32)?
            .to_vec1::<f32>()?;
        let norm = mean.iter().map(|v| v * v).sum::<f32>().sqrt().max(1e-12);
        Ok(mean.into_iter().map(|v| v / norm).collect())
    }

    /// Forgets a view that left the frame store.
    pub fn forget(&mut self, frame_id: u64) {
        self.cache.remove(frame_id);
    }

    /// Reconstructs the avatar from the given views (tokens reused from the cache; a view
    /// evicted from it is encoded again from its image).
    pub fn reconstruct(
        &mut self,
        views: &[(u64, &Preprocessed)],
    ) -> Result<Avatar, ReconstructError> {
        if views.is_empty() {
            return Err(ReconstructError::NoViews);
        }
        let mut tokens = Vec::with_capacity(views.len());
        for (id, image) in views {
            let t = self.image_tensor(image)?;
            tokens.push(self.cache.get_or_encode(&self.model, *id, &t)?);
        }
        if tokens.len() > self.network_views {
            // Each view described by its mean patch token.
            let descriptors = tokens
                .iter()
                .map(|t| {
                    t.patch_tokens
                        .to_dtype(DType::F32)?
                        .mean(0)?
                        .to_vec1::<f32>()
                })
                .collect::<candle_core::Result<Vec<_>>>()?;
            let keep = most_different(&descriptors, self.network_views);
            tracing::debug!(
                given = tokens.len(),
                read = keep.len(),
                "the network reads the most different views (model.max_views)"
            );
            tokens = keep.into_iter().map(|i| tokens[i].clone()).collect();
        }
        let (feat, betas) =
            self.model
                .fuse_with_betas(&self.anchor_positions, &self.anchor_normals, &tokens)?;
        if let (Some(betas), Some(_)) = (betas, &self.prior) {
            let betas = betas.flatten_all()?.to_vec1::<f32>()?;
            if self.predicted_shape.is_none() {
                tracing::info!(
                    "the network's shape head predicts the SMPL-X betas ({} values); they are \
                     carried in the avatar message unless inputs.shape_topic gives a shape",
                    betas.len()
                );
            }
            self.predicted_shape = Some(AcceptedShape::SmplxBetas(betas));
        }
        let out = self
            .model
            .gs_head()
            .forward(&feat, &self.anchor_positions)?;
        let a = out.to_cpu_arrays()?;
        let n = a.opacities.len();
        let v3 = |v: &[f32], i: usize| Vec3::new(v[3 * i], v[3 * i + 1], v[3 * i + 2]);
        let mut positions: Vec<Vec3> = (0..n).map(|i| v3(&a.positions, i)).collect();
        let mut scales: Vec<Vec3> = (0..n).map(|i| v3(&a.scales, i)).collect();
        let mut opacities = a.opacities;
        let mut rotations: Vec<Quat> = (0..n)
            .map(|i| {
                let r = &a.rotations[4 * i..4 * i + 4];
                Quat::from_xyzw(r[1], r[2], r[3], r[0]).normalize()
            })
            .collect();
        let skin = match &self.prior {
            Some(prior) => {
                apply_part_rules(prior, &mut scales, &mut opacities);
                // Predicted in the official neutral pose; avatars live in the rest pose.
                prior.all_to_rest(&mut positions, &mut rotations)
            }
            None => self.skin.clone(),
        };
        let colors: Vec<Vec3> = (0..n).map(|i| v3(&a.colors, i)).collect();
        let gaussians = Gaussians::from_rgb(positions, scales, rotations, opacities, &colors)?
            .with_features(a.feature_dim, a.features)?;
        let model_id = match self.prior {
            Some(_) => SMPLX_MODEL_ID,
            None => MAKEHUMAN_MODEL_ID,
        };
        Ok(Avatar::new(gaussians, skin, model_id)?)
    }
}

/// Anchor positions and normals as `(n, 3)` tensors of `dtype` on `device`.
fn anchor_tensors(
    positions: &[Vec3],
    normals: &[Vec3],
    dtype: DType,
    device: &Device,
) -> Result<(Tensor, Tensor), ReconstructError> {
    let flat = |v: &[Vec3]| v.iter().flat_map(|p| p.to_array()).collect::<Vec<f32>>();
    let n = positions.len();
    let p = Tensor::from_vec(flat(positions), (n, 3), device)?.to_dtype(dtype)?;
    let q = Tensor::from_vec(flat(normals), (n, 3), device)?.to_dtype(dtype)?;
    Ok((p, q))
}

/// The official LHMPP-Prior body when `model.prior_dir` is set (only for the official
/// network: preset `lhmpp-700m` or a hub-folder checkpoint), `num_points` of its points.
fn load_prior(
    config: &ModelConfig,
    official: bool,
    preset: &str,
) -> Result<Option<OfficialPrior>, ReconstructError> {
    if config.prior_dir.is_empty() {
        if official {
            tracing::warn!(
                "the official network was trained on the SMPL-X prior; set model.prior_dir to \
                 the LHMPP-Prior folder (using the MakeHuman body instead)"
            );
        }
        return Ok(None);
    }
    if !official {
        return Err(ReconstructError::Model(format!(
            "model.prior_dir is only used with the official network (preset lhmpp-700m or a \
             hub-folder checkpoint), not preset `{preset}`"
        )));
    }
    let mut paths = PriorPaths::in_dir(Path::new(&config.prior_dir));
    if !config.smplx_model.is_empty() {
        paths.smplx = config.smplx_model.clone().into();
    }
    let prior = OfficialPrior::load(&paths)?.subsample(config.num_points);
    tracing::info!(
        "body prior: {} ({} of its query points)",
        config.prior_dir,
        prior.len()
    );
    Ok(Some(prior))
}

/// Cosine similarity; zero vectors and length mismatches count as dissimilar (0).
pub fn cosine_similarity(a: &[f32], b: &[f32]) -> f32 {
    if a.len() != b.len() || a.is_empty() {
        return 0.0;
    }
    let (mut dot, mut na, mut nb) = (0.0f64, 0.0f64, 0.0f64);
    for (x, y) in a.iter().zip(b) {
        dot += f64::from(*x) * f64::from(*y);
        na += f64::from(*x) * f64::from(*x);
        nb += f64::from(*y) * f64::from(*y);
    }
    if na == 0.0 || nb == 0.0 {
        return 0.0;
    }
    (dot / (na.sqrt() * nb.sqrt())) as f32
}

/// The indices (ascending) of `k` of the views whose descriptors differ most: the first view,
/// then each time the view least similar (cosine) to its most similar chosen one.
pub fn most_different(descriptors: &[Vec<f32>], k: usize) -> Vec<usize> {
    let n = descriptors.len();
    if k >= n {
        return (0..n).collect();
    }
    let mut chosen = vec![0];
    // Each view's highest similarity to a chosen view.
    let mut nearest: Vec<f32> = descriptors
        .iter()
        .map(|d| cosine_similarity(d, &descriptors[0]))
        .collect();
    while chosen.len() < k.max(1) {
        let next = (0..n)
            .filter(|i| !chosen.contains(i))
            .min_by(|&a, &b| nearest[a].total_cmp(&nearest[b]))
            .expect("fewer chosen than views");
        chosen.push(next);
        for (i, d) in descriptors.iter().enumerate() {
            nearest[i] = nearest[i].max(cosine_similarity(d, &descriptors[next]));
        }
    }
    chosen.sort_unstable();
    chosen
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_network_reads_the_most_different_views() {
        // Views 0–2 nearly alike, 3 and 4 apart: two of five are the first and the one
        // furthest from it; three add the remaining outlier.
        let d = vec![
            vec![1.0, 0.0, 0.0],
            vec![0.99, 0.05, 0.0],
            vec![0.98, 0.0, 0.05],
            vec![0.0, 1.0, 0.0],
            vec![0.0, 0.0, 1.0],
        ];
        assert_eq!(super::most_different(&d, 2), vec![0, 3]);
        assert_eq!(super::most_different(&d, 3), vec![0, 3, 4]);
        assert_eq!(super::most_different(&d, 9), vec![0, 1, 2, 3, 4]);
    }
}
