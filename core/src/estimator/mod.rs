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
//!    landmarks enter as MSC (or direct) LiDAR-depth measurements (`estimator/problem_lidar.rs`);
//! 5. depth-only optimization of the LiDAR landmarks (paper V.D), then outlier culling by
//!    reprojection (paper V.E);
//! 6. restart the INS from the newest optimized keyframe (moving the de-skew window with it).
//!
//! Capacities are const generics: `N` keyframes, `L` landmarks, `D = 16 N + 6` error-state
//! dimensions (15 per keyframe, 6 extrinsic, 1 delay per keyframe). The struct holds every
//! buffer (about 5.1 MB for `N = 10`, `L = 200`, LiDAR buffers included): put it in a `static`
//! built by the `const` [`Estimator::empty`] (all zero bits, so it lives in `.bss`) and
//! [`Estimator::configure`] it in place, or in a `Box`. Processing needs no large stack: keyframe
//! intervals and camera frames are swapped between estimator-owned buffers, never moved by
//! value (the EuRoC replay runs on a 96 KiB stack at the test profile's optimization level; the
//! test uses 256 KiB).

pub mod config;
mod health;
mod imu_noise;
mod lidar;
mod marginalize;
mod predict;
pub mod prior;
pub mod problem;
mod problem_lidar;
mod problem_visual;
pub mod report;
mod slots;
pub mod timing;
pub mod window;

pub use config::{EstimatorConfig, FirstStatePrior, VisualDepth, VisualMode};
pub use health::{Breakdown, HealthConfig};
pub use imu_noise::ImuNoiseAdapt;
pub use predict::FeaturePrediction;
pub use report::{Admission, Counters, DepthEvent, DepthEventKind, KeyframeReport};
pub use timing::{IMU_QUEUE, PENDING_LIDAR_POINTS, PENDING_SWEEPS};

use crate::camera::{CameraExtrinsic, FeatureObs};
use crate::factors::pose_only_visual::PoseOnlyAnchors;
use crate::factors::{CamFrame, KeyframePose, TimedObs};
use crate::frontend::{
    mean_parallax_px, CameraMotion, KeyframeDecision, KeyframeSelector, NormalizedObs,
    RestDetector, RestVerdict, TrackTable,
};
use crate::inertial::init::StaticInitializer;
use crate::inertial::ins::{Ins, InsConfig};
use crate::inertial::window::InsWindow;
use crate::inertial::{ImuSample, InsUpdate, NavState};
use crate::landmarks::{depth_std, TwoView};
#[cfg(feature = "lidar")]
use crate::lidar::association::{GRID_H, GRID_W};
#[cfg(feature = "lidar")]
use crate::lidar::buffer::MAX_LIDAR_POINTS;
use crate::lidar::{LdmMode, PendingSweeps, PointBuffer, SphereGrid};
use crate::math::{log_so3, Vec3};
use crate::solver::{LandmarkSchur, Ldlt, LmWorkspace, NormalEquations};
use crate::Error;
use heapless::Vec as HVec;
use prior::MargPrior;
use problem::{FactorSet, InitialPriors, Landmarks, Problem, Saved, SCHUR_COLS};
use problem_lidar::TauLandmark;
use window::{Keyframe, Layout, Preint, Window, MAX_INTERVAL_SAMPLES};

/// Most feature observations per camera frame.
pub const MAX_FEATURES: usize = 512;
/// IMU samples the static initializer can hold (must cover `min_static_s` at the IMU rate).
pub const INIT_SAMPLES: usize = 1024;
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
}

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

