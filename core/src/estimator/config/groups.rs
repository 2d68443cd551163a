//! The estimator configuration's groups (TOML tables `[zupt]`, `[td]`, `[cull]`): the
//! zero-velocity updates, the camera-IMU time delay's estimation, and the outlier culls.

use crate::ranges::{self, Ranges};
use crate::Error;

/// Zero-velocity updates: while the images show the platform at rest, keyframes get a
/// zero-velocity factor and consecutive ones a zero-motion factor.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct ZuptConfig {
    /// Add the factors at all.
    pub enabled: bool,
    /// Standard deviation of the zero-velocity factor, m/s.
    pub sigma_mps: f64,
    /// Largest speed the INS may show at a keyframe for the images' rest to be believed, m/s.
    /// Features far ahead of a platform moving towards them hardly move in the image (a robot
    /// at 0.9 m/s: under 2 px in 0.3 s with exact tracks), so the images alone take slow forward
    /// motion for rest, and they see a start late (a robot 0.5 s after it set off: 0.1 m/s,
    /// 2 cm, under 2 px). Like any measurement, a zero velocity must agree with the state it
    /// corrects: 0.05 m/s is five of the factor's sigmas and above a healthy window's velocity
    /// error at rest (EuRoC's vibrating MAV keeps all its rest keyframes down to 0.03 m/s).
    pub max_speed_mps: f64,
    /// Standard deviation of the zero-motion factor between keyframes at rest, position, m.
    pub motion_sigma_m: f64,
    /// Standard deviation of the zero-motion factor between keyframes at rest, rotation, rad.
    pub motion_sigma_rad: f64,
}

impl ZuptConfig {
    /// The defaults (what [`Default`] gives); `const` for static configurations.
    pub const DEFAULT: ZuptConfig = ZuptConfig {
        enabled: true,
        sigma_mps: 0.01,
        max_speed_mps: 0.05,
        motion_sigma_m: 2e-3,
        motion_sigma_rad: 2e-3,
    };

    /// Checks ranges ([`Self::check_ranges`]).
    pub fn validate(&self) -> Result<(), Error> {
        ranges::validate(|r| self.check_ranges(r))
    }

    /// The range checks (`[zupt]`): positive standard deviations and speed limit.
    pub fn check_ranges(&self, r: &mut Ranges<'_>) {
        r.positive("zupt.sigma_mps", self.sigma_mps);
        r.positive("zupt.max_speed_mps", self.max_speed_mps);
        r.positive("zupt.motion_sigma_m", self.motion_sigma_m);
        r.positive("zupt.motion_sigma_rad", self.motion_sigma_rad);
    }
}

impl Default for ZuptConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Estimation of the camera-IMU time delay (`t_imu = t_cam + td`, a random walk between
/// keyframes; its initial value is [`super::EstimatorConfig::td_s`]).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct TdConfig {
    /// Estimate the delay (otherwise it stays at its initial value).
    pub estimate: bool,
    /// Random-walk density of the time delay, s/sqrt(s).
    pub rw_s_per_sqrt_s: f64,
    /// Prior standard deviation of the first time delay, s. Wide: a blind start (td = 0) must
    /// reach a true delay of tens of ms; the 5 ms used before 2026-12-02 lived on in the
    /// marginalization prior and held a true -25 ms 3-4 ms off at 20 s (BENCHMARKS.md, issue 31).
    pub prior_s: f64,
    /// The delay is held (not estimated) in a solve whose admitted observations carry less
    /// information on it than this, `sum |v * f| ^ 2 / sigma_px ^ 2` over their feature velocities
    /// `v` (1/s), focal lengths `f` (px) and pixel noise (px), 1/s^2: the features of a slow
    /// start (a ramp from rest) move too little to separate the delay from the motion, and what
    /// the velocity model gets wrong then decides the estimate. Replaces the landmark count
    /// (`min_landmarks`) of the hold before 2026-12-02.
    pub min_info_per_s2: f64,
}

/// Default of [`TdConfig::min_info_per_s2`], 1/s^2: a delay standard deviation of 1 ms from the
/// observations alone (measured on the simulated calm flight: reached 1-2 s into its ramp
/// from rest).
pub const MIN_INFO_PER_S2: f64 = 1e6;

impl TdConfig {
    /// The defaults (what [`Default`] gives); `const` for static configurations.
    pub const DEFAULT: TdConfig = TdConfig {
        estimate: true,
        rw_s_per_sqrt_s: 1e-4,
        prior_s: 5e-2,
        min_info_per_s2: MIN_INFO_PER_S2,
    };

    /// Checks ranges ([`Self::check_ranges`]).
    pub fn validate(&self) -> Result<(), Error> {
        ranges::validate(|r| self.check_ranges(r))
    }

