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
//! last [`GYRO_SAMPLES`] accepted gyro readings, and [`Vio::update`] processes them. Front end
//! and back end stay usable separately: [`Vio::estimator`] / [`Vio::estimator_mut`] and
//! [`Vio::tracker`] give the parts, and an estimator fed with [`Estimator::push_frame`] directly
//! works as before. The front end with its rotation seed is [`ImageFrontEnd`]; alone, without an
//! estimator (its seed from the configured delay and extrinsic, no bias), it is [`Tracking`],
//! what `povins track` runs.
//!
//! Both are [`crate::odometry::Odometry`]s.
//!
//! Images are processed in the caller's order: push an image once the IMU stream has reached
//! its stamp (as a live system does), so the INS covers it. A bad image (size differing from the
//! camera's, time not increasing, a pyramid that does not fit) returns an [`Error`] and is
//! counted in [`VioCounters`]; nothing panics and nothing allocates.
//!
//! Memory: `size_of::<Estimator<N, L, D>>() + size_of::<FeatureTracker<F, BYTES, LEVELS>>()`
//! plus `L` hints (24 bytes each) and the gyro buffer ([`GYRO_SAMPLES`] x 32 bytes): the README's
//! footprint table gives [`EurocVio`], [`HdVio`] and [`WuxgaVio`]. Keep it in a `static` or a
//! `Box`, built on a thread with a large stack.

mod front_end;
mod gyro;
mod tracking;

pub use front_end::{ImageFrontEnd, SeedFrame};
pub use gyro::GyroIntegrator;
pub use tracking::{EurocTracking, HdTracking, Tracking, WuxgaTracking};

use crate::camera::FeatureObs;
use crate::estimator::{Estimator, EstimatorConfig, ImuOutput, Status};
use crate::frontend::image::{pyramid_bytes, FeatureTracker, ImageView, TrackerConfig};
use crate::inertial::{ImuSample, InsUpdate, NavState};
use crate::lidar::LidarPoint;
use crate::math::{Mat3, Vec3};
use crate::odometry::{FrameOutput, Odometry, OdometryCounters, Output};
pub use crate::odometry::{ImageReport, VioCounters};
use crate::Error;

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

/// Pyramid levels of the 1920x1200 capacity ([`WuxgaVio`], [`WuxgaTracking`]): one more than
/// the smaller capacities, so that a configuration may track on `max_level = 4` (the same angular
/// motion is about 2.5 times as many pixels as on a 752-pixel-wide camera; the coarsest level of
/// 1920x1200 is 120x75). The default configuration uses 4 of them.
pub const WUXGA_LEVELS: usize = 5;

/// Bytes of each pyramid of the 1920x1200 capacity ([`pyramid_bytes`]`(1920, 1200, 5)` =
/// 3 069 000).
pub const WUXGA_PYRAMID_BYTES: usize = pyramid_bytes(1920, 1200, WUXGA_LEVELS);

