//! Synthetic LHMPP-Prior files for tests: a tiny SMPL-X-like model (55 joints with the real
//! SMPL-X parents, a small octahedron of vertices around each joint, each vertex fully
//! weighted to its joint), query points scattered around the vertices, and a dense
//! skinning volume giving each node its nearest joint in the neutral pose.

#![allow(dead_code)]

use std::path::Path;

use candle_core::{Device, Tensor};
use glam::{Quat, Vec3};
use lhmpp::body::official::{PriorPaths, NEUTRAL_HIP_ANGLE};
use lhmpp::body::{write_point_ply, SMPLX_JOINT_NAMES};

/// SMPL-X kinematic parents (joint 0 is the root).
#[rustfmt::skip]
pub const SMPLX_PARENTS: [i64; 55] = [
    -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 15, 15, 15,
    20, 25, 26, 20, 28, 29, 20, 31, 32, 20, 34, 35, 20, 37, 38,
    21, 40, 41, 21, 43, 44, 21, 46, 47, 21, 49, 50, 21, 52, 53,
];

/// Offset of a joint from its parent, by name (metres, SMPL-X axes: +y up, +x the body's left).
fn bone(name: &str) -> Vec3 {
    let side = if name.starts_with("left") { 1.0 } else { -1.0 };
    let n = name
        .trim_start_matches("left_")
        .trim_start_matches("right_");
    match n {
        "hip" => Vec3::new(0.09 * side, -0.08, 0.0),
        "knee" => Vec3::new(0.0, -0.38, 0.0),
        "ankle" => Vec3::new(0.0, -0.4, 0.0),
        "foot" => Vec3::new(0.0, -0.05, 0.12),
        "collar" => Vec3::new(0.07 * side, 0.12, 0.0),
        "shoulder" => Vec3::new(0.1 * side, 0.02, 0.0),
        "elbow" => Vec3::new(0.26 * side, 0.0, 0.0),
        "wrist" => Vec3::new(0.25 * side, 0.0, 0.0),
        "jaw" => Vec3::new(0.0, 0.02, 0.06),
        "eye_smplhf" => Vec3::new(0.03 * side, 0.08, 0.07),
        "spine1" | "spine2" | "spine3" => Vec3::new(0.0, 0.12, 0.0),
        "neck" => Vec3::new(0.0, 0.12, 0.0),
        "head" => Vec3::new(0.0, 0.1, 0.0),
        _ => Vec3::new(0.03 * side, 0.0, 0.0), // finger joints
    }
}

/// Joint positions in the SMPL-X model frame (pelvis at about 0.3 m above the origin, as
/// SMPL-X's model frame has its origin near the pelvis rather than at the soles).
pub fn joints() -> Vec<Vec3> {
    let mut j = vec![Vec3::new(0.0, 0.3, 0.02)];
    for i in 1..55 {
        let p = j[SMPLX_PARENTS[i] as usize];
        let mut o = bone(SMPLX_JOINT_NAMES[i]);
        if SMPLX_JOINT_NAMES[i].contains("thumb") {
            o.z += 0.02;
        }
        j.push(p + o);
    }
    j
}

const OCTA: [[f32; 3]; 6] = [
    [1., 0., 0.],
    [-1., 0., 0.],
    [0., 1., 0.],
    [0., -1., 0.],
    [0., 0., 1.],
    [0., 0., -1.],
];
const OCTA_FACES: [[u32; 3]; 8] = [
    [0, 2, 4],
    [2, 1, 4],
    [1, 3, 4],
    [3, 0, 4],
    [2, 0, 5],
    [1, 2, 5],
    [3, 1, 5],
    [0, 3, 5],
];
/// Octahedron radius around each joint.
pub const RADIUS: f32 = 0.012;

/// Template vertices (6 per joint, model frame).
pub fn vertices() -> Vec<Vec3> {
    joints()
        .iter()
        .flat_map(|j| OCTA.iter().map(move |o| *j + Vec3::from_array(*o) * RADIUS))
        .collect()
}

