//! The feature tracker: pyramid, seeded pyramidal LK, forward-backward check, RANSAC, top-up
//! detection, ids and ages, in fixed memory.
//!
//! This module holds the configuration, the statistics, the tracker's state and its per-frame
//! entry point ([`FeatureTracker::track`]); the steps of a frame are in submodules: `forward`
//! (seeding, forward LK, forward-backward check), `patches` (anchored refinement, first-steps
//! check), `outliers` (undistortion, RANSAC, compaction of the survivors) and `top_up` (new
//! corners).

use super::corners::{Corner, DetectStats, DetectorConfig, GridDetector};
use super::equalize::Equalization;
use super::lk::{LkConfig, LkScratch};
use super::provisional::ProvisionalConfig;
use super::pyramid::{pyramid_bytes, Pyramid, PyramidFilter};
use super::ransac::{RansacConfig, RansacModel, RansacOutcome};
use super::reference::{ReferenceConfig, References};
use super::view::ImageView;
use crate::camera::{FeatureObs, PinholeCamera};
use crate::math::Mat3;
use crate::Error;
use heapless::Vec;

mod forward;
mod outliers;
mod patches;
mod top_up;

/// Everything the tracker can be tuned with. [`Default`] follows LE-VINS / VINS-Fusion: 150
/// features, 21x21 window, pyramid levels 0..=3, one level when the INS predicts the position,
/// forward-backward check at 0.5 px, epipolar RANSAC at 1.5 px (8-point; 3 px for the 2-point
/// model with the gyro rotation), minimum distance 20 px, an 8 x 6 grid.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct TrackerConfig {
    /// Features kept per frame (top-up target), at most the tracker's `F`.
    pub max_features: usize,
    /// Corner detection.
    pub detector: DetectorConfig,
    /// Lucas-Kanade.
    pub lk: LkConfig,
    /// Coarsest pyramid level for features seeded at their previous position (OpenCV's
    /// `maxLevel`; the pyramid has `max_level + 1` levels, at most the tracker's `LEVELS`).
    pub max_level: usize,
    /// Coarsest level for features seeded by an INS prediction (LE-VINS: 1).
    pub predicted_max_level: usize,
    /// Coarsest level for features seeded by the gyro rotation.
    pub rotation_max_level: usize,
    /// Whether tracks are checked by tracking back to the previous frame.
    pub fb_check: bool,
    /// Largest forward-backward round-trip error, px.
    pub fb_threshold_px: f32,
    /// Coarsest level of the backward track (seeded at the original position, as VINS-Fusion).
    pub fb_max_level: usize,
    /// Geometric outlier rejection.
    pub ransac: RansacConfig,
    /// Pyramid downsampling filter.
    pub pyramid_filter: PyramidFilter,
    /// Contrast equalization of the input.
    pub equalization: Equalization,
    /// Anchored refinement against each track's reference patch.
    pub reference: ReferenceConfig,
    /// First-steps check of new tracks against their detection patch (occlusion-edge corners).
    pub provisional: ProvisionalConfig,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        TrackerConfig {
            max_features: 150,
            detector: DetectorConfig::default(),
            lk: LkConfig::default(),
            max_level: 3,
            predicted_max_level: 1,
            rotation_max_level: 1,
            fb_check: true,
            fb_threshold_px: 0.5,
            fb_max_level: 0,
            ransac: RansacConfig::default(),
            pyramid_filter: PyramidFilter::Gaussian5,
            equalization: Equalization::Off,
            reference: ReferenceConfig::default(),
            provisional: ProvisionalConfig::default(),
        }
    }
}

