//! Per-view token cache: adding or dropping a view encodes only the new image.
//!
//! Keyed by frame id, bounded by a capacity with least-recently-used eviction.

use std::collections::{HashMap, VecDeque};

use candle_core::{Result, Tensor};

use super::lhmpp::{Lhmpp, ViewTokens};

/// Bounded LRU cache of [`ViewTokens`] by frame id.
#[derive(Debug)]
pub struct ViewTokenCache {
    capacity: usize,
    entries: HashMap<u64, ViewTokens>,
    recency: VecDeque<u64>,
    encodes: usize,
}

impl ViewTokenCache {
    /// An empty cache holding at most `capacity` views (at least 1).
    pub fn new(capacity: usize) -> Self {
        Self {
            capacity: capacity.max(1),
            entries: HashMap::new(),
            recency: VecDeque::new(),
            encodes: 0,
        }
    }

    /// Tokens of `frame_id`, encoding `image [3, H, W]` only when not cached.
    pub fn get_or_encode(
        &mut self,
        model: &Lhmpp,
        frame_id: u64,
        image: &Tensor,
    ) -> Result<ViewTokens> {
        if let Some(t) = self.entries.get(&frame_id).cloned() {
            self.touch(frame_id);
            return Ok(t);
        }
        let tokens = model.encode_view(image)?;
        self.encodes += 1;
        self.insert(frame_id, tokens.clone());
        Ok(tokens)
    }

    /// Inserts (or replaces) the tokens of `frame_id`, evicting the least recently used view
    /// when full.
    pub fn insert(&mut self, frame_id: u64, tokens: ViewTokens) {
        if self.entries.insert(frame_id, tokens).is_none() {
            while self.entries.len() > self.capacity {
                if let Some(old) = self.recency.pop_front() {
                    self.entries.remove(&old);
                } else {
                    break;
                }
            }
        }
        self.touch(frame_id);
    }

    /// Drops one view; returns whether it was cached.
    pub fn remove(&mut self, frame_id: u64) -> bool {
        self.recency.retain(|&id| id != frame_id);
        self.entries.remove(&frame_id).is_some()
    }

    /// Tokens of the given frames in that order (`None` if any is missing).
    pub fn views(&self, frame_ids: &[u64]) -> Option<Vec<ViewTokens>> {
        frame_ids
            .iter()
            .map(|id| self.entries.get(id).cloned())
            .collect()
    }

    /// Whether `frame_id` is cached.
    pub fn contains(&self, frame_id: u64) -> bool {
        self.entries.contains_key(&frame_id)
    }

    /// Number of cached views.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether the cache is empty.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// How many images this cache has encoded so far.
    pub fn encode_count(&self) -> usize {
        self.encodes
    }

    fn touch(&mut self, frame_id: u64) {
        self.recency.retain(|&id| id != frame_id);
        self.recency.push_back(frame_id);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::checkpoint::seeded_var_builder;
    use crate::model::LhmppConfig;
    use crate::testing::max_abs_diff as max_diff;
    use candle_core::{DType, Device};

    #[test]
    fn adding_a_view_encodes_only_the_new_image_and_matches_a_full_recompute() {
        let dev = Device::Cpu;
        let model = Lhmpp::new(
            &LhmppConfig::tiny(),
            seeded_var_builder(4, DType::F32, &dev),
        )
        .unwrap();
        let images: Vec<Tensor> = (0..3)
            .map(|_| Tensor::rand(0f32, 1.0, (3, 112, 112), &dev).unwrap())
            .collect();
        let mut cache = ViewTokenCache::new(8);
        for (i, img) in images.iter().take(2).enumerate() {
            cache.get_or_encode(&model, i as u64, img).unwrap();
        }
        assert_eq!(cache.encode_count(), 2);
        for (i, img) in images.iter().enumerate() {
            cache.get_or_encode(&model, i as u64, img).unwrap();
        }
        assert_eq!(cache.encode_count(), 3, "only the new view is encoded");
        let cached = cache.views(&[0, 1, 2]).unwrap();
        let tokens_inc = model.image_tokens(&cached).unwrap();
        let fresh: Vec<ViewTokens> = images
            .iter()
            .map(|i| model.encode_view(i).unwrap())
            .collect();
        let tokens_full = model.image_tokens(&fresh).unwrap();
        assert!(max_diff(&tokens_inc, &tokens_full) < 1e-5);
        assert!(
            max_diff(
                &model.conditioning(&cached).unwrap(),
                &model.conditioning(&fresh).unwrap()
            ) < 1e-5
        );
        assert!(cache.remove(1));
        assert_eq!(cache.views(&[0, 2]).unwrap().len(), 2);
        assert!(cache.views(&[1]).is_none());
    }

    #[test]
    fn least_recently_used_view_is_evicted_first() {
        let dev = Device::Cpu;
        let t = ViewTokens {
            patch_tokens: Tensor::zeros((1, 1), DType::F32, &dev).unwrap(),
            cls: Tensor::zeros(1, DType::F32, &dev).unwrap(),
            grid: (1, 1),
        };
        let mut cache = ViewTokenCache::new(2);
        cache.insert(1, t.clone());
        cache.insert(2, t.clone());
        assert!(cache.views(&[1]).is_some());
        cache.insert(1, t.clone()); // touch 1: 2 is now the oldest
        cache.insert(3, t);
        assert!(cache.contains(1) && cache.contains(3) && !cache.contains(2));
        assert_eq!(cache.len(), 2);
    }
}
