//! The estimator: the only module that knows the order of the steps.
//!
//! Sensor timing is the estimator's ([`timing`]): `push_*` only queue, [`Estimator::update`]
//! processes the queued IMU samples in time order on a delayed horizon, with the frames and
//! sweeps they reach. Per IMU sample: INS mechanization (the INS-centric design), preintegration into the open
//! keyframe interval, and (with LiDAR) the INS state into the de-skew window. Per LiDAR sweep:
//! de-skew and store its points ([`crate::lidar::PointBuffer`]). Per camera frame (processed when
//! the IMU reaches its time `t_cam + td`): track validation and undistortion, keyframe decision
//! from the INS-predicted motion. Per keyframe:
//! 1. marginalize the oldest keyframe if the window is full (Schur complement into the
//!    square-root prior, at the last optimized state);
//! 2. append the keyframe (INS state at the image time, the closed preintegration) and its
//!    observations to the landmark manager; associate LiDAR depths with its new landmarks
//!    ([`crate::lidar::SphereGrid`]);
//! 3. prepare landmarks: anchor `e` of largest parallax, pose-only depth, parallax and depth gates
//!    (inverse-depth mode: initialize the inverse depth), the uncertainty-based rejection of
//!    LiDAR depths (paper IV.C, tested in inverse depth: `lidar::rejection`);
//! 4. LM pass 1, chi-square cull of observations, LM pass 2 when the cull removed enough; LiDAR
//!    landmarks enter as MSC (or direct) LiDAR-depth measurements (`estimator/problem::lidar.rs`;
//!    with the depth eliminated, the default, the MSC one is the eliminated measurement with a
//!    depth row, `estimator/problem/visual.rs`);
//! 5. depth-only optimization of the LiDAR landmarks (paper V.D), then outlier culling by
//!    reprojection (paper V.E);
//! 6. restart the INS from the newest optimized keyframe (moving the de-skew window with it).
//!
//! Where the steps live: [`timing`] (the sensor queues and [`Estimator::update`]), `imu_step`
//! (one IMU sample), `frame_step` (one camera frame and the keyframe decision), `keyframe`
//! (steps 1, 2 and 6), `marginalize` (step 1), `prepare` (step 3), `solve` (the LM passes of
//! step 4 and the diagnostics' single steps), `lidar` (sweeps, association, depth-only
//! optimization), `cull` (the chi-square and reprojection culls), `health` (the breakdown
//! check); the least-squares problem in [`problem`] with its factor interface and landmark
//! models in `problem::factor`, the landmark pass in `problem::landmarks` and its factors in
//! `problem::priors`, `problem::inertial`, `problem::pose_only`, `problem::visual`,
//! `problem::inverse_depth` and `problem::lidar`, the 1-D inverse-depth solve in `tau_landmark`.
//!
//! Capacities are const generics: `N` keyframes, `L` landmarks, `D = 16 N + 6` error-state
//! dimensions (15 per keyframe, 6 extrinsic, 1 delay per keyframe). The struct holds every
//! buffer (about 5.1 MB for `N = 10`, `L = 200`, LiDAR buffers included): put it in a `static`
//! built by the `const` [`Estimator::empty`] (all zero bits, so it lives in `.bss`) and
//! [`Estimator::configure`] it in place, or in a `Box`. Processing needs no large stack: keyframe
//! intervals and camera frames are swapped between estimator-owned buffers, never moved by
//! value (the EuRoC replay runs on a 96 KiB stack at the test profile's optimization level; the
//! test uses 256 KiB).

pub mod clock_jump;
pub mod config;
mod covariance;
mod cull;
mod frame_step;
mod gap_pose;
mod health;
mod imu_noise;
mod imu_step;
mod keyframe;
mod lidar;
mod marginalize;
mod motion_history;
mod outage_heading;
mod output;
mod predict;
mod prepare;
pub mod prior;
pub mod problem;
pub mod report;
mod slots;
mod solve;
mod tau_landmark;
pub mod timing;
pub mod window;