/// The sliding-window estimator (see the module docs for the order of the steps).
///
/// Capacities: `N` keyframes, `L` landmarks, `D = 16 N + 6` error-state dimensions, and for
/// LiDAR `P` buffered points, a `GW` x `GH` association grid and `Q` queued raw points
/// (defaults from the `lidar` feature: [`LIDAR_POINTS`], [`LIDAR_GRID_W`], [`LIDAR_GRID_H`],
/// [`PENDING_LIDAR_POINTS`]; all 0 leaves the LiDAR out of the footprint, and a configuration
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
> {
    cfg: EstimatorConfig,
    selector: KeyframeSelector,
    status: Status,
    static_init: StaticInitializer<INIT_SAMPLES>,
    ins: Held<Ins>,
    last_imu: Option<ImuSample>,
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
    ins_window: InsWindow<INS_WINDOW>,
    points: PointBuffer<P>,
    /// LiDAR sweeps waiting for the IMU ([`timing`]).
    sweeps_in: PendingSweeps<Q, PENDING_SWEEPS>,
    /// IMU samples waiting for [`Estimator::update`] ([`timing`]).
    imu_in: heapless::Deque<ImuSample, IMU_QUEUE>,
    grid: SphereGrid<GW, GH>,
    events: HVec<DepthEvent, MAX_EVENTS>,
    /// The delay is held in the current solve (too few landmarks to estimate it).
    td_hold: bool,
    /// Consecutive keyframes with large residuals (health monitor).
    bad_keyframes: u32,
    /// Set by a re-initialization: the delay to start the new window with (and its first
    /// keyframe takes the wide re-initialization prior).
    reinit_td: Option<f64>,
    /// Online scale of the IMU white-noise densities.
    imu_scale: imu_noise::ImuNoiseScale,
    /// The INS epoch ([`Held::epoch`]) a fast path following [`ImuOutput::ins`] holds.
    ins_synced: u32,
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

fn now(cfg: &EstimatorConfig) -> u64 {
    cfg.clock.map_or(0, |c| c())
}

impl<
        const N: usize,
        const L: usize,
        const D: usize,
        const P: usize,
        const GW: usize,
        const GH: usize,
        const Q: usize,
    > Estimator<N, L, D, P, GW, GH, Q>
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
            ins: Held::empty(Ins::blank()),
            last_imu: None,
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
            last_marg: None,
            ins_window: InsWindow::new(),
            points: PointBuffer::new(),
            sweeps_in: PendingSweeps::new(),
            imu_in: heapless::Deque::new(),
            grid: SphereGrid::new(),
            events: HVec::new(),
            td_hold: false,
            bad_keyframes: 0,
            reinit_td: None,
            imu_scale: imu_noise::ImuNoiseScale::new(),
            ins_synced: 0,
        }
    }

    /// Validates `cfg` ([`Error::InvalidConfig`], and then nothing changes) and resets the
    /// estimator in place to the state [`Self::new`]`(cfg)` builds: whatever it held before
    /// (keyframes, landmarks, priors, counters, LiDAR points) is dropped, and it waits for
    /// initialization ([`Status::WaitingForInit`]). Builds nothing large on the stack, so a
    /// `static` estimator ([`Self::empty`]) can be configured, and re-configured, from a thread
    /// with a small stack.
    pub fn configure(&mut self, cfg: EstimatorConfig) -> Result<(), Error> {
        #[allow(clippy::let_unit_value)]
        let () = Self::LAYOUT_OK;
        cfg.validate()?;
        if cfg.lidar.enabled && (P == 0 || GW == 0 || GH == 0 || Q == 0) {
            // Built without LiDAR storage (the `lidar` feature, or zero capacities).
            return Err(Error::InvalidConfig);
        }
        let selector = KeyframeSelector::new(cfg.keyframe)?;
        if L > problem::LANDMARK_INDEX || L > u16::MAX as usize {
            return Err(Error::InvalidConfig);
        }
        // The last check: nothing has changed when it fails.
        self.static_init.reset_to_new(cfg.static_init)?;
        self.cfg = cfg;
        self.selector = selector;
        self.status = Status::WaitingForInit;
        self.ins.clear();
        self.last_imu = None;
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
        self.ins_window.clear();
        self.points.reset_to_new();
        self.sweeps_in.clear();
        self.imu_in.clear();
        self.grid.reset_to_new();
        self.events.clear();
        self.td_hold = false;
        self.bad_keyframes = 0;
        self.reinit_td = None;
        self.imu_scale = imu_noise::ImuNoiseScale::new();
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

    /// Keyframes in the window (oldest first).
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
        let ins = Ins::new(cfg, state)?;
        self.reset_window();
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
        self.window.clear();
        self.lms.clear();
        self.prior.clear();
        self.initial = None;
        self.open_active = false;
        self.pending.clear();
        self.tracks.clear();
        self.rest.clear();
        self.ext = self.cfg.extrinsic;
        // Buffered INS states and points belong to the INS run that ends here.
        self.ins_window.clear();
        self.points.clear();
    }

    /// Drops everything and waits for a new initialization (counted). Does nothing while
    /// [`Status::Unconfigured`].
    pub fn reset(&mut self) {
        if self.status == Status::Unconfigured {
            return;
        }
        self.reset_window();
        self.ins.clear();
        self.status = Status::WaitingForInit;
        self.counters.resets += 1;
        // A fresh detector: the samples before the reset must not count as static time.
        let _ = self.static_init.reset_to_new(self.cfg.static_init);
    }

    /// Queues a camera frame of tracked features (raw pixels) at camera time `t_cam_ns`. It is
    /// processed by [`Self::update`] at the first IMU sample at or past `t_cam + td`
    /// ([`PENDING_FRAMES`] are held; one more drops the oldest, counted). Refused, counted:
    /// [`Error::TimeNotIncreasing`], [`Error::OutOfRange`] (more than `max_frame_lead_s` ahead
    /// of the newest IMU sample pushed). [`Error::NotInitialized`] (nothing counted) while
    /// [`Status::Unconfigured`].
    pub fn push_frame(&mut self, t_cam_ns: i64, obs: &[FeatureObs]) -> Result<(), Error> {
        if self.status == Status::Unconfigured {
            return Err(Error::NotInitialized);
        }
        self.counters.frames += 1;
        // A frame far ahead of the IMU would block every real frame until the IMU caught up
        // (and overflow the open interval): refuse it.
        let lead_limit_ns = (self.cfg.max_frame_lead_s * 1e9) as i64;
        let newest = self.imu_in.back().or(self.last_imu.as_ref());
        if newest.is_some_and(|s| t_cam_ns.saturating_sub(s.t_ns) > lead_limit_ns) {
            self.counters.frames_rejected_time += 1;
            return Err(Error::OutOfRange);
        }
        if let Some(p) = self.pending.back() {
            if t_cam_ns <= p.t_cam_ns {
                self.counters.frames_rejected_time += 1;
                return Err(Error::TimeNotIncreasing);
            }
        }
        if self.pending.is_full() {
            let _ = self.pending.pop_front();
            self.counters.frames_dropped_no_imu += 1;
        }
        let mut pf = PendingFrame {
            t_cam_ns,
            obs: HVec::new(),
        };
        let take = obs.len().min(MAX_FEATURES);
        for o in obs.iter().take(take) {
            let _ = pf.obs.push(*o);
        }
        self.counters.features_rejected += (obs.len() - take) as u64;
        self.counters.features_received += (obs.len() - take) as u64;
        // Not full (made room above): cannot fail.
        let _ = self.pending.push_back(pf);
        Ok(())
    }

    /// The open keyframe interval's preintegration, if one is open.
    fn open(&self) -> Option<&Preint> {
        self.open_active.then_some(&self.open)
    }

    /// The open interval, mutable.
    fn open_mut(&mut self) -> Option<&mut Preint> {
        if self.open_active {
            Some(&mut self.open)
        } else {
            None
        }
    }

    /// Time of the INS state (the newest propagated sample), ns.
    fn ins_time(&self) -> i64 {
        self.ins.as_ref().map_or(i64::MIN, |i| i.state().t_ns)
    }

    fn current_td(&self) -> f64 {
        self.window
            .last()
            .map_or(self.reinit_td.unwrap_or(self.cfg.td_s), |k| k.td_s)
    }

    /// One sample before initialization: frames feed the track velocities and the rest
    /// detector; the static initializer may start the INS.
    fn imu_waiting_for_init(&mut self, s: &ImuSample) -> Result<(), Error> {
        while self.next_frame() {
            self.counters.frames_before_init += 1;
            let t_cam_ns = self.frame.t_cam_ns;
            if self
                .tracks
                .process(
                    t_cam_ns,
                    &self.frame.obs,
                    &self.cfg.camera,
                    CameraMotion::ZERO,
                    &mut self.frame_obs,
                )
                .is_ok()
            {
                self.rest.push(t_cam_ns, &self.frame_obs, self.focal_px());
            }
        }
        let td_ns = (self.cfg.td_s * 1e9) as i64;
        let rest_since = match self.rest.verdict() {
            RestVerdict::Rest { since_ns } => Some(since_ns.saturating_add(td_ns)),
            _ => None,
        };
        match self.static_init.push_with_rest(s, rest_since) {
            Ok(Some(state)) => {
                let ins = Ins::new(self.ins_config(), state)?;
                self.ins.set(ins);
                if let Some(ins) = self.ins.as_mut() {
                    let st = *ins.propagate(s)?;
                    self.record_ins(&st);
                }
                self.status = Status::Running;
                Ok(())
            }
            Ok(None) => Ok(()),
            Err(Error::CapacityExceeded) => Err(Error::InvalidConfig),
            Err(e) => Err(e),
        }
    }

    /// One sample while running: pending frames whose IMU time has been reached are processed
    /// at exactly that time (or at this sample when it is already past: the observations' delay
    /// correction accounts for the difference, see `add_keyframe`), then the INS propagates to
    /// the sample. Returns the INS epoch the final propagation started from when it was a plain
    /// propagation of `s` (see [`Self::fast_path_update`]).
    fn imu_running(&mut self, s: &ImuSample, out: &mut ImuOutput) -> Result<Option<u32>, Error> {
        while let Some(t_f) = self
            .pending
            .front()
            .map(|p| p.t_cam_ns.saturating_add((self.current_td() * 1e9) as i64))
            .filter(|t_f| *t_f <= s.t_ns)
        {
            // The keyframe sample: the real one at t_f, or one interpolated at t_f, or (the frame
            // is late, or right after initialization) this sample itself.
            let sample_f = match self.last_imu {
                _ if t_f == s.t_ns => *s,
                Some(prev) if prev.t_ns < t_f && self.ins_time() <= t_f => {
                    interpolate(&prev, s, t_f)
                }
                // Late: the sample at t_f from the open interval (the keyframe is rewound there).
                _ => self.open_sample_at(t_f).unwrap_or(*s),
            };
            if self.ins_time() < sample_f.t_ns {
                self.advance(&sample_f)?;
            }
            if self.next_frame() {
                if let Some(r) = self.process_frame(&sample_f)? {
                    out.keyframe = Some(r);
                }
            }
        }
        if self.ins.as_ref().is_none_or(|i| i.state().t_ns >= s.t_ns) {
            return Ok(None);
        }
        let from = self.ins.epoch;
        self.advance(s)?;
        let plain = self.ins.held && self.ins.epoch == from.wrapping_add(1);
        Ok(plain.then_some(from))
    }

    /// INS propagation and preintegration of one sample (real or interpolated).
    fn advance(&mut self, s: &ImuSample) -> Result<(), Error> {
        let Some(ins) = self.ins.as_mut() else {
            return Err(Error::NotInitialized);
        };
        match ins.propagate(s).copied() {
            Ok(st) => {
                let finite = st.p_wb.iter().chain(st.v_wb.iter()).all(|x| x.is_finite())
                    && st.q_wb.coords.iter().all(|x| x.is_finite());
                if !finite || st.v_wb.amax() > self.cfg.max_speed_mps {
                    // Diverged (or fed garbage that passed the range check): start over.
                    self.counters.divergence_resets += 1;
                    self.reset();
                    return Ok(());
                }
                self.record_ins(&st);
            }
            Err(Error::TimeGap) => {
                self.reset();
                return Ok(());
            }
            Err(e) => return Err(e),
        }
        if let Some(open) = self.open_mut() {
            match open.push(s) {
                Ok(()) => {}
                // The interval cannot be bridged: start over rather than integrate a hole.
                Err(Error::CapacityExceeded) | Err(Error::TimeGap) => self.reset(),
                Err(e) => return Err(e),
            }
        }
        Ok(())
    }

    /// Moves the oldest pending frame into `self.frame` (swapped in place: a frame is too large
    /// to pass through the stack of the processing path). False when none is pending.
    #[inline(never)]
    fn next_frame(&mut self) -> bool {
        let Some(front) = self.pending.front_mut() else {
            return false;
        };
        core::mem::swap(front, &mut self.frame);
        // The previous frame, swapped into the queue, is dropped here.
        let _ = self.pending.pop_front();
        true
    }

    /// The camera's motion at `sample` (camera frame), for the track velocities: the gyro minus
    /// the bias, and the velocity of the camera's origin, both rotated by the current extrinsic;
    /// at rest before the INS starts (or if not finite).
    fn camera_motion(&self, sample: &ImuSample) -> CameraMotion {
        let Some(nav) = self.ins.as_ref().map(|i| i.state()) else {
            return CameraMotion::ZERO;
        };
        let w_b = sample.gyro_rps - nav.bg;
        let q_cb = self.ext.q_bc.inverse();
        let w_c = q_cb * w_b;
        let v_c = q_cb * (nav.q_wb.inverse() * nav.v_wb + w_b.cross(&self.ext.p_bc));
        if w_c.iter().chain(v_c.iter()).all(|v| v.is_finite()) {
            CameraMotion {
                w_c_rps: [w_c.x, w_c.y, w_c.z],
                v_c_mps: [v_c.x, v_c.y, v_c.z],
            }
        } else {
            CameraMotion::ZERO
        }
    }

    /// Processes `self.frame` (see [`Self::next_frame`]) at `sample`.
    fn process_frame(&mut self, sample: &ImuSample) -> Result<Option<KeyframeReport>, Error> {
        let t0 = now(&self.cfg);
        let t_cam_ns = self.frame.t_cam_ns;
        let motion = self.camera_motion(sample);
        let st = match self.tracks.process(
            t_cam_ns,
            &self.frame.obs,
            &self.cfg.camera,
            motion,
            &mut self.frame_obs,
        ) {
            Ok(st) => st,
            Err(Error::TimeNotIncreasing) => {
                self.counters.frames_rejected_time += 1;
                return Ok(None);
            }
            Err(e) => return Err(e),
        };
        self.counters.features_received += u64::from(st.received);
        self.counters.features_rejected += u64::from(st.received - st.accepted);
        self.rest.push(t_cam_ns, &self.frame_obs, self.focal_px());
        let Some(ins) = self.ins.as_ref() else {
            return Ok(None);
        };
        let nav = *ins.state();

        let decision = match self.window.last() {
            None => KeyframeDecision::First,
            Some(last) => {
                let dt_s = nav.t_ns.saturating_sub(last.state.t_ns) as f64 * 1e-9;
                let dp = (nav.p_wb - last.state.p_wb).norm();
                let dr = log_so3(&(last.state.q_wb.inverse() * nav.q_wb)).norm();
                let (parallax, tracked) = self.parallax_and_tracked(&nav);
                let nearly_full = self
                    .open()
                    .is_some_and(|o| o.len() + 16 >= MAX_INTERVAL_SAMPLES);
                match self.selector.decide(dt_s, dp, dr, parallax, tracked) {
                    KeyframeDecision::No
                        if nearly_full && dt_s >= self.cfg.keyframe.min_interval_s =>
                    {
                        KeyframeDecision::Timeout
                    }
                    d => d,
                }
            }
        };
        if !decision.is_keyframe() {
            return Ok(None);
        }
        // A late frame (its IMU time already passed, e.g. a negative delay): the keyframe goes
        // at its own time and the samples after it are replayed into the next interval.
        let tail = if sample.t_ns < nav.t_ns {
            self.rewind_to(sample)
        } else {
            None
        };
        let nav = self.ins.as_ref().map_or(nav, |i| *i.state());
        let report = self.add_keyframe(t_cam_ns, nav, sample, decision, t0)?;
        for s in tail.iter().flatten() {
            self.advance(s)?;
        }
        Ok(Some(report))
    }

    /// The IMU sample at `t_ns` interpolated from the open interval's samples (strictly after its
    /// start), if it holds that time.
    fn open_sample_at(&self, t_ns: i64) -> Option<ImuSample> {
        let v = self.open()?.samples();
        let k = v.iter().position(|x| x.t_ns >= t_ns).filter(|&k| k > 0)?;
        let (a, b) = (v.get(k - 1)?, v.get(k)?);
        Some(if b.t_ns == t_ns {
            *b
        } else {
            interpolate(a, b, t_ns)
        })
    }

    /// Rewinds the INS and the open interval to `sample` (between the newest keyframe and the
    /// newest sample): the interval is truncated there and the INS re-propagated from the
    /// keyframe. Returns the samples after `sample`, to replay once the keyframe is in; `None`
    /// (nothing changed) when there is no keyframe yet or too many samples to replay.
    fn rewind_to(&mut self, sample: &ImuSample) -> Option<HVec<ImuSample, LATE_SAMPLES>> {
        let kf_state = self.window.last()?.state;
        let ins_cfg = self.ins_config();
        let open = self.open_mut()?;
        let mut tail: HVec<ImuSample, LATE_SAMPLES> = HVec::new();
        for s in open.samples().iter().filter(|s| s.t_ns > sample.t_ns) {
            tail.push(*s).ok()?;
        }
        open.truncate_at(sample).ok()?;
        let mut ins = Ins::new(ins_cfg, kf_state).ok()?;
        for s in open.samples() {
            ins.propagate(s).ok()?;
        }
        self.ins.set(ins);
        Some(tail)
    }

    /// Mean focal length, px.
    fn focal_px(&self) -> f64 {
        0.5 * (self.cfg.camera.fx + self.cfg.camera.fy)
    }

    /// True when the images show the platform at rest since at or before the newest keyframe.
    fn at_rest_since_last_keyframe(&self) -> bool {
        match (self.rest.verdict(), self.window.last()) {
            (RestVerdict::Rest { since_ns }, Some(last)) => since_ns <= last.t_cam_ns,
            _ => false,
        }
    }

    /// Mean pixel displacement of the current frame's tracks w.r.t. the newest keyframe (with
    /// `keyframe.compensate_rotation`, after rotating the keyframe's rays by the rotation the
    /// INS predicts between them), and the share of the keyframe's features still tracked.
    fn parallax_and_tracked(&self, nav: &NavState) -> (f64, f64) {
        let (Some(pos), Some(last)) = (self.window.len().checked_sub(1), self.window.last()) else {
            return (0.0, 1.0);
        };
        // Rotation taking the keyframe camera's rays into the current camera's.
        let r_ck = self.cfg.keyframe.compensate_rotation.then(|| {
            let ck = self.ext.camera_pose(&last.state.p_wb, &last.state.q_wb);
            let cc = self.ext.camera_pose(&nav.p_wb, &nav.q_wb);
            cc.q_wc.inverse() * ck.q_wc
        });
        let pairs = self.frame_obs.iter().filter_map(|o| {
            let k = self.lms.get(o.id)?.obs.get(pos)?.as_ref()?;
            Some((k.x_n, [o.x_n[0], o.x_n[1]]))
        });
        let (parallax, n) = mean_parallax_px(pairs, r_ck.as_ref(), self.focal_px());
        // The share is only needed by the tracked-share rule (off by default): no pass over the
        // landmark store per frame otherwise.
        let seen = if self.cfg.keyframe.min_tracked_ratio > 0.0 {
            self.lms
                .landmarks()
                .iter()
                .filter(|lm| matches!(lm.obs.get(pos), Some(Some(_))))
                .count()
        } else {
            0
        };
        let tracked = if seen == 0 {
            1.0
        } else {
            n as f64 / seen as f64
        };
        (parallax, tracked)
    }

    fn add_keyframe(
        &mut self,
        t_cam_ns: i64,
        nav: NavState,
        sample: &ImuSample,
        decision: KeyframeDecision,
        t0: u64,
    ) -> Result<KeyframeReport, Error> {
        let mut report = KeyframeReport {
            t_ns: nav.t_ns,
            t_cam_ns,
            decision,
            ..Default::default()
        };
        self.events.clear();
        // 1. Marginalize the oldest keyframe at the last optimized state.
        if self.window.is_full() {
            let tm = now(&self.cfg);
            self.last_marg = None;
            if self.marginalize_oldest().is_err() {
                self.counters.marginalization_failures += 1;
                self.prior.clear();
                self.initial = None;
                let _ = self.window.drop_oldest();
                self.lms.shift_out_oldest();
            }
            report.marginalization_ns = now(&self.cfg).saturating_sub(tm);
            if let Some((m, p)) = self.last_marg {
                report.marginalized_rank_deficiency = m;
                report.prior_rank_deficiency = p;
                if let Some((pos, yaw)) = self.prior.gauge_std() {
                    report.prior_gauge_std = (pos[0].max(pos[1]).max(pos[2]), yaw);
                }
            }
        }

        // 2. Append the keyframe with the interval's preintegration, start the next interval.
        let td = self.current_td();
        // The sample at the keyframe time starts the next interval.
        let sample = ImuSample {
            t_ns: nav.t_ns,
            ..*sample
        };
        let at_rest = self.cfg.zupt
            && self.at_rest_since_last_keyframe()
            && nav.v_wb.norm() <= self.cfg.zupt_max_speed_mps;
        report.at_rest = at_rest;
        // The interval closes: swapped into the keyframe's slot (which hands back storage for
        // the next one).
        let interval = if core::mem::take(&mut self.open_active) {
            // A closed interval is evaluated at every LM step: factor its covariance once.
            let _ = self.open.cache_whitening();
            Some(&mut self.open)
        } else {
            None
        };
        self.window.push(t_cam_ns, nav, td, at_rest, interval)?;
        if self.window.len() == 1 {
            self.prior.clear();
            self.initial = Some(self.initial_priors(&nav, td));
            self.reinit_td = None;
        }
        self.open.restart_with(
            self.imu_scale.apply(self.cfg.imu_noise),
            self.cfg.preint,
            &sample,
            nav.bg,
            nav.ba,
        )?;
        self.open_active = true;
        let pos = self.window.len() - 1;
        // The observations were taken at `t_cam + td_true`; the keyframe's state is at its sample
        // time, so the delay they are referred to is that time minus the camera time (equal to
        // `td` unless the frame was processed late).
        let td0 = nav.t_ns.saturating_sub(t_cam_ns) as f64 * 1e-9;
        self.lms.add_keyframe(pos, &self.frame_obs, td0)?;
        let (mv_tracks, mv_obs) = self.lms.store().multi_view();
        report.multi_view_tracks = mv_tracks;
        report.multi_view_observations = mv_obs;
        self.counters.keyframes += 1;
        self.associate_depths(pos, &nav, &mut report);
        let (promoted, evicted) = self.select_landmarks();
        report.landmarks_promoted = promoted;
        report.landmarks_evicted = evicted;

        // 3-5. Optimize and cull.
        let ts = now(&self.cfg);
        let before = self.window.poses();
        if self.window.len() >= 2 {
            self.optimize(&mut report);
        }
        report.solve_ns = now(&self.cfg).saturating_sub(ts);
        let (correction, window_path_m) = self.window_correction(&before);
        report.window_correction_m = correction;
        if self.window.len() >= 2 {
            let health = self.check_health(&nav, &report, window_path_m);
            if let Some(b) = health {
                // The window broke down: INS-only from its own prediction, a new window next.
                report.breakdown = Some(b);
                self.reinitialize_from(nav);
                report.total_ns = now(&self.cfg).saturating_sub(t0);
                return Ok(report);
            }
        }

        // 6. The INS continues from the newest optimized keyframe; the open interval is
        // re-linearized at its biases (it holds only the keyframe sample so far).
        if let Some(last) = self.window.last() {
            let st = last.state;
            self.correct_ins_window(&nav, &st);
            if let Some(ins) = self.ins.as_mut() {
                ins.set_state(st)?;
            }
            if let Some(open) = self.open_mut() {
                open.reset(&sample, st.bg, st.ba)?;
            }
        }
        report.window_len = self.window.len() as u32;
        report.td_s = self.current_td();
        report.imu_noise_scale = self.imu_scale.density_scale();
        report.landmarks_total = self.lms.len() as u32;
        report.total_ns = now(&self.cfg).saturating_sub(t0);
        Ok(report)
    }

    fn initial_priors(&self, kf0: &NavState, td: f64) -> InitialPriors {
        let p = match self.reinit_td {
            Some(_) => &self.cfg.health.reinit_prior,
            None => &self.cfg.first_prior,
        };
        InitialPriors {
            kf0: *kf0,
            kf0_sigma: [p.p_m, p.theta_rad, p.v_mps, p.bg_rps, p.ba_mps2],
            td0: (td, self.cfg.td_prior_s),
            ext: (
                self.cfg.extrinsic,
                self.cfg.extrinsic_prior.0,
                self.cfg.extrinsic_prior.1,
            ),
        }
    }

    /// Chooses anchors and gates every landmark for the coming solve. With `reject`, also runs
    /// the uncertainty-based test on LiDAR depths (see [`crate::lidar::rejection`]); returns (depths rejected,
    /// time spent on the test in ns).
    fn prepare_landmarks(&mut self, reject: bool) -> (u32, u64, Admission) {
        let count = self.window.len();
        let ext = self.ext;
        let poses = self.window.poses();
        let cams: [crate::camera::CameraPose; N] =
            core::array::from_fn(|k| ext.camera_pose(&poses[k].p_wb, &poses[k].q_wb));
        // Relative rotations once per camera pair, not per landmark and pair.
        let rel = slots::relative_rotations(&cams, count);
        let (dmin, dmax) = self.cfg.depth_range_m;
        let min_par = self.cfg.min_parallax;
        let max_rel = self.cfg.max_rel_depth_std;
        let sigma_px = self.cfg.sigma_px;
        let focal = crate::camera::Vec2::new(self.cfg.camera.fx, self.cfg.camera.fy);
        let mode = self.cfg.mode;
        // Modes that keep an inverse depth per landmark (a state, or the eliminated one's last
        // solution as the next solve's start).
        let depth_state = mode == VisualMode::InverseDepth || self.cfg.depth_eliminated();
        let lc = self.cfg.lidar;
        let test_depths = reject && lc.enabled && lc.depth_outlier_rejection;
        let clock = self.cfg.clock;
        let (mut rejected, mut reject_ns) = (0u32, 0u64);
        let mut adm = Admission::default();
        for lm in self.lms.landmarks_mut() {
            lm.usable = false;
            if !lc.enabled {
                // PO-VINS-WO: depths may exist (associated before a switch) but are never used.
                lm.lidar = None;
            }
            let s = lm.anchor_s as usize;
            let td_s = self.window.get(s).map_or(0.0, |k| k.td_s);
            let (Some(x_s), Some(cs)) = (corrected_obs(lm, s, td_s), cams.get(s)) else {
                continue;
            };
            let mut best: Option<(usize, f64, Vec3)> = None;
            for (k, row) in rel.iter().enumerate().take(count) {
                if k == s {
                    continue;
                }
                let td_k = self.window.get(k).map_or(0.0, |kf| kf.td_s);
                let (Some(x_k), Some(r_ks)) = (corrected_obs(lm, k, td_k), row.get(s)) else {
                    continue;
                };
                let theta = x_k.cross(&(r_ks * x_s)).norm();
                if theta.is_finite() && best.is_none_or(|(_, t, _)| theta > t) {
                    best = Some((k, theta, x_k));
                }
            }
            let Some((e, theta, x_e)) = best else {
                lm.anchor_e = None;
                adm.single_view += 1;
                continue;
            };
            lm.anchor_e = Some(e as u8);
            let Some(ce) = cams.get(e) else { continue };
            let (r_es, t_es) = ce.relative_from(cs);
            // The pose-only depth from (s, e) and its analytic uncertainty (paper IV.A-B).
            let two = TwoView::new(&x_s, &x_e, &r_es, &t_es);
            let d_v = two.signed_depth();
            let visual = (d_v > 0.0 && d_v.is_finite()).then_some((d_v, two));

            if let (true, Some(ld), Some((d_v, two))) = (test_depths, lm.lidar, visual.as_ref()) {
                let t0 = clock.map_or(0, |c| c());
                let sd_v = depth_std(two, lc.rejection_sigma_px, &focal).unwrap_or(f64::INFINITY);
                let pair = crate::lidar::DepthPair {
                    d_v_m: *d_v,
                    sigma_dv_m: sd_v,
                    d_r_m: ld.depth_m,
                    sigma_dr_m: ld.sigma_m,
                };
                // In inverse depth the test gates itself at low parallax (large sigma);
                // the range check keeps degenerate geometry out.
                let testable = theta >= min_par && *d_v >= dmin && *d_v <= dmax;
                if testable && pair.is_outlier(lc.rejection_sigmas) {
                    lm.lidar = None;
                    lm.inv_depth = 0.0;
                    rejected += 1;
                    let _ = self.events.push(DepthEvent {
                        id: lm.id,
                        kind: DepthEventKind::Rejected,
                        depth_m: ld.depth_m,
                    });
                }
                reject_ns += clock.map_or(0, |c| c()).saturating_sub(t0);
            }

            if let Some(ld) = lm.lidar {
                let in_range = ld.depth_m >= dmin && ld.depth_m <= dmax;
                // MSC (and the inverse-depth baseline) take the depth from the LiDAR: no
                // parallax needed. The direct LDM rides on the pose-only visual measurements,
                // so it needs their gates.
                if in_range && (lc.ldm == LdmMode::Msc || mode == VisualMode::InverseDepth) {
                    lm.usable = true;
                    adm.admitted += 1;
                    if !(lm.inv_depth > 0.0 && lm.inv_depth.is_finite()) {
                        lm.inv_depth = 1.0 / ld.depth_m;
                    }
                    continue;
                }
            }
            if theta < min_par {
                adm.low_parallax += 1;
                continue;
            }
            let Some((d_s, two)) = visual else {
                adm.bad_depth += 1;
                continue;
            };
            if !(d_s >= dmin && d_s <= dmax) {
                adm.bad_depth += 1;
                continue;
            }
            // The two-view residuals treat the depth from (s, e) as exact: admit a landmark only
            // once its analytic depth uncertainty (paper IV.B) is a small fraction of the depth.
            // (An eliminated depth carries its own uncertainty: no such gate.)
            let two_view = mode == VisualMode::PoseOnly && !depth_state;
            if two_view && !depth_std(&two, sigma_px, &focal).is_ok_and(|sd| sd <= max_rel * d_s) {
                adm.uncertain_depth += 1;
                continue;
            }
            lm.usable = true;
            adm.admitted += 1;
            if depth_state && (lm.inv_depth.is_nan() || lm.inv_depth <= 0.0) {
                lm.inv_depth = 1.0 / d_s;
            }
        }
        (rejected, reject_ns, adm)
    }

    /// The window's least-squares problem over `layout`, beside the LM workspace and the
    /// marginalization system (disjoint borrows of the estimator).
    fn split(
        &mut self,
        layout: Layout<N>,
        set: FactorSet,
    ) -> (
        Problem<'_, N, L, D>,
        &mut LmWorkspace<D>,
        &mut NormalEquations<D>,
    ) {
        let td_hold = self
            .td_hold
            .then(|| core::array::from_fn(|k| self.window.get(k).map_or(0.0, |kf| kf.td_s)));
        let problem = Problem {
            cfg: &self.cfg,
            window: &mut self.window,
            lms: &mut self.lms,
            ext: &mut self.ext,
            prior: &mut self.prior,
            initial: self.initial.as_ref(),
            layout,
            set,
            schur: &mut self.schur,
            saved: &mut self.saved,
            counts: Default::default(),
            td_hold,
            tau_fresh: false,
        };
        (problem, &mut self.lm, &mut self.marg_ne)
    }

    fn solve_layout(&self) -> Layout<N> {
        Layout::solve(
            self.window.len(),
            self.cfg.estimate_extrinsic,
            self.cfg.estimate_td,
        )
    }

    fn run_lm(&mut self, cfg: &crate::solver::LmConfig, report: &mut KeyframeReport) -> bool {
        let layout = self.solve_layout();
        let (mut problem, lm, _) = self.split(layout, FactorSet::All);
        let res = lm.solve(&mut problem, cfg);
        report.disabled_landmarks += problem.counts.disabled;
        report.landmarks_used = problem.counts.landmarks;
        report.ldm_count = problem.counts.ldm;
        report.observations_used = problem.counts.observations;
        match res {
            Ok(sum) => {
                if report.iterations == 0 {
                    report.cost.0 = sum.initial_cost;
                }
                report.cost.1 = sum.final_cost;
                report.iterations += sum.iterations as u32;
                report.termination = Some(sum.termination);
                true
            }
            Err(_) => {
                self.counters.solver_failures += 1;
                false
            }
        }
    }

    fn optimize(&mut self, report: &mut KeyframeReport) {
        // Re-integrate intervals whose bias estimate moved far from the linearization point.
        for k in 1..self.window.len() {
            let (bg, ba) = match self.window.get(k - 1) {
                Some(a) => (a.state.bg, a.state.ba),
                None => continue,
            };
            if let Some(pre) = self.window.get_mut(k).and_then(|b| b.preint_mut()) {
                if pre.needs_reintegration(&bg, &ba) {
                    let _ = pre.reintegrate(bg, ba);
                    let _ = pre.cache_whitening();
                }
            }
        }
        let (rej, rej_ns, adm) = self.prepare_landmarks(true);
        report.depths_rejected = rej;
        report.rejection_ns = rej_ns;
        report.admission = adm;
        self.td_hold = adm.admitted < self.cfg.td_min_landmarks;
        let first = self.cfg.lm_first;
        if !self.run_lm(&first, report) {
            return;
        }
        report.culled_chi2 = self.chi2_cull();
        let min_culled = self.cfg.second_pass_min_culled_frac * f64::from(report.observations_used);
        if report.culled_chi2 > 0 && f64::from(report.culled_chi2) >= min_culled {
            self.prepare_landmarks(false);
            let second = self.cfg.lm_second;
            self.run_lm(&second, report);
        }
        self.update_imu_noise_scale(&self.solve_layout());
        if self.cfg.lidar.enabled && self.cfg.lidar.depth_only_opt {
            let t0 = now(&self.cfg);
            self.depth_only_optimization();
            report.depth_opt_ns = now(&self.cfg).saturating_sub(t0);
        }
        let (obs, lms, rms) = self.reprojection_cull();
        report.culled_observations = obs;
        report.culled_landmarks = lms;
        report.residual_rms_px = rms;
    }

    /// Body poses and camera frames of the window, computed once for a pass over landmarks.
    fn window_frames(&self) -> ([KeyframePose; N], [CamFrame; N]) {
        let poses = self.window.poses();
        let ext = self.ext;
        let frames = core::array::from_fn(|k| CamFrame::new(&poses[k], &ext));
        (poses, frames)
    }

    /// Whitened residuals of the observations `j != s` of landmark `li` (`None` where not
    /// defined), with the anchors' geometry formed once for all of them.
    fn landmark_residuals(
        &self,
        li: usize,
        wf: &([KeyframePose; N], [CamFrame; N]),
    ) -> [Option<crate::camera::Vec2>; N] {
        let mut out = [None; N];
        let (poses, frames) = wf;
        let Some(lm) = self.lms.landmarks().get(li) else {
            return out;
        };
        let s = lm.anchor_s as usize;
        let to = |o: &crate::landmarks::KfObs| TimedObs {
            x_n: crate::camera::Vec2::new(o.x_n[0], o.x_n[1]),
            vel: crate::camera::Vec2::new(o.vel[0], o.vel[1]),
            td0: o.td0_s,
        };
        let (Some(Some(os)), Some(ps), Some(fs)) = (lm.obs.get(s), poses.get(s), frames.get(s))
        else {
            return out;
        };
        let obs_s = to(os);
        let sqrt_info =
            crate::camera::Vec2::new(self.cfg.camera.fx, self.cfg.camera.fy) / self.cfg.sigma_px;
        let lc = &self.cfg.lidar;
        // A LiDAR landmark's depth comes from the depth-only optimization (paper V.D), so that
        // culling sees the depth the LiDAR pulled it to; without it, the pose-only depth.
        let lidar_tau = lc.enabled && lc.depth_only_opt && lm.lidar.is_some() && lm.inv_depth > 0.0;
        let observed = lm
            .obs
            .iter()
            .zip(poses.iter().zip(frames.iter()))
            .enumerate()
            .take(self.window.len())
            .filter(|(j, _)| *j != s)
            .filter_map(|(j, (o, pf))| o.as_ref().map(|o| (j, to(o), pf)));
        let eliminated = self.cfg.depth_eliminated() && lm.inv_depth > 0.0;
        if lidar_tau || eliminated || self.cfg.mode == VisualMode::InverseDepth {
            // The inverse-depth residuals on the landmark's rays: the anchor's ray formed once,
            // a few flops per observation instead of the whole factor chain.
            let m = TauLandmark::new(&lm.obs, s, None, sqrt_info, self.window.len());
            let rays = m.as_ref().map(|m| m.rays(poses, frames));
            if let (Some(m), Some(Ok(rays))) = (m, rays) {
                for ((j, _), ray) in m.obs.iter().zip(rays.iter()) {
                    if let Some(o) = out.get_mut(*j) {
                        *o = ray.residual_and_d_tau(lm.inv_depth).ok().map(|(r, _)| r);
                    }
                }
            }
            return out;
        }
        let Some(e) = lm.anchor_e.map(usize::from) else {
            return out;
        };
        let (Some(Some(oe)), Some(pe), Some(fe)) = (lm.obs.get(e), poses.get(e), frames.get(e))
        else {
            return out;
        };
        let Ok(anchors) = PoseOnlyAnchors::new(
            (s, e),
            obs_s,
            to(oe),
            sqrt_info,
            (ps, pe),
            (fs, fe),
            &self.ext,
            None,
        ) else {
            return out;
        };
        let sd = problem::anchor_depth_std(&self.cfg, &anchors);
        let anchors = anchors.with_depth_std(sd);
        for (j, obs_j, (pj, fj)) in observed {
            if let Some(o) = out.get_mut(j) {
                *o = anchors.residual(j, &obs_j, pj, fj).ok();
            }
        }
        out
    }

    /// Removes observations whose whitened squared residual exceeds the chi-square threshold.
    fn chi2_cull(&mut self) -> u32 {
        let count = self.window.len();
        let wf = self.window_frames();
        let mut culled = 0;
        for li in 0..self.lms.len() {
            let usable = self.lms.landmarks().get(li).is_some_and(|l| l.usable);
            if !usable {
                continue;
            }
            let s = self
                .lms
                .landmarks()
                .get(li)
                .map_or(0, |l| l.anchor_s as usize);
            let res = self.landmark_residuals(li, &wf);
            for (j, r) in res.iter().enumerate().take(count) {
                if j == s {
                    continue;
                }
                let bad = r.is_some_and(|r| r.norm_squared() > self.cfg.chi2_threshold);
                if bad && self.lms.invalidate_obs(li, j) {
                    culled += 1;
                }
            }
        }
        self.fix_anchors();
        culled
    }

    /// After removing observations: re-anchor `s` at the first remaining observation (dropping
    /// depth state that was expressed in the old anchor) and drop unobserved landmarks.
    fn fix_anchors(&mut self) {
        for lm in self.lms.landmarks_mut() {
            if let Some(s) = lm.first_obs() {
                if s != lm.anchor_s as usize {
                    lm.anchor_s = s as u8;
                    lm.inv_depth = 0.0;
                    lm.lidar = None;
                }
            }
            if lm
                .anchor_e
                .is_some_and(|e| lm.obs.get(e as usize).is_none_or(|o| o.is_none()))
            {
                lm.anchor_e = None;
            }
        }
        self.lms.retain(|lm| lm.first_obs().is_some(), true);
    }

    /// Paper V.E: drop landmarks whose mean reprojection error exceeds `cull_mean_px`, otherwise
    /// single observations above `cull_obs_px`. Returns (observations, landmarks, rms px).
    fn reprojection_cull(&mut self) -> (u32, u32, f64) {
        let count = self.window.len();
        let wf = self.window_frames();
        let sigma = self.cfg.sigma_px;
        let (mut n_obs, mut n_lm) = (0u32, 0u32);
        let (mut sq_sum, mut sq_n) = (0.0, 0u32);
        let mut drop_lm: HVec<u64, L> = HVec::new();
        for li in 0..self.lms.len() {
            let Some(lm) = self.lms.landmarks().get(li) else {
                break;
            };
            if !lm.usable {
                continue;
            }
            let (id, s) = (lm.id, lm.anchor_s as usize);
            let mut errs = [0.0f64; N];
            let (mut sum, mut n) = (0.0, 0u32);
            let res = self.landmark_residuals(li, &wf);
            for (j, (e, r)) in errs.iter_mut().zip(res.iter()).enumerate().take(count) {
                if j == s {
                    continue;
                }
                if let Some(r) = r {
                    *e = libm::sqrt(r.norm_squared()) * sigma;
                    sum += *e;
                    n += 1;
                    sq_sum += r.norm_squared() * sigma * sigma;
                    sq_n += 2;
                }
            }
            if n == 0 {
                continue;
            }
            // A track with one gross observation is a wrong track from there on (a tracker that
            // jumps stays on what it jumped to): with `cull_whole_tracks` it goes whole.
            let gross = self.cfg.cull_whole_tracks
                && errs
                    .iter()
                    .enumerate()
                    .take(count)
                    .any(|(j, e)| j != s && *e > self.cfg.cull_obs_px);
            if gross || sum / f64::from(n) > self.cfg.cull_mean_px {
                let _ = drop_lm.push(id);
                if let Some(d) = self.lms.landmarks().get(li).and_then(|l| l.lidar) {
                    let _ = self.events.push(DepthEvent {
                        id,
                        kind: DepthEventKind::Culled,
                        depth_m: d.depth_m,
                    });
                }
                continue;
            }
            for (j, e) in errs.iter().enumerate().take(count) {
                if j != s && *e > self.cfg.cull_obs_px && self.lms.invalidate_obs(li, j) {
                    n_obs += 1;
                }
            }
        }
        if !drop_lm.is_empty() {
            for &id in drop_lm.iter() {
                self.lms.ban(id);
            }
            n_lm = self.lms.retain(|lm| !drop_lm.contains(&lm.id), true) as u32;
        }
        self.fix_anchors();
        let rms = if sq_n > 0 {
            libm::sqrt(sq_sum / f64::from(sq_n))
        } else {
            0.0
        };
        (n_obs, n_lm, rms)
    }
}

