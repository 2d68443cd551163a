//! Camera images + IMU in, state out: the image front end ([`FeatureTracker`]) feeding the
//! estimator ([`Estimator`]), heap-free.
//!
//! [`Vio`] owns one of each and does, per image ([`Vio::push_image`]):
//! 1. asks the estimator for the INS prediction of every window landmark with a depth
//!    ([`Estimator::predict_features`], once it runs): those features are tracked on
//!    `predicted_max_level + 1` pyramid levels from the predicted pixel;
//! 2. integrates the buffered gyro (minus the estimated bias) over
//!    `[t_prev + td, t_cur + td]` (`t_imu = t_cam + td`, the estimator's current delay) and turns
//!    it into the camera rotation `R_cur_prev` with the estimated camera-IMU rotation: the seed of
//!    the other features and the 2-point RANSAC model. It works before initialization too (with
//!    a zero bias);
//! 3. tracks ([`FeatureTracker::track`]) and offers the tracks to the estimator
//!    ([`Estimator::push_frame`]).
//!
//! IMU samples go through [`Vio::push_imu`], which queues them in the estimator and keeps the
//! last [`GYRO_SAMPLES`] accepted gyro readings, and [`Vio::update`] processes them. Front end and back end stay usable separately:
//! [`Vio::estimator`] / [`Vio::estimator_mut`] and [`Vio::tracker`] give the parts, and an
//! estimator fed with [`Estimator::push_frame`] directly works as before.
//!
//! Images are processed in the caller's order: push an image once the IMU stream has reached
//! its stamp (as a live system does), so the INS covers it. A bad image (size differing from the
//! camera's, time not increasing, a pyramid that does not fit) returns an [`Error`] and is
//! counted in [`VioCounters`]; nothing panics and nothing allocates.
//!
//! Memory: `size_of::<Estimator<N, L, D>>() + size_of::<FeatureTracker<F, BYTES, LEVELS>>()`
//! plus `L` predictions and hints (72 bytes each) and the gyro buffer ([`GYRO_SAMPLES`] x 32
//! bytes): [`EurocVio`] is about 5.9 MB (the estimator's 4.6 MB, the tracker's 1.26 MB). Keep it
//! in a `static` or a `Box`, built on a thread with a large stack.

use crate::camera::FeatureObs;
use crate::estimator::{Estimator, FeaturePrediction, ImuOutput, Status};
use crate::frontend::image::TrackerConfig;
use crate::frontend::image::{pyramid_bytes, FeatureTracker, ImageView, TrackHints, TrackStats};
use crate::inertial::ImuSample;
use crate::math::{exp_so3, Mat3, Vec3};
use crate::Error;
use heapless::Deque;

/// Gyro readings kept for the rotation seed (2.5 s at 200 Hz; an image interval must fit).
pub const GYRO_SAMPLES: usize = 512;

/// Longest extrapolation of the gyro past its newest reading, ns (as the INS prediction's
/// `MAX_EXTRAPOLATION_NS`).
pub const GYRO_EXTRAPOLATION_NS: i64 = 50_000_000;

/// Longest image interval the gyro rotation is integrated over, ns (a longer gap gives no
/// rotation seed).
pub const MAX_ROTATION_INTERVAL_NS: i64 = 1_000_000_000;

/// The paper's estimator (10 keyframes, 200 landmarks) with a front end for images up to
/// 752x480 (EuRoC; 640x360 fits too), 256 features, 4 pyramid levels: about 5.9 MB.
pub type EurocVio = Vio<10, 200, 166, 256, { pyramid_bytes(752, 480, 4) }, 4>;

/// The same for images up to 1280x720: about 7.4 MB.
pub type HdVio = Vio<10, 200, 166, 256, { pyramid_bytes(1280, 720, 4) }, 4>;

/// Which parts of the INS aid the tracker.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct VioAiding {
    /// Seed features with a landmark depth at their INS-predicted pixel.
    pub predictions: bool,
    /// Seed the others with the gyro rotation (and allow the 2-point RANSAC).
    pub gyro_rotation: bool,
}