pub use crate::ranges::InvalidSetting;
pub use config::{
    CullConfig, EstimatorConfig, FirstStatePrior, HealthConfig, ImuGapConfig, ImuSpikeConfig,
    InitConfig, InitMode, KnownBiases, SolveBudget, TdConfig, VisualDepth, VisualMode, ZuptConfig,
};
pub use imu_noise::ImuNoiseAdapt;
pub use predict::FeaturePrediction;
pub use report::{
    Admission, Breakdown, Counters, DepthEvent, DepthEventKind, ExtrinsicSd, KeyframeReport,
};
pub use timing::{IMU_QUEUE, PENDING_LIDAR_POINTS, PENDING_SWEEPS};

use crate::camera::{CameraExtrinsic, FeatureObs};
use crate::factors::TimedObs;
use crate::frontend::{KeyframeSelector, NormalizedObs, RestDetector, TrackTable};
use crate::inertial::covariance::MaybeCovariance;
use crate::inertial::init::StaticInitializer;
use crate::inertial::ins::{Ins, InsConfig};
use crate::inertial::motion_init::MotionInitializer;
use crate::inertial::preintegration::UnmeasuredSpan;
use crate::inertial::window::InsWindow;
use crate::inertial::{ImuSample, InsUpdate, NavState};
#[cfg(feature = "lidar")]
use crate::lidar::association::{GRID_H, GRID_W};
#[cfg(feature = "lidar")]
use crate::lidar::buffer::MAX_LIDAR_POINTS;
use crate::lidar::{PendingSweeps, PointBuffer, SphereGrid};
use crate::math::Vec3;
use crate::solver::{LandmarkSchur, Ldlt, LmWorkspace, NormalEquations};
use crate::Error;
use heapless::Vec as HVec;
use prior::MargPrior;
use problem::{InitialPriors, Landmarks, Saved, SCHUR_COLS};
use window::{Keyframe, Preint, Window};

/// Most feature observations per camera frame.
pub const MAX_FEATURES: usize = 512;
/// IMU samples the static initializer can hold (must cover `min_static_s` at the IMU rate).
pub const INIT_SAMPLES: usize = 1024;
/// Init frames the in-motion initializer keeps.
pub const MOTION_INIT_FRAMES: usize = 10;
/// INS states kept for LiDAR de-skewing (2.5 s at 200 Hz; a sweep must end within it).
pub const INS_WINDOW: usize = 512;
/// LiDAR-depth events one keyframe step can report.
pub const MAX_EVENTS: usize = 1024;
/// IMU samples a late keyframe can replay (its time lies this many samples before the newest
/// one: 0.32 s at 200 Hz); a frame later than that is taken at the newest sample.
pub const LATE_SAMPLES: usize = 64;
/// Camera frames waiting for the IMU to reach their time (`t_cam + td`); more arriving drop
/// the oldest (counted in `frames_dropped_no_imu`). Four cover a delay of three frame periods.
pub const PENDING_FRAMES: usize = 4;

/// Largest frame gap over which feature velocities are kept, s.
const TRACK_MAX_GAP_S: f64 = 0.5;
/// Gyro readings kept for a rolling shutter's angular acceleration (8: 35 ms at 200 Hz).
const GYRO_RECENT: usize = 8;
/// The span of gyro readings the angular acceleration is fitted over, ns: this much before the
/// frame and half of it after.
const ANGULAR_ACCEL_SPAN_NS: i64 = 25_000_000;

/// The PO-VINS configuration of the paper: 10 keyframes, 200 landmarks.
pub type PoVins = Estimator<10, 200, 166>;

/// Lifecycle of the estimator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Status {
    /// Built by [`Estimator::empty`] and not configured yet ([`Estimator::configure`]): every
    /// input is refused.
    Unconfigured,
    /// Waiting for a static period (or an explicit initial state).
    WaitingForInit,
    /// INS running; keyframes are being added.
    Running,
}

