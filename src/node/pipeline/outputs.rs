//! Where results go: avatar PLY files and PNG frames under the output directory, and the
//! ROS 2 messages (GaussianAvatar, rendered Image, ReconstructionStatus) built from them.

use super::AvatarUpdate;
use crate::avatar::Avatar;
use crate::msgs::{
    GaussianAvatar, GaussianCloud, GaussianColors, Header, Image, Point, ReconstructionStatus, Time,
};
use crate::splat::{sh_dc_to_rgb, write_ply, PlyError};
use image::RgbImage;
use std::path::{Path, PathBuf};

/// A file output failed; names the file.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// Writing a PLY failed.
    #[error(transparent)]
    Ply(#[from] PlyError),
    /// Writing a PNG or creating a directory failed.
    #[error("{path}: {message}")]
    File {
        /// File or directory.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// A message could not be built.
    #[error("message: {0}")]
    Message(#[from] crate::msgs::MsgError),
}

/// Writes avatars and frames under one directory (`out/` by default).
#[derive(Debug, Clone)]
pub struct FileOutputs {
    dir: PathBuf,
    /// The checkpoint kind when its Gaussian RGB is not display-ready (PLY colours warn).
    latent_rgb: Option<String>,
    /// Set once the latent-RGB warning was logged.
    warned: std::sync::OnceLock<()>,
}

impl FileOutputs {
    /// Creates `dir` and `dir/frames` and checks that a file can be written there (a probe
    /// file is created and removed), so that a read-only or unusable directory is found at
    /// startup rather than at the first avatar.
    pub fn new(dir: &Path) -> Result<Self, OutputError> {
        let failed = |path: &Path, e: std::io::Error| OutputError::File {
            path: path.to_path_buf(),
            message: e.to_string(),
        };
        for d in [dir.to_path_buf(), dir.join("frames")] {
            std::fs::create_dir_all(&d).map_err(|e| failed(&d, e))?;
        }
        let probe = dir.join(".lhmpp-write-probe");
        std::fs::write(&probe, b"lhmpp").map_err(|e| failed(&probe, e))?;
        std::fs::remove_file(&probe).map_err(|e| failed(&probe, e))?;
        Ok(Self {
            dir: dir.to_path_buf(),
            latent_rgb: None,
            warned: std::sync::OnceLock::new(),
        })
    }

    /// Notes that the avatars' RGB is not display-ready (`checkpoint_kind` names the
    /// checkpoint): the first PLY written logs a warning that its colours are latent.
    pub fn with_latent_rgb(mut self, checkpoint_kind: &str) -> Self {
        self.latent_rgb = Some(checkpoint_kind.to_owned());
        self
    }

    /// Writes `avatar_<person>_rev<N>.ply` and `avatar_<person>.ply` (the latest); returns the
    /// latest's path.
    pub fn write_avatar(
        &self,
        person: &str,
        revision: u64,
        avatar: &Avatar,
    ) -> Result<PathBuf, OutputError> {
        let versioned = self.dir.join(format!("avatar_{person}_rev{revision}.ply"));
        if let Some(kind) = &self.latent_rgb {
            if self.warned.set(()).is_ok() {
                tracing::warn!(
                    "avatar PLY colours (f_dc) are not display-ready: the checkpoint ({kind}) \
                     never supervised its Gaussian RGB against images; they are a latent \
                     intermediate that the network's neural renderer decodes (the node's frames \
                     use it with outputs.renderer: auto or neural), not colours to show"
                );
            }
        }
        let written = write_ply(
            &versioned,
            &avatar.canonical,
            Some(&avatar.skin),
            Some(&avatar.body_model),
        );
        if let Err(e) = written {
            // No partial avatar is left behind (a full disk cuts the file short).
            let _ = std::fs::remove_file(&versioned);
            return Err(e.into());
        }
        // The latest is replaced in one rename, so a reader never sees a partial file.
        let latest = self.dir.join(format!("avatar_{person}.ply"));
        let partial = self.dir.join(format!(".avatar_{person}.ply.partial"));
        let replaced =
            std::fs::copy(&versioned, &partial).and_then(|_| std::fs::rename(&partial, &latest));
        if let Err(e) = replaced {
            let _ = std::fs::remove_file(&partial);
            return Err(OutputError::File {
                path: latest,
                message: e.to_string(),
            });
        }
        Ok(latest)
    }

    /// Writes `frames/<name>.png` (removed again if it could not be written whole).
    pub fn write_frame(&self, name: &str, image: &RgbImage) -> Result<PathBuf, OutputError> {
        let path = self.dir.join("frames").join(format!("{name}.png"));
        image.save(&path).map_err(|e| {
            let _ = std::fs::remove_file(&path);
            OutputError::File {
                path: path.clone(),
                message: e.to_string(),
            }
        })?;
        Ok(path)
    }
}

/// The GaussianAvatar message of an avatar revision (canonical Gaussians, skinning,
/// skeleton, and whether its RGB is display-ready).
pub fn avatar_message(update: &AvatarUpdate<'_>) -> Result<GaussianAvatar, OutputError> {
    let AvatarUpdate {
        person,
        revision,
        views_used,
        stamp_ns,
        avatar,
        template,
        shape_params,
        rgb_display_ready,
        neural_renderer,
    } = *update;
    let g = &avatar.canonical;
    let colors = (0..g.len())
        .map(|i| sh_dc_to_rgb(g.sh_of(i)[0]).to_array())
        .collect();
    let cloud = GaussianCloud {
        positions: g.positions.iter().map(|p| p.to_array()).collect(),
        scales: g.scales.iter().map(|s| s.to_array()).collect(),
        rotations: g.rotations.iter().map(|q| [q.w, q.x, q.y, q.z]).collect(),
        opacities: g.opacities.clone(),
        colors: GaussianColors::Rgb(colors),
        skin: avatar.skin.clone(),
    };
    let header = Header::new(Time::from_nanos(stamp_ns), "lhmpp_canonical");
    let skeleton = &template.skeleton;
    Ok(GaussianAvatar {
        gaussians: cloud.to_point_cloud(header.clone())?,
        header,
        person_id: person.to_owned(),
        revision: revision as u32,
        views_used: views_used as u32,
        body_model: avatar.body_model.clone(),
        shape_params: shape_params.to_vec(),
        sh_degree: 0,
        rgb_display_ready,
        neural_renderer: neural_renderer.to_owned(),
        bone_names: skeleton.bone_names.clone(),
        bone_parents: skeleton
            .parents
            .iter()
            .map(|p| p.map_or(-1, |i| i as i32))
            .collect(),
        bone_rest_positions: skeleton.joints.iter().map(|j| Point::from(*j)).collect(),
    })
}

/// A ReconstructionStatus message; `render_ms` is the per-frame render time of the last
/// rendered batch (0 before the first).
#[allow(clippy::too_many_arguments)]
pub fn status_message(
    person: &str,
    views_held: usize,
    revision: u64,
    latency_ms: f64,
    render_ms: f64,
    state: u8,
    message: impl Into<String>,
    stamp_ns: i64,
) -> ReconstructionStatus {
    ReconstructionStatus {
        header: Header::new(Time::from_nanos(stamp_ns), "lhmpp_canonical"),
        person_id: person.to_owned(),
        views_held: views_held as u32,
        revision: revision as u32,
        last_latency_ms: latency_ms,
        last_render_ms: render_ms,
        state,
        message: message.into(),
        ..Default::default()
    }
}

/// An rgb8 Image message of a rendered frame.
pub fn frame_message(image: &RgbImage, stamp_ns: i64, frame_id: &str) -> Image {
    crate::node::ros::rgb8_image(image, stamp_ns, frame_id)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::SkinWeights;
    use crate::splat::Gaussians;
    use glam::{Quat, Vec3};
    use std::sync::{Arc, Mutex};

    fn avatar() -> Avatar {
        let g = Gaussians::from_rgb(
            vec![Vec3::ZERO],
            vec![Vec3::splat(0.01)],
            vec![Quat::IDENTITY],
            vec![1.0],
            &[Vec3::new(0.2, 0.4, 0.6)],
        )
        .unwrap();
        let skin = SkinWeights {
            bones: vec![[0; 4]],
            weights: vec![[1.0, 0.0, 0.0, 0.0]],
        };
        Avatar::new(g, skin, "test-body").unwrap()
    }

    /// The log lines written while `f` runs, at warn level and above.
    fn warnings(f: impl FnOnce()) -> String {
        #[derive(Clone, Default)]
        struct Buf(Arc<Mutex<Vec<u8>>>);
        impl std::io::Write for Buf {
            fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
                self.0.lock().unwrap().extend_from_slice(b);
                Ok(b.len())
            }
            fn flush(&mut self) -> std::io::Result<()> {
                Ok(())
            }
        }
        let buf = Buf::default();
        let writer = buf.clone();
        let subscriber = tracing_subscriber::fmt()
            .with_max_level(tracing::Level::WARN)
            .with_ansi(false)
            .with_writer(move || writer.clone())
            .finish();
        tracing::subscriber::with_default(subscriber, f);
        let text = buf.0.lock().unwrap().clone();
        String::from_utf8(text).unwrap()
    }

    #[test]
    fn latent_rgb_ply_export_warns_once_naming_the_checkpoint_kind() {
        let tmp = tempfile::tempdir().unwrap();
        let files = FileOutputs::new(tmp.path())
            .unwrap()
            .with_latent_rgb("LHMPP-700M");
        let log = warnings(|| {
            for revision in 1..=3 {
                files.write_avatar("p", revision, &avatar()).unwrap();
            }
        });
        assert_eq!(log.matches("not display-ready").count(), 1, "{log}");
        assert!(log.contains("LHMPP-700M"), "{log}");
        assert!(tmp.path().join("avatar_p_rev3.ply").exists());
    }

    #[test]
    fn display_ready_ply_export_is_silent() {
        let tmp = tempfile::tempdir().unwrap();
        let files = FileOutputs::new(tmp.path()).unwrap();
        let log = warnings(|| {
            files.write_avatar("p", 1, &avatar()).unwrap();
        });
        assert_eq!(log, "");
        assert!(tmp.path().join("avatar_p.ply").exists());
    }
}
