//! Dressed training samples ([`Realism::Dressed`](super::Realism)): a [`DressedPerson`] in a
//! random pose under a random [`Lighting`], its input views lit, over a [`Backdrop`], through
//! random [`CameraEffects`], then preprocessed as the node does; the ground truth is the
//! albedo: per anchor the albedo of the outermost surface over it (with that surface's
//! garment and position), and the target views rendered unlit on white.
//!
//! Why unlit targets: the network's avatar is rendered without lighting, and its colour must
//! be the albedo; the anchor colours are the albedo; a lit target would ask the render loss
//! for shading that no unlit avatar can show and would fight the anchor loss. The input views
//! stay lit so the network learns to see the albedo through shading, white balance and noise.

use super::{
    resized, rolled, sample_pose, DatasetOptions, RenderedInput, TrainingSample, HIDDEN_ANCHOR,
};
use crate::avatar::Avatar;
use crate::body::MAKEHUMAN_MODEL_ID;
use crate::reconstruct::preprocess::{preprocess, PreprocessConfig, Subject};
use crate::splat::{render, Gaussians, RenderOptions};
use crate::synth::backdrop::Backdrop;
use crate::synth::camera_fx::CameraEffects;
use crate::synth::dressed::DressedPerson;
use crate::synth::lighting::Lighting;
use crate::synth::person::SynthError;
use crate::synth::scene::{Rig, RigCamera};
use glam::{Quat, Vec3};
use image::{GrayImage, RgbImage};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Makes the dressed training sample of `seed` (the caller checked the seed range).
pub(super) fn make_dressed_sample(
    seed: u64,
    options: &DatasetOptions,
) -> Result<TrainingSample, SynthError> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x6472_6573_7365_6474);
    let person = DressedPerson::new(seed, options.person_points)?;
    let height = person.template.height();
    let views = rng.gen_range(1..=options.max_views.max(1));
    let size = [128u32, 192, 256][rng.gen_range(0..3)];
    let rig = if rng.gen_bool(0.7) {
        Rig::ring(seed, views, options.heldout_targets, size, height)
    } else {
        Rig::moving(seed, views, options.heldout_targets, size, height)
    };
    let pose = sample_pose(&person.template, seed, &mut rng);
    let matrices = person
        .template
        .skeleton
        .try_skinning_matrices(&pose)
        .map_err(|e| SynthError::Pose(e.to_string()))?;
    let posed_person = person.avatar.animate(&matrices);
    let lighting = Lighting::random(&mut rng);
    let shadow = match lighting.lights.first() {
        Some(key) => Some(person.light_visibility(&matrices, &posed_person, key.direction)?),
        None => None,
    };

    let pre = PreprocessConfig {
        out_height: options.input_height,
        out_width: options.input_width,
        ..PreprocessConfig::default()
    };
    let black = RenderOptions::default();
    let input_pixels = (options.input_height * options.input_width) as usize;
    let mut images = Vec::with_capacity(views * 3 * input_pixels);
    let mut rendered_inputs = Vec::with_capacity(views);
    for rig_camera in &rig.inputs {
        let camera = rolled(&rig_camera.camera, rng.gen_range(-0.12..0.12));
        let eye = Vec3::from(camera.world_from_camera.translation);
        let lit = lighting.lit(&person, &posed_person, eye, shadow.as_deref(), false);
        let out = render(&lit, &camera, &black);
        let backdrop = Backdrop::random(&mut rng);
        let effects = CameraEffects::random(&mut rng);
        let (w, h) = (out.width, out.height);
        let composite: Vec<f32> = (0..(w * h) as usize)
            .flat_map(|i| {
                let (x, y) = (i as u32 % w, i as u32 / w);
                let c = Vec3::from_slice(&out.rgb[3 * i..3 * i + 3])
                    + (1.0 - out.alpha[i]) * backdrop.at(x, y, w, h);
                c.to_array()
            })
            .collect();
        let mut rgb: RgbImage = effects.apply(&composite, w, h);
        if backdrop == Backdrop::White {
            // A person cut out onto white: the background stays white.
            for (i, p) in rgb.pixels_mut().enumerate() {
                if out.alpha[i] < 1.0 / 255.0 {
                    p.0 = [255; 3];
                }
            }
        }
        let masked = rng.gen_bool(options.mask_fraction.clamp(0.0, 1.0));
        let mask = GrayImage::from_fn(w, h, |x, y| {
            image::Luma([if out.alpha[(y * w + x) as usize] >= 0.5 {
                255
            } else {
                0
            }])
        });
        let subject = if masked {
            Subject::Mask(&mask)
        } else {
            Subject::FullFrame
        };
        let view = preprocess(&rgb, subject, &pre)
            .or_else(|_| preprocess(&rgb, Subject::FullFrame, &pre))
            .map_err(|e| SynthError::Dataset(format!("preprocess: {e}")))?;
        images.extend(view.chw.iter().map(|v| (v * 255.0).round() as u8));
        rendered_inputs.push(RenderedInput {
            camera,
            region: view.region,
            width: w,
            height: h,
            alpha: out.alpha,
            depth: out.depth,
        });
    }

    // Anchors, their ground truth (outermost surface's albedo), the pose.
    let anchors = person
        .template
        .sample_anchors(options.points, options.anchor_seed);
    let truth = person.anchor_truth(&anchors)?;
    let n = anchors.len();
    let points = |positions: Vec<Vec3>, skin| -> Result<Gaussians, SynthError> {
        let frame = Gaussians::from_rgb(
            positions,
            vec![Vec3::splat(0.01); n],
            vec![Quat::IDENTITY; n],
            vec![1.0; n],
            &vec![Vec3::ZERO; n],
        )?;
        Ok(Avatar::new(frame, skin, MAKEHUMAN_MODEL_ID)?.animate(&matrices))
    };
    let posed_frame = points(anchors.positions.clone(), anchors.skin.clone())?;
    let posed_surface = points(truth.surface.clone(), truth.surface_skin.clone())?;
    let flat = |v: &[Vec3]| v.iter().flat_map(|p| p.to_array()).collect::<Vec<f32>>();
    // Where each anchor's colour shows: its outermost surface point, posed.
    let anchor_pixels = rendered_inputs
        .iter()
        .flat_map(|view| {
            posed_surface.positions.iter().flat_map(|p| {
                view.locate(*p, options.input_width, options.input_height)
                    .unwrap_or([HIDDEN_ANCHOR; 2])
            })
        })
        .collect();

    // Targets: unlit (albedo), on white.
    let mut targets: Vec<&RigCamera> = rig.heldout.iter().collect();
    targets.push(&rig.inputs[rng.gen_range(0..rig.inputs.len())]);
    let white = RenderOptions {
        background: Vec3::ONE,
        ..RenderOptions::default()
    };
    let r = options.target_size;
    let mut target_rgb = Vec::new();
    let mut target_alpha = Vec::new();
    let mut target_intrinsics = Vec::new();
    let mut target_camera_from_world = Vec::new();
    for t in targets.iter() {
        let camera = resized(&t.camera, r);
        let out = render(&posed_person, &camera, &white);
        for c in 0..3 {
            target_rgb.extend(
                out.rgb
                    .chunks_exact(3)
                    .map(|p| (p[c].clamp(0.0, 1.0) * 255.0).round() as u8),
            );
        }
        target_alpha.extend(
            out.alpha
                .iter()
                .map(|a| (a.clamp(0.0, 1.0) * 255.0).round() as u8),
        );
        let i = camera.intrinsics;
        target_intrinsics.extend([i.fx, i.fy, i.cx, i.cy]);
        let m = glam::Mat4::from(camera.camera_from_world());
        for row in 0..3 {
            target_camera_from_world.extend((0..4).map(|col| m.col(col)[row]));
        }
    }
    // Where the node puts the anchors without knowing the girth (for some samples). Their
    // outermost surface is the true person's, not in that frame: it is left out.
    let girth_one = super::anchors_at_girth_one(seed, options);
    let (anchors, posed_frame) = if girth_one {
        super::girth_one_anchors(&person.template, person.girth_scale, &anchors, &pose)?
    } else {
        (anchors, posed_frame)
    };
    Ok(TrainingSample {
        seed,
        views,
        images,
        image_size: (options.input_height as usize, options.input_width as usize),
        anchors: flat(&anchors.positions),
        normals: flat(&anchors.normals),
        colors: flat(&truth.albedo),
        posed_anchors: flat(&posed_frame.positions),
        posed_rotations: posed_frame
            .rotations
            .iter()
            .flat_map(|q| [q.w, q.x, q.y, q.z])
            .collect(),
        target_rgb,
        target_alpha,
        target_intrinsics,
        target_camera_from_world,
        shape: [person.height_scale, person.girth_scale],
        anchor_pixels,
        anchor_garment: Some(truth.garment),
        anchor_surface: (!girth_one).then(|| flat(&truth.surface)),
    })
}
