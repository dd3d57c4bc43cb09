//! Per-person bounded store of input views (sans-io).
//!
//! Each person holds at most `max_views` views. A view whose embedding is nearly identical
//! (cosine similarity above a threshold) to a held view from the same camera is a duplicate:
//! it is dropped, or replaces the older view, by [`DuplicatePolicy`]. When the set is full, a
//! view in which another person's box covered this person's ([`View::hidden`] above the
//! tracker's [`CROWDED_COVER`]) goes first, the most covered one (new view included): its
//! pixels and landmarks mix people. Otherwise the view that is most redundant is evicted so the set stays
//! diverse: of the most similar pair (new view included), the older one goes. Memory is
//! bounded by `max_views` × (the largest preprocessed image the caller inserts + a frame of at
//! most 640 pixels on its long side).
//!
//! Every change of a person's set bumps its `version`, which the scheduler watches.

use crate::reconstruct::photo_colours::ViewEvidence;
use crate::reconstruct::preprocess::Preprocessed;
pub use crate::reconstruct::reconstructor::cosine_similarity;
use crate::tracking::CROWDED_COVER;
use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;

/// One input view of a person.
#[derive(Debug, Clone, PartialEq)]
pub struct View {
    /// Frame id given by the caller (unique per store, increasing with arrival).
    pub frame_id: u64,
    /// Camera (topic) the frame came from.
    pub camera: String,
    /// Message header stamp, nanoseconds since the epoch.
    pub stamp_ns: i64,
    /// Node clock when the frame arrived.
    pub arrival: Duration,
    /// Encoder-ready image.
    pub image: Arc<Preprocessed>,
    /// Small descriptor for similarity (e.g. mean image token or a thumbnail).
    pub embedding: Vec<f32>,
    /// What perception saw of the person in the original frame (`None`: masked by a topic or
    /// whole frames).
    pub evidence: Option<Arc<ViewEvidence>>,
    /// The largest share of the person's box another person's box covered in the frame
    /// (0..1; 0 when one person is followed).
    pub hidden: f32,
}

/// What to do with a near-duplicate of a held view from the same camera.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DuplicatePolicy {
    /// Keep the held view, drop the new one (the set does not change).
    #[default]
    Drop,
    /// Replace the held view by the newer one (the set changes).
    ReplaceOlder,
}

/// Bounds and duplicate handling of the frame store (built from the node's `frame_store.*`).
#[derive(Debug, Clone, PartialEq)]
pub struct StoreLimits {
    /// Most views held per person.
    pub max_views: usize,
    /// Cosine similarity above which two views of one camera are duplicates.
    pub duplicate_similarity: f32,
    /// Duplicate handling.
    pub duplicate_policy: DuplicatePolicy,
}

impl Default for StoreLimits {
    /// The node's defaults (`frame_store.*` of [`crate::config::NodeConfig`]).
    fn default() -> Self {
        Self::from(&crate::config::FrameStoreConfig::default())
    }
}

impl From<&crate::config::FrameStoreConfig> for StoreLimits {
    fn from(c: &crate::config::FrameStoreConfig) -> Self {
        Self {
            max_views: c.max_views,
            duplicate_similarity: c.duplicate_similarity,
            duplicate_policy: DuplicatePolicy::Drop,
        }
    }
}

/// Result of offering a view to the store.
#[derive(Debug, Clone, PartialEq)]
pub enum InsertOutcome {
    /// The view was added; the set had room.
    Added,
    /// The view was added and the held view with this frame id was evicted to make room.
    AddedEvicting {
        /// Evicted frame id.
        evicted: u64,
    },
    /// The view replaced its near-duplicate (`ReplaceOlder`).
    Replaced {
        /// Replaced frame id.
        replaced: u64,
        /// Their cosine similarity.
        similarity: f32,
    },
    /// The set was full and the view's person was more hidden by others than in any held
    /// view: it was dropped.
    DroppedHidden,
    /// The view was a near-duplicate and was dropped (`Drop`), or the eviction chose it.
    Dropped {
        /// Held frame id it duplicated (or was most similar to).
        kept: u64,
        /// Their cosine similarity.
        similarity: f32,
    },
}