    /// The range checks (`[td]`): a positive random-walk density and prior, a non-negative
    /// information.
    pub fn check_ranges(&self, r: &mut Ranges<'_>) {
        r.positive("td.rw_s_per_sqrt_s", self.rw_s_per_sqrt_s);
        r.positive("td.prior_s", self.prior_s);
        r.non_negative("td.min_info_per_s2", self.min_info_per_s2);
    }
}

impl Default for TdConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Outlier culls: the chi-square cull between the two LM passes and the reprojection cull after
/// the solve (paper V.E).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct CullConfig {
    /// Chi-square threshold (2 dof, 95%) of the cull between the two LM passes.
    pub chi2_threshold: f64,
    /// The second LM pass runs when the chi-square cull removed at least this fraction of the
    /// observations (and at least one): an outlier burst. Removing a few Huber-weighted outliers
    /// barely moves the optimum, and the next keyframe's solve starts from there anyway (0.02
    /// before 2026-11-29, a second pass at 63% of the corridor's keyframes; 0.1 gave an ATE
    /// geometric mean ratio of 0.965 over 102 regression sequences and the corridor's back-end
    /// median 1.99 -> 1.74 ms).
    pub second_pass_min_culled_frac: f64,
    /// Drop a landmark whose mean reprojection error exceeds this after the solve, px.
    pub mean_px: f64,
    /// Drop a single observation whose reprojection error exceeds this, px.
    pub obs_px: f64,
    /// Drop (and ban) the whole track instead of the single observation.
    pub whole_tracks: bool,
}

impl CullConfig {
    /// The defaults (what [`Default`] gives); `const` for static configurations.
    pub const DEFAULT: CullConfig = CullConfig {
        chi2_threshold: 5.991,
        second_pass_min_culled_frac: 0.1,
        mean_px: 4.5,
        obs_px: 4.5,
        whole_tracks: false,
    };

    /// Checks ranges ([`Self::check_ranges`]).
    pub fn validate(&self) -> Result<(), Error> {
        ranges::validate(|r| self.check_ranges(r))
    }

    /// The range checks (`[cull]`): positive thresholds, a fraction in `[0, 1]`.
    pub fn check_ranges(&self, r: &mut Ranges<'_>) {
        r.positive("cull.chi2_threshold", self.chi2_threshold);
        let frac = self.second_pass_min_culled_frac;
        r.within("cull.second_pass_min_culled_frac", frac, 0.0, 1.0, "0..=1");
        r.positive("cull.mean_px", self.mean_px);
        r.positive("cull.obs_px", self.obs_px);
    }
}

impl Default for CullConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// The work budget of one keyframe's solve (`[solve_budget]`), for a bounded time per keyframe:
/// the Levenberg-Marquardt passes (the first, and the second after the chi-square cull) share
/// at most `max_linearizations` linearizations, `max_trials` trial steps (each a damped
/// factorization and a cost evaluation) and a work of `max_work` units, or `max_work_ratio`
/// times the median work of the last keyframes' solves, whichever is least. The work grows with
/// the data where a count of iterations does not: its unit is one observation's residual
/// evaluated, an eliminated depth's inner solve counting each of its passes, a linearization
/// 12 per observation (`problem::factor::linearization_work`); `KeyframeReport::solve_work`
/// reports each keyframe's. A step is not started when the work it is predicted to take (the
/// last one's) would pass the budget, and the first iteration always runs, so the solve's work
/// is at most the budget plus one misprediction, or its first iteration.
///
/// When it runs out, the solve keeps its best state (a step is applied only when it lowers the
/// cost) and the keyframe goes on: the culls, the depth-only optimization and the
/// marginalization always complete. The budget counts work, not time, so the output stays
/// bit-identical from run to run and across machines.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct SolveBudget {
    /// Linearizations of the window over both passes (`u32::MAX`: no budget).
    pub max_linearizations: u32,
    /// Trial steps over both passes (`u32::MAX`: no budget).
    pub max_trials: u32,
    /// Work over both passes, in units of one observation's residual evaluated (`u32::MAX`: no
    /// budget). A platform's figure: `povins run`'s `stats.csv` gives each keyframe's
    /// `solve_work` beside its `solve_ms`.
    pub max_work: u32,
    /// Work over both passes relative to the median of what the last
    /// [`SolveBudget::HISTORY`] keyframes' solves took, or would have taken without the budget
    /// (the work done plus the step the budget refused: the work done alone would ratchet down),
    /// applied once [`SolveBudget::HISTORY_MIN`] keyframes have been solved since the estimator
    /// started (`inf`: no budget). A bound that follows the data: the worst keyframe's solve at
    /// about this many times the typical one's.
    pub max_work_ratio: f64,
}

impl SolveBudget {
    /// No budget: each pass stops by its own `max_iterations` and `max_retries` only.
    pub const UNLIMITED: SolveBudget = SolveBudget {
        max_linearizations: u32::MAX,
        max_trials: u32::MAX,
        max_work: u32::MAX,
        max_work_ratio: f64::INFINITY,
    };

