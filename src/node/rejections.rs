//! Rejected input messages counted by reason, from every path (live subscriptions, bag replay,
//! the pipeline's own checks), for the run summary and `ReconstructionStatus`.

use std::fmt;

/// Why an input message was not used.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum RejectReason {
    /// The CDR payload does not decode as the topic's type (malformed, truncated, other type).
    Cdr,
    /// An image message that decodes but cannot be used: step and size disagree, unsupported
    /// encoding, empty or over `inputs.max_image_side`, corrupt JPEG/PNG.
    Image,
    /// A camera frame that preprocessing could not use.
    Frame,
    /// A `BodyPose` with values or bone names the skeleton refuses.
    Pose,
    /// A `BodyShape` of another body model, length or range.
    Shape,
}

impl RejectReason {
    /// Every reason, in the order summaries list them.
    pub const ALL: [RejectReason; 5] = [
        RejectReason::Cdr,
        RejectReason::Image,
        RejectReason::Frame,
        RejectReason::Pose,
        RejectReason::Shape,
    ];

    /// The reason's name in summaries and `ReconstructionStatus.rejected_reasons`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Cdr => "cdr",
            Self::Image => "image",
            Self::Frame => "frame",
            Self::Pose => "pose",
            Self::Shape => "shape",
        }
    }
}

/// Rejected messages per [`RejectReason`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Rejections {
    counts: [u64; RejectReason::ALL.len()],
}

impl Rejections {
    /// Counts one rejected message.
    pub fn add(&mut self, reason: RejectReason) {
        self.counts[reason as usize] += 1;
    }

    /// Messages rejected for `reason`.
    pub fn count(&self, reason: RejectReason) -> u64 {
        self.counts[reason as usize]
    }

    /// Messages rejected for any reason.
    pub fn total(&self) -> u64 {
        self.counts.iter().sum()
    }

    /// These counts plus `other`'s.
    pub fn merged(&self, other: &Rejections) -> Rejections {
        let mut counts = self.counts;
        counts
            .iter_mut()
            .zip(other.counts)
            .for_each(|(a, b)| *a += b);
        Rejections { counts }
    }

    /// The reasons with at least one rejection and their counts, in [`RejectReason::ALL`]
    /// order.
    pub fn nonzero(&self) -> impl Iterator<Item = (RejectReason, u64)> + '_ {
        RejectReason::ALL
            .into_iter()
            .map(|r| (r, self.count(r)))
            .filter(|&(_, n)| n > 0)
    }
}

impl fmt::Display for Rejections {
    /// `0`, or the total and its reasons: `6 (cdr 2, image 4)`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.total())?;
        let parts: Vec<String> = self
            .nonzero()
            .map(|(r, n)| format!("{} {n}", r.as_str()))
            .collect();
        if !parts.is_empty() {
            write!(f, " ({})", parts.join(", "))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_merge_and_print_by_reason() {
        let mut a = Rejections::default();
        assert_eq!(a.to_string(), "0");
        a.add(RejectReason::Image);
        a.add(RejectReason::Cdr);
        a.add(RejectReason::Image);
        let mut b = Rejections::default();
        b.add(RejectReason::Shape);
        let m = a.merged(&b);
        assert_eq!(m.to_string(), "4 (cdr 1, image 2, shape 1)");
        assert_eq!((m.total(), m.count(RejectReason::Pose)), (4, 0));
    }
}
