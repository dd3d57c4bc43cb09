//! Rasteriser behaviour: analytic single Gaussian, depth order, robustness to bad input,
//! background, features and determinism across thread counts.

use glam::{Affine3A, Quat, Vec3};
use lhmpp::splat::synthetic::body_cloud;
use lhmpp::splat::{render, Camera, Gaussians, Intrinsics, RenderOptions};

/// Camera at the origin looking along world +Z (optical frame = world frame).
fn axis_camera(size: u32, f: f32) -> Camera {
    let c = 0.5 * (size as f32 - 1.0);
    Camera::from_camera_info(
        [
            f as f64, 0.0, c as f64, 0.0, f as f64, c as f64, 0.0, 0.0, 1.0,
        ],
        size,
        size,
        Affine3A::IDENTITY,
    )
}

fn one(pos: Vec3, sigma: f32, opacity: f32, rgb: Vec3) -> Gaussians {
    Gaussians::from_rgb(
        vec![pos],
        vec![Vec3::splat(sigma)],
        vec![Quat::IDENTITY],
        vec![opacity],
        &[rgb],
    )
    .unwrap()
}

fn concat(a: &Gaussians, b: &Gaussians) -> Gaussians {
    let mut g = a.clone();
    g.positions.extend(&b.positions);
    g.scales.extend(&b.scales);
    g.rotations.extend(&b.rotations);
    g.opacities.extend(&b.opacities);
    g.sh.extend(&b.sh);
    g.features.extend(&b.features);
    g
}

#[test]
fn single_isotropic_gaussian_renders_the_analytic_2d_gaussian() {
    // 32×32 image, principal point at the shared corner of the 4 tiles, so all tiles are binned.
    let cam = axis_camera(32, 100.0);
    let (z, sigma, opacity) = (2.0, 0.08, 0.9);
    let out = render(
        &one(Vec3::new(0.0, 0.0, z), sigma, opacity, Vec3::ONE),
        &cam,
        &RenderOptions::default(),
    );
    // Projected variance (f σ / z)² plus the 0.3 px² low-pass.
    let var = (100.0 * sigma / z).powi(2) + 0.3;
    let mut max_err = 0.0f32;
    for v in 0..32 {
        for u in 0..32 {
            let (du, dv) = (u as f32 - 15.5, v as f32 - 15.5);
            let a = opacity * (-0.5 * (du * du + dv * dv) / var).exp();
            // 3DGS skips samples with alpha < 1/255.
            let expected = if a < 1.0 / 255.0 { 0.0 } else { a };
            let got = out.pixel(u, v);
            max_err = max_err.max((got - Vec3::splat(expected)).abs().max_element());
            max_err = max_err.max((out.alpha[(v * 32 + u) as usize] - expected).abs());
        }
    }
    assert!(max_err < 1e-3, "max error {max_err}");
    assert!(
        (out.depth[15 * 32 + 15] - z).abs() < 1e-5,
        "expected depth is the Gaussian's depth"
    );
}

#[test]
fn overlapping_gaussians_composite_in_depth_order_regardless_of_input_order() {
    let cam = axis_camera(32, 100.0);
    let red = one(Vec3::new(0.0, 0.0, 2.0), 0.1, 0.8, Vec3::X);
    let blue = one(Vec3::new(0.02, 0.0, 3.0), 0.15, 0.8, Vec3::Z);
    let opts = RenderOptions::default();
    let near_first = render(&concat(&red, &blue), &cam, &opts);
    let far_first = render(&concat(&blue, &red), &cam, &opts);
    assert_eq!(near_first.rgb, far_first.rgb);
    assert_eq!(near_first.depth, far_first.depth);
    // The centre pixel shows red over blue: red weight ≈ 0.8, blue ≈ 0.8 · 0.2 at most.
    let c = near_first.pixel(16, 16);
    assert!(c.x > 0.7 && c.z < 0.2 && c.z > 0.05, "{c}");
    let d = near_first.depth[16 * 32 + 16];
    assert!(
        d > 2.0 && d < 2.5,
        "expected depth weighted towards the near Gaussian: {d}"
    );
}

