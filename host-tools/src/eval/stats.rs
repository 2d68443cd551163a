//! Summary statistics of an error series, defined as evo's `PE.get_all_statistics` does:
//! `rmse = sqrt(mean(e^2))`, `sse = sum(e^2)`, `median` as numpy (mean of the two middle values
//! for an even count), `std` the population standard deviation (`np.std`, divisor `n`).
//!
//! OpenVINS' `Statistics::calculate` differs in two places (sample `std` with divisor `n - 1`,
//! and an off-by-one even-count median); we use evo's definitions everywhere so ATE and RTE
//! numbers are comparable with the tool most papers quote.

use serde::Serialize;

/// Statistics of a non-empty series of non-negative errors, in the unit of the series.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Stats {
    /// Root mean square.
    pub rmse: f64,
    /// Arithmetic mean.
    pub mean: f64,
    /// Median (mean of the two middle values for an even count).
    pub median: f64,
    /// Population standard deviation.
    pub std: f64,
    /// Smallest value.
    pub min: f64,
    /// Largest value.
    pub max: f64,
    /// Sum of squares.
    pub sse: f64,
}

impl Stats {
    /// Statistics of `values`; `None` when empty.
    pub fn from_values(values: &[f64]) -> Option<Stats> {
        let n = values.len();
        if n == 0 {
            return None;
        }
        let mut sorted = values.to_vec();
        sorted.sort_by(f64::total_cmp);
        let nf = n as f64;
        let sse: f64 = values.iter().map(|e| e * e).sum();
        let mean = values.iter().sum::<f64>() / nf;
        let var = values.iter().map(|e| (e - mean) * (e - mean)).sum::<f64>() / nf;
        let mid = n / 2;
        let median = if n % 2 == 1 {
            sorted[mid]
        } else {
            0.5 * (sorted[mid - 1] + sorted[mid])
        };
        Some(Stats {
            rmse: (sse / nf).sqrt(),
            mean,
            median,
            std: var.sqrt(),
            min: sorted[0],
            max: sorted[n - 1],
            sse,
        })
    }

    /// `(name, value)` pairs in display order, for tables and flat JSON keys.
    pub fn named(&self) -> [(&'static str, f64); 7] {
        [
            ("rmse", self.rmse),
            ("mean", self.mean),
            ("median", self.median),
            ("std", self.std),
            ("min", self.min),
            ("max", self.max),
            ("sse", self.sse),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_hand_computed_values() {
        let s = Stats::from_values(&[3.0, 1.0, 4.0, 2.0]).unwrap();
        assert_eq!(s.median, 2.5);
        assert_eq!(s.mean, 2.5);
        assert_eq!(s.sse, 30.0);
        assert!((s.rmse - 7.5f64.sqrt()).abs() < 1e-15);
        assert!((s.std - 1.25f64.sqrt()).abs() < 1e-15);
        assert_eq!((s.min, s.max), (1.0, 4.0));
        let odd = Stats::from_values(&[5.0, 1.0, 3.0]).unwrap();
        assert_eq!(odd.median, 3.0);
        assert!(Stats::from_values(&[]).is_none());
    }
}