impl InsertOutcome {
    /// Whether the person's view set changed.
    pub fn changed(&self) -> bool {
        !matches!(self, Self::Dropped { .. } | Self::DroppedHidden)
    }
}

/// A consistent copy of a person's views (cheap: images are shared).
#[derive(Debug, Clone, PartialEq)]
pub struct ViewSet {
    /// Version of the set this snapshot shows.
    pub version: u64,
    /// Views in arrival order.
    pub views: Vec<View>,
}

impl ViewSet {
    /// Arrival time of the newest view, if any.
    pub fn last_arrival(&self) -> Option<Duration> {
        self.views.iter().map(|v| v.arrival).max()
    }
}

/// One person's views, bounded and diverse: the store's entry for a person, also held on its
/// own by the pipeline's per-person state.
#[derive(Debug, Clone)]
pub struct PersonViews {
    limits: StoreLimits,
    version: u64,
    views: Vec<View>,
}

impl PersonViews {
    /// No views yet. `max_views` is raised to at least 1.
    pub fn new(mut limits: StoreLimits) -> Self {
        limits.max_views = limits.max_views.max(1);
        Self {
            limits,
            version: 0,
            views: Vec::new(),
        }
    }

    /// Offers `view`; returns what happened to it.
    pub fn insert(&mut self, view: View) -> InsertOutcome {
        let cfg = &self.limits;
        // Near-duplicate of a held view from the same camera?
        let dup = self
            .views
            .iter()
            .enumerate()
            .filter(|(_, held)| held.camera == view.camera)
            .map(|(i, held)| (i, cosine_similarity(&held.embedding, &view.embedding)))
            .filter(|(_, s)| *s > cfg.duplicate_similarity)
            .max_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((i, similarity)) = dup {
            return match cfg.duplicate_policy {
                DuplicatePolicy::Drop => InsertOutcome::Dropped {
                    kept: self.views[i].frame_id,
                    similarity,
                },
                DuplicatePolicy::ReplaceOlder => {
                    let replaced = self.views.remove(i).frame_id;
                    self.views.push(view);
                    self.version += 1;
                    InsertOutcome::Replaced {
                        replaced,
                        similarity,
                    }
                }
            };
        }
        if self.views.len() < cfg.max_views {
            self.views.push(view);
            self.version += 1;
            return InsertOutcome::Added;
        }
        // Full. A view where others covered the person goes first, the most covered one (the
        // older of equals): its pixels mix people.
        self.views.push(view);
        let new_index = self.views.len() - 1;
        if let Some((hidden, _)) = self
            .views
            .iter()
            .enumerate()
            .filter(|(_, v)| v.hidden > CROWDED_COVER)
            .max_by(|a, b| {
                a.1.hidden
                    .total_cmp(&b.1.hidden)
                    .then(b.1.frame_id.cmp(&a.1.frame_id))
            })
        {
            if hidden == new_index {
                self.views.pop();
                return InsertOutcome::DroppedHidden;
            }
            let evicted = self.views.remove(hidden).frame_id;
            self.version += 1;
            return InsertOutcome::AddedEvicting { evicted };
        }
        // Then, among held views plus the new one, the most similar pair; its older member goes.
        let (a, b, similarity) = most_similar_pair(&self.views);
        let (older, newer) = if self.views[a].frame_id <= self.views[b].frame_id {
            (a, b)
        } else {
            (b, a)
        };
        if older == new_index {
            // Only when frame ids are out of order: the new view is the redundant one.
            let kept = self.views[newer].frame_id;
            self.views.pop();
            return InsertOutcome::Dropped { kept, similarity };
        }
        let evicted = self.views.remove(older).frame_id;
        self.version += 1;
        InsertOutcome::AddedEvicting { evicted }
    }

