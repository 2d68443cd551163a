//! Keyframe selection (LE-VINS rules, thresholds as configuration).
//!
//! Between the last keyframe and the current frame, with `dt` the elapsed time, `dp` the
//! INS-predicted translation and `dr` the rotation angle:
//! - never a keyframe when `dt < min_interval_s` (0.096 s);
//! - a keyframe when `dr > max_rotation_rad` (10 deg), or when `dt >= min_translation_interval_s`
//!   (0.285 s) and `dp > min_translation_m` (0.2 m) — or, with `min_parallax_px` set (IC-GVINS),
//!   when the mean feature parallax exceeds it instead of the translation test;
//! - otherwise a keyframe at the latest after `max_interval_s` (0.475 s).
//!
//! Two options (off by default) give VINS-Mono's rule instead: `compensate_rotation` measures the
//! parallax after removing the predicted rotation (so a turn alone makes none), and
//! `min_tracked_ratio` makes a keyframe when fewer than that share of the newest keyframe's
//! features are still tracked (what the rotation rule stands in for: tracks leaving the view).

/// Keyframe thresholds.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct KeyframeConfig {
    /// No keyframe closer than this to the previous one, s.
    pub min_interval_s: f64,
    /// Translation threshold, m.
    pub min_translation_m: f64,
    /// The translation (or parallax) test applies only after this long, s.
    pub min_translation_interval_s: f64,
    /// Rotation threshold, rad.
    pub max_rotation_rad: f64,
    /// A keyframe is forced after this long, s.
    pub max_interval_s: f64,
    /// When set, mean pixel parallax replaces the translation test (IC-GVINS), px.
    #[cfg_attr(
        feature = "serde",
        serde(default, skip_serializing_if = "Option::is_none")
    )]
    pub min_parallax_px: Option<f64>,
    /// Measure the parallax of `min_parallax_px` after removing the INS-predicted rotation
    /// since the newest keyframe (VINS-Mono).
    pub compensate_rotation: bool,
    /// A keyframe (after `min_interval_s`) when fewer than this share of the newest keyframe's
    /// features are tracked in the frame; 0 = off.
    pub min_tracked_ratio: f64,
}

impl KeyframeConfig {
    /// The range checks (`[keyframe]`): finite, non-negative thresholds, `max_interval_s` not
    /// below `min_interval_s`, a ratio in `0..=1`.
    pub fn check_ranges(&self, r: &mut crate::ranges::Ranges<'_>) {
        r.non_negative("keyframe.min_interval_s", self.min_interval_s);
        r.non_negative("keyframe.min_translation_m", self.min_translation_m);
        let dt = self.min_translation_interval_s;
        r.non_negative("keyframe.min_translation_interval_s", dt);
        r.non_negative("keyframe.max_rotation_rad", self.max_rotation_rad);
        r.non_negative("keyframe.max_interval_s", self.max_interval_s);
        if let Some(px) = self.min_parallax_px {
            r.non_negative("keyframe.min_parallax_px", px);
        }
        let ratio = self.min_tracked_ratio;
        r.within("keyframe.min_tracked_ratio", ratio, 0.0, 1.0, "0..=1");
        r.check(
            "keyframe.max_interval_s",
            self.max_interval_s,
            ">= keyframe.min_interval_s",
            self.max_interval_s >= self.min_interval_s,
        );
    }

    /// The LE-VINS thresholds (what [`Default`] gives); `const` for static configurations.
    pub const DEFAULT: KeyframeConfig = KeyframeConfig {
        min_interval_s: 0.096,
        min_translation_m: 0.2,
        min_translation_interval_s: 0.285,
        max_rotation_rad: 10.0 * core::f64::consts::PI / 180.0,
        max_interval_s: 0.475,
        min_parallax_px: None,
        compensate_rotation: false,
        min_tracked_ratio: 0.0,
    };
}

impl Default for KeyframeConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Why a frame became (or did not become) a keyframe.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum KeyframeDecision {
    /// Not a keyframe.
    #[default]
    No,
    /// First frame after initialization.
    First,
    /// Rotation exceeded the threshold.
    Rotation,
    /// Translation (or parallax) exceeded the threshold.
    Translation,
    /// Too few of the newest keyframe's features are still tracked.
    Tracks,
    /// Maximum interval reached.
    Timeout,
}

impl KeyframeDecision {
    /// True for every decision except [`KeyframeDecision::No`].
    pub fn is_keyframe(self) -> bool {
        self != KeyframeDecision::No
    }
}

/// Mean pixel distance between the normalized image points of `pairs` (`(keyframe, current)`)
/// at focal length `focal_px`, and how many pairs entered it. With `r_ck` (the rotation taking
/// keyframe-camera rays into the current camera's) the keyframe point is rotated first, so a
/// pure rotation gives no parallax; a point whose rotated ray is not in front is skipped.
pub fn mean_parallax_px(
    pairs: impl Iterator<Item = ([f64; 2], [f64; 2])>,
    r_ck: Option<&crate::math::Quat>,
    focal_px: f64,
) -> (f64, usize) {
    let (mut sum, mut n) = (0.0, 0usize);
    for (k, c) in pairs {
        let mut x = k;
        if let Some(r) = r_ck {
            let ray = r * crate::math::Vec3::new(k[0], k[1], 1.0);
            if ray.z <= 1e-6 {
                continue;
            }
            x = [ray.x / ray.z, ray.y / ray.z];
        }
        let (dx, dy) = (c[0] - x[0], c[1] - x[1]);
        sum += libm::sqrt(dx * dx + dy * dy) * focal_px;
        n += 1;
    }
    (if n == 0 { 0.0 } else { sum / n as f64 }, n)
}