impl TrackerConfig {
    /// What an unconfigured tracker holds ([`FeatureTracker::empty`]): every number zero
    /// (invalid: [`Self::validate`] refuses it).
    pub const PLACEHOLDER: TrackerConfig = TrackerConfig {
        max_features: 0,
        detector: DetectorConfig {
            grid_cols: 0,
            grid_rows: 0,
            max_per_cell: 0,
            min_distance_px: 0.0,
            quality_level: 0.0,
            min_eigen: 0.0,
            border_px: 0,
            quality_from_tracks: false,
        },
        lk: LkConfig {
            window: 0,
            coarse_window: 0,
            max_iterations: 0,
            epsilon_px: 0.0,
            coarse_epsilon_px: 0.0,
            min_eigen: 0.0,
            max_residual: 0.0,
            photometric: super::affine::Photometric::None,
        },
        max_level: 0,
        predicted_max_level: 0,
        rotation_max_level: 0,
        fb_check: false,
        fb_threshold_px: 0.0,
        fb_max_level: 0,
        ransac: RansacConfig {
            model: RansacModel::Off,
            threshold_px: 0.0,
            two_point_threshold_px: 0.0,
            confidence: 0.0,
            max_iterations: 0,
            seed: 0,
            eight_point_min_flow_px: 0.0,
        },
        pyramid_filter: PyramidFilter::Gaussian5,
        equalization: Equalization::Off,
        reference: ReferenceConfig::PLACEHOLDER,
        provisional: ProvisionalConfig::PLACEHOLDER,
    };

    /// Checks every parameter's range ([`Error::InvalidConfig`] otherwise). The capacities of a
    /// particular tracker are checked by [`FeatureTracker::new`].
    pub fn validate(&self) -> Result<(), Error> {
        self.detector.validate()?;
        self.lk.validate()?;
        self.ransac.validate()?;
        self.equalization.validate()?;
        self.reference.validate()?;
        self.provisional.validate()?;
        let ok = self.max_features >= 1
            && self.max_level <= 8
            && self.predicted_max_level <= self.max_level
            && self.rotation_max_level <= self.max_level
            && self.fb_max_level <= self.max_level
            && self.fb_threshold_px > 0.0
            && self.fb_threshold_px <= 100.0;
        if ok {
            Ok(())
        } else {
            Err(Error::InvalidConfig)
        }
    }
}

/// What the caller knows about the motion since the previous frame.
#[derive(Debug, Clone, Copy, Default)]
pub struct TrackHints<'a> {
    /// Rotation of the previous camera frame into the current one, `R_cur_prev` (camera axes,
    /// e.g. from the integrated gyro and the camera-IMU extrinsic). Seeds the features without a
    /// prediction and enables the 2-point RANSAC.
    pub r_cur_prev: Option<Mat3>,
    /// Predicted raw pixels `(id, [u, v])` of features whose depth is known (the INS
    /// prediction, [`crate::estimator::Estimator::predict_features`]); those are tracked on
    /// `predicted_max_level + 1` levels only. Unknown ids and non-finite pixels are ignored.
    pub predictions: &'a [(u64, [f64; 2])],
}

impl TrackHints<'static> {
    /// No rotation, no predictions.
    pub const NONE: TrackHints<'static> = TrackHints {
        r_cur_prev: None,
        predictions: &[],
    };
}

/// How the geometric check ran on a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RansacRun {
    /// Not run (disabled, first frame, or too few points).
    #[default]
    None,
    /// 2-point model with the gyro rotation.
    TwoPoint,
    /// 8-point fundamental matrix.
    EightPoint,
    /// 8-point skipped: median image motion below `eight_point_min_flow_px` and no gyro
    /// rotation for the 2-point model.
    SkippedLowFlow,
}