/// Writes the SMPL-X-like npz.
pub fn write_smplx(path: &Path) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    let dev = Device::Cpu;
    let v = vertices();
    let nv = v.len();
    let flat: Vec<f32> = v.iter().flat_map(|p| p.to_array()).collect();
    let faces: Vec<i64> = (0..55u32)
        .flat_map(|j| {
            OCTA_FACES
                .iter()
                .flat_map(move |f| f.map(|k| (6 * j + k) as i64))
        })
        .collect();
    let mut jr = vec![0f32; 55 * nv];
    let mut w = vec![0f32; nv * 55];
    for j in 0..55 {
        for k in 0..6 {
            jr[j * nv + 6 * j + k] = 1.0 / 6.0;
            w[(6 * j + k) * 55 + j] = 1.0;
        }
    }
    let mut kt: Vec<i64> = SMPLX_PARENTS.to_vec();
    kt.extend(0..55i64);
    let shapedirs = vec![0f32; nv * 3 * 10];
    let tensors = [
        ("v_template", Tensor::from_vec(flat, (nv, 3), &dev).unwrap()),
        ("f", Tensor::from_vec(faces, (55 * 8, 3), &dev).unwrap()),
        ("J_regressor", Tensor::from_vec(jr, (55, nv), &dev).unwrap()),
        ("weights", Tensor::from_vec(w, (nv, 55), &dev).unwrap()),
        (
            "kintree_table",
            Tensor::from_vec(kt, (2, 55), &dev).unwrap(),
        ),
        (
            "shapedirs",
            Tensor::from_vec(shapedirs, (nv, 3, 10), &dev).unwrap(),
        ),
    ];
    let refs: Vec<(&str, &Tensor)> = tensors.iter().map(|(k, t)| (*k, t)).collect();
    Tensor::write_npz(&refs, path).unwrap();
}

/// `n` query points (model frame, zero pose): around the vertices, jittered deterministically.
pub fn query_points(n: usize) -> Vec<Vec3> {
    let v = vertices();
    (0..n)
        .map(|i| {
            let t = i as f32;
            let jitter = Vec3::new((t * 1.7).sin(), (t * 2.3).cos(), (t * 0.9).sin()) * 0.004;
            v[i % v.len()] + jitter
        })
        .collect()
}

/// Neutral-pose joints: the two leg chains rotated about their hips by ±π/9 (z).
pub fn neutral_joints() -> Vec<Vec3> {
    let j = joints();
    let mut out = j.clone();
    for (hip, angle) in [(1usize, NEUTRAL_HIP_ANGLE), (2, -NEUTRAL_HIP_ANGLE)] {
        let r = Quat::from_rotation_z(angle);
        let mut in_leg = [false; 55];
        in_leg[hip] = true;
        for i in hip + 1..55 {
            in_leg[i] = in_leg[SMPLX_PARENTS[i] as usize];
        }
        for i in 0..55 {
            if in_leg[i] && i != hip {
                out[i] = j[hip] + r * (j[i] - j[hip]);
            }
        }
    }
    out
}

/// Writes a dense `[X, Y, Z, 55]` volume: each node one-hot on its nearest neutral joint.
pub fn write_volume(path: &Path) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    let nj = neutral_joints();
    let (lo, hi) = nj
        .iter()
        .fold((Vec3::MAX, Vec3::MIN), |(l, h), p| (l.min(*p), h.max(*p)));
    let (lo, hi) = (lo - Vec3::splat(0.1), hi + Vec3::splat(0.1));
    let dims = [16usize, 24, 8];
    let mut data = vec![0f32; dims[0] * dims[1] * dims[2] * 55];
    for x in 0..dims[0] {
        for y in 0..dims[1] {
            for z in 0..dims[2] {
                let t = Vec3::new(
                    x as f32 / (dims[0] - 1) as f32,
                    y as f32 / (dims[1] - 1) as f32,
                    z as f32 / (dims[2] - 1) as f32,
                );
                let p = lo + t * (hi - lo);
                let best = (0..55)
                    .min_by(|a, b| nj[*a].distance(p).total_cmp(&nj[*b].distance(p)))
                    .unwrap();
                data[((x * dims[1] + y) * dims[2] + z) * 55 + best] = 1.0;
            }
        }
    }
    let dev = Device::Cpu;
    let bounds: Vec<f32> = [lo.to_array(), hi.to_array()].concat();
    let tensors = [
        (
            "diff_weight_volume",
            Tensor::from_vec(data, (dims[0], dims[1], dims[2], 55), &dev).unwrap(),
        ),
        (
            "volume_bounds",
            Tensor::from_vec(bounds, (2, 3), &dev).unwrap(),
        ),
    ];
    let refs: Vec<(&str, &Tensor)> = tensors.iter().map(|(k, t)| (*k, t)).collect();
    Tensor::write_npz(&refs, path).unwrap();
}

