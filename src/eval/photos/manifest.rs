//! The list of people `lhmpp eval-photos` scores: a JSON manifest (the dev set's is
//! `scripts/devset/photos.json`), or a directory of photos.
//!
//! ```json
//! {
//!   "root": "../../target/devset",
//!   "people": [
//!     { "name": "bus_man", "views": [
//!         { "photo": "ultralytics/bus.jpg", "mask": "hand_masks/bus_man_cream_coat.png" } ] },
//!     { "name": "pose2sim_woman", "views": [
//!         { "photo": "pose2sim/multi_cam1_f030.png", "person": { "box": [470, 780, 990, 1750] } },
//!         { "photo": "pose2sim/multi_cam2_f030.png", "person": "leftmost" } ] }
//!   ]
//! }
//! ```
//!
//! `root` (optional) is relative to the manifest's folder, and photo and mask paths to
//! `root`. A person's views are photos of the same person (ideally the same instant from
//! several cameras): they are reconstructed together into one avatar. `mask` (optional) is a
//! mono8 person mask of the photo's size; `person` (optional) picks the person when several
//! are in the frame ([`PersonHint`]: `"best"`, `"largest"`, `"leftmost"`, `"rightmost"` or
//! `{"box": [x0, y0, x1, y1]}`); without it, the box around the mask when a mask is given,
//! else the detector's best-scoring person.

use crate::reconstruct::photos::PersonHint;
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// Why a manifest or photo directory could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ManifestError {
    /// The file or directory could not be read.
    #[error("reading {path}: {source}")]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// What went wrong.
        source: std::io::Error,
    },
    /// The manifest is not valid JSON of the expected shape.
    #[error("{path}: {source}")]
    Json {
        /// The manifest.
        path: PathBuf,
        /// What is wrong, and where.
        source: serde_json::Error,
    },
    /// The manifest or directory names no photo, or a person without views.
    #[error("{path}: {message}")]
    Empty {
        /// The manifest or directory.
        path: PathBuf,
        /// What is missing.
        message: String,
    },
}

/// People to score.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// Folder the photo and mask paths are relative to (itself relative to the manifest's
    /// folder); absent: the manifest's folder.
    #[serde(default)]
    pub root: Option<PathBuf>,
    /// The people.
    pub people: Vec<ManifestPerson>,
}

/// One person and their photos.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ManifestPerson {
    /// Name in tables.
    pub name: String,
    /// What the person wears, where they are (for readers).
    #[serde(default)]
    pub note: String,
    /// Their photos, reconstructed together.
    pub views: Vec<ManifestView>,
}

/// One photo of a person.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ManifestView {
    /// The photo (JPEG or PNG).
    pub photo: PathBuf,
    /// A person mask of the photo (mono8 PNG, 255 = person), e.g. traced by hand.
    #[serde(default)]
    pub mask: Option<PathBuf>,
    /// Which person, when several are in the frame.
    #[serde(default)]
    pub person: Option<PersonHint>,
    /// A held-out photo: the avatar is made (and recoloured) from the person's other photos
    /// and only held-out photos are scored, so the score says how the avatar looks from a view
    /// it never saw.
    #[serde(default)]
    pub heldout: bool,
}

