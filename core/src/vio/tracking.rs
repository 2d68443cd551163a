//! [`Tracking`]: the image front end alone, as an [`Odometry`] that estimates nothing (what
//! `povins track` runs to measure the front end). Its rotation seed integrates the gyro with
//! the configured delay (`td_s`) and camera-IMU rotation of its [`EstimatorConfig`] and no bias;
//! nothing predicts features. It takes IMU samples (their gyro readings) and images; feature
//! frames and LiDAR sweeps are refused ([`Error::InvalidConfig`]), and [`Odometry::update`]
//! never has an output.

use super::front_end::{ImageFrontEnd, SeedFrame};
use super::VioAiding;
use crate::camera::FeatureObs;
use crate::estimator::{EstimatorConfig, Status};
use crate::frontend::image::{pyramid_bytes, FeatureTracker, ImageView, TrackerConfig};
use crate::inertial::{ImuSample, InsUpdate, NavState};
use crate::lidar::LidarPoint;
use crate::math::Vec3;
use crate::odometry::{FrameOutput, Odometry, OdometryCounters, Output};
use crate::Error;

/// The front end alone for images up to 752x480 (256 features, 4 levels).
pub type EurocTracking = Tracking<256, { pyramid_bytes(752, 480, 4) }, 4>;

/// The front end alone for images up to 1280x720.
pub type HdTracking = Tracking<256, { pyramid_bytes(1280, 720, 4) }, 4>;

/// The image front end alone (see the module docs).
pub struct Tracking<const F: usize, const BYTES: usize, const LEVELS: usize> {
    fe: ImageFrontEnd<F, BYTES, LEVELS>,
    cfg: EstimatorConfig,
    /// Times the front end ([`Self::set_clock`]).
    clock: Option<fn() -> u64>,
}

impl<const F: usize, const BYTES: usize, const LEVELS: usize> Tracking<F, BYTES, LEVELS> {
    /// Unconfigured (`const`, see [`FeatureTracker::empty`]): refuses images until
    /// [`Self::configure`]d.
    pub const fn empty() -> Self {
        Tracking {
            fe: ImageFrontEnd::empty(),
            cfg: EstimatorConfig::PLACEHOLDER,
            clock: None,
        }
    }

    /// Configures the tracker with `tracker` and the seed and camera with `cfg` (its camera,
    /// extrinsic and `td_s` are used). [`Error::InvalidConfig`] when either is invalid
    /// (then nothing changes).
    pub fn configure(&mut self, cfg: EstimatorConfig, tracker: TrackerConfig) -> Result<(), Error> {
        Self::check(&cfg, &tracker)?;
        self.fe.configure(tracker)?;
        self.cfg = cfg;
        Ok(())
    }

    /// Whether this type accepts the configurations (the estimator configuration's ranges, the
    /// tracker's capacities); [`Self::configure`] checks the same.
    pub fn check(cfg: &EstimatorConfig, tracker: &TrackerConfig) -> Result<(), Error> {
        cfg.validate()?;
        ImageFrontEnd::<F, BYTES, LEVELS>::check(tracker)
    }

    /// Sets the monotonic clock, ns, that times the front end (none, the default: the
    /// timings are zero); [`Self::configure`] keeps it.
    pub fn set_clock(&mut self, clock: Option<fn() -> u64>) {
        self.clock = clock;
    }

    /// Chooses the aids: only `gyro_rotation` applies (nothing predicts features).
    pub fn set_aiding(&mut self, aiding: VioAiding) {
        self.fe.set_aiding(aiding);
    }

    /// The tracker (current tracks, ages).
    pub fn tracker(&self) -> &FeatureTracker<F, BYTES, LEVELS> {
        self.fe.tracker()
    }
}

impl<const F: usize, const BYTES: usize, const LEVELS: usize> Odometry
    for Tracking<F, BYTES, LEVELS>
{
    fn config(&self) -> &EstimatorConfig {
        &self.cfg
    }

    fn status(&self) -> Status {
        Status::WaitingForInit
    }

    fn initialize(&mut self, _state: NavState) -> Result<(), Error> {
        Err(Error::InvalidConfig)
    }

    fn fast_path_seed(&self) -> Option<InsUpdate> {
        None
    }

    fn push_imu(&mut self, s: &ImuSample) -> Result<(), Error> {
        if self.fe.push_gyro(s.t_ns, &s.gyro_rps) {
            Ok(())
        } else if s.gyro_rps.iter().all(|x| x.is_finite()) {
            Err(Error::TimeNotIncreasing)
        } else {
            Err(Error::NonFinite)
        }
    }

    fn push_frame<'a>(
        &'a mut self,
        _t_cam_ns: i64,
        _obs: &'a [FeatureObs],
    ) -> Result<FrameOutput<'a>, Error> {
        Err(Error::InvalidConfig)
    }

    fn push_image(&mut self, t_cam_ns: i64, image: &ImageView) -> Result<FrameOutput<'_>, Error> {
        let seed = SeedFrame {
            td_s: self.cfg.td_s,
            bg: Vec3::zeros(),
            r_bc: self.cfg.extrinsic.q_bc.to_rotation_matrix().into_inner(),
        };
        let camera = self.cfg.camera;
        let report = self
            .fe
            .track(t_cam_ns, image, &camera, &seed, &[], self.clock)?;
        Ok(FrameOutput {
            t_cam_ns,
            predictions: &[],
            tracks: self.fe.features(),
            track_ages: self.fe.tracker().ages(),
            image: Some(report),
            frame_error: None,
        })
    }

    fn push_lidar(&mut self, _points: &[LidarPoint]) -> Result<(), Error> {
        Err(Error::InvalidConfig)
    }

    fn update(&mut self) -> Result<Option<Output<'_>>, Error> {
        Ok(None)
    }

    fn counters(&self) -> OdometryCounters {
        OdometryCounters {
            estimator: Default::default(),
            images: self.fe.counters(),
        }
    }
}
