//! The CUDA rasteriser's source (`src/splat/cuda/rasterize.cu`, kernels and host code) built
//! for the CPU against its CUDA emulation (`emulate.h`) and run on scenes that exercise every
//! stage: culling rules, SH degree 3, features in two channel chunks, several radix-sort blocks
//! and scan levels, tiles
//! with more than one 256-splat batch, early termination, partial edge tiles, an empty scene.
//! Each image must agree with the Rust CPU rasteriser within 5e-4 (the GPU build: 2e-3),
//! with the same visible count and the same number of (tile, Gaussian) pairs. This checks the
//! kernels' logic without a GPU; `lhmpp bench render --device cuda` checks the GPU build.

mod splat_cuda_support;

use glam::{Affine3A, Quat, Vec3};
use lhmpp::splat::cuda::{FlatScene, SplatParams};
use lhmpp::splat::synthetic::body_cloud;
use lhmpp::splat::{render_timed, Camera, Gaussians, RenderOptions, RenderOutput};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use splat_cuda_support::{camera, max_abs_diff};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

/// Agreement bound of the emulation: 4× below the 2e-3 required of the GPU build,
/// since on the CPU neither side fuses multiply-adds (measured: 8e-5 at most, 2e-7 typical).
const TOLERANCE: f32 = 5e-4;

/// Builds the emulated rasteriser once per test run.
fn emulator() -> &'static Path {
    static BINARY: OnceLock<PathBuf> = OnceLock::new();
    BINARY.get_or_init(|| {
        let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/splat/cuda");
        let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join("splat-cuda-emulation");
        let compiler = std::env::var("CXX").unwrap_or_else(|_| "c++".into());
        let status = Command::new(&compiler)
            .args([
                "-std=c++20",
                "-O2",
                "-pthread",
                "-Wall",
                "-Wextra",
                "-Werror",
                "-x",
                "c++",
            ])
            .arg(src.join("rasterize.cu"))
            .args(["-x", "none"])
            .arg(src.join("emulate_main.cpp"))
            .arg("-o")
            .arg(&out)
            .status()
            .unwrap_or_else(|e| panic!("cannot run the C++ compiler `{compiler}`: {e}"));
        assert!(status.success(), "building the CUDA emulation failed");
        out
    })
}

fn floats(bytes: &mut Vec<u8>, values: &[f32]) {
    bytes.extend(values.iter().flat_map(|v| v.to_le_bytes()));
}

/// Renders through the emulated CUDA rasteriser: (image, visible, tile pairs).
fn render_emulated(
    gaussians: &Gaussians,
    camera: &Camera,
    options: &RenderOptions,
    name: &str,
) -> (RenderOutput, usize, usize) {
    let params = SplatParams::new(gaussians, camera, options);
    let flat = FlatScene::new(gaussians, options);
    let mut bytes = b"LHSPLAT1".to_vec();
    bytes.extend((std::mem::size_of::<SplatParams>() as u32).to_le_bytes());
    bytes.extend(bytemuck::bytes_of(&params));
    for array in [
        &flat.positions,
        &flat.scales,
        &flat.rotations,
        &flat.opacities,
        &flat.sh,
        &flat.features,
        &flat.background_features,
    ] {
        floats(&mut bytes, array);
    }
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"));
    let (scene_path, out_path) = (
        dir.join(format!("emu-{name}.scene")),
        dir.join(format!("emu-{name}.out")),
    );
    std::fs::write(&scene_path, bytes).unwrap();
    let run = Command::new(emulator())
        .arg(&scene_path)
        .arg(&out_path)
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "emulated render of {name} failed: {}",
        String::from_utf8_lossy(&run.stderr)
    );
    let raw = std::fs::read(&out_path).unwrap();
    let word = |i: usize| u32::from_le_bytes(raw[4 * i..4 * i + 4].try_into().unwrap());
    let values: Vec<f32> = raw[8..]
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
        .collect();
    let pixels = (params.width * params.height) as usize;
    let channels = params.channels as usize;
    assert_eq!(
        values.len(),
        pixels * (5 + channels),
        "output size of {name}"
    );
    let (rgb, rest) = values.split_at(pixels * 3);
    let (alpha, rest) = rest.split_at(pixels);
    let (depth, features) = rest.split_at(pixels);
    let out = RenderOutput {
        width: params.width as u32,
        height: params.height as u32,
        rgb: rgb.to_vec(),
        alpha: alpha.to_vec(),
        depth: depth.to_vec(),
        feature_channels: channels,
        features: features.to_vec(),
    };
    (out, word(0) as usize, word(1) as usize)
}

/// Renders `gaussians` both ways and asserts the agreement; returns the CPU image.
fn assert_agrees(
    gaussians: &Gaussians,
    camera: &Camera,
    options: &RenderOptions,
    name: &str,
) -> RenderOutput {
    let (cpu, times) = render_timed(gaussians, camera, options);
    let (emu, visible, pairs) = render_emulated(gaussians, camera, options, name);
    assert_eq!(visible, times.visible, "{name}: visible Gaussians");
    assert_eq!(pairs, times.tile_pairs, "{name}: (tile, Gaussian) pairs");
    for (map, a, b) in [
        ("rgb", &cpu.rgb, &emu.rgb),
        ("alpha", &cpu.alpha, &emu.alpha),
        ("depth", &cpu.depth, &emu.depth),
        ("features", &cpu.features, &emu.features),
    ] {
        let d = max_abs_diff(a, b);
        assert!(d < TOLERANCE, "{name}: {map} differs by {d}");
    }
    cpu
}

