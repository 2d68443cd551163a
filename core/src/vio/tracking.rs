//! [`Tracking`]: the image front end alone, as an [`Odometry`] that estimates nothing (what
//! `povins track` runs to measure the front end). Its rotation seed integrates the gyro with
//! the configured delay (`td_s`) and camera-IMU rotation of its [`EstimatorConfig`] and no bias;
//! nothing predicts features. It takes IMU samples (their gyro readings) and images; feature
//! frames and LiDAR sweeps are refused ([`Error::InvalidConfig`]), and [`Odometry::update`]
//! never has an output.

use super::front_end::{ImageFrontEnd, SeedFrame};
use super::{VioAiding, WUXGA_LEVELS, WUXGA_PYRAMID_BYTES};
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

/// The front end alone for images up to 1920x1200 (5 levels, see [`super::WuxgaVio`]).
pub type WuxgaTracking = Tracking<256, WUXGA_PYRAMID_BYTES, WUXGA_LEVELS>;

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

    /// Nothing is held back: the front end alone answers every push at once.
    fn end_input(&mut self) {}

    fn counters(&self) -> OdometryCounters {
        OdometryCounters {
            estimator: Default::default(),
            images: self.fe.counters(),
        }
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::camera::{CameraExtrinsic, Distortion, PinholeCamera};
    use crate::frontend::image::testutil::{big_stack, render, texture};
    use crate::inertial::ImuNoise;
    use crate::math::Quat;
    use std::boxed::Box;

    /// The unit tests' texture with structure at every scale up to a few hundred pixels, so that
    /// the coarse levels of a large image have texture too.
    fn multiscale(x: f64, y: f64) -> f64 {
        0.6 * texture(x, y)
            + 0.4 * texture(x * 0.2 + 517.0, y * 0.2 - 311.0)
            + 10.0 * libm::sin(0.013 * x - 0.021 * y)
    }

    fn config(width: u32, height: u32) -> EstimatorConfig {
        let camera = PinholeCamera {
            readout_s: 0.0,
            width,
            height,
            fx: 0.6 * f64::from(width),
            fy: 0.6 * f64::from(width),
            cx: 0.5 * f64::from(width) - 0.5,
            cy: 0.5 * f64::from(height) - 0.5,
            distortion: Distortion::None,
        };
        let ext = CameraExtrinsic {
            p_bc: Vec3::zeros(),
            q_bc: Quat::identity(),
        };
        EstimatorConfig::new(camera, ext, ImuNoise::EUROC_ADIS16448)
    }

    /// Tracks a `w x h` image into the same texture shifted by `(dx, dy)` px (no gyro, no
    /// prediction: every feature seeded at its previous position) with the default tracker, in
    /// the 1920x1200 capacity: at least 100 features, each moved by the shift within 0.1 px.
    fn tracks_a_known_shift(w: usize, h: usize, (dx, dy): (f64, f64)) {
        let mut t: Box<WuxgaTracking> = Box::new(Tracking::empty());
        t.configure(config(w as u32, h as u32), TrackerConfig::default())
            .unwrap();
        let a = render(w, h, 0.0, 0.0, multiscale);
        let b = render(w, h, dx, dy, multiscale);
        let first = t
            .push_image(0, &ImageView::new(&a, w, h, w).unwrap())
            .unwrap();
        let before = first.tracks.to_vec();
        assert_eq!(before.len(), 150, "{:?}", first.image);
        let second = t
            .push_image(50_000_000, &ImageView::new(&b, w, h, w).unwrap())
            .unwrap();
        let stats = second.image.unwrap().track;
        assert!(stats.tracked >= 100, "{stats:?}");
        let mut matched = 0;
        for f in second.tracks {
            // Features new in this frame have ids the first frame did not give.
            let Some(p) = before.iter().find(|p| p.id == f.id) else {
                continue;
            };
            let (ex, ey) = (f.u_px - p.u_px - dx, f.v_px - p.v_px - dy);
            assert!(
                ex.abs() < 0.1 && ey.abs() < 0.1,
                "feature {} at ({}, {}) moved by ({}, {}), not ({dx}, {dy})",
                f.id,
                p.u_px,
                p.v_px,
                f.u_px - p.u_px,
                f.v_px - p.v_px
            );
            matched += 1;
        }
        assert_eq!(matched, stats.tracked as usize);
        assert_eq!(t.counters().images.images_rejected, 0);
    }

    #[test]
    fn wuxga_capacity_tracks_a_1920x1200_image_across_a_known_shift() {
        big_stack(|| tracks_a_known_shift(1920, 1200, (23.5, -11.25)));
    }

    /// The paper's 1280x1024 camera (taller than [`HdTracking`]'s 720 rows).
    #[test]
    fn wuxga_capacity_tracks_a_1280x1024_image_across_a_known_shift() {
        big_stack(|| tracks_a_known_shift(1280, 1024, (-17.0, 9.5)));
    }

    /// An image whose pyramid does not fit (2048x1536) is refused, and counted.
    #[test]
    fn wuxga_capacity_refuses_a_larger_image() {
        big_stack(|| {
            let mut t: Box<WuxgaTracking> = Box::new(Tracking::empty());
            t.configure(config(2048, 1536), TrackerConfig::default())
                .unwrap();
            let img = std::vec![128u8; 2048 * 1536];
            let view = ImageView::new(&img, 2048, 1536, 2048).unwrap();
            assert_eq!(t.push_image(0, &view).err(), Some(Error::CapacityExceeded));
            assert_eq!(t.counters().images.images_rejected, 1);
        });
    }
}
