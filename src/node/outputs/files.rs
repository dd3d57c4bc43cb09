//! The file output: [`FileOutputs`] writes each person's latest avatar as a PLY file (and, with
//! `outputs.keep_revisions`, their last revisions beside it) and the end-of-replay animation as
//! PNG frames under the output directory (`outputs.dir`), within `outputs.max_disk_mb`
//! ([`DiskLedger`]: the oldest files go first).

use super::disk::{DiskLedger, DiskUsage, FileKind};
use super::{Animation, AvatarUpdate, OutputError, Publisher};
use crate::avatar::Avatar;
use crate::msgs::ReconstructionStatus;
use crate::node::pipeline::RenderedFrame;
use crate::splat::write_ply;
use image::RgbImage;
use std::collections::{BTreeMap, VecDeque};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// How much the file output keeps (`outputs.keep_revisions`, `outputs.max_disk_mb`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Retention {
    /// Numbered revision files (`avatar_<person>_rev<N>.ply`) kept per person besides the
    /// latest (`avatar_<person>.ply`); 0 writes none.
    pub keep_revisions: usize,
    /// Cap on the bytes of every file the node writes under the directory (`None`: no cap).
    pub max_bytes: Option<u64>,
}

impl Retention {
    /// Every revision kept and no cap (for tests and tools that want every file).
    pub const EVERYTHING: Self = Self {
        keep_revisions: usize::MAX,
        max_bytes: None,
    };

    /// From the node config's `outputs.keep_revisions` and `outputs.max_disk_mb` (0: no cap).
    pub fn from_config(outputs: &crate::config::OutputConfig) -> Self {
        Self {
            keep_revisions: outputs.keep_revisions as usize,
            max_bytes: (outputs.max_disk_mb > 0.0).then_some((outputs.max_disk_mb * 1e6) as u64),
        }
    }
}

/// What the files hold now: the ledger, and each person's numbered revision files of this run,
/// oldest first.
#[derive(Debug, Default)]
struct Held {
    ledger: DiskLedger,
    revisions: BTreeMap<String, VecDeque<PathBuf>>,
}

/// Writes avatars and frames under one directory (`out/` by default).
#[derive(Debug)]
pub struct FileOutputs {
    dir: PathBuf,
    retention: Retention,
    held: Mutex<Held>,
    /// The checkpoint kind when its Gaussian RGB is not display-ready (PLY colours warn).
    latent_rgb: Option<String>,
    /// Set once the latent-RGB warning was logged.
    warned: std::sync::OnceLock<()>,
}

