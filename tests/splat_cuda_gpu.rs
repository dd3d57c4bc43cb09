//! The CUDA rasteriser on a real GPU (only with `--features cuda`; needs CUDA device 0): its
//! images agree with the CPU rasteriser within 2e-3, its maps stay on the GPU as
//! tensors of the right shapes, and a bad scene tensor is refused with its name.
#![cfg(feature = "cuda")]

mod splat_cuda_support;

use candle_core::{Device, Tensor};
use glam::Vec3;
use lhmpp::splat::cuda::{CudaRasterizer, CudaRenderError, CudaScene};
use lhmpp::splat::synthetic::body_cloud;
use lhmpp::splat::{render_timed, RenderOptions};
use splat_cuda_support::{camera, max_abs_diff};

fn gpu() -> Device {
    Device::new_cuda(0).expect("these tests need CUDA device 0")
}

#[test]
fn gpu_image_agrees_with_the_cpu_rasteriser() {
    let device = gpu();
    let mut rasterizer = CudaRasterizer::new(&device).unwrap();
    let g = body_cloud(40_000, 8, 3);
    let options = RenderOptions {
        background: Vec3::new(0.2, 0.3, 0.9),
        render_features: true,
        background_features: vec![0.5; 8],
        ..RenderOptions::default()
    };
    for (w, h) in [(200, 150), (592, 592)] {
        let cam = camera(w, h);
        let (cpu, times) = render_timed(&g, &cam, &options);
        let scene = CudaScene::from_gaussians(&g, &device).unwrap();
        let frame = rasterizer.render(&scene, &cam, &options).unwrap();
        assert_eq!(frame.visible, times.visible);
        assert_eq!(frame.tile_pairs, times.tile_pairs);
        assert_eq!(frame.rgb.dims(), [h as usize, w as usize, 3]);
        assert!(frame.rgb.device().is_cuda());
        let out = frame.to_render_output().unwrap();
        for (name, a, b) in [
            ("rgb", &cpu.rgb, &out.rgb),
            ("alpha", &cpu.alpha, &out.alpha),
            ("features", &cpu.features, &out.features),
        ] {
            let d = max_abs_diff(a, b);
            assert!(d < 2e-3, "{w}×{h}: {name} differs by {d}");
        }
    }
}

#[test]
fn scene_tensors_of_the_wrong_shape_are_refused_by_name() {
    let device = gpu();
    let t = |shape: &[usize]| Tensor::zeros(shape, candle_core::DType::F32, &device).unwrap();
    let err = CudaScene::from_tensors(
        t(&[10, 3]),
        t(&[10, 3]),
        t(&[10, 3]), // rotations need 4 columns
        t(&[10]),
        t(&[10, 1, 3]),
        0,
        None,
    )
    .unwrap_err();
    assert!(
        matches!(
            err,
            CudaRenderError::Tensor {
                name: "rotations",
                ..
            }
        ),
        "{err}"
    );
}