impl Manifest {
    /// Reads a manifest; paths come back resolved (root joined on).
    pub fn load(path: &Path) -> Result<Self, ManifestError> {
        let text = std::fs::read_to_string(path).map_err(|source| ManifestError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let mut manifest: Manifest =
            serde_json::from_str(&text).map_err(|source| ManifestError::Json {
                path: path.to_path_buf(),
                source,
            })?;
        let base = path.parent().unwrap_or(Path::new("."));
        let root = match &manifest.root {
            Some(r) => base.join(r),
            None => base.to_path_buf(),
        };
        for person in &mut manifest.people {
            if person.views.is_empty() {
                return Err(ManifestError::Empty {
                    path: path.to_path_buf(),
                    message: format!("person `{}` has no views", person.name),
                });
            }
            for view in &mut person.views {
                view.photo = root.join(&view.photo);
                view.mask = view.mask.as_ref().map(|m| root.join(m));
            }
        }
        if manifest.people.is_empty() {
            return Err(ManifestError::Empty {
                path: path.to_path_buf(),
                message: "no people".into(),
            });
        }
        manifest.root = Some(root);
        Ok(manifest)
    }

    /// Every photo (`.jpg`, `.jpeg`, `.png`) of `dir` as a person of its own, named by its
    /// stem, with `<stem>_mask.png` beside it as its mask when there is one (mask files are
    /// not photos).
    pub fn from_dir(dir: &Path) -> Result<Self, ManifestError> {
        let io = |source| ManifestError::Io {
            path: dir.to_path_buf(),
            source,
        };
        let mut photos: Vec<PathBuf> = std::fs::read_dir(dir)
            .map_err(io)?
            .map(|e| e.map(|e| e.path()).map_err(io))
            .collect::<Result<_, _>>()?;
        photos.retain(|p| {
            let ext = p
                .extension()
                .map(|e| e.to_string_lossy().to_ascii_lowercase());
            let stem = p.file_stem().map(|s| s.to_string_lossy().into_owned());
            matches!(ext.as_deref(), Some("jpg" | "jpeg" | "png"))
                && !stem.is_some_and(|s| s.ends_with("_mask"))
        });
        photos.sort();
        if photos.is_empty() {
            return Err(ManifestError::Empty {
                path: dir.to_path_buf(),
                message: "no photos (.jpg, .jpeg, .png)".into(),
            });
        }
        let people = photos
            .into_iter()
            .map(|photo| {
                let stem = photo
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_default();
                let mask = dir.join(format!("{stem}_mask.png"));
                ManifestPerson {
                    name: stem,
                    note: String::new(),
                    views: vec![ManifestView {
                        photo,
                        mask: mask.is_file().then_some(mask),
                        person: None,
                        heldout: false,
                    }],
                }
            })
            .collect();
        Ok(Self {
            root: Some(dir.to_path_buf()),
            people,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn manifests_resolve_paths_and_reject_unknown_keys() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.json");
        std::fs::write(
            &path,
            r#"{"root": "set", "people": [{"name": "a", "views": [
                {"photo": "p/a.png", "mask": "m/a.png"},
                {"photo": "p/b.png", "person": {"box": [1, 2, 3, 4]}}]}]}"#,
        )
        .unwrap();
        let m = Manifest::load(&path).unwrap();
        let root = dir.path().join("set");
        let views = &m.people[0].views;
        assert_eq!(views[0].photo, root.join("p/a.png"));
        assert_eq!(views[0].mask, Some(root.join("m/a.png")));
        assert_eq!(views[1].person, Some(PersonHint::Box([1.0, 2.0, 3.0, 4.0])));

        std::fs::write(
            &path,
            r#"{"people": [{"name": "a", "views": [{"foto": "x"}]}]}"#,
        )
        .unwrap();
        let e = Manifest::load(&path).unwrap_err().to_string();
        assert!(e.contains("foto"), "{e}");
        std::fs::write(&path, r#"{"people": [{"name": "a", "views": []}]}"#).unwrap();
        assert!(matches!(
            Manifest::load(&path),
            Err(ManifestError::Empty { .. })
        ));
    }

    #[test]
    fn a_directory_is_one_person_per_photo_with_masks_beside() {
        let dir = tempfile::tempdir().unwrap();
        for name in ["b.jpg", "a.png", "a_mask.png", "notes.txt"] {
            std::fs::write(dir.path().join(name), b"").unwrap();
        }
        let m = Manifest::from_dir(dir.path()).unwrap();
        let names: Vec<&str> = m.people.iter().map(|p| p.name.as_str()).collect();
        assert_eq!(names, ["a", "b"]);
        assert_eq!(
            m.people[0].views[0].mask,
            Some(dir.path().join("a_mask.png"))
        );
        assert_eq!(m.people[1].views[0].mask, None);
        let empty = tempfile::tempdir().unwrap();
        assert!(Manifest::from_dir(empty.path()).is_err());
    }
}
