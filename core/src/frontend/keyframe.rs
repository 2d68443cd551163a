//! Keyframe selection (LE-VINS rules, thresholds as configuration).
//!
//! Between the last keyframe and the current frame, with `dt` the elapsed time, `dp` the
//! INS-predicted translation and `dr` the rotation angle:
//! - never a keyframe when `dt < min_interval_s` (0.096 s);
//! - a keyframe when `dr > max_rotation_rad` (10 deg), or when `dt >= min_translation_interval_s`
//!   (0.285 s) and `dp > min_translation_m` (0.2 m) — or, with `min_parallax_px` set (IC-GVINS),
//!   when the mean feature parallax exceeds it instead of the translation test;
//! - otherwise a keyframe at the latest after `max_interval_s` (0.475 s).

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
}

impl KeyframeConfig {
    /// The LE-VINS thresholds (what [`Default`] gives); `const` for static configurations.
    pub const DEFAULT: KeyframeConfig = KeyframeConfig {
        min_interval_s: 0.096,
        min_translation_m: 0.2,
        min_translation_interval_s: 0.285,
        max_rotation_rad: 10.0 * core::f64::consts::PI / 180.0,
        max_interval_s: 0.475,
        min_parallax_px: None,
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
    /// Maximum interval reached.
    Timeout,
}

impl KeyframeDecision {
    /// True for every decision except [`KeyframeDecision::No`].
    pub fn is_keyframe(self) -> bool {
        self != KeyframeDecision::No
    }
}

/// Stateless rule set over [`KeyframeConfig`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeyframeSelector {
    /// The thresholds.
    pub config: KeyframeConfig,
}

impl KeyframeSelector {
    /// Checks the thresholds (finite, non-negative, consistent ordering).
    pub fn new(config: KeyframeConfig) -> Result<Self, crate::Error> {
        let c = &config;
        let vals = [
            c.min_interval_s,
            c.min_translation_m,
            c.min_translation_interval_s,
            c.max_rotation_rad,
            c.max_interval_s,
            c.min_parallax_px.unwrap_or(0.0),
        ];
        if vals.iter().any(|v| !v.is_finite() || *v < 0.0) || c.max_interval_s < c.min_interval_s {
            return Err(crate::Error::InvalidConfig);
        }
        Ok(KeyframeSelector { config })
    }

    /// Decides for a frame `dt_s` after the last keyframe with the given predicted motion.
    pub fn decide(
        &self,
        dt_s: f64,
        translation_m: f64,
        rotation_rad: f64,
        mean_parallax_px: f64,
    ) -> KeyframeDecision {
        let c = &self.config;
        if dt_s < c.min_interval_s {
            return KeyframeDecision::No;
        }
        if rotation_rad > c.max_rotation_rad {
            return KeyframeDecision::Rotation;
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

    #[test]
    fn le_vins_rules() {
        let s = KeyframeSelector::new(KeyframeConfig::default()).unwrap();
        let deg = core::f64::consts::PI / 180.0;
        assert_eq!(s.decide(0.05, 5.0, 90.0 * deg, 0.0), KeyframeDecision::No);
        assert_eq!(
            s.decide(0.1, 0.0, 11.0 * deg, 0.0),
            KeyframeDecision::Rotation
        );
        assert_eq!(s.decide(0.2, 0.5, 1.0 * deg, 0.0), KeyframeDecision::No);
        assert_eq!(
            s.decide(0.3, 0.5, 1.0 * deg, 0.0),
            KeyframeDecision::Translation
        );
        assert_eq!(s.decide(0.3, 0.1, 1.0 * deg, 0.0), KeyframeDecision::No);
        assert_eq!(
            s.decide(0.48, 0.1, 1.0 * deg, 0.0),
            KeyframeDecision::Timeout
        );
        let p = KeyframeSelector::new(KeyframeConfig {
            min_parallax_px: Some(20.0),
            ..Default::default()
        })
        .unwrap();
        assert_eq!(p.decide(0.3, 5.0, 0.0, 10.0), KeyframeDecision::No);
        assert_eq!(p.decide(0.3, 0.0, 0.0, 25.0), KeyframeDecision::Translation);
        assert!(KeyframeSelector::new(KeyframeConfig {
            max_interval_s: f64::NAN,
            ..Default::default()
        })
        .is_err());
    }
}