/// Writes a complete synthetic prior with `n` points under `dir` (official layout).
pub fn write_prior(dir: &Path, n: usize) -> PriorPaths {
    let paths = PriorPaths::in_dir(dir);
    write_smplx(&paths.smplx);
    write_volume(&paths.volume);
    let pts = query_points(n);
    write_point_ply(&paths.points, &pts, &vec![[200, 200, 200]; n]).unwrap();
    paths
}

/// Sets an official `config.json` value to ViT-S widths (d 384, 6 heads): the encoder, the
/// joint width (`pcl_dim`, `transformer_dim`) and the `image_backbone` frame blocks.
pub fn vit_s_widths(v: &mut serde_json::Value) {
    use serde_json::json;
    v["encoder_model_name"] = json!("dinov2_vits14_reg");
    v["encoder_feat_dim"] = json!(384);
    v["pcl_dim"] = json!(384);
    v["transformer_dim"] = json!(384);
    v["transformer_heads"] = json!(6);
    let ib = &mut v["transformer_decoder"]["image_backbone"];
    ib["embed_dim"] = json!(384);
    ib["num_heads"] = json!(6);
}

/// Sets an official `config.json` value's point backbone to one block per stage at small
/// widths, ending in 128 channels (the official `gs_query_dim`).
pub fn slim_point_backbone(v: &mut serde_json::Value) {
    use serde_json::json;
    let pb = &mut v["transformer_decoder"]["point_backbone"];
    pb["enc_depths"] = json!([1, 1, 1, 1]);
    pb["enc_channels"] = json!([16, 32, 32, 64]);
    pb["enc_num_head"] = json!([2, 2, 4, 4]);
    pb["enc_patch_size"] = json!([256, 256, 128, 64]);
    pb["dec_depths"] = json!([1, 1, 1]);
    pb["dec_channels"] = json!([128, 32, 64]);
    pb["dec_num_head"] = json!([2, 2, 4]);
    pb["dec_patch_size"] = json!([256, 256, 128]);
}

/// Writes tensors `(name, little-endian bytes, shape)` of `dtype` as one safetensors file.
pub fn write_tensors(
    path: &Path,
    dtype: safetensors::Dtype,
    tensors: &[(String, Vec<u8>, Vec<usize>)],
) {
    let views: Vec<(String, safetensors::tensor::TensorView)> = tensors
        .iter()
        .map(|(n, b, d)| {
            let v = safetensors::tensor::TensorView::new(dtype, d.clone(), b).unwrap();
            (n.clone(), v)
        })
        .collect();
    safetensors::serialize_to_file(views, None, path).unwrap();
}

/// A small encoder input: white with a coloured block moved right by `shift` pixels (RGB in
/// [0, 1], channel-major).
pub fn view(size: u32, shift: usize) -> lhmpp::reconstruct::preprocess::Preprocessed {
    let s = size as usize;
    let mut chw = vec![1.0f32; 3 * s * s];
    for c in 0..3 {
        for y in s / 4..3 * s / 4 {
            for x in (s / 3 + shift)..(2 * s / 3 + shift).min(s) {
                chw[c * s * s + y * s + x] = 0.2 + 0.3 * c as f32;
            }
        }
    }
    lhmpp::reconstruct::preprocess::Preprocessed {
        height: size,
        width: size,
        chw,
        region: lhmpp::reconstruct::preprocess::BBox {
            x0: 0,
            y0: 0,
            x1: i64::from(size),
            y1: i64::from(size),
        },
    }
}
