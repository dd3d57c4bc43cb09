//! The backward pass against central finite differences of the forward renderer.

use super::*;
use crate::splat::{rgb_to_sh_dc, Intrinsics, SH_C0};
use glam::{Quat, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A few large, overlapping, rotated, half-transparent Gaussians about 2 m in front of a small
/// camera, centred near its axis: their α = 1/255 edges (steps the derivative does not see)
/// lie outside the disc [`Loss`] weighs, so finite differences see a smooth function.
pub(crate) fn scene(seed: u64) -> (Gaussians, Camera) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n = 8;
    let mut positions = Vec::new();
    let mut scales = Vec::new();
    let mut rotations = Vec::new();
    let mut opacities = Vec::new();
    let mut colours = Vec::new();
    for _ in 0..n {
        positions.push(Vec3::new(
            rng.gen_range(-0.08..0.08),
            rng.gen_range(-0.08..0.08),
            rng.gen_range(-0.15..0.15),
        ));
        scales.push(Vec3::new(
            rng.gen_range(0.18..0.35),
            rng.gen_range(0.18..0.35),
            rng.gen_range(0.18..0.35),
        ));
        let axis = Vec3::new(
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
        )
        .normalize();
        // Not unit: the renderer normalises.
        rotations.push(Quat::from_axis_angle(axis, rng.gen_range(0.0..3.0)) * 1.3);
        opacities.push(rng.gen_range(0.2..0.5));
        colours.push(Vec3::new(
            rng.gen_range(0.1..0.9),
            rng.gen_range(0.1..0.9),
            rng.gen_range(0.1..0.9),
        ));
    }
    let g = Gaussians::from_rgb(positions, scales, rotations, opacities, &colours).unwrap();
    let eye = Vec3::new(0.6, 0.4, 1.9);
    let camera = Camera::look_at(
        eye,
        Vec3::ZERO,
        Vec3::Y,
        Intrinsics::from_fov_y(48, 48, 0.45),
    );
    (g, camera)
}

/// Radius (pixels) of the disc about the image centre that the loss weighs.
const DISC: f32 = 12.0;

/// `L = Σ wᵣ · rgb + Σ wₐ · alpha` with fixed random weights inside the disc (0 outside),
/// summed in f64.
pub(crate) struct Loss {
    pub(crate) rgb: Vec<f32>,
    pub(crate) alpha: Vec<f32>,
}

impl Loss {
    pub(crate) fn new(camera: &Camera, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let k = camera.intrinsics;
        let inside: Vec<bool> = (0..k.height)
            .flat_map(|y| (0..k.width).map(move |x| (x, y)))
            .map(|(x, y)| {
                let (dx, dy) = (x as f32 - k.cx, y as f32 - k.cy);
                dx * dx + dy * dy <= DISC * DISC
            })
            .collect();
        let mut weight = |inside: bool| {
            let w: f32 = rng.gen_range(-1.0..1.0);
            if inside {
                w
            } else {
                0.0
            }
        };
        Self {
            rgb: inside
                .iter()
                .flat_map(|&i| [i; 3])
                .map(&mut weight)
                .collect(),
            alpha: inside.iter().map(|&i| weight(i)).collect(),
        }
    }

    pub(crate) fn value(&self, g: &Gaussians, camera: &Camera, options: &RenderOptions) -> f64 {
        let out = crate::splat::render(g, camera, options);
        let a: f64 = out
            .rgb
            .iter()
            .zip(&self.rgb)
            .map(|(v, w)| (v * w) as f64)
            .sum();
        let b: f64 = out
            .alpha
            .iter()
            .zip(&self.alpha)
            .map(|(v, w)| (v * w) as f64)
            .sum();
        a + b
    }
}

pub(crate) fn options() -> RenderOptions {
    RenderOptions {
        background: Vec3::new(0.2, 0.5, 0.9),
        ..RenderOptions::default()
    }
}

pub(crate) fn analytic(g: &Gaussians, camera: &Camera, loss: &Loss) -> GaussianGrads {
    let mut rasterizer = Rasterizer::new();
    let mut out = RenderOutput::default();
    forward(&mut rasterizer, g, camera, &options(), &mut out);
    let frame = FrameGrads {
        rgb: &loss.rgb,
        alpha: &loss.alpha,
    };
    backward(&rasterizer, g, camera, &options(), frame).unwrap()
}