/// `body_cloud` with view-dependent colour: SH degree 3, the DC term kept, 15 random terms.
fn with_sh3(mut g: Gaussians, seed: u64) -> Gaussians {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let dc = std::mem::take(&mut g.sh);
    for c in dc {
        g.sh.push(c);
        for _ in 0..15 {
            g.sh.push(std::array::from_fn(|_| rng.gen_range(-0.3..0.3)));
        }
    }
    g.sh_degree = 3;
    g
}

#[test]
fn body_with_sh3_and_features_agrees_with_the_cpu_rasteriser() {
    // 6,000 Gaussians: several radix-sort blocks for the depth order, a two-level scan, hundreds
    // of splats per tile (several 256-splat batches) and opaque pixels that stop early.
    // 37 feature channels: one full 32-channel blend launch and a partial one.
    let g = with_sh3(body_cloud(6000, 37, 11), 12);
    let options = RenderOptions {
        background: Vec3::new(0.2, 0.3, 0.9),
        render_features: true,
        background_features: (0..37).map(|k| 0.1 * k as f32 - 1.0).collect(),
        ..RenderOptions::default()
    };
    // 90 × 75: partial tiles on the right and bottom edges.
    let out = assert_agrees(&g, &camera(90, 75), &options, "body");
    let covered = out.alpha.iter().filter(|&&a| a > 0.5).count();
    assert!(
        covered > 500,
        "the body covers the image ({covered} pixels)"
    );
    assert!(
        out.alpha.iter().any(|&a| a > 0.999),
        "some pixels are opaque"
    );
}

#[test]
fn culled_and_degenerate_gaussians_are_skipped_the_same_way() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut g = body_cloud(400, 0, 3);
    let mut push = |pos: Vec3, scale: Vec3, rot: Quat, opacity: f32| {
        g.positions.push(pos);
        g.scales.push(scale);
        g.rotations.push(rot);
        g.opacities.push(opacity);
        g.sh.push([rng.gen_range(-1.0..1.0), 0.2, -0.4]);
    };
    let cam_pos = Vec3::new(0.4, 1.1, 2.6);
    push(
        cam_pos + Vec3::new(0.0, 0.0, 1.0),
        Vec3::splat(0.1),
        Quat::IDENTITY,
        0.9,
    ); // behind
    push(
        Vec3::new(0.0, 1.0, 0.0),
        Vec3::splat(0.05),
        Quat::IDENTITY,
        f32::NAN,
    );
    push(
        Vec3::new(0.0, 1.0, 0.0),
        Vec3::splat(0.05),
        Quat::IDENTITY,
        0.001,
    ); // < 1/255
    push(
        Vec3::new(0.0, 1.0, 0.0),
        Vec3::splat(0.05),
        Quat::from_xyzw(0.0, 0.0, 0.0, 0.0),
        0.8,
    );
    push(
        Vec3::new(f32::INFINITY, 1.0, 0.0),
        Vec3::splat(0.05),
        Quat::IDENTITY,
        0.8,
    );
    push(
        Vec3::new(0.0, 1.0, 0.0),
        Vec3::new(0.05, f32::NAN, 0.05),
        Quat::IDENTITY,
        0.8,
    );
    push(
        Vec3::new(30.0, 1.0, 0.0),
        Vec3::splat(0.05),
        Quat::IDENTITY,
        0.8,
    ); // off screen
    push(
        Vec3::new(0.0, 1.0, 0.0),
        Vec3::splat(0.0),
        Quat::IDENTITY,
        0.8,
    ); // point: low-pass only
    push(
        Vec3::new(0.1, 0.9, 0.5),
        Vec3::new(2.0, 0.01, 0.3),
        Quat::from_rotation_z(0.7),
        0.6,
    ); // huge, thin
    push(
        Vec3::new(0.0, 0.8, 0.2),
        Vec3::splat(1.5),
        Quat::IDENTITY,
        0.3,
    ); // covers all tiles
    push(
        Vec3::new(0.0, 1.0, 0.0),
        Vec3::splat(0.05),
        Quat::from_xyzw(0.0, 0.0, 3.0, 4.0),
        1.7,
    ); // unnormalised, opacity > 1
    assert_agrees(&g, &camera(64, 48), &RenderOptions::default(), "culling");
}

#[test]
fn an_empty_scene_and_an_all_culled_scene_render_the_background() {
    let options = RenderOptions {
        background: Vec3::new(0.1, 0.6, 0.3),
        ..RenderOptions::default()
    };
    let empty = Gaussians::from_rgb(vec![], vec![], vec![], vec![], &[]).unwrap();
    let out = assert_agrees(&empty, &camera(40, 24), &options, "empty");
    assert!(out.alpha.iter().all(|&a| a == 0.0));
    let behind = Gaussians::from_rgb(
        vec![Vec3::new(0.4, 1.1, 4.0)],
        vec![Vec3::splat(0.1)],
        vec![Quat::IDENTITY],
        vec![0.9],
        &[Vec3::ONE],
    )
    .unwrap();
    assert_agrees(&behind, &camera(40, 24), &options, "behind");
}

#[test]
fn a_camera_from_camera_info_with_an_off_centre_principal_point_agrees() {
    let g = body_cloud(1500, 0, 8);
    let world_from_camera = camera(10, 10).world_from_camera;
    let cam = Camera::from_camera_info(
        [70.0, 0.0, 20.0, 0.0, 75.0, 41.0, 0.0, 0.0, 1.0],
        50,
        70,
        world_from_camera * Affine3A::from_rotation_z(0.2),
    );
    assert_agrees(&g, &cam, &RenderOptions::default(), "intrinsics");
}
