//! Distributions of durations over a whole run in constant memory (an HDR histogram at 3
//! significant digits, 1 µs to 1 h), for the percentiles the run summary and the soak report.

use hdrhistogram::Histogram;
use std::time::Duration;

/// Longest duration kept exactly; longer ones are recorded as this.
const LONGEST_US: u64 = 3_600_000_000;

/// Recorded durations of one kind (e.g. input queue waits).
#[derive(Debug, Clone, PartialEq)]
pub struct Timings(Histogram<u64>);

impl Default for Timings {
    fn default() -> Self {
        Self(Histogram::new_with_bounds(1, LONGEST_US, 3).expect("valid histogram bounds"))
    }
}

impl Timings {
    /// Records one duration (clamped to 1 µs..1 h).
    pub fn record(&mut self, d: Duration) {
        let us = (d.as_micros() as u64).clamp(1, LONGEST_US);
        self.0.saturating_record(us);
    }

    /// Durations recorded.
    pub fn count(&self) -> u64 {
        self.0.len()
    }

    /// The `q`-quantile (0..=1) in milliseconds, `None` before the first record.
    pub fn quantile_ms(&self, q: f64) -> Option<f64> {
        (self.count() > 0).then(|| self.0.value_at_quantile(q) as f64 / 1e3)
    }

    /// The longest recorded, milliseconds.
    pub fn max_ms(&self) -> Option<f64> {
        (self.count() > 0).then(|| self.0.max() as f64 / 1e3)
    }
}

impl std::fmt::Display for Timings {
    /// `p50 1.2 / p95 3.4 / p99 5.6 / max 7.8 ms (n 120)`, or `none`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match (
            self.quantile_ms(0.5),
            self.quantile_ms(0.95),
            self.quantile_ms(0.99),
            self.max_ms(),
        ) {
            (Some(p50), Some(p95), Some(p99), Some(max)) => write!(
                f,
                "p50 {p50:.1} / p95 {p95:.1} / p99 {p99:.1} / max {max:.1} ms (n {})",
                self.count()
            ),
            _ => f.write_str("none"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_of_a_known_spread_within_the_histogram_precision() {
        let mut t = Timings::default();
        assert_eq!(t.to_string(), "none");
        for ms in 1..=1000u64 {
            t.record(Duration::from_millis(ms));
        }
        assert_eq!(t.count(), 1000);
        let p50 = t.quantile_ms(0.5).unwrap();
        let p99 = t.quantile_ms(0.99).unwrap();
        assert!((p50 - 500.0).abs() < 1.0, "p50 {p50}");
        assert!((p99 - 990.0).abs() < 1.5, "p99 {p99}");
        assert!((t.max_ms().unwrap() - 1000.0).abs() < 1.0);
        assert!(t.to_string().starts_with("p50 500"), "{t}");
    }

    #[test]
    fn memory_does_not_grow_with_records() {
        let mut t = Timings::default();
        let before = t.clone();
        for us in 0..200_000u64 {
            t.record(Duration::from_micros(us * 17 % 5_000_000));
        }
        // The histogram's buckets are allocated up front: same size after 200,000 records.
        assert_eq!(t.0.distinct_values(), before.0.distinct_values());
        assert_eq!(t.count(), 200_000);
    }
}