/// What one IMU sample produced.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuOutput {
    /// The IMU-rate navigation state (INS propagated from the newest optimized keyframe), once
    /// initialized.
    pub nav: Option<NavState>,
    /// The report of a keyframe processed at this sample.
    pub keyframe: Option<KeyframeReport>,
    /// Set when the INS changed at this sample other than by propagating it (initialization, a
    /// keyframe's optimized state, a frame processed at an interpolated sample, a reset): hand
    /// it to a [`crate::inertial::FastPath`], which then follows `nav` bit for bit.
    pub ins: Option<InsUpdate>,
    /// Set when an IMU gap ending at this sample was bridged (`imu_gap`): its length, s.
    pub gap_bridged_s: Option<f64>,
    /// Set when the clock jumped before this sample ([`clock_jump`]): the jump, s.
    pub clock_jump_s: Option<f64>,
    /// True when `nav` is withheld (`None` although the estimator runs): after an IMU gap
    /// bridged as a long one, until the keyframes after it have corrected the INS's pose and
    /// velocity (the second keyframe after the gap; at most [`GAP_WITHHOLD_MAX_S`]); a fast
    /// path is reset for that time.
    pub nav_withheld: bool,
}

/// Longest time the state is withheld after a long bridged IMU gap, s, when the keyframes do
/// not come (a camera out as well): the INS is then handed out as it is. Keyframes come every
/// 0.3-0.5 s on the simulator's scenarios and on EuRoC: the second after a gap 0.35-0.55 s
/// after it.
pub const GAP_WITHHOLD_MAX_S: f64 = 1.0;

#[derive(Clone)]
struct PendingFrame {
    t_cam_ns: i64,
    obs: HVec<FeatureObs, MAX_FEATURES>,
}

/// Points the LiDAR buffer of an [`Estimator`] holds by default: `MAX_LIDAR_POINTS` with the
/// `lidar` cargo feature (the default), 0 without (the estimator then refuses a configuration
/// with LiDAR enabled).
#[cfg(feature = "lidar")]
pub const LIDAR_POINTS: usize = MAX_LIDAR_POINTS;
/// Points the LiDAR buffer of an [`Estimator`] holds by default (0: built without `lidar`).
#[cfg(not(feature = "lidar"))]
pub const LIDAR_POINTS: usize = 0;
/// Azimuth cells of the depth-association grid by default (`GRID_W` with `lidar`, else 0).
#[cfg(feature = "lidar")]
pub const LIDAR_GRID_W: usize = GRID_W;
/// Azimuth cells of the depth-association grid by default (0: built without `lidar`).
#[cfg(not(feature = "lidar"))]
pub const LIDAR_GRID_W: usize = 0;
/// Elevation cells of the depth-association grid by default (`GRID_H` with `lidar`, else 0).
#[cfg(feature = "lidar")]
pub const LIDAR_GRID_H: usize = GRID_H;
/// Elevation cells of the depth-association grid by default (0: built without `lidar`).
#[cfg(not(feature = "lidar"))]
pub const LIDAR_GRID_H: usize = 0;

/// Cells of the LiDAR thinning grid by default (`THIN_CELLS` with `lidar`, else 0).
#[cfg(feature = "lidar")]
pub const LIDAR_THIN_CELLS: usize = crate::lidar::thin::THIN_CELLS;
/// Cells of the LiDAR thinning grid by default (0: built without `lidar`).
#[cfg(not(feature = "lidar"))]
pub const LIDAR_THIN_CELLS: usize = 0;

/// The sliding-window estimator (see the module docs for the order of the steps).
///
/// Capacities: `N` keyframes, `L` landmarks, `D = 16 N + 6` error-state dimensions, and for
/// LiDAR `P` buffered points, a `GW` x `GH` association grid, `Q` queued raw points and `TC`
/// cells of the thinning grid ([`crate::lidar::thin`]) (defaults from the `lidar` feature:
/// [`LIDAR_POINTS`], [`LIDAR_GRID_W`], [`LIDAR_GRID_H`], [`PENDING_LIDAR_POINTS`],
/// [`LIDAR_THIN_CELLS`]; all 0 leaves the LiDAR out of the footprint, and a configuration
/// with LiDAR enabled is then refused). The README's
/// footprint table lists `size_of` for a few choices (checked by `core/tests/footprint.rs`).
#[derive(Clone)]
pub struct Estimator<
    const N: usize,
    const L: usize,
    const D: usize,
    const P: usize = LIDAR_POINTS,
    const GW: usize = LIDAR_GRID_W,
    const GH: usize = LIDAR_GRID_H,
    const Q: usize = PENDING_LIDAR_POINTS,
    const TC: usize = LIDAR_THIN_CELLS,
