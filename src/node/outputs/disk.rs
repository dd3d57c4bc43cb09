//! The file output's ledger of what it holds on disk: every file the node wrote under
//! `outputs.dir` (and those an earlier run left there), oldest first, with the bytes written and
//! removed so far. While the whole is over `outputs.max_disk_mb` it removes the oldest frames
//! and numbered revisions first, then the oldest latest avatars, never the files just written.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

/// What the file output wrote and removed so far, and what it holds now.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct DiskUsage {
    /// Files written (each avatar revision's files, animation frames).
    pub written_files: u64,
    /// Bytes written.
    pub written_bytes: u64,
    /// Files removed to keep within `outputs.keep_revisions` and `outputs.max_disk_mb`.
    pub removed_files: u64,
    /// Bytes removed.
    pub removed_bytes: u64,
    /// The node's files under `outputs.dir` now (those of earlier runs included).
    pub held_files: u64,
    /// Their bytes.
    pub held_bytes: u64,
}

impl std::fmt::Display for DiskUsage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "written {} files ({}), removed {} files ({}), held {} files ({})",
            self.written_files,
            megabytes(self.written_bytes),
            self.removed_files,
            megabytes(self.removed_bytes),
            self.held_files,
            megabytes(self.held_bytes),
        )
    }
}

/// `bytes` as megabytes (10⁶ bytes) for people to read.
pub fn megabytes(bytes: u64) -> String {
    format!("{:.1} MB", bytes as f64 / 1e6)
}

/// What a file is to the cap: a person's latest avatar goes only after every other file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum FileKind {
    /// A frame or a numbered revision.
    Other,
    /// A person's latest avatar (`avatar_<person>.ply`).
    Latest,
}

/// Where a file stands in the removal order: its kind, then when it was written.
type Place = (FileKind, u64);

/// The files held, oldest first.
#[derive(Debug, Default)]
pub struct DiskLedger {
    /// Cap on the bytes held (`None`: no cap).
    max_bytes: Option<u64>,
    /// Removal order → file.
    order: BTreeMap<Place, PathBuf>,
    /// File → (removal order, bytes).
    files: HashMap<PathBuf, (Place, u64)>,
    next: u64,
    usage: DiskUsage,
    /// Whether the "cap cannot be met" warning was logged.
    over_cap_noted: bool,
}

impl DiskLedger {
    /// An empty ledger capped at `max_bytes`.
    pub fn new(max_bytes: Option<u64>) -> Self {
        Self {
            max_bytes,
            ..Self::default()
        }
    }

    /// Takes in files an earlier run left (oldest first by modification time), so that a
    /// restarted node stays within the cap too; they count as held, not as written.
    pub fn adopt(&mut self, mut found: Vec<(PathBuf, FileKind, u64, std::time::SystemTime)>) {
        found.sort_by(|a, b| a.3.cmp(&b.3).then_with(|| a.0.cmp(&b.0)));
        for (path, kind, bytes, _) in found {
            self.insert(path, kind, bytes);
        }
    }

    /// A file of `kind` was written (or replaced) with `bytes`: it becomes the newest.
    pub fn wrote(&mut self, path: &Path, kind: FileKind, bytes: u64) {
        self.usage.written_files += 1;
        self.usage.written_bytes += bytes;
        self.insert(path.to_path_buf(), kind, bytes);
    }

    /// Removes `path` from disk and the ledger (counted as removed); whether it was held.
    pub fn remove(&mut self, path: &Path) -> bool {
        let Some((place, bytes)) = self.files.remove(path) else {
            return false;
        };
        self.order.remove(&place);
        self.usage.held_files -= 1;
        self.usage.held_bytes -= bytes;
        match std::fs::remove_file(path) {
            Ok(()) => {
                self.usage.removed_files += 1;
                self.usage.removed_bytes += bytes;
                tracing::debug!(path = %path.display(), bytes, "output file removed");
            }
            // Removed by someone else: no longer held, not removed by us.
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => tracing::warn!("removing {}: {e}", path.display()),
        }
        true
    }

    /// Removes the oldest files while more than the cap is held (frames and numbered
    /// revisions before latest avatars), never one of `keep` (the files just written); returns
    /// the files removed. Logs once when the cap cannot be met.
    pub fn enforce(&mut self, keep: &[&Path]) -> Vec<PathBuf> {
        let Some(max) = self.max_bytes else {
            return Vec::new();
        };
        let mut removed = Vec::new();
        while self.usage.held_bytes > max {
            let oldest = self
                .order
                .values()
                .find(|p| !keep.contains(&p.as_path()))
                .cloned();
            let Some(oldest) = oldest else {
                if !self.over_cap_noted {
                    self.over_cap_noted = true;
                    tracing::warn!(
                        "outputs.max_disk_mb: the newest files alone ({}) are over the cap ({}); \
                         they are kept",
                        megabytes(self.usage.held_bytes),
                        megabytes(max)
                    );
                }
                break;
            };
            self.remove(&oldest);
            removed.push(oldest);
        }
        removed
    }