impl Default for VioAiding {
    fn default() -> Self {
        VioAiding {
            predictions: true,
            gyro_rotation: true,
        }
    }
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
    /// Front-end time (predictions, gyro integration, tracking), ns, by the estimator
    /// configuration's clock (0 without a clock).
    pub frontend_ns: u64,
    /// The estimator refused the frame (its counters have the reason); the tracker advanced.
    pub frame_error: Option<Error>,
}

/// Counts of what [`Vio`] refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
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

/// Estimator + image front end (see the module docs).
pub struct Vio<
    const N: usize,
    const L: usize,
    const D: usize,
    const F: usize,
    const BYTES: usize,
    const LEVELS: usize,
> {
    est: Estimator<N, L, D>,
    tracker: FeatureTracker<F, BYTES, LEVELS>,
    aiding: VioAiding,
    gyro: GyroIntegrator<GYRO_SAMPLES>,
    bg: Vec3,
    last_image_ns: Option<i64>,
    preds: [FeaturePrediction; L],
    hints: [(u64, [f64; 2]); L],
    counters: VioCounters,
}

impl<
        const N: usize,
        const L: usize,
        const D: usize,
        const F: usize,
        const BYTES: usize,
        const LEVELS: usize,
    > Vio<N, L, D, F, BYTES, LEVELS>
{
    /// A new estimator and tracker ([`Error::InvalidConfig`] if either configuration is
    /// invalid or does not fit the capacities).
    pub fn new(
        estimator: crate::estimator::EstimatorConfig,
        tracker: TrackerConfig,
    ) -> Result<Self, Error> {
        Ok(Vio {
            est: Estimator::new(estimator)?,
            tracker: FeatureTracker::new(tracker)?,
            aiding: VioAiding::default(),
            gyro: GyroIntegrator::new(),
            bg: Vec3::zeros(),
            last_image_ns: None,
            preds: [FeaturePrediction::EMPTY; L],
            hints: [(0, [0.0; 2]); L],
            counters: VioCounters::default(),
        })
    }

    /// An unconfigured estimator and tracker ([`Estimator::empty`], [`FeatureTracker::empty`]),
    /// to be [`Self::configure`]d: `const`, so it can initialize a `static` or be written to the
    /// heap without passing through a stack (`povins_platform::boxed::boxed_vio`).
    pub const fn empty() -> Self {
        Vio {
            est: Estimator::empty(),
            tracker: FeatureTracker::empty(),
            aiding: VioAiding {
                predictions: true,
                gyro_rotation: true,
            },
            gyro: GyroIntegrator::new(),
            bg: Vec3::new(0.0, 0.0, 0.0),
            last_image_ns: None,
            preds: [FeaturePrediction::EMPTY; L],
            hints: [(0, [0.0; 2]); L],
            counters: VioCounters {
                images: 0,
                images_rejected: 0,
                frames_rejected: 0,
                no_rotation_seed: 0,
            },
        }
    }

    /// Validates both configurations as [`Self::new`] does (and then nothing changes) and
    /// resets the estimator ([`Estimator::configure`]) and the tracker
    /// ([`FeatureTracker::configure`]) in place: the state `new(estimator, tracker)` builds,
    /// default aiding included. Builds nothing large on the stack.
    pub fn configure(
        &mut self,
        estimator: crate::estimator::EstimatorConfig,
        tracker: TrackerConfig,
    ) -> Result<(), Error> {
        // Checked first, so that nothing changes when either is invalid (the estimator's
        // `configure` changes nothing when it fails).
        FeatureTracker::<F, BYTES, LEVELS>::check(&tracker)?;
        self.est.configure(estimator)?;
        self.tracker.configure(tracker)?;
        self.aiding = VioAiding::default();
        self.gyro.clear();
        self.bg = Vec3::zeros();
        self.last_image_ns = None;
        self.preds.fill(FeaturePrediction::EMPTY);
        self.hints.fill((0, [0.0; 2]));
        self.counters = VioCounters::default();
        Ok(())
    }

    /// Chooses which INS aids the tracker gets (both by default).
    pub fn set_aiding(&mut self, aiding: VioAiding) {
        self.aiding = aiding;
    }

    /// The estimator (state, keyframes, counters, configuration).
    pub fn estimator(&self) -> &Estimator<N, L, D> {
        &self.est
    }

    /// The estimator, mutable (e.g. [`Estimator::initialize`], [`Estimator::push_lidar`]).
    pub fn estimator_mut(&mut self) -> &mut Estimator<N, L, D> {
        &mut self.est
    }

    /// The front end (current tracks, ages, pyramid).
    pub fn tracker(&self) -> &FeatureTracker<F, BYTES, LEVELS> {
        &self.tracker
    }

    /// The current tracks (what the last image gave the estimator).
    pub fn features(&self) -> &[FeatureObs] {
        self.tracker.features()
    }

    /// What was refused so far.
    pub fn counters(&self) -> VioCounters {
        self.counters
    }

    /// Queues one IMU sample in the estimator ([`Estimator::push_imu`], same result) and keeps
    /// its gyro reading for the rotation seed when the estimator accepted it. Drain
    /// [`Self::update`] after it.
    pub fn push_imu(&mut self, s: &ImuSample) -> Result<(), Error> {
        self.est.push_imu(s)?;
        self.gyro.push(s.t_ns, &s.gyro_rps);
        Ok(())
    }

    /// Processes the estimator's next due IMU sample ([`Estimator::update`], same result) and
    /// takes the gyro bias of the rotation seed from its state.
    pub fn update(&mut self) -> Result<Option<ImuOutput>, Error> {
        let out = self.est.update()?;
        if let Some(o) = &out {
            self.bg = match o.nav {
                Some(nav) if nav.bg.iter().all(|x| x.is_finite()) => nav.bg,
                _ => Vec3::zeros(),
            };
        }
        Ok(out)
    }

    /// Tracks the image taken at `t_cam_ns` (camera clock) and offers its tracks to the
    /// estimator (see the module docs).
    ///
    /// Errors (the tracker and estimator are unchanged): those of [`FeatureTracker::track`]
    /// ([`Error::TimeNotIncreasing`], [`Error::DimensionMismatch`] for an image whose size
    /// differs from the configured camera's, [`Error::CapacityExceeded`] for an image too
    /// large for `BYTES`, [`Error::InvalidConfig`]). When the estimator refuses the tracked
    /// frame the report says so in [`ImageReport::frame_error`].
    pub fn push_image(&mut self, t_cam_ns: i64, image: &ImageView) -> Result<ImageReport, Error> {
        self.counters.images += 1;
        let clock = self.est.config().clock;
        let t0 = clock.map_or(0, |c| c());
        let camera = self.est.config().camera;

        let mut n_pred = 0usize;
        if self.aiding.predictions && self.est.status() == Status::Running {
            n_pred = self
                .est
                .predict_features(t_cam_ns, &mut self.preds)
                .unwrap_or(0);
            for (h, p) in self.hints.iter_mut().zip(self.preds.iter()).take(n_pred) {
                *h = (p.id, p.uv_px);
            }
            n_pred = n_pred.min(self.hints.len());
        }
        let rotation = match self.last_image_ns {
            Some(prev) if self.aiding.gyro_rotation => self.camera_rotation(prev, t_cam_ns),
            _ => None,
        };
        if self.last_image_ns.is_some() && self.aiding.gyro_rotation && rotation.is_none() {
            self.counters.no_rotation_seed += 1;
        }
        let hints = TrackHints {
            r_cur_prev: rotation,
            predictions: self.hints.get(..n_pred).unwrap_or(&[]),
        };
        let track = match self.tracker.track(t_cam_ns, image, &hints, &camera) {
            Ok(s) => s,
            Err(e) => {
                self.counters.images_rejected += 1;
                return Err(e);
            }
        };
        self.last_image_ns = Some(t_cam_ns);
        let frontend_ns = clock.map_or(0, |c| c().saturating_sub(t0));
        let frame_error = self.est.push_frame(t_cam_ns, self.tracker.features()).err();
        if frame_error.is_some() {
            self.counters.frames_rejected += 1;
        }
        Ok(ImageReport {
            track,
            predictions: n_pred as u32,
            rotation_seed: rotation.is_some(),
            tracks: self.tracker.features().len() as u32,
            frontend_ns,
            frame_error,
        })
    }

    /// Rotation of the camera at image time `t0_cam_ns` into the camera at `t1_cam_ns`,
    /// `R_c1_c0`, from the buffered gyro minus the estimated bias, the estimator's current delay
    /// and camera-IMU rotation ([`GyroIntegrator::camera_rotation`]).
    pub fn camera_rotation(&self, t0_cam_ns: i64, t1_cam_ns: i64) -> Option<Mat3> {
        let r_bc = self.est.extrinsic().q_bc.to_rotation_matrix().into_inner();
        self.gyro
            .camera_rotation(t0_cam_ns, t1_cam_ns, self.est.td_s(), &self.bg, &r_bc)
    }
}

