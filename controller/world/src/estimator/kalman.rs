//! The covariance both filters keep and their one measurement update: a scalar measurement at a
//! time (equivalent to the stacked update for independent noises), so no matrix is inverted and
//! nothing is allocated after construction.

/// A row of a measurement's Jacobian: (state index, coefficient) pairs, the rest zero.
pub(super) type Row<'a> = &'a [(usize, f64)];

/// The filter's covariance, row-major `n × n`, with its gain buffer.
#[derive(Debug, Clone)]
pub(super) struct Covariance {
    pub(super) n: usize,
    pub(super) p: Vec<f64>,
    gain: Vec<f64>,
}

impl Covariance {
    pub(super) fn new(n: usize) -> Self {
        Self {
            n,
            p: vec![0.0; n * n],
            gain: vec![0.0; n],
        }
    }

    #[inline]
    pub(super) fn at(&self, i: usize, j: usize) -> f64 {
        self.p[i * self.n + j]
    }

    /// The standard deviation of state `i`.
    pub(super) fn std(&self, i: usize) -> f64 {
        self.at(i, i).max(0.0).sqrt()
    }

    /// Zero, then these variances on the diagonal.
    pub(super) fn reset(&mut self, variance: impl Fn(usize) -> f64) {
        self.p.fill(0.0);
        for i in 0..self.n {
            self.p[i * self.n + i] = variance(i);
        }
    }

    /// Adds `variance` to state `i`'s (process noise on the diagonal).
    pub(super) fn add_variance(&mut self, i: usize, variance: f64) {
        self.p[i * self.n + i] += variance;
    }

    /// States `first..first + 3` forget everything: no correlation left, this variance.
    pub(super) fn forget(&mut self, first: usize, variance: f64) {
        let n = self.n;
        for i in first..first + 3 {
            for j in 0..n {
                self.p[i * n + j] = 0.0;
                self.p[j * n + i] = 0.0;
            }
            self.p[i * n + i] = variance;
        }
    }

    /// One scalar measurement with Jacobian row `h`, `innovation` (measured minus predicted)
    /// and noise variance `r`: adds the gain times the innovation to `correction` and shrinks
    /// the covariance. False (nothing changed) when the innovation's variance is not positive
    /// and finite.
    pub(super) fn update(&mut self, h: Row<'_>, innovation: f64, r: f64, correction: &mut [f64]) -> bool {
        let n = self.n;
        // g = P hᵀ
        for (row, g) in self.gain.iter_mut().enumerate() {
            *g = h.iter().map(|&(i, c)| c * self.p[row * n + i]).sum();
        }
        let s = h.iter().map(|&(i, c)| c * self.gain[i]).sum::<f64>() + r;
        if !(s.is_finite() && s > 0.0) {
            return false;
        }
        for (x, g) in correction.iter_mut().zip(&self.gain) {
            *x += g / s * innovation;
        }
        for row in 0..n {
            let gr = self.gain[row] / s;
            for (col, g) in self.gain.iter().enumerate() {
                self.p[row * n + col] -= gr * g;
            }
        }
        true
    }

    /// `h · correction`: what a correction already made predicts of a measurement.
    pub(super) fn predicted(h: Row<'_>, correction: &[f64]) -> f64 {
        h.iter().map(|&(i, c)| c * correction[i]).sum()
    }

    pub(super) fn symmetrise(&mut self) {
        let n = self.n;
        for i in 0..n {
            for j in i + 1..n {
                let m = 0.5 * (self.p[i * n + j] + self.p[j * n + i]);
                self.p[i * n + j] = m;
                self.p[j * n + i] = m;
            }
        }
    }

    pub(super) fn is_finite(&self) -> bool {
        self.p.iter().all(|v| v.is_finite())
    }
}
