//! Measures the shared memory iceoryx2 reserves, from the files it creates in `/dev/shm`.
//!
//! Take a [`ShmSnapshot`] before creating ports and one after; [`ShmSnapshot::growth_since`]
//! sums the files that appeared. `reserved` is their size (what iceoryx2 preallocated),
//! `resident` the pages actually backed by memory so far.

use std::collections::BTreeMap;
use std::os::unix::fs::MetadataExt;
use std::path::Path;

/// Directory where POSIX shared memory objects live on Linux.
pub const SHM_DIR: &str = "/dev/shm";

/// Sizes of the shared-memory files present at one moment.
#[derive(Debug, Clone, Default)]
pub struct ShmSnapshot {
    files: BTreeMap<String, (u64, u64)>,
}

/// Shared memory of the files that appeared between two snapshots.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ShmFootprint {
    /// Files that appeared.
    pub files: usize,
    /// Sum of their sizes in bytes (reserved address space).
    pub reserved: u64,
    /// Sum of their allocated blocks in bytes (memory actually touched).
    pub resident: u64,
}

impl ShmSnapshot {
    /// Lists [`SHM_DIR`]; empty if it cannot be read (not Linux, no tmpfs).
    pub fn take() -> Self {
        Self::take_in(Path::new(SHM_DIR))
    }

    /// Lists `dir`.
    pub fn take_in(dir: &Path) -> Self {
        let mut files = BTreeMap::new();
        if let Ok(entries) = std::fs::read_dir(dir) {
            for entry in entries.flatten() {
                if let Ok(meta) = entry.metadata() {
                    if meta.is_file() {
                        let name = entry.file_name().to_string_lossy().into_owned();
                        files.insert(name, (meta.len(), meta.blocks() * 512));
                    }
                }
            }
        }
        Self { files }
    }

    /// Files present now but not in `before`, summed.
    pub fn growth_since(&self, before: &ShmSnapshot) -> ShmFootprint {
        let mut out = ShmFootprint::default();
        for (name, (len, resident)) in &self.files {
            if !before.files.contains_key(name) {
                out.files += 1;
                out.reserved += len;
                out.resident += resident;
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn growth_counts_only_new_files() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("old"), vec![1u8; 4096]).unwrap();
        let before = ShmSnapshot::take_in(dir.path());
        std::fs::write(dir.path().join("new"), vec![1u8; 8192]).unwrap();
        let growth = ShmSnapshot::take_in(dir.path()).growth_since(&before);
        assert_eq!(growth.files, 1);
        assert_eq!(growth.reserved, 8192);
    }
}
