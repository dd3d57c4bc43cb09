//! Noticing a camera in which perception finds nobody, frame after frame, so that it can be
//! said once: a camera pointed where nobody stands, people too small for the detector's input,
//! or too little light all look alike from outside (no mask, no pose, no avatar).

/// Seconds of frames with nobody found after which a camera is reported.
pub const NOBODY_SECONDS: f64 = 5.0;
/// Frames with nobody found a camera needs, too, before it is reported.
pub const NOBODY_FRAMES: u64 = 10;

/// A stretch of frames of one camera in which nobody was found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NobodyStretch {
    /// Frames in the stretch.
    pub frames: u64,
    /// Seconds from its first frame to its last (by the frames' stamps).
    pub seconds: f64,
}

/// One camera's frames, watched for a stretch of [`NOBODY_SECONDS`] and [`NOBODY_FRAMES`] in
/// which nobody is found; reported once per watch (once per camera and run).
#[derive(Debug, Default, Clone)]
pub struct NobodyWatch {
    /// Stamp of the stretch's first frame (`None`: the last frame showed someone).
    since: Option<f64>,
    frames: u64,
    reported: bool,
}

impl NobodyWatch {
    /// Records a frame stamped `seconds` in which someone was `found` or not. Returns the
    /// stretch the first time nobody has been found for long enough, and never again.
    pub fn observe(&mut self, found: bool, seconds: f64) -> Option<NobodyStretch> {
        if found {
            self.since = None;
            self.frames = 0;
            return None;
        }
        // A stamp from before the stretch (a bag replayed from its start) starts it again.
        let since = match self.since {
            Some(since) if seconds >= since => since,
            _ => {
                self.frames = 0;
                seconds
            }
        };
        self.since = Some(since);
        self.frames += 1;
        let stretch = NobodyStretch {
            frames: self.frames,
            seconds: seconds - since,
        };
        let long = stretch.seconds >= NOBODY_SECONDS && stretch.frames >= NOBODY_FRAMES;
        if long && !self.reported {
            self.reported = true;
            return Some(stretch);
        }
        None
    }

    /// Whether this camera has been reported.
    pub fn reported(&self) -> bool {
        self.reported
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nobody_for_five_seconds_is_reported_once() {
        let mut watch = NobodyWatch::default();
        let mut reports = Vec::new();
        // 10 Hz for 12 s, nobody in any frame.
        for i in 0..120 {
            if let Some(s) = watch.observe(false, 100.0 + i as f64 * 0.1) {
                reports.push((i, s));
            }
        }
        assert_eq!(reports.len(), 1, "{reports:?}");
        let (i, s) = reports[0];
        assert_eq!(i, 50, "the frame 5 s after the first");
        assert_eq!(s.frames, 51);
        assert!((s.seconds - 5.0).abs() < 1e-9);
        assert!(watch.reported());
    }

    #[test]
    fn someone_found_starts_the_stretch_again() {
        let mut watch = NobodyWatch::default();
        for i in 0..200 {
            // someone every 4 s: never 5 s of nobody
            let found = i % 40 == 0;
            assert_eq!(watch.observe(found, i as f64 * 0.1), None, "frame {i}");
        }
        assert!(!watch.reported());
    }

    #[test]
    fn few_frames_over_a_long_time_are_not_enough() {
        let mut watch = NobodyWatch::default();
        for i in 0..9 {
            assert_eq!(watch.observe(false, i as f64 * 2.0), None);
        }
        assert!(watch.observe(false, 18.0).is_some(), "the tenth frame");
    }

    #[test]
    fn a_stamp_going_back_starts_the_stretch_again() {
        let mut watch = NobodyWatch::default();
        for i in 0..30 {
            assert_eq!(watch.observe(false, 50.0 + i as f64 * 0.1), None);
        }
        // The bag starts over at 10 s: 3 s before was 53 s, not 7 s.
        for i in 0..49 {
            assert_eq!(watch.observe(false, 10.0 + i as f64 * 0.1), None, "{i}");
        }
        assert!(watch.observe(false, 15.0).is_some());
    }
}
