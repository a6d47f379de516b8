//! A point estimate with its confidence interval, and how two of them compare.

use serde::Serialize;

/// A point estimate with its confidence interval.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Estimate {
    /// Point estimate (a median, or a ratio of medians).
    pub value: f64,
    /// Lower end of the interval.
    pub lo: f64,
    /// Upper end of the interval.
    pub hi: f64,
    /// Smallest number of repetitions among the samples involved.
    pub reps: usize,
}

impl Estimate {
    /// An estimate without uncertainty (`lo = hi = value`).
    pub fn point(value: f64, reps: usize) -> Self {
        Self { value, lo: value, hi: value, reps }
    }

    /// True when every sample involved had a single repetition: the interval is the point
    /// itself and says nothing about the noise.
    pub fn degenerate(&self) -> bool {
        self.reps < 2 || self.lo == self.hi
    }

    /// Multiply value and interval by a positive factor.
    pub fn scale(&self, k: f64) -> Self {
        Self { value: self.value * k, lo: self.lo * k, hi: self.hi * k, reps: self.reps }
    }

    /// `1.23 [1.20, 1.26]`, or `1.23 (1 rep)` when degenerate, with `digits` decimals.
    pub fn show(&self, digits: usize) -> String {
        if self.degenerate() {
            format!("{:.*} (n={})", digits, self.value, self.reps)
        } else {
            format!("{:.*} [{:.*}, {:.*}]", digits, self.value, digits, self.lo, digits, self.hi)
        }
    }
}

/// How two estimates compare, allowing for their uncertainty.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Compare {
    /// The first is larger beyond the noise.
    Greater,
    /// The first is smaller beyond the noise.
    Less,
    /// The difference is within the noise.
    Within,
}

/// Relative difference under which two single-repetition estimates count as equal.
pub const SINGLE_REP_MARGIN: f64 = 0.05;

/// Compare `a` with `b`: by interval separation when at least one has a real interval,
/// else (single repetitions) by a relative margin of [`SINGLE_REP_MARGIN`].
pub fn compare(a: &Estimate, b: &Estimate) -> Compare {
    if a.degenerate() && b.degenerate() {
        let scale = a.value.abs().max(b.value.abs()).max(f64::MIN_POSITIVE);
        let d = (a.value - b.value) / scale;
        if d > SINGLE_REP_MARGIN {
            Compare::Greater
        } else if d < -SINGLE_REP_MARGIN {
            Compare::Less
        } else {
            Compare::Within
        }
    } else if a.lo > b.hi {
        Compare::Greater
    } else if a.hi < b.lo {
        Compare::Less
    } else {
        Compare::Within
    }
}
