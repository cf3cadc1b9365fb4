//! Latency summaries for bench binaries: collect samples, print percentiles a person can read.

use std::fmt;
use std::time::Duration;

/// Percentiles of a set of duration samples, in microseconds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Summary {
    /// Number of samples.
    pub count: usize,
    /// Mean, µs.
    pub mean_us: f64,
    /// Median, µs.
    pub p50_us: f64,
    /// 99th percentile, µs.
    pub p99_us: f64,
    /// Largest sample, µs.
    pub max_us: f64,
}

impl Summary {
    /// Summarises `samples` (sorted in place). Returns `None` for an empty slice.
    pub fn of(samples: &mut [Duration]) -> Option<Self> {
        if samples.is_empty() {
            return None;
        }
        samples.sort_unstable();
        let us = |d: Duration| d.as_secs_f64() * 1e6;
        let at = |q: f64| {
            // Nearest-rank percentile: the smallest sample with at least q of the samples at or below it.
            let rank = (q * samples.len() as f64).ceil().max(1.0) as usize;
            us(samples[rank.min(samples.len()) - 1])
        };
        let total: f64 = samples.iter().map(|&d| us(d)).sum();
        Some(Self {
            count: samples.len(),
            mean_us: total / samples.len() as f64,
            p50_us: at(0.50),
            p99_us: at(0.99),
            max_us: us(samples[samples.len() - 1]),
        })
    }
}

impl fmt::Display for Summary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "p50 {:>9.2} µs   p99 {:>9.2} µs   max {:>9.2} µs   mean {:>9.2} µs   (n = {})",
            self.p50_us, self.p99_us, self.max_us, self.mean_us, self.count
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_rank_percentiles() {
        let mut samples: Vec<Duration> = (1..=100).rev().map(Duration::from_micros).collect();
        let s = Summary::of(&mut samples).unwrap();
        assert_eq!((s.p50_us, s.p99_us, s.max_us, s.count), (50.0, 99.0, 100.0, 100));
        assert!((s.mean_us - 50.5).abs() < 1e-9);
        assert!(Summary::of(&mut []).is_none());
    }
}