> {
    cfg: EstimatorConfig,
    selector: KeyframeSelector,
    status: Status,
    static_init: StaticInitializer<INIT_SAMPLES>,
    motion_init: MotionInitializer<MOTION_INIT_FRAMES, MAX_FEATURES, INIT_SAMPLES>,
    /// Set by an in-motion start: the first keyframe takes `cfg.init.motion_prior`.
    motion_started: bool,
    /// IMU time of the newest sample at which the images showed a rest while waiting.
    last_rest_ns: Option<i64>,
    /// After a full reset: where the consumer last saw the platform (the INS state, or the
    /// newest keyframe's when the INS is not finite); the next start continues from its
    /// position and yaw ([`Self::continued`]).
    resume: Option<NavState>,
    /// The rotation and the path the images show while the IMU is out, for the yaw and the
    /// position of the next start ([`Self::continued`]).
    outage: outage_heading::OutageHeading,
    ins: Held<Ins>,
    last_imu: Option<ImuSample>,
    /// The IMU gap being bridged (`timing`'s `bridge_gap`), declared to every keyframe interval
    /// that overlaps it.
    gap: Option<UnmeasuredSpan>,
    /// The recent IMU samples in blocks: a long gap is bridged only when they were smooth.
    motion: motion_history::MotionHistory,
    /// Set after a long bridged gap: the state is withheld until keyframes correct it.
    withheld: Option<timing::Withheld>,
    /// Set by [`Estimator::end_input`] until the next push: nothing waits for later input.
    input_ended: bool,
    tracks: TrackTable<MAX_FEATURES>,
    rest: RestDetector<MAX_FEATURES>,
    frame_obs: HVec<NormalizedObs, MAX_FEATURES>,
    pending: heapless::Deque<PendingFrame, PENDING_FRAMES>,
    /// The frame being processed (taken from `pending` by [`Self::next_frame`]).
    frame: PendingFrame,
    window: Window<N>,
    /// Storage of the open keyframe interval's preintegration, valid with `open_active` (swapped
    /// into the window with its keyframe, see [`Window::push`]).
    open: Preint,
    open_active: bool,
    lms: Landmarks<N, L>,
    ext: CameraExtrinsic,
    prior: MargPrior<D, N>,
    initial: Option<InitialPriors>,
    lm: LmWorkspace<D>,
    marg_ne: NormalEquations<D>,
    marg_ldlt: Ldlt<D>,
    schur: [LandmarkSchur<SCHUR_COLS>; L],
    saved: Saved<N, L>,
    counters: Counters,
    /// Rank deficiencies (marginalized block, new prior) of the last marginalization.
    last_marg: Option<(u32, u32)>,
    /// The newest keyframe's marginal covariance ([`covariance`]), the INS's start.
    kf_cov: MaybeCovariance,
    ins_window: InsWindow<INS_WINDOW>,
    points: PointBuffer<P>,
    /// LiDAR sweeps waiting for the IMU ([`timing`]).
    sweeps_in: PendingSweeps<Q, PENDING_SWEEPS>,
    /// The crop of pushed sweeps to the camera's view (`lidar.crop_to_view`), made from the
    /// configuration once: `None` when off or when the lens cannot be inverted.
    view_crop: Option<crate::lidar::ViewCrop>,
    /// Thinning of a LiDAR faster than the buffer's span ([`crate::lidar::thin`]).
    thin: crate::lidar::ThinGrid<TC>,
    /// Due time of the last sweep de-skewed (its rate decides the thinning), ns.
    last_sweep_due_ns: Option<i64>,
    /// IMU samples waiting for [`Estimator::update`] ([`timing`]).
    imu_in: heapless::Deque<ImuSample, IMU_QUEUE>,
    /// The newest gyro readings `(t_ns, rad/s)`, for the angular acceleration a rolling
    /// shutter's rows need ([`frame_step`]).
    gyro_recent: heapless::Deque<(i64, Vec3), GYRO_RECENT>,
    grid: SphereGrid<GW, GH>,
    events: HVec<DepthEvent, MAX_EVENTS>,
    /// The delay is held in the current solve (too few landmarks to estimate it).
    td_hold: bool,
    /// The work of the last keyframes' solves (a ring; `max_work_ratio` of [`SolveBudget`]).
    work_history: heapless::Deque<u32, { SolveBudget::HISTORY }>,
    /// Consecutive keyframes with large residuals (health monitor).
    bad_keyframes: u32,
    /// Set by a re-initialization: the calibration the new window starts from (and its first
    /// keyframe takes the wide re-initialization prior).
    reinit: Option<Reinit>,
    /// Online scale of the IMU white-noise densities.
    imu_scale: imu_noise::ImuNoiseScale,
    /// The INS epoch ([`Held::epoch`]) a fast path following [`ImuOutput::ins`] holds.
    ins_synced: u32,
    /// The last IMU sample spacing that was not a gap, ns (0: none yet; [`clock_jump`]).
    imu_dt_ns: i64,
    /// The spacing of the last two frames taken from the queue, ns ([`clock_jump`]).
    frame_dt_ns: i64,
    /// The inputs' clock against the estimator's ([`clock_jump`]).
    clock_map: clock_jump::ClockMap,
    /// What the estimator lends with its outputs ([`output`]).
    out: output::OutputBuffers<N, L>,
    /// Monotonic clock of the timing statistics, ns ([`Estimator::set_clock`]; none: every
    /// timing is zero).
    clock: Option<fn() -> u64>,
}