impl FileOutputs {
    /// Creates `dir` and `dir/frames` and checks that a file can be written there (a probe
    /// file is created and removed), so that a read-only or unusable directory is found at
    /// startup rather than at the first avatar. The avatar PLY and frame PNG files an earlier
    /// run left there count towards `retention.max_bytes` (the oldest go first).
    pub fn new(dir: &Path, retention: Retention) -> Result<Self, OutputError> {
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
        let mut ledger = DiskLedger::new(retention.max_bytes);
        ledger.adopt(earlier_files(dir));
        let adopted = ledger.usage();
        if adopted.held_files > 0 {
            tracing::info!(
                "outputs.dir `{}` holds {} avatar/frame files ({}) from earlier runs: they count \
                 towards outputs.max_disk_mb",
                dir.display(),
                adopted.held_files,
                super::disk::megabytes(adopted.held_bytes)
            );
        }
        ledger.enforce(&[]);
        Ok(Self {
            dir: dir.to_path_buf(),
            retention,
            held: Mutex::new(Held {
                ledger,
                revisions: BTreeMap::new(),
            }),
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

    /// What was written and removed so far, and what is held.
    pub fn usage(&self) -> DiskUsage {
        self.held().ledger.usage()
    }

    fn held(&self) -> std::sync::MutexGuard<'_, Held> {
        self.held
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Writes `avatar_<person>.ply` (the latest, replaced in one rename so that a reader never
    /// sees a partial file) and, with `keep_revisions` > 0, `avatar_<person>_rev<N>.ply`,
    /// removing that person's numbered files beyond the last `keep_revisions` and the oldest
    /// files over the cap; returns the latest's path.
    pub fn write_avatar(
        &self,
        person: &str,
        revision: u64,
        avatar: &Avatar,
    ) -> Result<PathBuf, OutputError> {
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
        let latest = self.dir.join(format!("avatar_{person}.ply"));
        let partial = self.dir.join(format!(".avatar_{person}.ply.partial"));
        let versioned = (self.retention.keep_revisions > 0)
            .then(|| self.dir.join(format!("avatar_{person}_rev{revision}.ply")));
        // The numbered file is written first and copied; without one, the PLY goes straight
        // into the partial file.
        let first = versioned.as_ref().unwrap_or(&partial);
        let written = write_ply(
            first,
            &avatar.canonical,
            Some(&avatar.skin),
            Some(&avatar.body_model),
        );
        if let Err(e) = written {
            // No partial avatar is left behind (a full disk cuts the file short).
            let _ = std::fs::remove_file(first);
            return Err(e.into());
        }
        let bytes = file_size(first);
        let mut held = self.held();
        if let Some(versioned) = &versioned {
            held.ledger.wrote(versioned, FileKind::Other, bytes);
            let list = held.revisions.entry(person.to_owned()).or_default();
            list.retain(|p| p != versioned);
            list.push_back(versioned.clone());
            let surplus = list.len().saturating_sub(self.retention.keep_revisions);
            let old: Vec<PathBuf> = list.drain(..surplus).collect();
            for path in old {
                held.ledger.remove(&path);
            }
        }
        let replaced = match &versioned {
            Some(v) => std::fs::copy(v, &partial).map(|_| ()),
            None => Ok(()),
        }
        .and_then(|()| std::fs::rename(&partial, &latest));
        if let Err(e) = replaced {
            let _ = std::fs::remove_file(&partial);
            return Err(OutputError::File {
                path: latest,
                message: e.to_string(),
            });
        }
        held.ledger.wrote(&latest, FileKind::Latest, bytes);
        let keep: Vec<&Path> = [Some(latest.as_path()), versioned.as_deref()]
            .into_iter()
            .flatten()
            .collect();
        let removed = held.ledger.enforce(&keep);
        forget_revisions(&mut held.revisions, &removed);
        Ok(latest)
    }

    /// Writes `frames/<name>.png` (removed again if it could not be written whole), removing
    /// the oldest files over the cap.
    pub fn write_frame(&self, name: &str, image: &RgbImage) -> Result<PathBuf, OutputError> {
        let path = self.dir.join("frames").join(format!("{name}.png"));
        image.save(&path).map_err(|e| {
            let _ = std::fs::remove_file(&path);
            OutputError::File {
                path: path.clone(),
                message: e.to_string(),
            }
        })?;
        let mut held = self.held();
        held.ledger.wrote(&path, FileKind::Other, file_size(&path));
        let removed = held.ledger.enforce(&[&path]);
        forget_revisions(&mut held.revisions, &removed);
        Ok(path)
    }
}

/// Drops files the cap removed from the persons' revision lists (and persons left without).
fn forget_revisions(revisions: &mut BTreeMap<String, VecDeque<PathBuf>>, removed: &[PathBuf]) {
    if removed.is_empty() {
        return;
    }
    revisions.retain(|_, list| {
        list.retain(|p| !removed.contains(p));
        !list.is_empty()
    });
}

fn file_size(path: &Path) -> u64 {
    std::fs::metadata(path).map_or(0, |m| m.len())
}

/// The files the node writes that are already in `dir`: `avatar_*.ply` (numbered revisions
/// `avatar_*_rev<N>.ply`, the rest latest avatars) and `frames/*.png`, with their sizes and
/// modification times.
fn earlier_files(dir: &Path) -> Vec<(PathBuf, FileKind, u64, std::time::SystemTime)> {
    let list = |d: &Path, ours: &dyn Fn(&str) -> bool| -> Vec<_> {
        let Ok(entries) = std::fs::read_dir(d) else {
            return Vec::new();
        };
        entries
            .filter_map(Result::ok)
            .filter(|e| e.file_name().to_str().is_some_and(ours))
            .filter_map(|e| {
                let meta = e.metadata().ok().filter(std::fs::Metadata::is_file)?;
                let modified = meta.modified().unwrap_or(std::time::UNIX_EPOCH);
                let name = e.file_name().to_string_lossy().into_owned();
                Some((e.path(), kind_of(&name), meta.len(), modified))
            })
            .collect()
    };
    let mut found = list(dir, &|n| n.starts_with("avatar_") && n.ends_with(".ply"));
    found.extend(list(&dir.join("frames"), &|n| n.ends_with(".png")));
    found
}

/// A file name's kind: `avatar_<person>.ply` is a latest avatar unless it ends in
/// `_rev<digits>.ply`; frames are others.
fn kind_of(name: &str) -> FileKind {
    let Some(stem) = name
        .strip_prefix("avatar_")
        .and_then(|n| n.strip_suffix(".ply"))
    else {
        return FileKind::Other;
    };
    let numbered = stem
        .rsplit_once("_rev")
        .is_some_and(|(_, n)| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()));
    if numbered {
        FileKind::Other
    } else {
        FileKind::Latest
    }
}

/// Stores avatars and animation frames; takes no live stream (statuses, rendered frames,
/// previews).
impl Publisher for FileOutputs {
    /// Writes the avatar's PLY files ([`FileOutputs::write_avatar`]) and logs the path.
    fn avatar(&self, u: &AvatarUpdate<'_>) {
        match self.write_avatar(u.person, u.revision, u.avatar) {
            Ok(path) => tracing::info!("wrote {} (outputs: {})", path.display(), self.usage()),
            Err(e) => tracing::error!("avatar file: {e}"),
        }
    }
    fn status(&self, _msg: ReconstructionStatus) {}
    fn frame(&self, _: &str, _camera: usize, _frame: &RenderedFrame, _stamp_ns: i64) {}
    fn live(&self) -> bool {
        false
    }
    fn disk_usage(&self) -> Option<DiskUsage> {
        Some(self.usage())
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
        if self.written > 0 {
            tracing::info!(
                "wrote {} frame files (outputs: {})",
                self.written,
                self.files.usage()
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::SkinWeights;
    use crate::splat::Gaussians;
    use crate::testing::bytes_under;
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
        let files = FileOutputs::new(tmp.path(), Retention::EVERYTHING)
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
        let files = FileOutputs::new(tmp.path(), Retention::EVERYTHING).unwrap();
        let log = crate::testing::warnings_logged(|| {
            files.write_avatar("p", 1, &avatar()).unwrap();
        });
        assert_eq!(log, "");
        assert!(tmp.path().join("avatar_p.ply").exists());
    }

    /// An avatar of `n` Gaussians.
    fn avatar_of(n: usize) -> Avatar {
        let g = Gaussians::from_rgb(
            (0..n)
                .map(|i| Vec3::new(i as f32 * 0.01, 0.0, 0.0))
                .collect(),
            vec![Vec3::splat(0.01); n],
            vec![Quat::IDENTITY; n],
            vec![1.0; n],
            &vec![Vec3::new(0.2, 0.4, 0.6); n],
        )
        .unwrap();
        let skin = SkinWeights {
            bones: vec![[0; 4]; n],
            weights: vec![[1.0, 0.0, 0.0, 0.0]; n],
        };
        Avatar::new(g, skin, "test-body").unwrap()
    }

    /// The numbered revision files of `person` in `dir`, by revision.
    fn revisions_of(dir: &Path, person: &str) -> Vec<u64> {
        let prefix = format!("avatar_{person}_rev");
        let mut revs: Vec<u64> = std::fs::read_dir(dir)
            .unwrap()
            .filter_map(|e| {
                let name = e.unwrap().file_name().into_string().unwrap();
                name.strip_prefix(&prefix)?
                    .strip_suffix(".ply")?
                    .parse()
                    .ok()
            })
            .collect();
        revs.sort_unstable();
        revs
    }

    /// A long run: 3 persons × 150 revisions with `keep_revisions: 3` keep exactly the last 3
    /// numbered files per person beside the latest, and nothing more; a reader polling the
    /// latest file all along always reads a whole PLY of the newest size.
    #[test]
    fn a_long_run_keeps_the_last_revisions_and_the_latest_is_always_whole() {
        let tmp = tempfile::tempdir().unwrap();
        let keep = 3;
        let files = FileOutputs::new(
            tmp.path(),
            Retention {
                keep_revisions: keep,
                max_bytes: None,
            },
        )
        .unwrap();
        let persons = ["p0", "p1", "p2"];
        // The avatars grow with the revision: a torn file would read short.
        let latest = tmp.path().join("avatar_p0.ply");
        let stop = std::sync::atomic::AtomicBool::new(false);
        let reads = std::thread::scope(|s| {
            let reader = s.spawn(|| {
                let mut reads = 0;
                while !stop.load(std::sync::atomic::Ordering::SeqCst) {
                    if latest.exists() {
                        let ply = crate::splat::read_ply(&latest).expect("a whole PLY");
                        assert!(ply.gaussians.len() >= 10);
                        reads += 1;
                    }
                }
                reads
            });
            for revision in 1..=150u64 {
                for p in persons {
                    files
                        .write_avatar(p, revision, &avatar_of(10 + revision as usize))
                        .unwrap();
                    let revs = revisions_of(tmp.path(), p);
                    let first = revision.saturating_sub(keep as u64 - 1).max(1);
                    assert_eq!(revs, (first..=revision).collect::<Vec<_>>(), "{p}");
                }
            }
            stop.store(true, std::sync::atomic::Ordering::SeqCst);
            reader.join().unwrap()
        });
        assert!(reads > 0, "the reader never read the latest file");
        for p in persons {
            let ply = crate::splat::read_ply(&tmp.path().join(format!("avatar_{p}.ply"))).unwrap();
            assert_eq!(ply.gaussians.len(), 160, "{p}: the latest is the newest");
        }
        // 4 files per person: the latest and 3 numbered ones.
        let u = files.usage();
        assert_eq!(u.held_files, 12);
        assert_eq!(u.held_bytes, bytes_under(tmp.path()));
        assert_eq!(u.written_files, 2 * 450);
        assert_eq!(u.removed_files, 3 * 147);
    }

    /// The default (latest only) under a cap smaller than the avatars written: no numbered
    /// files, the directory stays under the cap however many revisions come, frames included,
    /// and every file left reads back whole.
    #[test]
    fn the_latest_only_stays_under_the_cap_with_frames_counted() {
        let tmp = tempfile::tempdir().unwrap();
        let size = {
            let probe = tempfile::tempdir().unwrap();
            let f = FileOutputs::new(probe.path(), Retention::default()).unwrap();
            let path = f.write_avatar("x", 1, &avatar_of(100)).unwrap();
            std::fs::metadata(path).unwrap().len()
        };
        // Room for 5 avatars: 8 persons' latest files and the frames do not fit.
        let cap = 5 * size + size / 2;
        let files = FileOutputs::new(
            tmp.path(),
            Retention {
                keep_revisions: 0,
                max_bytes: Some(cap),
            },
        )
        .unwrap();
        for revision in 1..=40u64 {
            let person = format!("p{}", revision % 8);
            files
                .write_avatar(&person, revision, &avatar_of(100))
                .unwrap();
            assert!(bytes_under(tmp.path()) <= cap, "revision {revision}");
            assert!(revisions_of(tmp.path(), &person).is_empty());
        }
        let mut animation = files.animation().unwrap();
        for f in 0..50 {
            assert!(animation.frame(&format!("p0_cam0_{f:03}"), &frame()));
            assert!(bytes_under(tmp.path()) <= cap, "frame {f}");
        }
        animation.finish();
        // The newest latest avatar stays.
        assert!(tmp.path().join("avatar_p0.ply").exists());
        let u = files.usage();
        assert_eq!(u.held_bytes, bytes_under(tmp.path()));
        assert_eq!(u.written_files, 90);
        assert!(u.removed_files > 0);
        for entry in std::fs::read_dir(tmp.path()).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "ply") {
                crate::splat::read_ply(&path).unwrap();
            }
        }
    }

    /// A restarted node counts the files its earlier run left towards the cap.
    #[test]
    fn files_of_an_earlier_run_count_towards_the_cap() {
        let tmp = tempfile::tempdir().unwrap();
        let everything = FileOutputs::new(tmp.path(), Retention::EVERYTHING).unwrap();
        for revision in 1..=6 {
            everything
                .write_avatar("old", revision, &avatar_of(100))
                .unwrap();
        }
        let size = std::fs::metadata(tmp.path().join("avatar_old.ply"))
            .unwrap()
            .len();
        let restarted = FileOutputs::new(
            tmp.path(),
            Retention {
                keep_revisions: 0,
                max_bytes: Some(3 * size),
            },
        )
        .unwrap();
        assert!(bytes_under(tmp.path()) <= 3 * size);
        restarted.write_avatar("new", 1, &avatar_of(100)).unwrap();
        assert!(bytes_under(tmp.path()) <= 3 * size);
        // The numbered files went first, the earlier run's latest avatar last.
        assert!(tmp.path().join("avatar_old.ply").exists());
        assert!(tmp.path().join("avatar_new.ply").exists());
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
        let files = FileOutputs::new(tmp.path(), Retention::EVERYTHING).unwrap();
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
        let files = FileOutputs::new(tmp.path(), Retention::EVERYTHING).unwrap();
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