/// The last `S` gyro readings, integrated into the camera rotation between two image times
/// (the tracker's rotation seed). Used by [`Vio`]; usable alone for a front end without the
/// estimator.
#[derive(Debug, Clone)]
pub struct GyroIntegrator<const S: usize> {
    buf: Deque<(i64, Vec3), S>,
}

impl<const S: usize> Default for GyroIntegrator<S> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const S: usize> GyroIntegrator<S> {
    /// An empty buffer.
    pub const fn new() -> Self {
        GyroIntegrator { buf: Deque::new() }
    }

    /// Drops every reading.
    pub fn clear(&mut self) {
        self.buf.clear();
    }

    /// Readings held.
    pub fn len(&self) -> usize {
        self.buf.len()
    }

    /// True when no reading is held.
    pub fn is_empty(&self) -> bool {
        self.buf.is_empty()
    }

    /// Adds the gyro reading `gyro_rps` (body frame) taken at `t_ns`, dropping the oldest when
    /// full. A non-finite reading or one not after the newest is ignored (returns false).
    pub fn push(&mut self, t_ns: i64, gyro_rps: &Vec3) -> bool {
        if !gyro_rps.iter().all(|x| x.is_finite()) || self.buf.back().is_some_and(|b| t_ns <= b.0) {
            return false;
        }
        if self.buf.is_full() {
            let _ = self.buf.pop_front();
        }
        // Not full (made room above): cannot fail.
        self.buf.push_back((t_ns, *gyro_rps)).is_ok()
    }