/// Per-frame counts: every feature that enters is tracked or counted as lost for one reason.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TrackStats {
    /// Frame index (0 for the first frame processed).
    pub frame: u64,
    /// All tracks were dropped because the image size changed.
    pub reset: bool,
    /// Tracks from the previous frame.
    pub previous: u32,
    /// Of those, seeded by an INS prediction.
    pub seeded_prediction: u32,
    /// Seeded by the gyro rotation.
    pub seeded_rotation: u32,
    /// Seeded at the previous position.
    pub seeded_previous: u32,
    /// Lost: too little texture in the template (LK eigenvalue check).
    pub lost_small_eigen: u32,
    /// Lost: left the image (during LK or at the end).
    pub lost_out_of_image: u32,
    /// Lost: photometric residual above `lk.max_residual`.
    pub lost_residual: u32,
    /// Lost: LK produced a non-finite position.
    pub lost_nonfinite: u32,
    /// Lost: forward-backward check.
    pub lost_forward_backward: u32,
    /// Lost: RANSAC outlier.
    pub lost_ransac: u32,
    /// Lost: the anchored refinement converged far from the frame-to-frame position.
    pub lost_reference: u32,
    /// Lost: a new track's detection patch is not explained by one surface (first-steps
    /// check, [`super::provisional`]).
    pub lost_provisional: u32,
    /// Tracks whose position was refined against their reference patch.
    pub refined: u32,
    /// Tracks whose reference patch was re-anchored (refinement not accepted).
    pub reanchored: u32,
    /// Median distance between the refined and the frame-to-frame positions over the frame's
    /// converged refinements, px (0 without any).
    pub reference_median_shift_px: f32,
    /// Tracks that survived every check.
    pub tracked: u32,
    /// Of those, level 0 stopped on the iteration cap rather than converging.
    pub not_converged: u32,
    /// Lucas-Kanade iterations (forward and backward, all levels).
    pub lk_iterations: u32,
    /// Tracked points that could not be undistorted (kept, but without geometric check).
    pub undistort_failed: u32,
    /// How RANSAC ran.
    pub ransac_run: RansacRun,
    /// RANSAC details.
    pub ransac: RansacOutcome,
    /// Corner detection details.
    pub detect: DetectStats,
    /// New features added.
    pub detected: u32,
    /// Features after the frame.
    pub total: u32,
}

/// Tracker for up to 256 features on images up to 752x480 pixels (EuRoC; any smaller image
/// such as 640x360 fits too), 4 pyramid levels: 1 457 248 bytes (two pyramids of 536 856 bytes:
/// [`pyramid_bytes`]`(752, 480, 4)` = 479 400 plus 32 KiB of row scratch and the 24 KiB
/// equalizer; the detector's 122 KiB; the LK scratch's 11 KiB; 54 KiB of per-feature arrays;
/// 191 KiB of reference templates and scratch for the anchored refinement).
pub type EurocTracker = FeatureTracker<256, { pyramid_bytes(752, 480, 4) }, 4>;

/// Tracker for up to 1280x720 images, 256 features, 4 levels: 2 946 448 bytes.
pub type HdTracker = FeatureTracker<256, { pyramid_bytes(1280, 720, 4) }, 4>;

/// Per-feature outcome of the forward pass.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Fate {
    Alive,
    Lost,
}

/// The image front end: holds the previous and current pyramids and up to `F` tracks.
///
/// `BYTES` sizes each pyramid ([`pyramid_bytes`] of the largest image and `LEVELS`); `LEVELS`
/// must be at least `max_level + 1`. The struct is large: keep it in a `static`, a `Box`, or a
/// thread with a large stack.
#[derive(Clone)]
pub struct FeatureTracker<const F: usize, const BYTES: usize, const LEVELS: usize> {
    cfg: TrackerConfig,
    pyr: [Pyramid<BYTES, LEVELS>; 2],
    cur: usize,
    has_prev: bool,
    dims: (usize, usize),
    last_t_ns: Option<i64>,
    frame: u64,
    next_id: u64,
    features: Vec<FeatureObs, F>,
    ages: Vec<u32, F>,
    norm: Vec<[f64; 2], F>,
    // Per-frame scratch.
    new_pos: [[f64; 2]; F],
    new_norm: [[f64; 2]; F],
    fate: [Fate; F],
    pred: [Option<[f64; 2]>; F],
    r_prev: [[f64; 2]; F],
    r_cur: [[f64; 2]; F],
    r_idx: [u16; F],
    r_in: [bool; F],
    r_y: [[f64; 3]; F],
    r_m: [[f64; 3]; F],
    flow: [f64; F],
    corners: [Corner; F],
    detector: GridDetector,
    lk: LkScratch,
    refs: References<F>,
}