/// Linear interpolation of an IMU sample at `t_ns` between `a` and `b` (`a.t < t <= b.t`).
fn interpolate(a: &ImuSample, b: &ImuSample, t_ns: i64) -> ImuSample {
    let span = b.t_ns.saturating_sub(a.t_ns) as f64;
    let w = if span > 0.0 {
        t_ns.saturating_sub(a.t_ns) as f64 / span
    } else {
        1.0
    };
    ImuSample {
        t_ns,
        gyro_rps: a.gyro_rps + (b.gyro_rps - a.gyro_rps) * w,
        accel_mps2: a.accel_mps2 + (b.accel_mps2 - a.accel_mps2) * w,
    }
}

impl<
        const N: usize,
        const L: usize,
        const D: usize,
        const P: usize,
        const GW: usize,
        const GH: usize,
        const Q: usize,
    > Estimator<N, L, D, P, GW, GH, Q>
{
    /// One Levenberg-Marquardt iteration on the current window (landmark preparation,
    /// linearization, damping, factorization, solve, evaluation of the step, accepted or not),
    /// with the first pass's settings. For benchmarks and diagnostics: a keyframe step runs a
    /// few of these per pass.
    pub fn lm_iteration(&mut self) -> Result<crate::solver::LmSummary, Error> {
        if self.window.len() < 2 {
            return Err(Error::NotEnoughData);
        }
        self.prepare_landmarks(false);
        let cfg = crate::solver::LmConfig {
            max_iterations: 1,
            ..self.cfg.lm_first
        };
        let layout = self.solve_layout();
        let (mut problem, lm, _) = self.split(layout, FactorSet::All);
        lm.solve(&mut problem, &cfg)
    }

    /// Marginalizes the oldest keyframe now, as the next keyframe of a full window would (Schur
    /// complement into the square-root prior, window shifted). For benchmarks and diagnostics.
    pub fn marginalize_oldest_now(&mut self) -> Result<(), Error> {
        if self.window.len() < 2 {
            return Err(Error::NotEnoughData);
        }
        self.marginalize_oldest()
    }

    /// Self-check of the assembled problem at the current state: compares the analytic gradient
    /// `-2 b` of the normal equations with central differences of the cost along every
    /// error-state column (step `h`), and returns the worst relative error. Restores the state.
    /// Meant for tests and diagnostics (it evaluates the cost `2 n` times).
    pub fn gradient_check(&mut self, h: f64) -> Result<f64, Error> {
        use crate::solver::LmProblem;
        self.prepare_landmarks(false);
        let layout = self.solve_layout();
        let n = layout.dim();
        let (mut problem, lm, _) = self.split(layout, FactorSet::All);
        lm.ne.reset(n)?;
        problem.linearize(&mut lm.ne)?;
        if problem.cfg.mode == VisualMode::InverseDepth {
            // The reduced system's b is the gradient of the cost minimized over the depths,
            // which central differences at fixed depths do not measure.
            return Err(Error::InvalidConfig);
        }
        let mut worst = 0.0f64;
        let mut dx = [0.0; D];
        for i in 0..n {
            let mut c = [0.0; 2];
            for (slot, sign) in c.iter_mut().zip([1.0, -1.0]) {
                problem.save();
                if let Some(d) = dx.get_mut(i) {
                    *d = sign * h;
                }
                problem.apply(dx.get(..n).unwrap_or(&[]));
                *slot = problem.cost()?;
                problem.restore();
                if let Some(d) = dx.get_mut(i) {
                    *d = 0.0;
                }
            }
            let g_num = (c[0] - c[1]) / (2.0 * h);
            let g_an = -2.0 * lm.ne.b.get(i).copied().unwrap_or(0.0);
            let err =
                libm::fabs(g_num - g_an) / (1.0 + libm::fmax(libm::fabs(g_num), libm::fabs(g_an)));
            worst = libm::fmax(worst, err);
        }
        Ok(worst)
    }
}
