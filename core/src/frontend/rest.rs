//! Rest detection from the images: the platform is at rest while its features do not move.
//!
//! The IMU alone cannot tell rest from gentle motion on a vibrating platform (EuRoC's MAV with
//! idling rotors: accelerometer spread up to 1.1 m/s^2 at rest, 1.2-1.8 m/s^2 in slow flight).
//! The images can: at rest the tracked features stay within a pixel or two of where they were
//! when the rest began (EuRoC V1_01: at most 1.5 px over 5 s, against 2-60 px within a second of
//! take-off). The detector keeps a reference frame and measures the median displacement of the
//! features it shares with each new frame; while that stays below `max_px` the rest lasts, and
//! the reference is replaced by the current frame the moment it does not (so slow motion cannot
//! hide in small steps). With too few common features nothing is claimed either way.

use super::tracks::NormalizedObs;
use heapless::Vec;

/// Thresholds of the image rest detector.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct RestConfig {
    /// Largest median displacement of the features since the rest began, px.
    pub max_px: f64,
    /// Fewest features shared with the reference frame for a verdict.
    pub min_features: usize,
}

impl RestConfig {
    /// The defaults (what [`Default`] gives); `const` for static configurations.
    pub const DEFAULT: RestConfig = RestConfig {
        max_px: 2.0,
        min_features: 8,
    };
}

impl Default for RestConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// What the detector says about the newest frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RestVerdict {
    /// Too few features to tell (first, so that a new detector's bits are all zero).
    Unknown,
    /// At rest since `since_ns` (camera time of the reference frame).
    Rest {
        /// Camera time at which the rest began, ns.
        since_ns: i64,
    },
    /// Moving.
    Moving,
}

/// Image rest detector holding up to `F` features of its reference frame.
#[derive(Clone)]
pub struct RestDetector<const F: usize> {
    cfg: RestConfig,
    reference: Vec<NormalizedObs, F>,
    reference_t_ns: i64,
    verdict: RestVerdict,
    scratch: Vec<f64, F>,
}

impl<const F: usize> RestDetector<F> {
    /// A detector with no reference yet.
    pub const fn new(cfg: RestConfig) -> Self {
        RestDetector {
            cfg,
            reference: Vec::new(),
            reference_t_ns: 0,
            verdict: RestVerdict::Unknown,
            scratch: Vec::new(),
        }
    }

    /// The verdict on the last frame.
    pub fn verdict(&self) -> RestVerdict {
        self.verdict
    }

    /// Forgets everything.
    pub fn clear(&mut self) {
        self.reference.clear();
        self.verdict = RestVerdict::Unknown;
    }

    /// Back to the state [`RestDetector::new`] builds with `cfg`, in place.
    pub fn reset_to_new(&mut self, cfg: RestConfig) {
        self.cfg = cfg;
        self.clear();
        self.reference_t_ns = 0;
        self.scratch.clear();
    }

    /// Feeds a frame's observations (sorted by id, as [`super::TrackTable`] gives them) at camera
    /// time `t_ns`; `focal_px` converts normalized displacements to pixels.
    pub fn push(&mut self, t_ns: i64, obs: &[NormalizedObs], focal_px: f64) -> RestVerdict {
        self.scratch.clear();
        let mut j = 0;
        for o in obs {
            while self.reference.get(j).is_some_and(|r| r.id < o.id) {
                j += 1;
            }
            if let Some(r) = self.reference.get(j).filter(|r| r.id == o.id) {
                let (dx, dy) = (o.x_n[0] - r.x_n[0], o.x_n[1] - r.x_n[1]);
                let _ = self.scratch.push(libm::sqrt(dx * dx + dy * dy) * focal_px);
            }
        }
        let n = self.scratch.len();
        self.verdict = if n < self.cfg.min_features.max(1) {
            RestVerdict::Unknown
        } else {
            // Median by partial selection (deterministic: total order on finite values).
            self.scratch.sort_unstable_by(|a, b| a.total_cmp(b));
            let med = self.scratch.get(n / 2).copied().unwrap_or(f64::INFINITY);
            if med <= self.cfg.max_px {
                RestVerdict::Rest {
                    since_ns: self.reference_t_ns,
                }
            } else {
                RestVerdict::Moving
            }
        };
        if !matches!(self.verdict, RestVerdict::Rest { .. }) {
            self.reference.clear();
            for o in obs.iter().take(F) {
                let _ = self.reference.push(*o);
            }
            self.reference_t_ns = t_ns;
        }
        self.verdict
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(shift: f64, n: u64) -> Vec<NormalizedObs, 32> {
        (0..n)
            .map(|id| NormalizedObs {
                id,
                x_n: [0.01 * id as f64 + shift, 0.0],
                vel: [0.0; 2],
                row_dt_s: 0.0,
            })
            .collect()
    }

    #[test]
    fn rest_lasts_until_the_features_move() {
        let mut d: RestDetector<32> = RestDetector::new(RestConfig::default());
        let f = 500.0;
        assert_eq!(d.push(0, &frame(0.0, 20), f), RestVerdict::Unknown);
        // 1 px of jitter: still at rest since the first frame.
        assert_eq!(
            d.push(50, &frame(1.0 / f, 20), f),
            RestVerdict::Rest { since_ns: 0 }
        );
        assert_eq!(
            d.push(100, &frame(-1.5 / f, 20), f),
            RestVerdict::Rest { since_ns: 0 }
        );
        // Slow drift adds up against the reference: 3 px from it is motion.
        assert_eq!(d.push(150, &frame(3.0 / f, 20), f), RestVerdict::Moving);
        // A new rest is measured from the frame where the motion was seen.
        assert_eq!(
            d.push(200, &frame(3.5 / f, 20), f),
            RestVerdict::Rest { since_ns: 150 }
        );
        // Too few common features: no verdict.
        assert_eq!(d.push(250, &frame(3.5 / f, 4), f), RestVerdict::Unknown);
    }
}