impl<const F: usize, const BYTES: usize, const LEVELS: usize> FeatureTracker<F, BYTES, LEVELS> {
    /// A tracker with no tracks.
    ///
    /// Errors: [`Error::InvalidConfig`] for an invalid configuration, `max_features > F`,
    /// `max_level + 1 > LEVELS`, or `F` above 65 535.
    pub fn new(cfg: TrackerConfig) -> Result<Self, Error> {
        Self::check(&cfg)?;
        let mut t = Self::empty();
        t.cfg = cfg;
        Ok(t)
    }

    /// Whether `cfg` is valid and fits the capacities (see [`Self::new`]).
    pub(crate) fn check(cfg: &TrackerConfig) -> Result<(), Error> {
        cfg.validate()?;
        if cfg.max_features > F || cfg.max_level + 1 > LEVELS || F > usize::from(u16::MAX) {
            return Err(Error::InvalidConfig);
        }
        Ok(())
    }

    /// Validates `cfg` as [`Self::new`] does (and then nothing changes) and resets the tracker
    /// in place to the state `new(cfg)` builds: no tracks, no previous image, ids from 0, the
    /// detector's history forgotten (the scratch buffers keep their bytes: every frame writes
    /// them before reading). Builds nothing large on the stack.
    pub fn configure(&mut self, cfg: TrackerConfig) -> Result<(), Error> {
        Self::check(&cfg)?;
        self.cfg = cfg;
        for p in self.pyr.iter_mut() {
            p.reset_to_new();
        }
        self.cur = 0;
        self.has_prev = false;
        self.dims = (0, 0);
        self.last_t_ns = None;
        self.frame = 0;
        self.next_id = 0;
        self.features.clear();
        self.ages.clear();
        self.norm.clear();
        self.fate.fill(Fate::Lost);
        self.pred.fill(None);
        self.detector.reset();
        Ok(())
    }

    /// A tracker with [`TrackerConfig::PLACEHOLDER`], to be [`Self::configure`]d: `const`, so
    /// it can initialize a `static` or be written to the heap without passing through a stack
    /// (`povins_platform::boxed`).
    pub const fn empty() -> Self {
        FeatureTracker {
            cfg: TrackerConfig::PLACEHOLDER,
            pyr: [Pyramid::new(), Pyramid::new()],
            cur: 0,
            has_prev: false,
            dims: (0, 0),
            last_t_ns: None,
            frame: 0,
            next_id: 0,
            features: Vec::new(),
            ages: Vec::new(),
            norm: Vec::new(),
            new_pos: [[0.0; 2]; F],
            new_norm: [[0.0; 2]; F],
            fate: [Fate::Lost; F],
            pred: [None; F],
            r_prev: [[0.0; 2]; F],
            r_cur: [[0.0; 2]; F],
            r_idx: [0; F],
            r_in: [false; F],
            r_y: [[0.0; 3]; F],
            r_m: [[0.0; 3]; F],
            flow: [0.0; F],
            corners: [Corner {
                x: 0,
                y: 0,
                response: 0.0,
            }; F],
            detector: GridDetector::new(),
            lk: LkScratch::new(),
            refs: References::new(),
        }
    }

    /// The configuration.
    pub fn config(&self) -> &TrackerConfig {
        &self.cfg
    }

    /// Current tracks (raw distorted pixels), sorted by id; what
    /// [`crate::estimator::Estimator::push_frame`] consumes.
    pub fn features(&self) -> &[FeatureObs] {
        &self.features
    }

    /// Age of each track in [`Self::features`] (frames it has been tracked; 0 when new).
    pub fn ages(&self) -> &[u32] {
        &self.ages
    }

    /// Frames processed.
    pub fn frames(&self) -> u64 {
        self.frame
    }

    /// The pyramid of the latest frame (level 0 is the equalized image), if any.
    pub fn pyramid(&self) -> Option<&Pyramid<BYTES, LEVELS>> {
        if self.frame == 0 {
            return None;
        }
        self.pyr.get(self.cur)
    }

