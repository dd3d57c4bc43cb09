//! Pairs camera frames with their person masks: the masks waiting for their frames, and the
//! frames of cameras with a mask topic waiting (briefly) for their masks. Both are bounded;
//! matching is by stamp, size and camera.

use crate::node::inputs::{CameraFrame, MaskFrame};
use image::GrayImage;
use std::collections::{HashSet, VecDeque};
use std::sync::Arc;
use std::time::Duration;

/// A frame ready for preprocessing, with its mask when one arrived in time.
pub type Paired = (CameraFrame, Option<Arc<GrayImage>>);

/// Frames of masked cameras waiting for their masks, at most this many (the oldest then goes
/// on without one).
const FRAMES_WAITING: usize = 8;

/// Matches frames and masks that arrive in either order: a segmentation node usually
/// publishes a frame's mask after the frame.
#[derive(Debug)]
pub struct MaskPairing {
    masks: MaskBuffer,
    /// Camera topics that have their own mask topic: their frames wait for a mask.
    masked_cameras: HashSet<String>,
    /// How long a frame waits for its mask.
    wait: Duration,
    waiting: VecDeque<(CameraFrame, Duration)>,
}

impl MaskPairing {
    /// Keeps up to `masks_kept` masks; frames of `masked_cameras` wait up to `wait` for theirs.
    pub fn new(
        masks_kept: usize,
        masked_cameras: impl IntoIterator<Item = String>,
        wait: Duration,
    ) -> Self {
        Self {
            masks: MaskBuffer::new(masks_kept),
            masked_cameras: masked_cameras.into_iter().collect(),
            wait,
            waiting: VecDeque::new(),
        }
    }

    /// Whether camera `topic` has a mask topic of its own.
    pub fn is_masked(&self, topic: &str) -> bool {
        self.masked_cameras.contains(topic)
    }

    /// Sets the camera topics whose frames wait for a mask of their own.
    pub fn set_masked_cameras(&mut self, cameras: impl IntoIterator<Item = String>) {
        self.masked_cameras = cameras.into_iter().collect();
    }

    /// A frame arrived at `now`: the frames ready to go on (this one with its mask, or without
    /// one when its camera has no mask topic; a waiting frame pushed out by the bound).
    pub fn frame(&mut self, frame: CameraFrame, now: Duration) -> Vec<Paired> {
        if let Some(mask) = self.masks.find(&frame) {
            return vec![(frame, Some(mask))];
        }
        if !self.masked_cameras.contains(&frame.topic) {
            return vec![(frame, None)];
        }
        self.waiting.push_back((frame, now + self.wait));
        let mut ready = Vec::new();
        while self.waiting.len() > FRAMES_WAITING {
            if let Some((f, _)) = self.waiting.pop_front() {
                ready.push((f, None));
            }
        }
        ready
    }

    /// A mask arrived: the waiting frames it belongs to, now ready.
    pub fn mask(&mut self, mask: MaskFrame) -> Vec<Paired> {
        self.masks.push(mask);
        let mut ready = Vec::new();
        let mut i = 0;
        while i < self.waiting.len() {
            if let Some(m) = self.masks.find(&self.waiting[i].0) {
                if let Some((f, _)) = self.waiting.remove(i) {
                    ready.push((f, Some(m)));
                }
            } else {
                i += 1;
            }
        }
        ready
    }

    /// The waiting frames whose wait ended at `now` (they go on without a mask).
    pub fn expired(&mut self, now: Duration) -> Vec<Paired> {
        let mut ready = Vec::new();
        while self.waiting.front().is_some_and(|(_, due)| *due <= now) {
            if let Some((f, _)) = self.waiting.pop_front() {
                ready.push((f, None));
            }
        }
        ready
    }

    /// When the oldest waiting frame's wait ends.
    pub fn next_deadline(&self) -> Option<Duration> {
        self.waiting.front().map(|(_, due)| *due)
    }

    /// Frames waiting for their masks.
    pub fn waiting(&self) -> usize {
        self.waiting.len()
    }
}

/// The latest person masks, oldest dropped first once `capacity` are held.
#[derive(Debug)]
pub struct MaskBuffer {
    masks: VecDeque<MaskFrame>,
    capacity: usize,
}

impl MaskBuffer {
    /// An empty buffer holding at most `capacity` masks (at least one).
    pub fn new(capacity: usize) -> Self {
        Self {
            masks: VecDeque::new(),
            capacity: capacity.max(1),
        }
    }

    /// Keeps `mask`, dropping the oldest mask when full.
    pub fn push(&mut self, mask: MaskFrame) {
        self.masks.push_back(mask);
        while self.masks.len() > self.capacity {
            self.masks.pop_front();
        }
    }

    /// The newest mask of `frame`: same stamp and size, from its camera's own mask topic or from
    /// the shared mask topic.
    pub fn find(&self, frame: &CameraFrame) -> Option<Arc<GrayImage>> {
        self.masks
            .iter()
            .rev()
            .find(|m| {
                m.stamp_ns == frame.stamp_ns
                    && m.camera.as_ref().is_none_or(|c| *c == frame.topic)
                    && m.mask.dimensions() == frame.image.dimensions()
            })
            .map(|m| m.mask.clone())
    }

