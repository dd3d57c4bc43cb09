//! Counting and rate-limited reporting of bad input messages (malformed CDR, undecodable
//! images): every error is counted per topic; at most one is reported per topic per period,
//! saying how many were suppressed since the last report. Pure; the caller passes the clock.

use std::collections::BTreeMap;
use std::time::Duration;

#[derive(Debug, Default, Clone)]
struct TopicErrors {
    total: u64,
    suppressed: u64,
    last_report: Option<Duration>,
}

/// Per-topic error counters with a report throttle.
#[derive(Debug, Clone)]
pub struct InputErrors {
    period: Duration,
    topics: BTreeMap<String, TopicErrors>,
}

impl InputErrors {
    /// Reports each topic's errors at most once per `period`.
    pub fn new(period: Duration) -> Self {
        Self {
            period,
            topics: BTreeMap::new(),
        }
    }

    /// Counts an error on `topic`; returns the line to log if this one is due for reporting.
    pub fn record(&mut self, topic: &str, reason: &str, now: Duration) -> Option<String> {
        let t = self.topics.entry(topic.to_owned()).or_default();
        t.total += 1;
        let due = t
            .last_report
            .is_none_or(|last| now.saturating_sub(last) >= self.period);
        if !due {
            t.suppressed += 1;
            return None;
        }
        let line = if t.suppressed > 0 {
            format!(
                "topic {topic}: dropped bad message: {reason} ({} more since last report, {} total)",
                t.suppressed, t.total
            )
        } else {
            format!("topic {topic}: dropped bad message: {reason}")
        };
        t.suppressed = 0;
        t.last_report = Some(now);
        Some(line)
    }

    /// Errors counted on `topic` so far.
    pub fn count(&self, topic: &str) -> u64 {
        self.topics.get(topic).map_or(0, |t| t.total)
    }

    /// Errors counted per topic (topics with at least one error).
    pub fn counts(&self) -> impl Iterator<Item = (&str, u64)> {
        self.topics.iter().map(|(t, e)| (t.as_str(), e.total))
    }

    /// Errors counted on all topics.
    pub fn total(&self) -> u64 {
        self.topics.values().map(|t| t.total).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reports_once_per_period_per_topic_but_counts_all() {
        let mut e = InputErrors::new(Duration::from_secs(5));
        let s = Duration::from_secs;
        assert!(e.record("/a", "bad step", s(0)).unwrap().contains("/a"));
        assert!(e.record("/a", "bad step", s(1)).is_none());
        assert!(e.record("/a", "bad step", s(4)).is_none());
        assert!(e.record("/b", "corrupt jpeg", s(4)).is_some());
        let line = e.record("/a", "bad step", s(5)).unwrap();
        assert!(
            line.contains("2 more") && line.contains("4 total"),
            "{line}"
        );
        assert_eq!((e.count("/a"), e.count("/b"), e.total()), (4, 1, 5));
    }
}