/// The paper's estimator with a front end for images up to 1920x1200 (WUXGA; 1920x1080 and the
/// paper's 1280x1024 fit too), 256 features, 5 pyramid levels ([`WUXGA_LEVELS`]): about
/// 12 MB. The front end's arithmetic holds for sides up to
/// [`crate::frontend::image::MAX_IMAGE_SIDE`]; at this size the 8 x 6 default grid has cells of
/// 240 x 200 px (at most [`crate::frontend::image::corners::MAX_CELL_SIDE`] = 512) and the
/// detector's occupancy mask has 8 px
/// blocks.
pub type WuxgaVio = Vio<10, 200, 166, 256, WUXGA_PYRAMID_BYTES, WUXGA_LEVELS>;

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
    fe: ImageFrontEnd<F, BYTES, LEVELS>,
    hints: [(u64, [f64; 2]); L],
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
    pub fn new(estimator: EstimatorConfig, tracker: TrackerConfig) -> Result<Self, Error> {
        Ok(Vio {
            est: Estimator::new(estimator)?,
            fe: ImageFrontEnd::new(tracker)?,
            hints: [(0, [0.0; 2]); L],
        })
    }

    /// An unconfigured estimator and tracker ([`Estimator::empty`], [`FeatureTracker::empty`]),
    /// to be [`Self::configure`]d: `const`, so it can initialize a `static` or be written to the
    /// heap without passing through a stack (`povins_platform::boxed::boxed_vio`).
    pub const fn empty() -> Self {
        Vio {
            est: Estimator::empty(),
            fe: ImageFrontEnd::empty(),
            hints: [(0, [0.0; 2]); L],
        }
    }

    /// Validates both configurations as [`Self::new`] does (and then nothing changes) and
    /// resets the estimator ([`Estimator::configure`]) and the tracker
    /// ([`FeatureTracker::configure`]) in place: the state `new(estimator, tracker)` builds,
    /// default aiding included. Builds nothing large on the stack.
    pub fn configure(
        &mut self,
        estimator: EstimatorConfig,
        tracker: TrackerConfig,
    ) -> Result<(), Error> {
        // Checked first, so that nothing changes when either is invalid (the estimator's
        // `configure` changes nothing when it fails).
        ImageFrontEnd::<F, BYTES, LEVELS>::check(&tracker)?;
        self.est.configure(estimator)?;
        self.fe.configure(tracker)?;
        self.hints.fill((0, [0.0; 2]));
        Ok(())
    }

    /// Chooses which INS aids the tracker gets (both by default).
    pub fn set_aiding(&mut self, aiding: VioAiding) {
        self.fe.set_aiding(aiding);
    }

    /// Sets the monotonic clock, ns, that times the front end and the estimator's steps
    /// ([`Estimator::set_clock`]; none, the default: every timing is zero).
    pub fn set_clock(&mut self, clock: Option<fn() -> u64>) {
        self.est.set_clock(clock);
    }

    /// Whether this type accepts the configurations ([`Estimator::check`],
    /// [`FeatureTracker::check`]: the tracker's capacities); [`Self::configure`] checks the same.
    pub fn check(estimator: &EstimatorConfig, tracker: &TrackerConfig) -> Result<(), Error> {
        Estimator::<N, L, D>::check(estimator)?;
        ImageFrontEnd::<F, BYTES, LEVELS>::check(tracker)
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
        self.fe.tracker()
    }

    /// The current tracks (what the last image gave the estimator).
    pub fn features(&self) -> &[FeatureObs] {
        self.fe.features()
    }

    /// What was refused so far.
    pub fn counters(&self) -> VioCounters {
        self.fe.counters()
    }

    /// Queues one IMU sample in the estimator ([`Estimator::push_imu`], same result) and keeps
    /// its gyro reading for the rotation seed when the estimator accepted it. Drain
    /// [`Self::update`] after it.
    pub fn push_imu(&mut self, s: &ImuSample) -> Result<(), Error> {
        self.est.push_imu(s)?;
        self.fe.push_gyro(s.t_ns, &s.gyro_rps);
        Ok(())
    }

    /// Processes the estimator's next due IMU sample ([`Estimator::update`], same result).
    pub fn update(&mut self) -> Result<Option<ImuOutput>, Error> {
        self.est.update()
    }

    /// What the rotation seed uses now: the estimator's current delay, gyro bias (zero before
    /// initialization, after a reset, or when not finite) and camera-IMU rotation.
    fn seed_frame(&self) -> SeedFrame {
        let bg = match self.est.nav_state() {
            Some(nav) if nav.bg.iter().all(|x| x.is_finite()) => nav.bg,
            _ => Vec3::zeros(),
        };
        SeedFrame {
            td_s: self.est.td_s(),
            bg,
            r_bc: self.est.extrinsic().q_bc.to_rotation_matrix().into_inner(),
        }
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
        let clock = self.est.clock();
        let t0 = clock.map_or(0, |c| c());
        let camera = self.est.config().camera;
        // Predicted whether or not they seed the tracker: they are part of the output.
        let preds = self.est.predictions_at(t_cam_ns);
        let mut n_pred = 0usize;
        if self.fe.aiding().predictions {
            for (h, p) in self.hints.iter_mut().zip(preds.iter()) {
                *h = (p.id, p.uv_px);
            }
            n_pred = preds.len().min(self.hints.len());
        }
        let seed = self.seed_frame();
        let hints = self.hints.get(..n_pred).unwrap_or(&[]);
        let mut report = self
            .fe
            .track(t_cam_ns, image, &camera, &seed, hints, None)?;
        report.frontend_ns = clock.map_or(0, |c| c().saturating_sub(t0));
        report.frame_error = self.est.push_frame(t_cam_ns, self.fe.features()).err();
        if report.frame_error.is_some() {
            self.fe.count_frame_rejected();
        }
        Ok(report)
    }

    /// Rotation of the camera at image time `t0_cam_ns` into the camera at `t1_cam_ns`,
    /// `R_c1_c0`, from the buffered gyro minus the estimated bias, the estimator's current delay
    /// and camera-IMU rotation ([`GyroIntegrator::camera_rotation`]).
    pub fn camera_rotation(&self, t0_cam_ns: i64, t1_cam_ns: i64) -> Option<Mat3> {
        self.fe
            .camera_rotation(t0_cam_ns, t1_cam_ns, &self.seed_frame())
    }
}

impl<
        const N: usize,
        const L: usize,
        const D: usize,
        const F: usize,
        const BYTES: usize,
        const LEVELS: usize,
    > Odometry for Vio<N, L, D, F, BYTES, LEVELS>
{
    fn config(&self) -> &EstimatorConfig {
        self.est.config()
    }

    fn status(&self) -> Status {
        self.est.status()
    }

    fn initialize(&mut self, state: NavState) -> Result<(), Error> {
        self.est.initialize(state)
    }

    fn fast_path_seed(&self) -> Option<InsUpdate> {
        self.est.fast_path_seed()
    }

    fn push_imu(&mut self, s: &ImuSample) -> Result<(), Error> {
        Vio::push_imu(self, s)
    }

    fn end_input(&mut self) {
        self.est.end_input();
    }

    fn push_frame<'a>(
        &'a mut self,
        t_cam_ns: i64,
        obs: &'a [FeatureObs],
    ) -> Result<FrameOutput<'a>, Error> {
        Odometry::push_frame(&mut self.est, t_cam_ns, obs)
    }

    fn push_image(&mut self, t_cam_ns: i64, image: &ImageView) -> Result<FrameOutput<'_>, Error> {
        let report = Vio::push_image(self, t_cam_ns, image)?;
        Ok(FrameOutput {
            t_cam_ns,
            predictions: self.est.last_predictions(),
            tracks: self.fe.features(),
            track_ages: self.fe.tracker().ages(),
            image: Some(report),
            frame_error: report.frame_error,
        })
    }

    fn push_lidar(&mut self, points: &[LidarPoint]) -> Result<(), Error> {
        self.est.push_lidar(points)
    }

    fn update(&mut self) -> Result<Option<Output<'_>>, Error> {
        self.est.update_output()
    }

    fn counters(&self) -> OdometryCounters {
        OdometryCounters {
            estimator: self.est.counters(),
            images: self.fe.counters(),
        }
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
    use crate::math::{exp_so3, Quat};
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