/// What a re-initialization ([`health`]) keeps of the broken window: the online calibration,
/// which the next window starts from and takes as its prior's mean (the keyframe states are
/// dropped). Without online estimation they are the configured values.
#[derive(Debug, Clone, Copy)]
struct Reinit {
    /// The camera-IMU delay, s.
    td_s: f64,
    /// The camera-IMU extrinsic.
    ext: CameraExtrinsic,
}

/// An optional value kept beside a flag rather than in an `Option`, so that "none" is all zero
/// bits (an `Option`'s `None` may be any pattern): keeps a `static` estimator in `.bss`. Every
/// mutable access counts in `epoch` (how the fast path's updates are found, see
/// [`Estimator::update`]).
#[derive(Clone)]
struct Held<T> {
    value: T,
    held: bool,
    epoch: u32,
}

impl<T> Held<T> {
    /// Nothing held; `value` is storage only.
    const fn empty(value: T) -> Self {
        Held {
            value,
            held: false,
            epoch: 0,
        }
    }

    fn as_ref(&self) -> Option<&T> {
        self.held.then_some(&self.value)
    }

    fn as_mut(&mut self) -> Option<&mut T> {
        if self.held {
            self.epoch = self.epoch.wrapping_add(1);
            Some(&mut self.value)
        } else {
            None
        }
    }

    fn set(&mut self, value: T) {
        self.value = value;
        self.held = true;
        self.epoch = self.epoch.wrapping_add(1);
    }

    fn clear(&mut self) {
        self.held = false;
        self.epoch = self.epoch.wrapping_add(1);
    }
}

/// Time-delay-corrected observation of `lm` at window position `k` (z = 1), or `None`.
fn corrected_obs<const N: usize>(
    lm: &crate::landmarks::Landmark<N>,
    k: usize,
    td_s: f64,
) -> Option<Vec3> {
    let o = lm.obs.get(k)?.as_ref()?;
    Some(
        TimedObs {
            x_n: crate::camera::Vec2::new(o.x_n[0], o.x_n[1]),
            vel: crate::camera::Vec2::new(o.vel[0], o.vel[1]),
            td0: o.td0_s,
        }
        .corrected(td_s),
    )
}

/// The time on `clock`, ns (0 without a clock).
fn now(clock: Option<fn() -> u64>) -> u64 {
    clock.map_or(0, |c| c())
}