    /// What was written and removed so far, and what is held.
    pub fn usage(&self) -> DiskUsage {
        self.usage
    }

    fn insert(&mut self, path: PathBuf, kind: FileKind, bytes: u64) {
        if let Some((place, old)) = self.files.remove(&path) {
            self.order.remove(&place);
            self.usage.held_files -= 1;
            self.usage.held_bytes -= old;
        }
        let place = (kind, self.next);
        self.next += 1;
        self.order.insert(place, path.clone());
        self.files.insert(path, (place, bytes));
        self.usage.held_files += 1;
        self.usage.held_bytes += bytes;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(dir: &Path, name: &str, bytes: usize) -> PathBuf {
        let path = dir.join(name);
        std::fs::write(&path, vec![7u8; bytes]).unwrap();
        path
    }

    #[test]
    fn the_oldest_files_go_first_and_the_newest_is_never_removed() {
        let tmp = tempfile::tempdir().unwrap();
        let mut ledger = DiskLedger::new(Some(250));
        let mut paths = Vec::new();
        for i in 0..5 {
            let p = file(tmp.path(), &format!("f{i}"), 100);
            ledger.wrote(&p, FileKind::Other, 100);
            ledger.enforce(&[&p]);
            paths.push(p);
        }
        let kept: Vec<bool> = paths.iter().map(|p| p.exists()).collect();
        assert_eq!(kept, [false, false, false, true, true]);
        let u = ledger.usage();
        assert_eq!((u.written_files, u.written_bytes), (5, 500));
        assert_eq!((u.removed_files, u.removed_bytes), (3, 300));
        assert_eq!((u.held_files, u.held_bytes), (2, 200));
        // A file alone over the cap is kept (and said once).
        let big = file(tmp.path(), "big", 400);
        ledger.wrote(&big, FileKind::Other, 400);
        ledger.enforce(&[&big]);
        assert!(big.exists());
        assert_eq!(ledger.usage().held_files, 1);
    }

    #[test]
    fn a_replaced_file_is_held_once_at_its_new_size() {
        let tmp = tempfile::tempdir().unwrap();
        let mut ledger = DiskLedger::new(None);
        let p = file(tmp.path(), "latest", 10);
        ledger.wrote(&p, FileKind::Latest, 10);
        ledger.wrote(&p, FileKind::Latest, 30);
        let u = ledger.usage();
        assert_eq!((u.held_files, u.held_bytes), (1, 30));
        assert_eq!((u.written_files, u.removed_files), (2, 0));
    }

    #[test]
    fn files_of_an_earlier_run_count_oldest_first() {
        let tmp = tempfile::tempdir().unwrap();
        let old = file(tmp.path(), "old", 100);
        let older = file(tmp.path(), "older", 100);
        let t = std::time::SystemTime::UNIX_EPOCH;
        let mut ledger = DiskLedger::new(Some(150));
        ledger.adopt(vec![
            (
                old.clone(),
                FileKind::Other,
                100,
                t + std::time::Duration::from_secs(2),
            ),
            (
                older.clone(),
                FileKind::Other,
                100,
                t + std::time::Duration::from_secs(1),
            ),
        ]);
        assert_eq!(ledger.usage().written_files, 0);
        let new = file(tmp.path(), "new", 50);
        ledger.wrote(&new, FileKind::Other, 50);
        ledger.enforce(&[&new]);
        assert!(!older.exists() && old.exists() && new.exists());
        assert_eq!(ledger.usage().held_bytes, 150);
    }

    #[test]
    fn latest_avatars_go_only_after_every_other_file() {
        let tmp = tempfile::tempdir().unwrap();
        let mut ledger = DiskLedger::new(Some(300));
        let latest = file(tmp.path(), "avatar_p.ply", 100);
        ledger.wrote(&latest, FileKind::Latest, 100);
        let frames: Vec<PathBuf> = (0..4)
            .map(|i| {
                let f = file(tmp.path(), &format!("frame{i}.png"), 100);
                ledger.wrote(&f, FileKind::Other, 100);
                ledger.enforce(&[&f]);
                f
            })
            .collect();
        assert!(
            latest.exists(),
            "the older latest avatar outlives newer frames"
        );
        assert_eq!(
            frames.iter().map(|f| f.exists()).collect::<Vec<_>>(),
            [false, false, true, true]
        );
        let big = file(tmp.path(), "frame_big.png", 250);
        ledger.wrote(&big, FileKind::Other, 250);
        ledger.enforce(&[&big]);
        assert!(!latest.exists() && big.exists(), "then the latest goes too");
    }
}