    /// Body rotation `R_b0_b1` from `t0_ns` to `t1_ns` (IMU clock): the product of
    /// `Exp((w_k - bg) dt)` with each reading held until the next and the newest extrapolated up
    /// to [`GYRO_EXTRAPOLATION_NS`]. `None` when the readings do not cover `[t0, t1]`, the
    /// interval is empty or longer than [`MAX_ROTATION_INTERVAL_NS`], or `bg` is not finite.
    pub fn body_rotation(&self, t0_ns: i64, t1_ns: i64, bg: &Vec3) -> Option<Mat3> {
        let span = t1_ns.checked_sub(t0_ns)?;
        if span <= 0 || span > MAX_ROTATION_INTERVAL_NS || !bg.iter().all(|x| x.is_finite()) {
            return None;
        }
        let (oldest, newest) = (self.buf.front()?.0, self.buf.back()?.0);
        if t0_ns < oldest || t1_ns > newest.saturating_add(GYRO_EXTRAPOLATION_NS) {
            return None;
        }
        let mut r = Mat3::identity();
        let mut it = self.buf.iter().peekable();
        while let Some(&(tk, wk)) = it.next() {
            let t_next = it.peek().map_or(t1_ns, |n| n.0);
            let (a, b) = (tk.max(t0_ns), t_next.min(t1_ns));
            if b > a {
                r *= exp_so3(&((wk - bg) * ((b - a) as f64 * 1e-9)));
            }
            if t_next >= t1_ns {
                break;
            }
        }
        Some(r)
    }