/// Stateless rule set over [`KeyframeConfig`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeyframeSelector {
    /// The thresholds.
    pub config: KeyframeConfig,
}

impl KeyframeSelector {
    /// Checks the thresholds (finite, non-negative, consistent ordering:
    /// [`KeyframeConfig::check_ranges`]).
    pub fn new(config: KeyframeConfig) -> Result<Self, crate::Error> {
        crate::ranges::validate(|r| config.check_ranges(r))?;
        Ok(KeyframeSelector { config })
    }

    /// Decides for a frame `dt_s` after the last keyframe with the given predicted motion,
    /// mean parallax and share of the last keyframe's features tracked.
    pub fn decide(
        &self,
        dt_s: f64,
        translation_m: f64,
        rotation_rad: f64,
        mean_parallax_px: f64,
        tracked_ratio: f64,
    ) -> KeyframeDecision {
        let c = &self.config;
        if dt_s < c.min_interval_s {
            return KeyframeDecision::No;
        }
        if rotation_rad > c.max_rotation_rad {
            return KeyframeDecision::Rotation;
        }
        if tracked_ratio < c.min_tracked_ratio {
            return KeyframeDecision::Tracks;
        }
        if dt_s >= c.min_translation_interval_s {
            let moved = match c.min_parallax_px {
                Some(px) => mean_parallax_px > px,
                None => translation_m > c.min_translation_m,
            };
            if moved {
                return KeyframeDecision::Translation;
            }
        }
        if dt_s >= c.max_interval_s {
            return KeyframeDecision::Timeout;
        }
        KeyframeDecision::No
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{Quat, Vec3};

    #[test]
    fn compensated_parallax_of_a_pure_rotation_is_zero() {
        let r_ck = Quat::from_euler_angles(0.05, -0.1, 0.2);
        let points = [
            Vec3::new(0.1, -0.2, 4.0),
            Vec3::new(-1.0, 0.5, 6.0),
            Vec3::new(0.3, 0.3, 2.0),
        ];
        let proj = |p: Vec3| [p.x / p.z, p.y / p.z];
        // The camera only turned: each point's ray is rotated, none moved.
        let pairs = || points.iter().map(|p| (proj(*p), proj(r_ck * p)));
        let (raw, n) = mean_parallax_px(pairs(), None, 400.0);
        assert!(raw > 20.0 && n == 3, "raw parallax {raw} px");
        let (comp, n) = mean_parallax_px(pairs(), Some(&r_ck), 400.0);
        assert!(comp < 1e-9 && n == 3, "compensated {comp} px");
        // A translation on top shows: 0.2 m sideways at 2-6 m depth.
        let moved = || {
            points
                .iter()
                .map(|p| (proj(*p), proj(r_ck * p + Vec3::new(0.2, 0.0, 0.0))))
        };
        let (comp, _) = mean_parallax_px(moved(), Some(&r_ck), 400.0);
        assert!(
            comp > 10.0,
            "compensated parallax of a translation {comp} px"
        );
    }

    #[test]
    fn le_vins_rules() {
        let s = KeyframeSelector::new(KeyframeConfig::default()).unwrap();
        let deg = core::f64::consts::PI / 180.0;
        assert_eq!(
            s.decide(0.05, 5.0, 90.0 * deg, 0.0, 1.0),
            KeyframeDecision::No
        );
        assert_eq!(
            s.decide(0.1, 0.0, 11.0 * deg, 0.0, 1.0),
            KeyframeDecision::Rotation
        );
        assert_eq!(
            s.decide(0.2, 0.5, 1.0 * deg, 0.0, 1.0),
            KeyframeDecision::No
        );
        assert_eq!(
            s.decide(0.3, 0.5, 1.0 * deg, 0.0, 1.0),
            KeyframeDecision::Translation
        );
        assert_eq!(
            s.decide(0.3, 0.1, 1.0 * deg, 0.0, 1.0),
            KeyframeDecision::No
        );
        assert_eq!(
            s.decide(0.48, 0.1, 1.0 * deg, 0.0, 1.0),
            KeyframeDecision::Timeout
        );
        let p = KeyframeSelector::new(KeyframeConfig {
            min_parallax_px: Some(20.0),
            ..Default::default()
        })
        .unwrap();
        assert_eq!(p.decide(0.3, 5.0, 0.0, 10.0, 1.0), KeyframeDecision::No);
        assert_eq!(
            p.decide(0.3, 0.0, 0.0, 25.0, 1.0),
            KeyframeDecision::Translation
        );
        let v = KeyframeSelector::new(KeyframeConfig {
            min_tracked_ratio: 0.5,
            ..Default::default()
        })
        .unwrap();
        assert_eq!(v.decide(0.05, 0.0, 0.0, 0.0, 0.1), KeyframeDecision::No);
        assert_eq!(v.decide(0.1, 0.0, 0.0, 0.0, 0.49), KeyframeDecision::Tracks);
        assert_eq!(v.decide(0.1, 0.0, 0.0, 0.0, 0.5), KeyframeDecision::No);
        assert!(KeyframeSelector::new(KeyframeConfig {
            min_tracked_ratio: 1.5,
            ..Default::default()
        })
        .is_err());
        assert!(KeyframeSelector::new(KeyframeConfig {
            max_interval_s: f64::NAN,
            ..Default::default()
        })
        .is_err());
    }
}
