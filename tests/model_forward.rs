//! Whole-network forward on the tiny preset: shapes, finiteness, determinism, incremental views.

use std::time::Instant;

use candle_core::{DType, Device, Tensor};
use lhmpp::model::cache::ViewTokenCache;
use lhmpp::model::checkpoint::seeded_var_builder;
use lhmpp::model::point::synthetic::body_surface_points;
use lhmpp::model::{GaussianOutput, Lhmpp, LhmppConfig};
use lhmpp::testing::max_abs_diff as max_diff;

fn points(n: usize) -> (Tensor, Tensor) {
    let (p, nrm) = body_surface_points(n, 7);
    let flat = |v: Vec<[f32; 3]>| {
        Tensor::from_vec(
            v.into_iter().flatten().collect::<Vec<f32>>(),
            (n, 3),
            &Device::Cpu,
        )
        .unwrap()
    };
    (flat(p), flat(nrm))
}

fn image(seed: f32) -> Tensor {
    // Deterministic smooth image in [0, 1].
    let (h, w) = (112, 112);
    let v: Vec<f32> = (0..3 * h * w)
        .map(|i| 0.5 + 0.5 * ((i as f32) * 0.013 + seed).sin())
        .collect();
    Tensor::from_vec(v, (3, h, w), &Device::Cpu).unwrap()
}

fn all_diff(a: &GaussianOutput, b: &GaussianOutput) -> f32 {
    [
        max_diff(&a.positions, &b.positions),
        max_diff(&a.scales, &b.scales),
        max_diff(&a.rotations, &b.rotations),
        max_diff(&a.opacities, &b.opacities),
        max_diff(&a.colors, &b.colors),
        max_diff(&a.features, &b.features),
    ]
    .into_iter()
    .fold(0.0, f32::max)
}

#[test]
fn tiny_forward_with_two_views_is_finite_shaped_and_deterministic() {
    let cfg = LhmppConfig::tiny();
    let model = Lhmpp::new(&cfg, seeded_var_builder(1, DType::F32, &Device::Cpu)).unwrap();
    let (anchors, normals) = points(4096);
    let start = Instant::now();
    let views: Vec<_> = [0.0, 1.0]
        .iter()
        .map(|&s| model.encode_view(&image(s)).unwrap())
        .collect();
    let a = model.reconstruct(&anchors, &normals, &views).unwrap();
    eprintln!(
        "tiny forward, 2 views, 4096 points: {:.0} ms",
        start.elapsed().as_secs_f64() * 1e3
    );
    let b = model.reconstruct(&anchors, &normals, &views).unwrap();
    assert_eq!(all_diff(&a, &b), 0.0, "two runs differ");
    let arr = a.to_cpu_arrays().unwrap();
    assert_eq!(arr.positions.len(), 4096 * 3);
    assert_eq!(arr.rotations.len(), 4096 * 4);
    assert_eq!(arr.opacities.len(), 4096);
    assert_eq!(arr.features.len(), 4096 * cfg.gs_head.gs_query_dim);
    let all = [
        &arr.positions,
        &arr.scales,
        &arr.rotations,
        &arr.opacities,
        &arr.colors,
        &arr.features,
    ];
    assert!(all.iter().all(|v| v.iter().all(|x| x.is_finite())));
    // The images matter: another second view changes the Gaussians.
    let other = vec![views[0].clone(), model.encode_view(&image(5.0)).unwrap()];
    let c = model.reconstruct(&anchors, &normals, &other).unwrap();
    assert!(max_diff(&a.features, &c.features) > 1e-6);
}

#[test]
fn incremental_view_update_equals_a_full_recompute() {
    let model = Lhmpp::new(
        &LhmppConfig::tiny(),
        seeded_var_builder(2, DType::F32, &Device::Cpu),
    )
    .unwrap();
    let (anchors, normals) = points(1024);
    let images: Vec<Tensor> = (0..3).map(|i| image(i as f32 * 2.0)).collect();
    let mut cache = ViewTokenCache::new(4);
    cache.get_or_encode(&model, 10, &images[0]).unwrap();
    cache.get_or_encode(&model, 11, &images[1]).unwrap();
    // A view arrives, one leaves.
    cache.get_or_encode(&model, 12, &images[2]).unwrap();
    cache.remove(10);
    assert_eq!(cache.encode_count(), 3);
    let inc = model
        .reconstruct(&anchors, &normals, &cache.views(&[11, 12]).unwrap())
        .unwrap();
    let fresh: Vec<_> = images[1..]
        .iter()
        .map(|i| model.encode_view(i).unwrap())
        .collect();
    let full = model.reconstruct(&anchors, &normals, &fresh).unwrap();
    assert!(all_diff(&inc, &full) < 1e-5);
}