    /// Rotation of the camera at image time `t0_cam_ns` into the camera at `t1_cam_ns`
    /// (`R_c1_c0 = R_bc^T R_b0_b1^T R_bc`), integrating over `[t0 + td, t1 + td]`
    /// (`t_imu = t_cam + td_s`) with the gyro bias `bg` and the camera-to-body rotation `r_bc`.
    /// `None` as [`Self::body_rotation`], or for a non-finite or above 1 s delay.
    pub fn camera_rotation(
        &self,
        t0_cam_ns: i64,
        t1_cam_ns: i64,
        td_s: f64,
        bg: &Vec3,
        r_bc: &Mat3,
    ) -> Option<Mat3> {
        if !td_s.is_finite() || libm::fabs(td_s) > 1.0 {
            return None;
        }
        let td_ns = libm::round(td_s * 1e9) as i64;
        let r_b0b1 = self.body_rotation(
            t0_cam_ns.saturating_add(td_ns),
            t1_cam_ns.saturating_add(td_ns),
            bg,
        )?;
        let r = r_bc.transpose() * r_b0b1.transpose() * r_bc;
        r.iter().all(|x| x.is_finite()).then_some(r)
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::camera::CameraExtrinsic;
    use crate::estimator::EstimatorConfig;
    use crate::frontend::image::testutil::{
        big_stack, noise, render_rotated, small_tracker_config as trk_cfg, test_camera as cam,
    };
    use crate::inertial::ImuNoise;
    use crate::math::Quat;
    use std::vec::Vec;

    const W: usize = 320;
    const H: usize = 240;
    type SmallVio = Vio<10, 200, 166, 64, { pyramid_bytes(W, H, 4) }, 4>;

    /// Camera axes: x right, y down, z forward; the body is the camera turned so that its z
    /// is up: `R_bc` maps camera y (down) to body -z.
    fn r_bc() -> Mat3 {
        Mat3::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0)
    }

    fn est_cfg() -> EstimatorConfig {
        let q_bc = Quat::from_matrix(&r_bc());
        let mut c = EstimatorConfig::new(
            cam(),
            CameraExtrinsic {
                p_bc: Vec3::zeros(),
                q_bc,
            },
            ImuNoise::EUROC_ADIS16448,
        );
        c.static_init.min_static_s = 0.5;
        c
    }

    /// The camera after yawing (about body z = camera -y) by `yaw` rad, looking at a textured
    /// plane at infinity.
    fn render_yawed(yaw: f64) -> Vec<u8> {
        // Body yaw about z -> camera rotation about -y.
        render_rotated(&exp_so3(&Vec3::new(0.0, -yaw, 0.0)))
    }

    #[test]
    fn gyro_integrator_covers_extrapolates_and_refuses() {
        let mut g: GyroIntegrator<8> = GyroIntegrator::new();
        let w = Vec3::new(0.0, 0.0, 0.5);
        assert!(g.body_rotation(0, 10, &Vec3::zeros()).is_none());
        for k in 0..10 {
            assert!(g.push(k * 5_000_000, &w));
        }
        // Capacity 8: the oldest two are gone.
        assert_eq!(g.len(), 8);
        assert!(g.body_rotation(0, 20_000_000, &Vec3::zeros()).is_none());
        // Non-finite and non-increasing readings are ignored.
        assert!(!g.push(45_000_000, &w));
        assert!(!g.push(50_000_000, &Vec3::new(f64::NAN, 0.0, 0.0)));
        // 20 ms inside, 30 ms more extrapolated: 0.5 rad/s x 50 ms about z.
        let r = g
            .body_rotation(10_000_000, 60_000_000, &Vec3::zeros())
            .unwrap();
        let e = exp_so3(&Vec3::new(0.0, 0.0, 0.025));
        assert!((r - e).amax() < 1e-12, "{r} vs {e}");
        // The bias is removed.
        let r = g.body_rotation(10_000_000, 40_000_000, &w).unwrap();
        assert!((r - Mat3::identity()).amax() < 1e-15);
        // Beyond the extrapolation limit, empty and reversed intervals.
        assert!(g
            .body_rotation(10_000_000, 100_000_000, &Vec3::zeros())
            .is_none());
        assert!(g
            .body_rotation(20_000_000, 20_000_000, &Vec3::zeros())
            .is_none());
        assert!(g
            .body_rotation(30_000_000, 20_000_000, &Vec3::zeros())
            .is_none());
        // Camera axes: body z is camera -y.
        let r = g
            .camera_rotation(10_000_000, 40_000_000, 0.0, &Vec3::zeros(), &r_bc())
            .unwrap();
        let expect = exp_so3(&Vec3::new(0.0, 0.015, 0.0));
        assert!((r - expect).amax() < 1e-12, "{r} vs {expect}");
        // The delay shifts the interval: td = -15 ms integrates [-5 ms, 25 ms]: not covered.
        assert!(g
            .camera_rotation(10_000_000, 40_000_000, -0.015, &Vec3::zeros(), &r_bc())
            .is_none());
        assert!(g
            .camera_rotation(10_000_000, 40_000_000, f64::NAN, &Vec3::zeros(), &r_bc())
            .is_none());
        g.clear();
        assert!(g.is_empty());
    }