    /// Drops every track and the previous image (ids keep increasing).
    pub fn reset(&mut self) {
        self.features.clear();
        self.ages.clear();
        self.norm.clear();
        self.has_prev = false;
        self.detector.reset();
    }

    /// Processes the image taken at `t_ns`: tracks the previous frame's features into it, rejects
    /// outliers, tops the features up with new corners. Read the result with
    /// [`Self::features`] and [`Self::ages`].
    ///
    /// Errors (nothing changes): [`Error::TimeNotIncreasing`] if `t_ns` is not after the
    /// previous frame; [`Error::DimensionMismatch`] if the image size differs from the
    /// camera's; [`Error::InvalidConfig`] for a camera with a zero or non-finite focal length
    /// or an image whose grid cells exceed [`super::corners::MAX_CELL_SIDE`];
    /// [`Error::NonFinite`] for a non-finite rotation hint; [`Error::CapacityExceeded`] if the
    /// image's pyramid does not fit in `BYTES`. An image whose size differs from the previous
    /// one (with a matching camera) drops all tracks and starts over (`reset` in the stats).
    #[inline(never)] // one call per frame; keeps it visible to profilers
    pub fn track(
        &mut self,
        t_ns: i64,
        image: &ImageView,
        hints: &TrackHints,
        camera: &PinholeCamera,
    ) -> Result<TrackStats, Error> {
        if self.last_t_ns.is_some_and(|t| t_ns <= t) {
            return Err(Error::TimeNotIncreasing);
        }
        let (w, h) = (image.width(), image.height());
        if w != camera.width as usize || h != camera.height as usize {
            return Err(Error::DimensionMismatch);
        }
        if !(camera.fx.is_finite()
            && camera.fy.is_finite()
            && camera.fx != 0.0
            && camera.fy != 0.0
            && camera.cx.is_finite()
            && camera.cy.is_finite())
        {
            return Err(Error::InvalidConfig);
        }
        let dc = &self.cfg.detector;
        if w.div_ceil(dc.grid_cols) > super::corners::MAX_CELL_SIDE
            || h.div_ceil(dc.grid_rows) > super::corners::MAX_CELL_SIDE
        {
            return Err(Error::InvalidConfig);
        }
        if let Some(r) = &hints.r_cur_prev {
            if !r.iter().all(|v| v.is_finite()) {
                return Err(Error::NonFinite);
            }
        }
        if pyramid_bytes(w, h, 1) > BYTES {
            return Err(Error::CapacityExceeded);
        }
        let mut stats = TrackStats {
            frame: self.frame,
            ..TrackStats::default()
        };
        if self.has_prev && self.dims != (w, h) {
            self.reset();
            stats.reset = true;
        }
        // Build the new pyramid in the free slot.
        let next = if self.has_prev {
            1 - self.cur
        } else {
            self.cur
        };
        let levels = self.cfg.max_level + 1;
        let built = match self.pyr.get_mut(next) {
            Some(p) => p.build(
                image,
                levels,
                self.cfg.pyramid_filter,
                self.cfg.equalization,
            ),
            None => Err(Error::CapacityExceeded),
        };
        if let Err(e) = built {
            // The slot of the previous image is untouched; a failed first image leaves nothing.
            if !self.has_prev {
                self.reset();
            }
            return Err(e);
        }
        stats.previous = self.features.len() as u32;
        if self.has_prev {
            self.track_forward(next, hints, camera, &mut stats);
            self.reject_outliers(hints, camera, &mut stats);
            self.compact(&mut stats);
        }
        self.cur = next;
        self.has_prev = true;
        self.dims = (w, h);
        self.last_t_ns = Some(t_ns);
        self.frame += 1;
        self.top_up(camera, &mut stats);
        stats.total = self.features.len() as u32;
        Ok(stats)
    }
}

/// The upper median of `v` (reordered), 0 for an empty slice.
fn median_of(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f64::total_cmp).1
}

#[cfg(test)]
#[path = "tracker_tests.rs"]
mod tests;
