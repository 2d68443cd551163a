//! One interface from sensor messages to estimates: [`Odometry`], implemented by the estimator
//! alone ([`crate::estimator::Estimator`], fed with feature tracks) and by the estimator with the
//! image front end ([`crate::vio::Vio`], fed with images or tracks).
//!
//! A caller pushes each measurement when it arrives ([`Odometry::push_imu`],
//! [`Odometry::push_frame`] or [`Odometry::push_image`], [`Odometry::push_lidar`]) and drains
//! [`Odometry::update`] until it returns `None` (the estimator owns the timing, see
//! [`crate::estimator::timing`]). Everything a caller needs comes back in the outputs, borrowed
//! from the estimator until its next call, so nobody reaches into the estimator for it:
//! - [`Output`], per processed IMU sample: the IMU-rate navigation state, the INS update for a
//!   [`crate::inertial::FastPath`], and for a keyframe its [`KeyframeOutput`] (the report, its
//!   LiDAR-depth events, the window's keyframe states and the window's landmarks in the world,
//!   what a viewer draws);
//! - [`FrameOutput`], per camera frame or image: the INS prediction of every window landmark with
//!   a depth at the frame's time (made before the frame is queued: what an INS-aided tracker
//!   seeds its search with), the tracks offered to the estimator, and for an image the front
//!   end's [`ImageReport`].
//!
//! Frames: `nav` and the keyframe states are the body (IMU) frame `b` in the world `w` (z up,
//! [`NavState`]); landmark points are in `w`; predictions are raw pixels of the camera.
//!
//! The trait is object safe: a host chooses the front end's capacity once (by image size) and
//! drives a `dyn Odometry` from there on.

use crate::camera::FeatureObs;
use crate::estimator::{
    Counters, DepthEvent, EstimatorConfig, FeaturePrediction, ImuOutput, KeyframeReport, Status,
};
use crate::frontend::image::ImageView;
use crate::frontend::image::TrackStats;
use crate::inertial::{ImuSample, InsCovariance, InsUpdate, NavState};
use crate::lidar::LidarPoint;
use crate::math::Vec3;
use crate::Error;

/// What one processed IMU sample produced (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Output<'a> {
    /// The IMU-rate navigation state (INS propagated from the newest optimized keyframe), once
    /// initialized.
    pub nav: Option<NavState>,
    /// The covariance of `nav`'s error state, with [`crate::estimator::EstimatorConfig::covariance`]
    /// (`None`: off, or unknown until the first solve after a start or a reset).
    pub nav_covariance: Option<&'a InsCovariance>,
    /// Set when the INS changed other than by propagating this sample: hand it to a
    /// [`crate::inertial::FastPath`] (see [`ImuOutput::ins`]).
    pub ins: Option<InsUpdate>,
    /// The keyframe processed at this sample, with what it changed.
    pub keyframe: Option<KeyframeOutput<'a>>,
    /// An IMU gap ending at this sample was bridged: its length, s ([`ImuOutput::gap_bridged_s`]).
    pub gap_bridged_s: Option<f64>,
    /// The clock jumped before this sample: the jump, s ([`ImuOutput::clock_jump_s`]).
    pub clock_jump_s: Option<f64>,
    /// `nav` is withheld after a long IMU gap until keyframes correct it
    /// ([`ImuOutput::nav_withheld`]).
    pub nav_withheld: bool,
}

impl Output<'_> {
    /// The compact, `'static` part ([`ImuOutput`]: what a thread boundary carries).
    pub fn imu_output(&self) -> ImuOutput {
        ImuOutput {
            nav: self.nav,
            keyframe: self.keyframe.as_ref().map(|k| k.report),
            ins: self.ins,
            gap_bridged_s: self.gap_bridged_s,
            clock_jump_s: self.clock_jump_s,
            nav_withheld: self.nav_withheld,
        }
    }
}

/// A keyframe step's results, borrowed from the estimator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeyframeOutput<'a> {
    /// The step's report.
    pub report: KeyframeReport,
    /// The LiDAR-depth events of the step (associated, rejected, culled), in the core's order.
    pub lidar_events: &'a [DepthEvent],
    /// Every keyframe of the window after the step, oldest first, at its optimized value.
    pub window: &'a [KeyframeState],
    /// The window's landmarks that have a depth, in the world frame.
    pub landmarks: &'a [LandmarkPoint],
}

/// One keyframe of the window as the step left it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeyframeState {
    /// Image time on the camera clock, ns.
    pub t_cam_ns: i64,
    /// The body's state at the IMU time of the image (`state.t_ns`).
    pub state: NavState,
    /// The keyframe's camera-IMU delay estimate, s (`t_imu = t_cam + td_s`).
    pub td_s: f64,
}

impl KeyframeState {
    /// All zero (a buffer's initial value).
    pub const ZERO: KeyframeState = KeyframeState {
        t_cam_ns: 0,
        state: NavState::ZERO,
        td_s: 0.0,
    };
}