    /// Static for 0.6 s (the estimator initializes), then the camera yaws at 1 rad/s with an
    /// image every 50 ms: the images are tracked with the gyro seed, their tracks reach the
    /// estimator, and bad images are refused and counted without changing anything.
    #[test]
    fn images_and_imu_drive_the_estimator_with_gyro_seeds() {
        big_stack(|| {
            let mut vio = SmallVio::new(est_cfg(), trk_cfg()).unwrap();
            let rate = 1.0;
            let dt_ns = 5_000_000i64;
            let t_move = 600_000_000i64;
            let yaw_at = |t: i64| rate * ((t - t_move).max(0) as f64 * 1e-9);
            let mut reports = Vec::new();
            let mut next_image = t_move;
            for k in 0..=300i64 {
                let t = k * dt_ns;
                // Images once the IMU has reached their stamp (as a live system).
                if t >= next_image && t > t_move {
                    let img = render_yawed(yaw_at(next_image));
                    let view = ImageView::new(&img, W, H, W).unwrap();
                    reports.push(vio.push_image(next_image, &view).unwrap());
                    next_image += 50_000_000;
                }
                let s = ImuSample {
                    t_ns: t,
                    gyro_rps: Vec3::new(0.0, 0.0, if t >= t_move { rate } else { 0.0 }),
                    accel_mps2: Vec3::new(0.0, 0.0, 9.81),
                };
                vio.push_imu(&s).unwrap();
                while vio.update().unwrap().is_some() {}
            }
            assert_eq!(vio.estimator().status(), Status::Running);
            assert!(reports.len() >= 15, "{}", reports.len());
            // First image: detection only; then every feature is seeded by the gyro (30 px of
            // motion per image at 300 px focal length) and tracked.
            assert!(!reports[0].rotation_seed);
            for r in &reports[1..] {
                assert!(r.rotation_seed);
                assert!(
                    r.track.seeded_rotation + r.track.seeded_prediction >= 30,
                    "{r:?}"
                );
                assert!(r.track.tracked >= 30, "{r:?}");
                assert_eq!(r.frame_error, None);
            }
            assert_eq!(vio.estimator().counters().frames, reports.len() as u64);
            assert_eq!(vio.counters().images_rejected, 0);
            assert_eq!(vio.counters().no_rotation_seed, 0);

            // Bad images: wrong size, time not increasing; noise and flat frames are tracked
            // (and lose their tracks) without panicking.
            let before = vio.features().to_vec();
            let t_last = next_image - 50_000_000;
            let small = std::vec![7u8; 100 * 80];
            let v = ImageView::new(&small, 100, 80, 100).unwrap();
            assert_eq!(
                vio.push_image(t_last + 10_000_000, &v),
                Err(Error::DimensionMismatch)
            );
            let img = render_yawed(0.0);
            let view = ImageView::new(&img, W, H, W).unwrap();
            assert_eq!(vio.push_image(t_last, &view), Err(Error::TimeNotIncreasing));
            assert_eq!(vio.features(), &before[..]);
            assert_eq!(vio.counters().images_rejected, 2);
            for (k, img) in [
                noise(W, H, 3),
                std::vec![0u8; W * H],
                std::vec![255u8; W * H],
            ]
            .iter()
            .enumerate()
            {
                let view = ImageView::new(img, W, H, W).unwrap();
                let r = vio
                    .push_image(t_last + 20_000_000 * (k as i64 + 1), &view)
                    .unwrap();
                assert!(r.tracks <= 40);
            }
            // A wider stride works as a plain view.
            let mut padded = std::vec![0u8; (W + 13) * H];
            for (row, src) in padded.chunks_mut(W + 13).zip(render_yawed(0.3).chunks(W)) {
                row[..W].copy_from_slice(src);
            }
            let view = ImageView::new(&padded, W, H, W + 13).unwrap();
            assert!(vio.push_image(t_last + 100_000_000, &view).is_ok());
        });
    }
}