impl<
        const N: usize,
        const L: usize,
        const D: usize,
        const P: usize,
        const GW: usize,
        const GH: usize,
        const Q: usize,
        const TC: usize,
    > Estimator<N, L, D, P, GW, GH, Q, TC>
{
    const LAYOUT_OK: () = assert!(D == 16 * N + 6 && N >= 2 && N < 128 && 7 * N + 6 <= SCHUR_COLS);

    /// A new estimator ([`Error::InvalidConfig`] for an invalid configuration): [`Self::empty`]
    /// then [`Self::configure`].
    ///
    /// The returned value is large (it is built on the stack and moved out); on a small stack
    /// put a [`Self::empty`] in a `static` and [`Self::configure`] it there.
    pub fn new(cfg: EstimatorConfig) -> Result<Self, Error> {
        let mut est = Self::empty();
        est.configure(cfg)?;
        Ok(est)
    }

    /// An unconfigured estimator ([`Status::Unconfigured`]: it refuses every input until
    /// [`Self::configure`]), with [`EstimatorConfig::PLACEHOLDER`] as its configuration.
    /// `const`, so it can initialize a `static` and never pass through a stack:
    ///
    /// Guaranteed to be all zero bits for every capacity (checked by the `.bss` test of
    /// `tests/estimator_static.rs`): a zeroed allocation is an
    /// empty estimator, which is how `povins_platform::boxed::boxed_estimator` puts one on the
    /// heap without a stack temporary. New fields must keep it so.
    ///
    /// ```
    /// use povins_core::estimator::{Estimator, PoVins, Status};
    /// static EST: PoVins = Estimator::empty();
    /// assert_eq!(EST.status(), Status::Unconfigured);
    /// ```
    pub const fn empty() -> Self {
        #[allow(clippy::let_unit_value)]
        let () = Self::LAYOUT_OK;
        Estimator {
            cfg: EstimatorConfig::PLACEHOLDER,
            selector: KeyframeSelector {
                config: EstimatorConfig::PLACEHOLDER.keyframe,
            },
            status: Status::Unconfigured,
            static_init: StaticInitializer::new_unchecked(EstimatorConfig::PLACEHOLDER.static_init),
            motion_init: MotionInitializer::new(EstimatorConfig::PLACEHOLDER.init.motion),
            motion_started: false,
            last_rest_ns: None,
            resume: None,
            outage: outage_heading::OutageHeading::new(),
            ins: Held::empty(Ins::blank()),
            last_imu: None,
            gap: None,
            withheld: None,
            input_ended: false,
            motion: motion_history::MotionHistory::new(),
            tracks: TrackTable::new(0.0),
            rest: RestDetector::new(EstimatorConfig::PLACEHOLDER.rest),
            frame_obs: HVec::new(),
            pending: heapless::Deque::new(),
            frame: PendingFrame {
                t_cam_ns: 0,
                obs: HVec::new(),
            },
            window: Window::new(),
            open: Preint::empty(),
            open_active: false,
            lms: Landmarks::new(),
            ext: EstimatorConfig::PLACEHOLDER.extrinsic,
            prior: MargPrior::new(),
            initial: None,
            lm: LmWorkspace::new(),
            marg_ne: NormalEquations::new(),
            marg_ldlt: Ldlt::new(),
            schur: [const { LandmarkSchur::new() }; L],
            saved: Saved::new(),
            counters: Counters::ZERO,
            work_history: heapless::Deque::new(),
            last_marg: None,
            kf_cov: MaybeCovariance::NONE,
            ins_window: InsWindow::new(),
            points: PointBuffer::new(),
            sweeps_in: PendingSweeps::new(),
            view_crop: None,
            thin: crate::lidar::ThinGrid::new(),
            last_sweep_due_ns: None,
            imu_in: heapless::Deque::new(),
            gyro_recent: heapless::Deque::new(),
            grid: SphereGrid::new(),
            events: HVec::new(),
            td_hold: false,
            bad_keyframes: 0,
            reinit: None,
            imu_scale: imu_noise::ImuNoiseScale::new(),
            ins_synced: 0,
            imu_dt_ns: 0,
            frame_dt_ns: 0,
            clock_map: clock_jump::ClockMap::new(),
            out: output::OutputBuffers::new(),
            clock: None,
        }
    }

    /// Sets the monotonic clock, ns, that times the steps in the reports
    /// ([`KeyframeReport::total_ns`] and the others; none, the default: every timing is zero).
    /// It is not part of the configuration: [`Self::configure`] keeps it, and the results never
    /// depend on it.
    pub fn set_clock(&mut self, clock: Option<fn() -> u64>) {
        self.clock = clock;
    }

    /// The clock set by [`Self::set_clock`].
    pub fn clock(&self) -> Option<fn() -> u64> {
        self.clock
    }

    /// Validates `cfg` ([`Error::InvalidConfig`], and then nothing changes) and resets the
    /// estimator in place to the state [`Self::new`]`(cfg)` builds: whatever it held before
    /// (keyframes, landmarks, priors, counters, LiDAR points) is dropped, and it waits for
    /// initialization ([`Status::WaitingForInit`]). Builds nothing large on the stack, so a
    /// `static` estimator ([`Self::empty`]) can be configured, and re-configured, from a thread
    /// with a small stack.
    pub fn configure(&mut self, cfg: EstimatorConfig) -> Result<(), Error> {
        Self::check(&cfg)?;
        let selector = KeyframeSelector::new(cfg.keyframe)?;
        // The last check: nothing has changed when it fails.
        self.static_init
            .reset_with_noise(cfg.static_init, &cfg.imu_noise)?;
        self.cfg = cfg;
        self.motion_init.reset(cfg.init.motion);
        self.motion_started = false;
        self.last_rest_ns = None;
        self.resume = None;
        self.outage.clear();
        self.selector = selector;
        self.status = Status::WaitingForInit;
        self.ins.clear();
        self.last_imu = None;
        self.imu_dt_ns = 0;
        self.frame_dt_ns = 0;
        self.input_ended = false;
        self.clock_map.clear();
        self.gap = None;
        self.withheld = None;
        self.motion.clear();
        self.gyro_recent.clear();
        self.tracks.reset_to_new(TRACK_MAX_GAP_S);
        self.rest.reset_to_new(cfg.rest);
        self.frame_obs.clear();
        self.pending.clear();
        self.frame.t_cam_ns = 0;
        self.frame.obs.clear();
        self.window.reset_to_new();
        self.open.reset_to_empty();
        self.open_active = false;
        self.lms.reset_to_new();
        self.ext = cfg.extrinsic;
        self.prior.reset_to_new();
        self.initial = None;
        self.lm.reset_to_new();
        self.marg_ne.reset_to_new();
        self.marg_ldlt.reset_to_new();
        for s in self.schur.iter_mut() {
            s.reset_to_new();
        }
        self.saved.reset_to_new();
        self.counters = Counters::ZERO;
        self.last_marg = None;
        self.kf_cov = MaybeCovariance::NONE;
        self.ins_window.clear();
        self.points.reset_to_new();
        self.sweeps_in.clear();
        self.thin.configure();
        self.last_sweep_due_ns = None;
        let l = &cfg.lidar;
        self.view_crop = l
            .crop_to_view
            .then(|| {
                crate::lidar::ViewCrop::new(
                    &cfg.camera,
                    &cfg.extrinsic,
                    &l.extrinsic,
                    l.view_margin_rad,
                )
            })
            .flatten();
        self.imu_in.clear();
        self.grid.reset_to_new();
        self.events.clear();
        self.td_hold = false;
        self.bad_keyframes = 0;
        self.reinit = None;
        self.imu_scale = imu_noise::ImuNoiseScale::new();
        self.out.clear();
        Ok(())
    }

    /// Whether this estimator's type accepts `cfg` ([`Error::InvalidConfig`] otherwise): the
    /// configuration's own ranges ([`EstimatorConfig::validate`]) and what the capacities allow
    /// (LiDAR enabled needs LiDAR storage). [`Self::configure`] checks the same.
    pub fn check(cfg: &EstimatorConfig) -> Result<(), Error> {
        #[allow(clippy::let_unit_value)]
        let () = Self::LAYOUT_OK;
        cfg.validate()?;
        if cfg.lidar.enabled && (P == 0 || GW == 0 || GH == 0 || Q == 0) {
            // Built without LiDAR storage (the `lidar` feature, or zero capacities).
            return Err(Error::InvalidConfig);
        }
        KeyframeSelector::new(cfg.keyframe)?;
        if L > problem::LANDMARK_INDEX || L > u16::MAX as usize || !cfg.static_init.is_valid() {
            return Err(Error::InvalidConfig);
        }
        Ok(())
    }

    /// The configuration.
    pub fn config(&self) -> &EstimatorConfig {
        &self.cfg
    }

    /// Current lifecycle state.
    pub fn status(&self) -> Status {
        self.status
    }

    /// Running counters.
    pub fn counters(&self) -> Counters {
        let mut c = self.counters;
        c.landmarks_refused_capacity = self.lms.stats.refused_capacity;
        c.landmarks_evicted = self.lms.stats.evicted;
        c
    }

    /// Keyframes in the window (oldest first), their times on the estimator's own clock (the
    /// inputs' less any clock jumps, [`clock_jump`]; the keyframe outputs are on the inputs').
    pub fn keyframes(&self) -> impl Iterator<Item = &Keyframe> + '_ {
        (0..self.window.len()).filter_map(|k| self.window.get(k))
    }

    /// Landmarks currently managed.
    pub fn landmarks(&self) -> &Landmarks<N, L> {
        &self.lms
    }

    /// Current camera-IMU extrinsic estimate.
    pub fn extrinsic(&self) -> &CameraExtrinsic {
        &self.ext
    }

    /// Starts from a known full state (e.g. ground truth in evaluation) instead of waiting for a
    /// static period. Its time should be that of the next IMU sample or earlier.
    /// [`Error::NotInitialized`] while [`Status::Unconfigured`].
    pub fn initialize(&mut self, state: NavState) -> Result<(), Error> {
        if self.status == Status::Unconfigured {
            return Err(Error::NotInitialized);
        }
        let cfg = self.ins_config();
        let state = NavState {
            t_ns: self.clock_map.inside(state.t_ns),
            ..state
        };
        let ins = Ins::new(cfg, state)?;
        self.reset_window();
        self.resume = None;
        self.ins.set(ins);
        self.status = Status::Running;
        Ok(())
    }

    fn ins_config(&self) -> InsConfig {
        InsConfig {
            gravity_mps2: self.cfg.gravity_mps2,
            max_dt_s: self.cfg.max_imu_dt_s,
        }
    }

    fn reset_window(&mut self) {
        self.pending.clear();
        self.drop_window();
    }

    /// [`Self::reset_window`] but for the queued frames.
    fn drop_window(&mut self) {
        self.window.clear();
        self.lms.clear();
        self.prior.clear();
        self.initial = None;
        self.open_active = false;
        self.tracks.clear();
        self.rest.clear();
        self.motion_init.reset(self.cfg.init.motion);
        self.motion_started = false;
        self.last_rest_ns = None;
        self.ext = self.cfg.extrinsic;
        // Buffered INS states and points belong to the INS run that ends here.
        self.ins_window.clear();
        self.points.clear();
        self.thin.clear();
        self.last_sweep_due_ns = None;
        self.gap = None;
        self.withheld = None;
        self.kf_cov = MaybeCovariance::NONE;
    }

    /// Drops everything and waits for a new initialization (counted). Does nothing while
    /// [`Status::Unconfigured`].
    pub fn reset(&mut self) {
        self.reset_keeping_frames_from(i64::MAX);
    }

    /// [`Self::reset`], keeping the queued frames at or after IMU time `t_ns` (those that came
    /// after a gap that resets: they belong to the next initialization).
    fn reset_keeping_frames_from(&mut self, t_ns: i64) {
        if self.status == Status::Unconfigured {
            return;
        }
        let td_ns = (self.current_td() * 1e9) as i64;
        while self
            .pending
            .front()
            .is_some_and(|p| p.t_cam_ns.saturating_add(td_ns) < t_ns)
        {
            let _ = self.pending.pop_front();
        }
        let finite = |s: &NavState| {
            s.p_wb.iter().chain(s.v_wb.iter()).all(|x| x.is_finite())
                && s.q_wb.coords.iter().all(|x| x.is_finite())
        };
        let newest_kf = self.window.last().map(|k| k.state);
        self.resume = self
            .ins
            .as_ref()
            .map(|i| *i.state())
            .filter(finite)
            .or(newest_kf)
            .or(self.resume);
        self.drop_window();
        self.ins.clear();
        self.status = Status::WaitingForInit;
        self.counters.resets += 1;
        // A fresh detector: the samples before the reset must not count as static time.
        let _ = self
            .static_init
            .reset_with_noise(self.cfg.static_init, &self.cfg.imu_noise);
    }
}
