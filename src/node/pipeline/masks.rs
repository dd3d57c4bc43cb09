//! The person masks waiting for their frames: bounded, matched by stamp, size and camera.

use crate::node::ros::{CameraFrame, MaskFrame};
use image::GrayImage;
use std::collections::VecDeque;
use std::sync::Arc;

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