/// A window landmark placed in the world by its depth (the depth a prediction uses: LiDAR
/// depth-only optimized, inverse depth, or the pose-only two-view depth).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LandmarkPoint {
    /// Feature (track) id.
    pub id: u64,
    /// Position in the world frame, m.
    pub p_w: Vec3,
    /// The depth came from LiDAR.
    pub lidar: bool,
}

impl LandmarkPoint {
    /// All zero (a buffer's initial value).
    pub const ZERO: LandmarkPoint = LandmarkPoint {
        id: 0,
        p_w: Vec3::new(0.0, 0.0, 0.0),
        lidar: false,
    };
}

/// What one camera frame or image produced.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameOutput<'a> {
    /// Image time (camera clock), ns.
    pub t_cam_ns: i64,
    /// The INS prediction of every window landmark with a depth at the frame's time, made before
    /// the frame was queued (empty before initialization or when the INS does not cover the
    /// time).
    pub predictions: &'a [FeaturePrediction],
    /// The tracks offered to the estimator (the frame's observations, or the image front end's
    /// tracks).
    pub tracks: &'a [FeatureObs],
    /// The image front end's age of each track (images it has been tracked over, 0 when new;
    /// same order as `tracks`; empty for a frame of tracks from elsewhere).
    pub track_ages: &'a [u32],
    /// The image front end's report (images only).
    pub image: Option<ImageReport>,
    /// The estimator refused the tracks (counted in its counters); `None`: queued.
    pub frame_error: Option<Error>,
}

/// What one image produced.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageReport {
    /// The tracker's statistics of the frame.
    pub track: TrackStats,
    /// INS predictions handed to the tracker.
    pub predictions: u32,
    /// A gyro rotation seeded the frame.
    pub rotation_seed: bool,
    /// Tracks offered to the estimator.
    pub tracks: u32,
    /// Front-end time (predictions, gyro integration, tracking), ns, on the clock given to
    /// `set_clock` (0 without a clock).
    pub frontend_ns: u64,
    /// The estimator refused the frame (its counters have the reason); the tracker advanced.
    pub frame_error: Option<Error>,
}

/// Counts of what an image front end ([`crate::vio::Vio`], [`crate::vio::Tracking`]) refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct VioCounters {
    /// Images offered.
    pub images: u64,
    /// Images the tracker refused (wrong size, time not increasing, too large).
    pub images_rejected: u64,
    /// Tracked frames the estimator refused.
    pub frames_rejected: u64,
    /// Images after the first without a gyro rotation (gyro not covering the interval).
    pub no_rotation_seed: u64,
}

/// The counters of an [`Odometry`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct OdometryCounters {
    /// The estimator's.
    pub estimator: Counters,
    /// The image front end's (zero without one).
    pub images: VioCounters,
}

/// Sensor messages in, estimates out (see the module docs).
pub trait Odometry {
    /// The estimator's configuration.
    fn config(&self) -> &EstimatorConfig;

    /// The estimator's lifecycle state.
    fn status(&self) -> Status;

    /// Starts from a known full state (e.g. ground truth in evaluation) instead of waiting for a
    /// static period ([`crate::estimator::Estimator::initialize`]).
    fn initialize(&mut self, state: NavState) -> Result<(), Error>;

    /// The INS a fast path starting beside this estimator takes first
    /// ([`crate::estimator::Estimator::fast_path_seed`]).
    fn fast_path_seed(&self) -> Option<InsUpdate>;

    /// Queues one IMU sample ([`crate::estimator::Estimator::push_imu`]); drain
    /// [`Self::update`] after it.
    fn push_imu(&mut self, s: &ImuSample) -> Result<(), Error>;

    /// Queues a frame of tracked features (raw pixels) at camera time `t_cam_ns`, after
    /// predicting the window's landmarks at that time. Errors: the tracks were refused (see
    /// [`crate::estimator::Estimator::push_frame`]; counted).
    fn push_frame<'a>(
        &'a mut self,
        t_cam_ns: i64,
        obs: &'a [FeatureObs],
    ) -> Result<FrameOutput<'a>, Error>;

    /// Tracks an image taken at `t_cam_ns` and queues its tracks
    /// ([`crate::vio::Vio::push_image`]). Errors: the image was refused (counted), or
    /// [`Error::InvalidConfig`] from an odometry without an image front end.
    fn push_image(&mut self, t_cam_ns: i64, image: &ImageView) -> Result<FrameOutput<'_>, Error>;

    /// Queues one LiDAR sweep ([`crate::estimator::Estimator::push_lidar`]).
    fn push_lidar(&mut self, points: &[LidarPoint]) -> Result<(), Error>;

    /// No more input comes (the end of a recording): what the odometry holds back for later
    /// input is processed by the next [`Odometry::update`] calls (see
    /// [`crate::estimator::Estimator::end_input`]); drain them. A later push ends this.
    fn end_input(&mut self);

    /// Processes the next due IMU sample ([`crate::estimator::Estimator::update`]); `Ok(None)`:
    /// nothing is due. An error ends that sample's processing (the sample is consumed).
    fn update(&mut self) -> Result<Option<Output<'_>>, Error>;

    /// What was accepted, refused and dropped so far.
    fn counters(&self) -> OdometryCounters;
}
