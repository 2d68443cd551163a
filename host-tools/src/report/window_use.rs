//! [`WindowUse`]: how much of what the window offers reaches the solver.

use crate::runner::percentile;
use povins_core::estimator::KeyframeReport;

/// How much of what the window offers reaches the solver: tracks with valid observations in at
/// least two of the window's keyframes ("multi-keyframe"), and how many of them and of their
/// observations the final solve of each keyframe used (a landmark's observations are its
/// residuals plus its anchor observation). Over the keyframes whose window holds at least two
/// keyframes.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct WindowUse {
    /// Keyframes counted.
    pub keyframes: usize,
    /// Multi-keyframe tracks the window offers, median per keyframe.
    pub offered_tracks_median: f64,
    /// Their observations, median per keyframe.
    pub offered_observations_median: f64,
    /// Landmarks in the final solve, median per keyframe.
    pub used_landmarks_median: f64,
    /// Observations in the final solve (residuals plus anchors), median per keyframe.
    pub used_observations_median: f64,
    /// Observations used over observations offered, summed over the keyframes (`None` when
    /// nothing was offered).
    pub observation_share: Option<f64>,
}

impl WindowUse {
    /// The figures of a run's keyframe reports.
    pub fn of(reports: &[KeyframeReport]) -> Self {
        let mut d = WindowUseDigest::default();
        for r in reports {
            d.push(r);
        }
        d.figures()
    }

    /// The `window` line of `povins run`'s summary (`None` before the window held two keyframes).
    pub fn line(&self) -> Option<String> {
        let share = self.observation_share?;
        Some(format!(
            "window    used {:.0} of {:.0} multi-keyframe tracks and {:.0} of {:.0} of their \
             observations (medians per keyframe); {:.1}% of all offered observations",
            self.used_landmarks_median,
            self.offered_tracks_median,
            self.used_observations_median,
            self.offered_observations_median,
            100.0 * share
        ))
    }
}

/// What [`WindowUse`] needs of the keyframe reports, accumulated one report at a time (four
/// counts per keyframe for the medians, and two sums).
#[derive(Debug, Clone, Default)]
pub struct WindowUseDigest {
    tracks: Vec<u32>,
    observations: Vec<u32>,
    landmarks: Vec<u32>,
    used: Vec<u32>,
    offered_sum: u64,
    used_sum: u64,
}

impl WindowUseDigest {
    /// Adds a keyframe's report (counted when its window holds at least two keyframes).
    pub fn push(&mut self, r: &KeyframeReport) {
        if r.window_len < 2 {
            return;
        }
        // A landmark's observations are its residuals plus its anchor observation.
        let used = r.observations_used + r.landmarks_used;
        self.tracks.push(r.multi_view_tracks);
        self.observations.push(r.multi_view_observations);
        self.landmarks.push(r.landmarks_used);
        self.used.push(used);
        self.offered_sum += u64::from(r.multi_view_observations);
        self.used_sum += u64::from(used);
    }

    /// The figures of the reports added.
    pub fn figures(&self) -> WindowUse {
        let median_of = |v: &[u32]| {
            let mut v = v.to_vec();
            v.sort_unstable();
            percentile(&v, 50.0)
        };
        WindowUse {
            keyframes: self.tracks.len(),
            offered_tracks_median: median_of(&self.tracks),
            offered_observations_median: median_of(&self.observations),
            used_landmarks_median: median_of(&self.landmarks),
            used_observations_median: median_of(&self.used),
            observation_share: (self.offered_sum > 0)
                .then(|| self.used_sum as f64 / self.offered_sum as f64),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::WindowUse;
    use povins_core::estimator::KeyframeReport;

    fn report(window_len: u32, offered: (u32, u32), used: (u32, u32)) -> KeyframeReport {
        KeyframeReport {
            window_len,
            multi_view_tracks: offered.0,
            multi_view_observations: offered.1,
            landmarks_used: used.0,
            observations_used: used.1,
            ..KeyframeReport::default()
        }
    }

    #[test]
    fn window_use_counts_anchors_and_skips_single_keyframe_windows() {
        let reports = [
            // A one-keyframe window offers nothing and must not dilute the figures.
            report(1, (0, 0), (0, 0)),
            report(2, (10, 30), (5, 10)),
            report(3, (20, 60), (10, 35)),
            report(4, (30, 90), (20, 60)),
        ];
        let w = WindowUse::of(&reports);
        assert_eq!(w.keyframes, 3);
        assert_eq!(w.offered_tracks_median, 20.0);
        assert_eq!(w.offered_observations_median, 60.0);
        assert_eq!(w.used_landmarks_median, 10.0);
        // Residuals plus one anchor observation per landmark: 15, 45, 80.
        assert_eq!(w.used_observations_median, 45.0);
        assert_eq!(w.observation_share, Some(140.0 / 180.0));
        let line = w.line().unwrap_or_default();
        assert!(
            line.contains("used 10 of 20 multi-keyframe tracks"),
            "{line}"
        );
        assert!(line.contains("77.8%"), "{line}");
        assert_eq!(WindowUse::of(&reports[..1]).line(), None);
    }
}
