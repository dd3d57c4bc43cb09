//! The tiled, SIMD rasteriser against a brute-force per-pixel reference, across instruction
//! sets and with reused buffers.

use super::bin::TileGrid;
use super::project::{project, MIN_ALPHA};
use super::*;
use crate::splat::synthetic::body_cloud;
use crate::splat::Intrinsics;
use crate::testing::max_abs_diff as max_diff;

/// 3DGS compositing evaluated pixel by pixel over every visible splat in depth order (no
/// tiles lists, no SIMD, `f32::exp`); a splat reaches the pixels of the tiles its 3σ square
/// touches, as in 3DGS.
fn reference(g: &Gaussians, camera: &Camera, options: &RenderOptions) -> RenderOutput {
    let mut projected = Vec::new();
    project(g, camera, options, &mut projected);
    let mut splats: Vec<_> = projected.iter().flatten().collect();
    splats.sort_by(|a, b| a.depth.total_cmp(&b.depth).then(a.index.cmp(&b.index)));
    let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
    let grid = TileGrid::new(w, h);
    let c = g.feature_channels;
    let mut out = RenderOutput {
        width: w,
        height: h,
        feature_channels: c,
        ..Default::default()
    };
    for v in 0..h as usize {
        for u in 0..w as usize {
            let (mut t, mut rgb, mut depth) = (1.0f32, Vec3::ZERO, 0.0f32);
            let mut feats = vec![0.0f32; c];
            for s in &splats {
                let r = grid.rect(s);
                let (tx, ty) = ((u / TILE) as u16, (v / TILE) as u16);
                if tx < r.x0 || tx >= r.x1 || ty < r.y0 || ty >= r.y1 {
                    continue;
                }
                let (dx, dy) = (s.mean[0] - u as f32, s.mean[1] - v as f32);
                let [a, b, cc] = s.conic;
                let power = -0.5 * (a * dx * dx + cc * dy * dy) - b * dx * dy;
                if power > 0.0 {
                    continue;
                }
                let alpha = (s.opacity * power.exp()).min(0.99);
                if alpha < MIN_ALPHA {
                    continue;
                }
                let next = t * (1.0 - alpha);
                if next < 1e-4 {
                    break;
                }
                let wgt = alpha * t;
                rgb += Vec3::from_array(s.rgb) * wgt;
                depth += s.depth * wgt;
                for (f, v) in feats.iter_mut().zip(g.features_of(s.index as usize)) {
                    *f += v * wgt;
                }
                t = next;
            }
            let colour = rgb + options.background * t;
            out.rgb.extend(colour.to_array());
            out.alpha.push(1.0 - t);
            out.depth
                .push(if t < 1.0 { depth / (1.0 - t) } else { 0.0 });
            for (k, f) in feats.iter().enumerate() {
                out.features
                    .push(f + t * options.background_features.get(k).copied().unwrap_or(0.0));
            }
        }
    }
    out
}

fn scene() -> (Gaussians, Camera, RenderOptions) {
    let g = body_cloud(4000, 2, 9);
    // 100×70: partial tiles on the right and bottom edges.
    let cam = Camera::orbit(
        2,
        8,
        2.2,
        0.1,
        Vec3::new(0.0, 0.9, 0.0),
        Intrinsics::from_fov_y(100, 70, 0.9),
    );
    let opts = RenderOptions {
        background: Vec3::new(0.2, 0.4, 0.6),
        render_features: true,
        background_features: vec![1.0, -1.0],
        ..Default::default()
    };
    (g, cam, opts)
}

#[test]
fn tiled_simd_render_matches_a_per_pixel_reference() {
    let (g, cam, opts) = scene();
    let fast = render(&g, &cam, &opts);
    let slow = reference(&g, &cam, &opts);
    assert!(
        fast.alpha.iter().filter(|a| **a > 0.9).count() > 200,
        "opaque body in view"
    );
    for (name, a, b, tol) in [
        ("rgb", &fast.rgb, &slow.rgb, 1e-4),
        ("alpha", &fast.alpha, &slow.alpha, 1e-4),
        ("features", &fast.features, &slow.features, 1e-4),
        ("depth", &fast.depth, &slow.depth, 1e-3),
    ] {
        let d = max_diff(a, b);
        assert!(d < tol, "{name} differs from the reference by {d}");
    }
}

#[test]
fn simd_and_portable_blends_agree_bit_for_bit() {
    let (g, cam, opts) = scene();
    let mut simd = Rasterizer::new();
    let mut portable = Rasterizer {
        portable: true,
        ..Default::default()
    };
    let (mut a, mut b) = (RenderOutput::default(), RenderOutput::default());
    simd.render_into(&g, &cam, &opts, &mut a);
    portable.render_into(&g, &cam, &opts, &mut b);
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&a.rgb), bits(&b.rgb));
    assert_eq!(bits(&a.alpha), bits(&b.alpha));
    assert_eq!(bits(&a.depth), bits(&b.depth));
    assert_eq!(bits(&a.features), bits(&b.features));
}

#[test]
fn a_reused_rasterizer_and_frame_render_like_fresh_ones() {
    let (g, cam, opts) = scene();
    let small = body_cloud(500, 0, 4);
    let small_cam = Camera::orbit(
        0,
        4,
        2.5,
        0.0,
        Vec3::new(0.0, 0.9, 0.0),
        Intrinsics::from_fov_y(48, 64, 0.9),
    );
    let mut rasterizer = Rasterizer::new();
    let mut frame = RenderOutput::default();
    // Big frame with features, then a small one without, then the big one again.
    rasterizer.render_into(&g, &cam, &opts, &mut frame);
    rasterizer.render_into(&small, &small_cam, &RenderOptions::default(), &mut frame);
    assert_eq!(frame, render(&small, &small_cam, &RenderOptions::default()));
    rasterizer.render_into(&g, &cam, &opts, &mut frame);
    assert_eq!(frame, render(&g, &cam, &opts));
}