    /// Masks held.
    pub fn len(&self) -> usize {
        self.masks.len()
    }

    /// Whether no mask is held.
    pub fn is_empty(&self) -> bool {
        self.masks.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::RgbImage;
    use std::time::Duration;

    fn mask(camera: Option<&str>, stamp_ns: i64, value: u8) -> MaskFrame {
        MaskFrame {
            topic: format!("{}/mask", camera.unwrap_or("/shared")),
            camera: camera.map(str::to_owned),
            stamp_ns,
            arrival: Duration::ZERO,
            mask: Arc::new(GrayImage::from_pixel(4, 3, image::Luma([value]))),
        }
    }

    fn frame(topic: &str, stamp_ns: i64, w: u32) -> CameraFrame {
        CameraFrame {
            topic: topic.into(),
            stamp_ns,
            frame_id: String::new(),
            arrival: Duration::ZERO,
            image: Arc::new(RgbImage::new(w, 3)),
        }
    }

    fn value(m: Option<Arc<GrayImage>>) -> Option<u8> {
        m.map(|m| m.get_pixel(0, 0).0[0])
    }

    #[test]
    fn each_camera_gets_its_own_mask_of_the_same_stamp() {
        let mut b = MaskBuffer::new(8);
        b.push(mask(Some("/cam0/image_raw"), 5, 10));
        b.push(mask(Some("/cam1/image_raw"), 5, 20));
        assert_eq!(value(b.find(&frame("/cam0/image_raw", 5, 4))), Some(10));
        assert_eq!(value(b.find(&frame("/cam1/image_raw", 5, 4))), Some(20));
        assert_eq!(value(b.find(&frame("/cam2/image_raw", 5, 4))), None);
    }

    #[test]
    fn the_shared_mask_serves_any_camera_but_needs_stamp_and_size() {
        let mut b = MaskBuffer::new(8);
        b.push(mask(None, 7, 30));
        assert_eq!(value(b.find(&frame("/cam3/image_raw", 7, 4))), Some(30));
        assert_eq!(value(b.find(&frame("/cam3/image_raw", 8, 4))), None);
        assert_eq!(value(b.find(&frame("/cam3/image_raw", 7, 5))), None);
    }

    fn topics(ready: &[Paired]) -> Vec<(String, Option<u8>)> {
        ready
            .iter()
            .map(|(f, m)| (f.topic.clone(), value(m.clone())))
            .collect()
    }

    #[test]
    fn a_frame_waits_for_a_mask_that_comes_after_it() {
        let wait = Duration::from_millis(100);
        let mut p = MaskPairing::new(8, ["/cam0/image_raw".to_string()], wait);
        let t0 = Duration::from_secs(1);
        assert!(p.frame(frame("/cam0/image_raw", 5, 4), t0).is_empty());
        // A camera without a mask topic goes on at once.
        let free = p.frame(frame("/cam9/image_raw", 5, 4), t0);
        assert_eq!(topics(&free), [("/cam9/image_raw".to_string(), None)]);
        // Another camera's mask of the same stamp does not release it.
        assert!(p.mask(mask(Some("/cam1/image_raw"), 5, 20)).is_empty());
        assert_eq!(p.next_deadline(), Some(t0 + wait));
        let ready = p.mask(mask(Some("/cam0/image_raw"), 5, 10));
        assert_eq!(topics(&ready), [("/cam0/image_raw".to_string(), Some(10))]);
        assert_eq!(p.waiting(), 0);
        assert_eq!(p.next_deadline(), None);
    }

    #[test]
    fn a_frame_whose_mask_never_comes_goes_on_without_one_after_the_wait() {
        let wait = Duration::from_millis(100);
        let mut p = MaskPairing::new(8, ["/c".to_string()], wait);
        assert!(p.frame(frame("/c", 1, 4), Duration::ZERO).is_empty());
        assert!(p.expired(Duration::from_millis(99)).is_empty());
        let ready = p.expired(Duration::from_millis(100));
        assert_eq!(topics(&ready), [("/c".to_string(), None)]);
        // A mask that came first is used at once.
        assert!(p.mask(mask(Some("/c"), 2, 7)).is_empty());
        let ready = p.frame(frame("/c", 2, 4), Duration::ZERO);
        assert_eq!(topics(&ready), [("/c".to_string(), Some(7))]);
    }

    #[test]
    fn waiting_frames_are_bounded() {
        let mut p = MaskPairing::new(8, ["/c".to_string()], Duration::from_secs(60));
        let mut released = 0;
        for stamp in 0..20 {
            released += p.frame(frame("/c", stamp, 4), Duration::ZERO).len();
        }
        assert_eq!(p.waiting(), FRAMES_WAITING);
        assert_eq!(released, 20 - FRAMES_WAITING);
    }

    #[test]
    fn the_buffer_is_bounded_and_the_newest_mask_wins() {
        let mut b = MaskBuffer::new(2);
        b.push(mask(None, 1, 1));
        b.push(mask(None, 2, 2));
        b.push(mask(None, 2, 3));
        assert_eq!(b.len(), 2);
        assert_eq!(value(b.find(&frame("/c", 1, 4))), None);
        assert_eq!(value(b.find(&frame("/c", 2, 4))), Some(3));
    }
}