    /// Removes the views that came from `camera`; the frame ids removed.
    pub fn remove_camera(&mut self, camera: &str) -> Vec<u64> {
        let (gone, kept): (Vec<View>, Vec<View>) = std::mem::take(&mut self.views)
            .into_iter()
            .partition(|v| v.camera == camera);
        self.views = kept;
        if !gone.is_empty() {
            self.version += 1;
        }
        gone.into_iter().map(|v| v.frame_id).collect()
    }

    /// A snapshot of the views.
    pub fn snapshot(&self) -> ViewSet {
        ViewSet {
            version: self.version,
            views: self.views.clone(),
        }
    }

    /// The views held, in arrival order.
    pub fn views(&self) -> &[View] {
        &self.views
    }

    /// Current version of the set (0 before the first view).
    pub fn version(&self) -> u64 {
        self.version
    }

    /// Number of views held.
    pub fn len(&self) -> usize {
        self.views.len()
    }

    /// Whether no view is held.
    pub fn is_empty(&self) -> bool {
        self.views.is_empty()
    }

    /// Bytes held by images, embeddings and evidence frames.
    pub fn memory_bytes(&self) -> usize {
        self.views
            .iter()
            .map(|v| {
                v.image.byte_size()
                    + v.embedding.len() * std::mem::size_of::<f32>()
                    + v.evidence
                        .as_ref()
                        .map_or(0, |e| e.frame.len() + e.mask.len())
            })
            .sum()
    }
}

/// Views per person, bounded and diverse.
#[derive(Debug)]
pub struct FrameStore {
    cfg: StoreLimits,
    persons: BTreeMap<String, PersonViews>,
}

impl FrameStore {
    /// An empty store. `max_views` is raised to at least 1.
    pub fn new(mut cfg: StoreLimits) -> Self {
        cfg.max_views = cfg.max_views.max(1);
        Self {
            cfg,
            persons: BTreeMap::new(),
        }
    }

    /// The parameters in use.
    pub fn config(&self) -> &StoreLimits {
        &self.cfg
    }

    /// Offers `view` for `person`; returns what happened to it.
    pub fn insert(&mut self, person: &str, view: View) -> InsertOutcome {
        self.persons
            .entry(person.to_owned())
            .or_insert_with(|| PersonViews::new(self.cfg.clone()))
            .insert(view)
    }

    /// A snapshot of the person's views, or `None` if none were ever added.
    pub fn snapshot(&self, person: &str) -> Option<ViewSet> {
        self.persons.get(person).map(PersonViews::snapshot)
    }

    /// Current version of the person's set (0 before the first view).
    pub fn version(&self, person: &str) -> u64 {
        self.persons.get(person).map_or(0, PersonViews::version)
    }

    /// Number of views held for the person.
    pub fn len(&self, person: &str) -> usize {
        self.persons.get(person).map_or(0, PersonViews::len)
    }

    /// Whether no view is held for the person.
    pub fn is_empty(&self, person: &str) -> bool {
        self.len(person) == 0
    }

    /// Persons with at least one view.
    pub fn persons(&self) -> impl Iterator<Item = &str> {
        self.persons.keys().map(String::as_str)
    }

    /// Forgets a person (e.g. when tracking ends); returns whether it was known.
    pub fn remove_person(&mut self, person: &str) -> bool {
        self.persons.remove(person).is_some()
    }

    /// Bytes held by images, embeddings and evidence frames across all persons.
    pub fn memory_bytes(&self) -> usize {
        self.persons.values().map(PersonViews::memory_bytes).sum()
    }
}