    /// The defaults (what [`Default`] gives).
    pub const DEFAULT: SolveBudget = SolveBudget::UNLIMITED;

    /// Keyframes whose solve's work the median of `max_work_ratio` is taken over.
    pub const HISTORY: usize = 16;

    /// Keyframes solved before `max_work_ratio` applies.
    pub const HISTORY_MIN: usize = 4;

    /// The range checks (`[solve_budget]`): at least one of each, a ratio of at least 1.
    pub fn check_ranges(&self, r: &mut Ranges<'_>) {
        r.check(
            "solve_budget.max_linearizations",
            f64::from(self.max_linearizations),
            ">= 1",
            self.max_linearizations >= 1,
        );
        r.check(
            "solve_budget.max_trials",
            f64::from(self.max_trials),
            ">= 1",
            self.max_trials >= 1,
        );
        r.check(
            "solve_budget.max_work",
            f64::from(self.max_work),
            ">= 1",
            self.max_work >= 1,
        );
        r.check(
            "solve_budget.max_work_ratio",
            self.max_work_ratio,
            ">= 1 (inf: no budget)",
            self.max_work_ratio >= 1.0,
        );
    }

    /// The work this keyframe's solve may take, given the `history` of the last solves' work
    /// (any order; only its first [`SolveBudget::HISTORY`] entries are read).
    pub fn work_limit(&self, history: &[u32]) -> u32 {
        let mut h = [0u32; Self::HISTORY];
        let n = history.len().min(Self::HISTORY);
        for (d, s) in h.iter_mut().zip(history.iter()) {
            *d = *s;
        }
        let h = h.get_mut(..n).unwrap_or(&mut []);
        if n < Self::HISTORY_MIN || !self.max_work_ratio.is_finite() {
            return self.max_work;
        }
        h.sort_unstable();
        // The upper median: deterministic, an observed value.
        let median = f64::from(h.get(n / 2).copied().unwrap_or(0));
        let rel = self.max_work_ratio * median;
        let rel = if rel >= f64::from(u32::MAX) {
            u32::MAX
        } else {
            // Truncation toward zero of a finite, non-negative value below u32::MAX.
            rel as u32
        };
        self.max_work.min(rel.max(1))
    }
}

impl Default for SolveBudget {
    fn default() -> Self {
        Self::DEFAULT
    }
}

#[cfg(test)]
mod tests {
    use super::SolveBudget;

    fn budget(max_work: u32, max_work_ratio: f64) -> SolveBudget {
        SolveBudget {
            max_work,
            max_work_ratio,
            ..SolveBudget::UNLIMITED
        }
    }

    #[test]
    fn the_work_limit_is_the_least_of_the_absolute_and_the_relative_budget() {
        let h = [40, 10, 30, 20, 50];
        // The upper median of five is the third smallest: 30.
        assert_eq!(budget(u32::MAX, 1.5).work_limit(&h), 45);
        assert_eq!(budget(40, 1.5).work_limit(&h), 40);
        assert_eq!(budget(100, f64::INFINITY).work_limit(&h), 100);
        assert_eq!(SolveBudget::UNLIMITED.work_limit(&h), u32::MAX);
        // Too short a history: the absolute budget only.
        let short = [10, 20, 30];
        assert!(short.len() < SolveBudget::HISTORY_MIN);
        assert_eq!(budget(100, 1.5).work_limit(&short), 100);
        // Only the first HISTORY entries count; their order does not.
        let mut long = [1000u32; SolveBudget::HISTORY + 4];
        for (i, w) in long.iter_mut().enumerate().take(SolveBudget::HISTORY) {
            *w = 10 + i as u32;
        }
        let mut rev = long;
        if let Some(s) = rev.get_mut(..SolveBudget::HISTORY) {
            s.reverse();
        }
        let a = budget(u32::MAX, 2.0).work_limit(&long);
        assert_eq!(a, 2 * (10 + SolveBudget::HISTORY as u32 / 2));
        assert_eq!(budget(u32::MAX, 2.0).work_limit(&rev), a);
        // A zero median still leaves one unit; a huge one saturates.
        assert_eq!(budget(u32::MAX, 1.0).work_limit(&[0; 8]), 1);
        assert_eq!(budget(u32::MAX, 4.0).work_limit(&[u32::MAX; 8]), u32::MAX);
    }

    #[test]
    fn the_ranges_refuse_an_empty_budget_and_a_ratio_below_one() {
        for b in [
            budget(0, f64::INFINITY),
            budget(1, 0.5),
            budget(1, f64::NAN),
        ] {
            let bad = crate::ranges::first_invalid(|r| b.check_ranges(r));
            assert!(bad.is_some(), "{b:?}");
        }
        let bad = crate::ranges::first_invalid(|r| budget(1, 1.0).check_ranges(r));
        assert_eq!(bad, None);
    }
}
