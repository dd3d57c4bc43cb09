//! What reading a damaged bag could not read: the unreadable byte ranges it skipped (reading
//! went on after each) and the point where a file cut short ends.

use std::fmt;

/// Where and why the scan of an incomplete bag stopped.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Truncation {
    /// Byte offset of the first record that could not be read.
    pub offset: u64,
    /// What was wrong there.
    pub reason: String,
}

/// How reading found its way past an unreadable range.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Resync {
    /// The unreadable chunk's own length was sound; reading went on after it.
    RecordLength,
    /// The summary's chunk index gave the next record.
    ChunkIndex,
    /// A scan of the bytes found the next chunk record (opcode 0x06).
    Scan,
    /// Nothing readable was left before the data section's end (known from the footer).
    DataEnd,
}

impl fmt::Display for Resync {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::RecordLength => "record length",
            Self::ChunkIndex => "chunk index",
            Self::Scan => "scan",
            Self::DataEnd => "data end",
        })
    }
}

/// A byte range skipped as unreadable (bad CRC, compression or length).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Skipped {
    /// First byte of the range: the start of the record that could not be read.
    pub offset: u64,
    /// First byte after it, where reading resumed.
    pub end: u64,
    /// What was wrong.
    pub reason: String,
    /// Messages lost in the range, from the message index records of its chunk; `None` when
    /// unknown (no index records, or they were in the range).
    pub messages: Option<u64>,
    /// How the next readable record was found.
    pub resync: Resync,
}

/// Everything a read of a bag skipped or could not reach; empty for a complete bag.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Salvage {
    /// Unreadable ranges skipped, in file order.
    pub skipped: Vec<Skipped>,
    /// Where an incomplete file ends.
    pub truncation: Option<Truncation>,
    /// Messages the bag's summary statistics record counts, when the summary was read.
    pub expected_messages: Option<u64>,
    /// Messages dropped because their channel is unknown: its record was in a skipped range
    /// and no summary repeats it.
    pub unknown_channel: u64,
}

impl Salvage {
    /// True when nothing was skipped or dropped and the file is complete.
    pub fn is_complete(&self) -> bool {
        self.skipped.is_empty() && self.truncation.is_none() && self.unknown_channel == 0
    }

    /// Bytes in the skipped ranges.
    pub fn skipped_bytes(&self) -> u64 {
        self.skipped.iter().map(|s| s.end - s.offset).sum()
    }

    /// Messages known to be lost in the skipped ranges, and whether every range's count is
    /// known.
    pub fn lost_messages(&self) -> (u64, bool) {
        let known = self.skipped.iter().filter_map(|s| s.messages).sum();
        (known, self.skipped.iter().all(|s| s.messages.is_some()))
    }
}

impl fmt::Display for Salvage {
    /// One line: `complete`, or the skipped ranges (bytes, lost messages) and the cut.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.is_complete() {
            return f.write_str("complete");
        }
        let mut parts = Vec::new();
        if !self.skipped.is_empty() {
            let lost = match self.lost_messages() {
                (n, true) => format!("{n} messages lost"),
                (0, false) => "messages lost unknown".into(),
                (n, false) => format!("at least {n} messages lost"),
            };
            let n = self.skipped.len();
            parts.push(format!(
                "skipped {n} unreadable range{} ({} bytes, {lost})",
                if n == 1 { "" } else { "s" },
                self.skipped_bytes(),
            ));
        }
        if self.unknown_channel > 0 {
            parts.push(format!(
                "dropped {} messages whose channel was defined only in a skipped range",
                self.unknown_channel
            ));
        }
        if let Some(t) = &self.truncation {
            parts.push(format!("cut short at byte {}: {}", t.offset, t.reason));
        }
        f.write_str(&parts.join("; "))
    }
}

impl fmt::Display for Skipped {
    /// `bytes A..B (N bytes, M messages, resumed by chunk index): reason`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let messages = self
            .messages
            .map_or("unknown messages".to_string(), |n| format!("{n} messages"));
        write!(
            f,
            "bytes {}..{} ({} bytes, {messages}, resumed by {}): {}",
            self.offset,
            self.end,
            self.end - self.offset,
            self.resync,
            self.reason
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn skipped(offset: u64, end: u64, messages: Option<u64>) -> Skipped {
        Skipped {
            offset,
            end,
            reason: "bad crc".into(),
            messages,
            resync: Resync::RecordLength,
        }
    }

    #[test]
    fn the_summary_line_counts_ranges_bytes_and_messages() {
        let mut s = Salvage::default();
        assert_eq!(s.to_string(), "complete");
        s.skipped.push(skipped(100, 400, Some(4)));
        assert_eq!(
            s.to_string(),
            "skipped 1 unreadable range (300 bytes, 4 messages lost)"
        );
        s.skipped.push(skipped(500, 600, None));
        s.unknown_channel = 2;
        s.truncation = Some(Truncation {
            offset: 900,
            reason: "no footer".into(),
        });
        assert_eq!(
            s.to_string(),
            "skipped 2 unreadable ranges (400 bytes, at least 4 messages lost); \
             dropped 2 messages whose channel was defined only in a skipped range; \
             cut short at byte 900: no footer"
        );
        assert_eq!(s.lost_messages(), (4, false));
    }
}
