//! Durations in a preallocated histogram: what the loop and the generator's worker measure of
//! themselves without allocating.

use std::time::Duration;

/// A histogram of durations in 10 µs bins up to 40 ms, preallocated.
#[derive(Debug, Clone)]
pub struct Histogram {
    bins: Vec<u32>,
    count: u64,
    max: Duration,
}

const BIN: Duration = Duration::from_micros(10);

impl Default for Histogram {
    fn default() -> Self {
        Self {
            bins: vec![0; 4000],
            count: 0,
            max: Duration::ZERO,
        }
    }
}

impl Histogram {
    /// Adds a sample (no allocation).
    pub fn record(&mut self, d: Duration) {
        let i = ((d.as_nanos() / BIN.as_nanos()) as usize).min(self.bins.len() - 1);
        self.bins[i] += 1;
        self.count += 1;
        self.max = self.max.max(d);
    }

    /// The `p`-quantile (upper edge of its bin, never above the largest sample).
    pub fn quantile(&self, p: f64) -> Duration {
        let want = (p * self.count as f64).ceil().max(1.0) as u64;
        let mut seen = 0u64;
        for (i, &c) in self.bins.iter().enumerate() {
            seen += u64::from(c);
            if seen >= want {
                return (BIN * (i as u32 + 1)).min(self.max);
            }
        }
        self.max
    }

    /// Largest sample.
    pub fn max(&self) -> Duration {
        self.max
    }

    /// Samples.
    pub fn count(&self) -> u64 {
        self.count
    }
}

impl std::fmt::Display for Histogram {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs over {} ticks",
            self.quantile(0.5).as_secs_f64() * 1e6,
            self.quantile(0.99).as_secs_f64() * 1e6,
            self.max.as_secs_f64() * 1e6,
            self.count
        )
    }
}
