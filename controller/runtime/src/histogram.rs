//! Durations in a preallocated histogram: what the loop and the generator's worker measure of
//! themselves without allocating, and what `report` measures of a recording's per-tick times: one
//! computation, so the run and its report print the same numbers.

use std::time::Duration;

/// A histogram of durations in 1 µs bins (each sample at its nearest whole microsecond) up to
/// 40 ms, preallocated.
#[derive(Debug, Clone)]
pub struct Histogram {
    bins: Vec<u32>,
    count: u64,
    max: Duration,
}

/// Bins: one per microsecond up to 40 ms (later samples share the last).
const BINS: usize = 40_000;

impl Default for Histogram {
    fn default() -> Self {
        Self {
            bins: vec![0; BINS],
            count: 0,
            max: Duration::ZERO,
        }
    }
}

impl Histogram {
    /// Adds a sample (no allocation).
    pub fn record(&mut self, d: Duration) {
        let i = (d.as_nanos().saturating_add(500) / 1000).min(BINS as u128 - 1) as usize;
        self.bins[i] += 1;
        self.count += 1;
        self.max = self.max.max(d);
    }

    /// Adds a sample of `us` microseconds (a recording's per-tick times); non-finite, negative or
    /// absurd ones are skipped.
    pub fn record_us(&mut self, us: f64) {
        if let Ok(d) = Duration::try_from_secs_f64(us * 1e-6) {
            self.record(d);
        }
    }

    /// The `p`-quantile by nearest rank (the smallest sample with at least `p` of all at or
    /// below it), to the microsecond, never above the largest sample.
    pub fn quantile(&self, p: f64) -> Duration {
        let want = (p * self.count as f64).ceil().max(1.0) as u64;
        let mut seen = 0u64;
        for (i, &c) in self.bins.iter().enumerate() {
            seen += u64::from(c);
            if seen >= want {
                return Duration::from_micros(i as u64).min(self.max);
            }
        }
        self.max
    }

    /// The quantile in microseconds.
    pub fn quantile_us(&self, p: f64) -> f64 {
        self.quantile(p).as_secs_f64() * 1e6
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
            self.quantile_us(0.5),
            self.quantile_us(0.99),
            self.max.as_secs_f64() * 1e6,
            self.count
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_are_the_nearest_rank_sample_to_the_microsecond_however_it_was_given() {
        let mut a = Histogram::default();
        let mut b = Histogram::default();
        // 1..=100 µs: p50 is the 50th sample, p99 the 99th.
        for us in 1..=100u64 {
            a.record(Duration::from_nanos(us * 1000 + 300));
            // As a recording keeps it: microseconds in an f32.
            b.record_us(f64::from((us as f32 * 1000.0 + 300.0) / 1000.0));
        }
        for h in [&a, &b] {
            assert_eq!(h.quantile(0.5), Duration::from_micros(50));
            assert_eq!(h.quantile(0.99), Duration::from_micros(99));
            assert_eq!(h.quantile(1.0), Duration::from_micros(100));
            assert_eq!(h.count(), 100);
        }
        assert_eq!(format!("{a}"), format!("{b}"));
        // A sample beyond the bins is still the maximum.
        a.record(Duration::from_millis(90));
        assert_eq!(a.quantile(1.0), Duration::from_micros(39_999));
        assert_eq!(a.max(), Duration::from_millis(90));
    }
}
