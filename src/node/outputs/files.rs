//! The file output: [`FileOutputs`] writes each avatar revision as PLY files and the
//! end-of-replay animation as PNG frames under the output directory (`outputs.dir`).

use super::{Animation, AvatarUpdate, OutputError, Publisher};
use crate::avatar::Avatar;
use crate::msgs::ReconstructionStatus;
use crate::node::pipeline::RenderedFrame;
use crate::splat::write_ply;
use image::RgbImage;
use std::path::{Path, PathBuf};

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

/// Stores avatars and animation frames; takes no live stream (statuses, rendered frames,
/// previews).
impl Publisher for FileOutputs {
    /// Writes the avatar's PLY files ([`FileOutputs::write_avatar`]) and logs the path.
    fn avatar(&self, u: &AvatarUpdate<'_>) {
        match self.write_avatar(u.person, u.revision, u.avatar) {
            Ok(path) => tracing::info!("wrote {}", path.display()),
            Err(e) => tracing::error!("avatar file: {e}"),
        }
    }
    fn status(&self, _msg: ReconstructionStatus) {}
    fn frame(&self, _: &str, _camera: usize, _frame: &RenderedFrame, _stamp_ns: i64) {}
    fn live(&self) -> bool {
        false
    }
    /// Writes the animation's frames as `frames/<name>.png`.
    fn animation(&self) -> Option<Box<dyn Animation + '_>> {
        Some(Box::new(FrameFiles {
            files: self,
            written: 0,
            failed: 0,
        }))
    }
}

/// The PNG files of one animation, counting what could not be written.
struct FrameFiles<'a> {
    files: &'a FileOutputs,
    written: usize,
    failed: usize,
}

impl Animation for FrameFiles<'_> {
    fn frame(&mut self, name: &str, frame: &RenderedFrame) -> bool {
        match self.files.write_frame(name, frame.rgb8()) {
            Ok(_) => {
                self.written += 1;
                true
            }
            Err(e) => {
                // The first failure is logged; the rest (a full disk fails them all) are
                // counted and summed up by `finish`.
                if self.failed == 0 {
                    tracing::error!("frame file: {e}");
                }
                self.failed += 1;
                false
            }
        }
    }
    fn finish(self: Box<Self>) {
        if self.failed > 1 {
            tracing::error!(
                "{} frame files of {} could not be written",
                self.failed,
                self.failed + self.written
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::SkinWeights;
    use crate::splat::Gaussians;
    use glam::{Quat, Vec3};

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

    #[test]
    fn latent_rgb_ply_export_warns_once_naming_the_checkpoint_kind() {
        let tmp = tempfile::tempdir().unwrap();
        let files = FileOutputs::new(tmp.path())
            .unwrap()
            .with_latent_rgb("LHMPP-700M");
        let log = crate::testing::warnings_logged(|| {
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
        let log = crate::testing::warnings_logged(|| {
            files.write_avatar("p", 1, &avatar()).unwrap();
        });
        assert_eq!(log, "");
        assert!(tmp.path().join("avatar_p.ply").exists());
    }

    /// A 4×2 grey frame.
    fn frame() -> RenderedFrame {
        let n = 4 * 2;
        RenderedFrame::new(crate::splat::RenderOutput {
            width: 4,
            height: 2,
            rgb: vec![0.5; n * 3],
            alpha: vec![1.0; n],
            depth: vec![1.0; n],
            ..Default::default()
        })
    }

    #[test]
    fn animation_frames_are_written_as_png_files_silently() {
        let tmp = tempfile::tempdir().unwrap();
        let files = FileOutputs::new(tmp.path()).unwrap();
        let log = crate::testing::warnings_logged(|| {
            let mut animation = files.animation().unwrap();
            assert!(animation.frame("p_cam0_000", &frame()));
            animation.finish();
        });
        assert_eq!(log, "");
        let written = image::open(tmp.path().join("frames/p_cam0_000.png")).unwrap();
        assert_eq!((written.width(), written.height()), (4, 2));
    }

    #[test]
    fn failed_animation_frames_log_the_first_failure_and_one_summary() {
        let tmp = tempfile::tempdir().unwrap();
        let files = FileOutputs::new(tmp.path()).unwrap();
        // `frames` becomes a regular file: no frame can be written under it.
        std::fs::remove_dir(tmp.path().join("frames")).unwrap();
        std::fs::write(tmp.path().join("frames"), b"x").unwrap();
        let log = crate::testing::warnings_logged(|| {
            let mut animation = files.animation().unwrap();
            for f in 0..3 {
                assert!(!animation.frame(&format!("p_cam0_{f:03}"), &frame()));
            }
            animation.finish();
        });
        assert_eq!(log.matches("frame file: ").count(), 1, "{log}");
        assert!(log.contains("frames/p_cam0_000.png"), "{log}");
        assert_eq!(
            log.matches("3 frame files of 3 could not be written")
                .count(),
            1,
            "{log}"
        );
    }
}
