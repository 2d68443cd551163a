//! [`ImageFrontEnd`]: the tracker with its gyro rotation seed, what [`super::Vio`] (beside the
//! estimator) and [`super::Tracking`] (alone) share. Per image it integrates the buffered gyro
//! over `[t_prev + td, t_cur + td]` (`t_imu = t_cam + td`) minus a bias into the camera rotation
//! `R_cur_prev` with the camera-IMU rotation `R_bc` (the seed of features without a prediction
//! and the 2-point RANSAC model), and tracks with the predicted pixels it is given.

use super::gyro::GyroIntegrator;
use super::{ImageReport, VioAiding, VioCounters, GYRO_SAMPLES};
use crate::camera::{FeatureObs, PinholeCamera};
use crate::frontend::image::{FeatureTracker, ImageView, TrackHints, TrackerConfig};
use crate::math::{Mat3, Vec3};
use crate::Error;

/// What the rotation seed of one image uses: the delay, the gyro bias and the camera-to-body
/// rotation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SeedFrame {
    /// Camera-IMU delay, s (`t_imu = t_cam + td_s`).
    pub td_s: f64,
    /// Gyro bias, rad/s (body frame).
    pub bg: Vec3,
    /// Camera-to-body rotation `R_bc`.
    pub r_bc: Mat3,
}

/// The image front end with its rotation seed (see the module docs).
pub struct ImageFrontEnd<const F: usize, const BYTES: usize, const LEVELS: usize> {
    tracker: FeatureTracker<F, BYTES, LEVELS>,
    aiding: VioAiding,
    gyro: GyroIntegrator<GYRO_SAMPLES>,
    last_image_ns: Option<i64>,
    counters: VioCounters,
}

impl<const F: usize, const BYTES: usize, const LEVELS: usize> ImageFrontEnd<F, BYTES, LEVELS> {
    /// A tracker configured with `cfg` ([`Error::InvalidConfig`] as [`FeatureTracker::new`]).
    pub fn new(cfg: TrackerConfig) -> Result<Self, Error> {
        Ok(ImageFrontEnd {
            tracker: FeatureTracker::new(cfg)?,
            ..Self::empty()
        })
    }

    /// Unconfigured (`const`, see [`FeatureTracker::empty`]).
    pub const fn empty() -> Self {
        ImageFrontEnd {
            tracker: FeatureTracker::empty(),
            aiding: VioAiding {
                predictions: true,
                gyro_rotation: true,
            },
            gyro: GyroIntegrator::new(),
            last_image_ns: None,
            counters: VioCounters {
                images: 0,
                images_rejected: 0,
                frames_rejected: 0,
                no_rotation_seed: 0,
            },
        }
    }

    /// Whether `cfg` fits (as [`FeatureTracker::check`]).
    pub fn check(cfg: &TrackerConfig) -> Result<(), Error> {
        FeatureTracker::<F, BYTES, LEVELS>::check(cfg)
    }

    /// Resets to the state `new(cfg)` builds, default aiding included.
    pub fn configure(&mut self, cfg: TrackerConfig) -> Result<(), Error> {
        self.tracker.configure(cfg)?;
        self.aiding = VioAiding::default();
        self.gyro.clear();
        self.last_image_ns = None;
        self.counters = VioCounters::default();
        Ok(())
    }

    /// Chooses which aids the tracker gets.
    pub fn set_aiding(&mut self, aiding: VioAiding) {
        self.aiding = aiding;
    }

    /// The aids the tracker gets.
    pub fn aiding(&self) -> VioAiding {
        self.aiding
    }

    /// The tracker (current tracks, ages, pyramid).
    pub fn tracker(&self) -> &FeatureTracker<F, BYTES, LEVELS> {
        &self.tracker
    }

    /// The current tracks.
    pub fn features(&self) -> &[FeatureObs] {
        self.tracker.features()
    }

    /// What was refused so far.
    pub fn counters(&self) -> VioCounters {
        self.counters
    }

    /// Counts a tracked frame the estimator refused.
    pub(super) fn count_frame_rejected(&mut self) {
        self.counters.frames_rejected += 1;
    }

    /// Keeps a gyro reading (body frame, rad/s) for the rotation seed; a non-finite one or one
    /// not after the newest is ignored (`false`).
    pub fn push_gyro(&mut self, t_ns: i64, gyro_rps: &Vec3) -> bool {
        self.gyro.push(t_ns, gyro_rps)
    }

    /// Camera rotation `R_c1_c0` from image time `t0_cam_ns` to `t1_cam_ns` with `seed`
    /// ([`GyroIntegrator::camera_rotation`]).
    pub fn camera_rotation(
        &self,
        t0_cam_ns: i64,
        t1_cam_ns: i64,
        seed: &SeedFrame,
    ) -> Option<Mat3> {
        self.gyro
            .camera_rotation(t0_cam_ns, t1_cam_ns, seed.td_s, &seed.bg, &seed.r_bc)
    }

    /// Tracks the image taken at `t_cam_ns` with the rotation seed of `seed` (when the aiding
    /// allows it) and the predicted pixels `predictions` (`(id, raw pixel)`, used as given);
    /// `clock` times it. The report's `tracks` are the tracks after it; `frame_error` is `None`
    /// (the caller queues the tracks). Errors as [`FeatureTracker::track`] (counted; nothing
    /// changes).
    pub fn track(
        &mut self,
        t_cam_ns: i64,
        image: &ImageView,
        camera: &PinholeCamera,
        seed: &SeedFrame,
        predictions: &[(u64, [f64; 2])],
        clock: Option<fn() -> u64>,
    ) -> Result<ImageReport, Error> {
        self.counters.images += 1;
        let t0 = clock.map_or(0, |c| c());
        let rotation = match self.last_image_ns {
            Some(prev) if self.aiding.gyro_rotation => self.camera_rotation(prev, t_cam_ns, seed),
            _ => None,
        };
        if self.last_image_ns.is_some() && self.aiding.gyro_rotation && rotation.is_none() {
            self.counters.no_rotation_seed += 1;
        }
        let hints = TrackHints {
            r_cur_prev: rotation,
            predictions,
        };
        let track = match self.tracker.track(t_cam_ns, image, &hints, camera) {
            Ok(s) => s,
            Err(e) => {
                self.counters.images_rejected += 1;
                return Err(e);
            }
        };
        self.last_image_ns = Some(t_cam_ns);
        Ok(ImageReport {
            track,
            predictions: predictions.len() as u32,
            rotation_seed: rotation.is_some(),
            tracks: self.tracker.features().len() as u32,
            frontend_ns: clock.map_or(0, |c| c().saturating_sub(t0)),
            frame_error: None,
        })
    }
}