#[test]
fn bad_gaussians_never_produce_nan_and_behind_camera_ones_are_invisible() {
    let cam = axis_camera(48, 60.0);
    let good = one(Vec3::new(0.0, 0.0, 2.0), 0.05, 0.9, Vec3::ONE);
    let bad = [
        one(Vec3::new(0.0, 0.0, -2.0), 0.5, 1.0, Vec3::ONE), // behind the camera
        one(Vec3::new(0.0, 0.0, 0.0), 0.5, 1.0, Vec3::ONE),  // at the camera centre
        one(Vec3::new(f32::NAN, 0.0, 2.0), 0.1, 1.0, Vec3::ONE), // NaN position
        one(Vec3::new(0.0, 0.0, 2.0), f32::NAN, 1.0, Vec3::ONE), // NaN scale
        one(Vec3::new(0.0, 0.0, 2.0), 0.1, f32::NAN, Vec3::ONE), // NaN opacity
        one(Vec3::new(0.0, 0.0, 2.0), 1e30, 1.0, Vec3::ONE), // overflowing scale
        one(Vec3::new(0.1, 0.0, 2.0), 1e4, 0.5, Vec3::ONE),  // huge but finite
        one(Vec3::new(0.0, 0.0, 2.0), 0.0, 1.0, Vec3::ONE),  // zero scale
        one(Vec3::new(0.0, 0.0, 2.0), f32::INFINITY, 1.0, Vec3::ONE),
        one(Vec3::new(1e30, 0.0, 2.0), 0.1, 1.0, Vec3::ONE), // far off screen
        one(Vec3::new(0.0, 0.0, 1e-9), 0.1, 1.0, Vec3::ONE), // on the near plane
    ];
    let mut all = good.clone();
    for b in &bad {
        all = concat(&all, b);
    }
    all.rotations.push(Quat::from_xyzw(0.0, 0.0, 0.0, 0.0));
    all.positions.push(Vec3::new(0.0, 0.0, 2.0));
    all.scales.push(Vec3::splat(0.1));
    all.opacities.push(1.0);
    all.sh.push([f32::NAN; 3]);
    let out = render(&all, &cam, &RenderOptions::default());
    for map in [&out.rgb, &out.alpha, &out.depth] {
        assert!(
            map.iter().all(|v| v.is_finite()),
            "non-finite value in output"
        );
    }
    let behind = render(&bad[0], &cam, &RenderOptions::default());
    assert!(behind.rgb.iter().all(|v| *v == 0.0) && behind.alpha.iter().all(|v| *v == 0.0));
}

#[test]
fn empty_set_renders_the_background_exactly() {
    let cam = axis_camera(40, 50.0);
    let opts = RenderOptions {
        background: Vec3::new(0.25, 0.5, 0.75),
        render_features: true,
        background_features: vec![3.0, -1.0],
        ..RenderOptions::default()
    };
    let empty = Gaussians::default().with_features(2, vec![]).unwrap();
    let out = render(&empty, &cam, &opts);
    assert_eq!(out.rgb.len(), 40 * 40 * 3);
    assert!(out.rgb.chunks(3).all(|p| p == [0.25, 0.5, 0.75]));
    assert!(out.alpha.iter().all(|a| *a == 0.0) && out.depth.iter().all(|d| *d == 0.0));
    assert!(out.features.chunks(2).all(|p| p == [3.0, -1.0]));
}

#[test]
fn feature_rendering_equals_the_rgb_blend_when_features_are_the_colours() {
    let mut g = body_cloud(3000, 0, 11);
    let colours: Vec<f32> =
        g.sh.iter()
            .flat_map(|dc| lhmpp::splat::sh_dc_to_rgb(*dc).max(Vec3::ZERO).to_array())
            .collect();
    g = g.with_features(3, colours).unwrap();
    let cam = Camera::look_at(
        Vec3::new(0.3, 1.0, 2.5),
        Vec3::new(0.0, 0.9, 0.0),
        Vec3::Y,
        Intrinsics::from_fov_y(96, 128, 0.9),
    );
    let bg = Vec3::new(0.1, 0.2, 0.3);
    let opts = RenderOptions {
        background: bg,
        render_features: true,
        background_features: bg.to_array().to_vec(),
        ..Default::default()
    };
    let out = render(&g, &cam, &opts);
    assert!(out.alpha.iter().any(|a| *a > 0.5), "the body is in view");
    let max = out
        .rgb
        .iter()
        .zip(&out.features)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(max < 1e-6, "feature map differs from RGB by {max}");
}

#[test]
fn render_is_bit_identical_on_one_and_two_threads() {
    let g = body_cloud(20_000, 4, 5);
    let cam = Camera::orbit(
        1,
        8,
        2.5,
        0.2,
        Vec3::new(0.0, 0.9, 0.0),
        Intrinsics::from_fov_y(150, 200, 0.9),
    );
    let opts = RenderOptions {
        render_features: true,
        ..Default::default()
    };
    let run = |threads| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| render(&g, &cam, &opts))
    };
    let (a, b) = (run(1), run(2));
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert!(a.alpha.iter().any(|x| *x > 0.5));
    assert_eq!(bits(&a.rgb), bits(&b.rgb));
    assert_eq!(bits(&a.alpha), bits(&b.alpha));
    assert_eq!(bits(&a.depth), bits(&b.depth));
    assert_eq!(bits(&a.features), bits(&b.features));
}