/// Central difference of the loss along one parameter that `set` moves by `h`.
fn central(
    g: &Gaussians,
    camera: &Camera,
    loss: &Loss,
    h: f32,
    set: impl Fn(&mut Gaussians, f32),
) -> f64 {
    let mut plus = g.clone();
    set(&mut plus, h);
    let mut minus = g.clone();
    set(&mut minus, -h);
    (loss.value(&plus, camera, &options()) - loss.value(&minus, camera, &options()))
        / (2.0 * h as f64)
}

/// Compares analytic and numeric derivatives; returns the failures.
pub(crate) fn check(name: &str, pairs: &[(f64, f64)], rel: f64) -> Vec<String> {
    let scale = pairs
        .iter()
        .map(|(a, n)| a.abs().max(n.abs()))
        .fold(0.0f64, f64::max);
    pairs
        .iter()
        .enumerate()
        .filter(|(_, (a, n))| (a - n).abs() > rel * a.abs().max(n.abs()) + 2e-3 * scale)
        .map(|(k, (a, n))| format!("{name}[{k}]: analytic {a:.5} numeric {n:.5}"))
        .collect()
}

#[test]
fn every_gradient_matches_finite_differences() {
    for seed in [1, 2, 3] {
        let (g, camera) = scene(seed);
        let loss = Loss::new(&camera, seed + 100);
        let grads = analytic(&g, &camera, &loss);
        let mut fails = Vec::new();
        let mut pairs = |name: &str,
                         analytic: &dyn Fn(usize, usize) -> f32,
                         dims: usize,
                         h: f32,
                         set: &dyn Fn(&mut Gaussians, usize, usize, f32)| {
            let mut p = Vec::new();
            for i in 0..g.len() {
                for d in 0..dims {
                    let n = central(&g, &camera, &loss, h, |x, h| set(x, i, d, h));
                    p.push((analytic(i, d) as f64, n));
                }
            }
            fails.extend(check(name, &p, 0.01));
        };
        pairs(
            "position",
            &|i, d| grads.positions[i][d],
            3,
            1e-3,
            &|x, i, d, h| x.positions[i][d] += h,
        );
        pairs(
            "scale",
            &|i, d| grads.scales[i][d],
            3,
            3e-3,
            &|x, i, d, h| x.scales[i][d] += h,
        );
        pairs(
            "rotation",
            &|i, d| grads.rotations[i][d],
            4,
            3e-3,
            &|x, i, d, h| {
                let mut v = glam::Vec4::from(x.rotations[i]);
                v[d] += h;
                x.rotations[i] = Quat::from_vec4(v);
            },
        );
        pairs(
            "opacity",
            &|i, _| grads.opacities[i],
            1,
            3e-3,
            &|x, i, _, h| x.opacities[i] += h,
        );
        pairs(
            "colour",
            &|i, d| grads.colours[i][d],
            3,
            1e-3,
            &|x, i, d, h| x.sh[i][d] += h / SH_C0,
        );
        assert!(fails.is_empty(), "seed {seed}:\n{}", fails.join("\n"));
    }
}

#[test]
fn the_forward_is_the_renderer_everyone_uses() {
    let (g, camera) = scene(4);
    let mut rasterizer = Rasterizer::new();
    let mut out = RenderOutput::default();
    forward(&mut rasterizer, &g, &camera, &options(), &mut out);
    assert_eq!(out, crate::splat::render(&g, &camera, &options()));
    assert!(out.alpha.iter().any(|a| *a > 0.5), "the scene is in view");
}

#[test]
fn a_stale_forward_or_wrong_frame_size_is_refused() {
    let (g, camera) = scene(5);
    let mut rasterizer = Rasterizer::new();
    let mut out = RenderOutput::default();
    forward(&mut rasterizer, &g, &camera, &options(), &mut out);
    let px = out.alpha.len();
    let rgb = vec![0.0; 3 * px];
    let alpha = vec![0.0; px];
    let short = FrameGrads {
        rgb: &rgb[1..],
        alpha: &alpha,
    };
    assert!(matches!(
        backward(&rasterizer, &g, &camera, &options(), short),
        Err(GradError::FrameSize { .. })
    ));
    let mut more = g.clone();
    more.positions.push(Vec3::ZERO);
    more.scales.push(Vec3::ONE);
    more.rotations.push(Quat::IDENTITY);
    more.opacities.push(1.0);
    more.sh.push(rgb_to_sh_dc(Vec3::ONE));
    let frame = FrameGrads {
        rgb: &rgb,
        alpha: &alpha,
    };
    assert!(matches!(
        backward(&rasterizer, &more, &camera, &options(), frame),
        Err(GradError::StaleForward { .. })
    ));
}