/// A default view embedding: the image average-pooled to `grid`×`grid` cells per channel,
/// with the mean removed so that cosine similarity reacts to content rather than brightness.
pub fn thumbnail_embedding(image: &Preprocessed, grid: u32) -> Vec<f32> {
    let grid = grid.max(1);
    let (w, h) = (image.width as usize, image.height as usize);
    let plane = w * h;
    let g = grid as usize;
    let mut sums = vec![0.0f64; 3 * g * g];
    let mut counts = vec![0u32; g * g];
    for y in 0..h {
        let gy = y * g / h.max(1);
        for x in 0..w {
            let gx = x * g / w.max(1);
            let cell = gy * g + gx;
            counts[cell] += 1;
            for c in 0..3 {
                sums[c * g * g + cell] += f64::from(image.chw[c * plane + y * w + x]);
            }
        }
    }
    let mut out: Vec<f32> = sums
        .iter()
        .enumerate()
        .map(|(i, s)| (s / f64::from(counts[i % (g * g)].max(1))) as f32)
        .collect();
    let mean = out.iter().sum::<f32>() / out.len() as f32;
    out.iter_mut().for_each(|v| *v -= mean);
    out
}

/// Indices (i < j) and similarity of the most similar pair of views (needs ≥ 2 views).
fn most_similar_pair(views: &[View]) -> (usize, usize, f32) {
    let mut best = (0, 1, f32::NEG_INFINITY);
    for i in 0..views.len() {
        for j in i + 1..views.len() {
            let s = cosine_similarity(&views[i].embedding, &views[j].embedding);
            if s > best.2 {
                best = (i, j, s);
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image() -> Arc<Preprocessed> {
        Arc::new(Preprocessed {
            height: 2,
            width: 2,
            chw: vec![0.5; 12],
            region: crate::reconstruct::preprocess::BBox {
                x0: 0,
                y0: 0,
                x1: 2,
                y1: 2,
            },
        })
    }

    fn view(id: u64, camera: &str, embedding: Vec<f32>) -> View {
        View {
            frame_id: id,
            camera: camera.into(),
            stamp_ns: id as i64 * 1_000_000,
            arrival: Duration::from_millis(id * 10),
            image: image(),
            embedding,
            evidence: None,
            hidden: 0.0,
        }
    }

    /// Unit vector along axis `k` in `n` dimensions, slightly tilted by `t`.
    fn axis(n: usize, k: usize, t: f32) -> Vec<f32> {
        let mut v = vec![0.0; n];
        v[k] = 1.0;
        v[(k + 1) % n] = t;
        v
    }

    fn store(max_views: usize, policy: DuplicatePolicy) -> FrameStore {
        FrameStore::new(StoreLimits {
            max_views,
            duplicate_similarity: 0.99,
            duplicate_policy: policy,
        })
    }

    #[test]
    fn near_duplicate_from_same_camera_is_dropped() {
        let mut s = store(4, DuplicatePolicy::Drop);
        assert_eq!(
            s.insert("p", view(1, "cam0", axis(8, 0, 0.0))),
            InsertOutcome::Added
        );
        let out = s.insert("p", view(2, "cam0", axis(8, 0, 0.01)));
        assert!(
            matches!(out, InsertOutcome::Dropped { kept: 1, .. }),
            "{out:?}"
        );
        assert!(!out.changed());
        assert_eq!(s.len("p"), 1);
        assert_eq!(s.version("p"), 1);
    }

    #[test]
    fn same_content_from_another_camera_is_kept() {
        let mut s = store(4, DuplicatePolicy::Drop);
        s.insert("p", view(1, "cam0", axis(8, 0, 0.0)));
        assert_eq!(
            s.insert("p", view(2, "cam1", axis(8, 0, 0.0))),
            InsertOutcome::Added
        );
        assert_eq!(s.len("p"), 2);
    }

    #[test]
    fn replace_policy_swaps_in_the_newer_duplicate() {
        let mut s = store(4, DuplicatePolicy::ReplaceOlder);
        s.insert("p", view(1, "cam0", axis(8, 0, 0.0)));
        let out = s.insert("p", view(2, "cam0", axis(8, 0, 0.01)));
        assert!(
            matches!(out, InsertOutcome::Replaced { replaced: 1, .. }),
            "{out:?}"
        );
        let snap = s.snapshot("p").unwrap();
        assert_eq!(snap.views.len(), 1);
        assert_eq!(snap.views[0].frame_id, 2);
        assert_eq!(snap.version, 2);
    }

    #[test]
    fn full_store_evicts_the_older_of_the_most_similar_pair() {
        let mut s = store(3, DuplicatePolicy::Drop);
        // Three distinct directions, then a fourth close (but not a duplicate) to view 1.
        s.insert("p", view(1, "a", axis(8, 0, 0.0)));
        s.insert("p", view(2, "b", axis(8, 2, 0.0)));
        s.insert("p", view(3, "c", axis(8, 4, 0.0)));
        let out = s.insert("p", view(4, "d", axis(8, 0, 0.5)));
        assert_eq!(out, InsertOutcome::AddedEvicting { evicted: 1 });
        let ids: Vec<u64> = s
            .snapshot("p")
            .unwrap()
            .views
            .iter()
            .map(|v| v.frame_id)
            .collect();
        assert_eq!(ids, vec![2, 3, 4]);
        assert_eq!(s.version("p"), 4);
    }

    #[test]
    fn a_view_where_others_cover_the_person_leaves_a_full_set_first() {
        let hidden = |id, camera, embedding, hidden| View {
            hidden,
            ..view(id, camera, embedding)
        };
        let ids = |s: &FrameStore| -> Vec<u64> {
            s.snapshot("p")
                .unwrap()
                .views
                .iter()
                .map(|v| v.frame_id)
                .collect()
        };
        let mut s = store(3, DuplicatePolicy::Drop);
        s.insert("p", view(1, "a", axis(8, 0, 0.0)));
        s.insert("p", hidden(2, "b", axis(8, 2, 0.0), 0.6));
        s.insert("p", view(3, "c", axis(8, 4, 0.0)));
        // A clear view close to view 1: the half-hidden view 2 goes, not the older of 1 and 4.
        let out = s.insert("p", view(4, "d", axis(8, 0, 0.5)));
        assert_eq!(out, InsertOutcome::AddedEvicting { evicted: 2 });
        // A new view more hidden than every held one is dropped; the set does not change.
        let out = s.insert("p", hidden(5, "e", axis(8, 6, 0.0), 0.3));
        assert_eq!(out, InsertOutcome::DroppedHidden);
        assert!(!out.changed());
        assert_eq!(ids(&s), vec![1, 3, 4]);
        // A barely touched box counts as clear.
        let out = s.insert("p", hidden(6, "f", axis(8, 6, 0.0), 0.1));
        assert_eq!(out, InsertOutcome::AddedEvicting { evicted: 1 });
    }

    #[test]
    fn persons_are_independent() {
        let mut s = store(2, DuplicatePolicy::Drop);
        s.insert("alice", view(1, "a", axis(4, 0, 0.0)));
        s.insert("bob", view(2, "a", axis(4, 0, 0.0)));
        assert_eq!((s.len("alice"), s.len("bob")), (1, 1));
        assert!(s.remove_person("alice"));
        assert!(s.is_empty("alice"));
        assert_eq!(s.persons().collect::<Vec<_>>(), vec!["bob"]);
    }

    #[test]
    fn cosine_handles_degenerate_inputs() {
        assert_eq!(cosine_similarity(&[0.0, 0.0], &[1.0, 0.0]), 0.0);
        assert_eq!(cosine_similarity(&[1.0], &[1.0, 0.0]), 0.0);
        assert!((cosine_similarity(&[1.0, 1.0], &[2.0, 2.0]) - 1.0).abs() < 1e-6);
    }
}
