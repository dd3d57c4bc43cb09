//! 3DGS-layout PLY export/import.

use glam::{Quat, Vec3};
use lhmpp::body::SkinWeights;
use lhmpp::splat::synthetic::body_cloud;
use lhmpp::splat::{read_ply, write_ply, Gaussians, PlyError};

fn degree3_set() -> Gaussians {
    let mut g = body_cloud(200, 3, 21);
    g.sh_degree = 3;
    g.sh = (0..200 * 16)
        .map(|k| [k as f32 * 0.001, -(k as f32) * 0.002, 0.5])
        .collect();
    g
}

#[test]
fn ply_round_trip_keeps_every_attribute() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("avatar.ply");
    let g = degree3_set();
    let skin = SkinWeights {
        bones: (0..200).map(|i| [i as u16, 7, 162, 0]).collect(),
        weights: (0..200).map(|_| [0.5, 0.25, 0.25, 0.0]).collect(),
    };
    write_ply(&path, &g, Some(&skin), Some("makehuman-cc0")).unwrap();
    let back = read_ply(&path).unwrap();
    assert_eq!(back.body_model.as_deref(), Some("makehuman-cc0"));
    assert_eq!(back.skin.as_ref(), Some(&skin));
    let r = &back.gaussians;
    assert_eq!((r.len(), r.sh_degree, r.feature_channels), (200, 3, 3));
    assert_eq!(r.positions, g.positions);
    assert_eq!(r.sh, g.sh);
    assert_eq!(r.features, g.features);
    for i in 0..200 {
        // Opacity goes through logit/sigmoid, scales through log/exp: f32 round-off only.
        assert!((r.opacities[i] - g.opacities[i]).abs() < 1e-6);
        assert!(
            ((r.scales[i] - g.scales[i]) / g.scales[i])
                .abs()
                .max_element()
                < 1e-6
        );
        assert!(r.rotations[i].dot(g.rotations[i]) > 1.0 - 1e-6);
    }
}

#[test]
fn header_follows_the_3dgs_layout_with_channel_major_f_rest() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("plain.ply");
    let mut g = Gaussians::from_rgb(
        vec![Vec3::ONE],
        vec![Vec3::splat(0.01)],
        vec![Quat::IDENTITY],
        vec![0.5],
        &[Vec3::ONE],
    )
    .unwrap();
    g.sh_degree = 1;
    g.sh = vec![
        [1.0, 2.0, 3.0],
        [10.0, 20.0, 30.0],
        [11.0, 21.0, 31.0],
        [12.0, 22.0, 32.0],
    ];
    write_ply(&path, &g, None, None).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let header = std::str::from_utf8(&bytes[..end]).unwrap();
    let props: Vec<&str> = header
        .lines()
        .filter_map(|l| l.strip_prefix("property float "))
        .collect();
    let expected: Vec<String> = [
        "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2",
    ]
    .iter()
    .map(|s| s.to_string())
    .chain((0..9).map(|k| format!("f_rest_{k}")))
    .chain(
        [
            "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
        ]
        .iter()
        .map(|s| s.to_string()),
    )
    .collect();
    assert_eq!(props, expected);
    assert!(header.starts_with("ply\nformat binary_little_endian 1.0\n"));
    let vals: Vec<f32> = bytes[end..]
        .chunks(4)
        .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
        .collect();
    assert_eq!(
        &vals[9..18],
        &[10.0, 11.0, 12.0, 20.0, 21.0, 22.0, 30.0, 31.0, 32.0],
        "red coefficients first"
    );
    assert_eq!(vals[18], 0.0, "opacity 0.5 is logit 0");
    assert!((vals[19] - 0.01f32.ln()).abs() < 1e-6, "log scale");
    assert_eq!(&vals[22..26], &[1.0, 0.0, 0.0, 0.0], "rotation w first");
}

#[test]
fn truncated_and_malformed_files_are_reported_with_their_path() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cut.ply");
    write_ply(&path, &body_cloud(10, 0, 1), None, None).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() - 7]).unwrap();
    let err = read_ply(&path).unwrap_err();
    assert!(matches!(err, PlyError::Truncated { .. }), "{err}");
    assert!(err.to_string().contains("cut.ply"), "{err}");

    let ascii = dir.path().join("ascii.ply");
    std::fs::write(
        &ascii,
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n0\n",
    )
    .unwrap();
    let err = read_ply(&ascii).unwrap_err();
    assert!(
        err.to_string().contains("ascii.ply") && err.to_string().contains("ascii"),
        "{err}"
    );

    let missing = dir.path().join("mesh.ply");
    std::fs::write(&missing, b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n\0\0\0\0\0\0\0\0\0\0\0\0").unwrap();
    let err = read_ply(&missing).unwrap_err();
    assert!(
        matches!(&err, PlyError::MissingProperty { name, .. } if name == "f_dc_0"),
        "{err}"
    );

    let err = read_ply(&dir.path().join("absent.ply")).unwrap_err();
    assert!(matches!(err, PlyError::Io { .. }) && err.to_string().contains("absent.ply"));

    let garbage = dir.path().join("garbage.ply");
    std::fs::write(&garbage, b"\x89PNG\r\n").unwrap();
    assert!(read_ply(&garbage)
        .unwrap_err()
        .to_string()
        .contains("garbage.ply"));
}
