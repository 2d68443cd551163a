//! The estimator as an [`Odometry`]: the outputs it hands back ([`crate::odometry`]) are written
//! into buffers it owns ([`OutputBuffers`]) and lent until its next call.
//!
//! - At a camera frame: the INS prediction of the window's landmarks at the frame's time
//!   ([`Estimator::predict_features`], made before the frame is queued).
//! - At a keyframe: the window's keyframe states and its landmarks placed in the world by the
//!   depth a prediction uses (see [`super::predict`]), beside the report and the step's LiDAR
//!   events.
//!
//! These buffers are a report of the state, never read back by the estimator.

use super::predict::predictor;
use super::{Estimator, FeaturePrediction, Status};
use crate::camera::FeatureObs;
use crate::estimator::EstimatorConfig;
use crate::frontend::image::ImageView;
use crate::inertial::{ImuSample, InsUpdate, NavState};
use crate::lidar::LidarPoint;
use crate::odometry::{
    FrameOutput, KeyframeOutput, KeyframeState, LandmarkPoint, Odometry, OdometryCounters, Output,
};
use crate::Error;
use heapless::Vec as HVec;

/// What the estimator lends with its outputs (see the module docs).
#[derive(Clone)]
pub(super) struct OutputBuffers<const N: usize, const L: usize> {
    predictions: [FeaturePrediction; L],
    n_predictions: usize,
    window: HVec<KeyframeState, N>,
    landmarks: HVec<LandmarkPoint, L>,
}

impl<const N: usize, const L: usize> OutputBuffers<N, L> {
    /// Empty (all zero bits, as [`Estimator::empty`] requires).
    pub(super) const fn new() -> Self {
        OutputBuffers {
            predictions: [FeaturePrediction::EMPTY; L],
            n_predictions: 0,
            window: HVec::new(),
            landmarks: HVec::new(),
        }
    }

    /// Empties every buffer.
    pub(super) fn clear(&mut self) {
        self.n_predictions = 0;
        self.window.clear();
        self.landmarks.clear();
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
        const TC: usize,
    > Estimator<N, L, D, P, GW, GH, Q, TC>
{
    /// The current INS state (the IMU-rate state after the last processed sample), once
    /// initialized; `None` while it is withheld after a long IMU gap
    /// ([`ImuOutput::nav_withheld`]).
    pub fn nav_state(&self) -> Option<NavState> {
        if self.withheld.is_some() {
            return None;
        }
        self.ins.as_ref().map(|i| NavState {
            t_ns: self.clock_map.outside(i.state().t_ns),
            ..*i.state()
        })
    }

    /// The covariance of [`Self::nav_state`]'s error state, with
    /// [`EstimatorConfig::covariance`] (`None`: off, or unknown until the first solve after a
    /// start or a reset; see [`crate::inertial::InsCovariance`]).
    pub fn nav_covariance(&self) -> Option<&crate::inertial::InsCovariance> {
        self.ins.as_ref().and_then(|i| i.covariance())
    }

    /// Predicts the window's landmarks at camera time `t_cam_ns` into the estimator's own buffer
    /// ([`Self::predict_features`]; empty when it cannot predict) and lends them.
    pub fn predictions_at(&mut self, t_cam_ns: i64) -> &[FeaturePrediction] {
        let t_cam_ns = self.clock_map.inside(t_cam_ns);
        let n = if self.status == Status::Running {
            predictor!(self)
                .predict(t_cam_ns, &mut self.out.predictions)
                .unwrap_or(0)
        } else {
            0
        };
        self.out.n_predictions = n;
        self.out.predictions.get(..n).unwrap_or(&[])
    }

    /// The predictions of the last [`Self::predictions_at`].
    pub(crate) fn last_predictions(&self) -> &[FeaturePrediction] {
        self.out
            .predictions
            .get(..self.out.n_predictions)
            .unwrap_or(&[])
    }

    /// Fills the keyframe buffers from the window after a keyframe step.
    fn record_keyframe_outputs(&mut self) {
        self.out.window.clear();
        for k in 0..self.window.len() {
            if let Some(kf) = self.window.get(k) {
                let m = &self.clock_map;
                let _ = self.out.window.push(KeyframeState {
                    t_cam_ns: m.outside(kf.t_cam_ns),
                    state: NavState {
                        t_ns: m.outside(kf.state.t_ns),
                        ..kf.state
                    },
                    td_s: kf.td_s,
                });
            }
        }
        self.out.landmarks.clear();
        let p = predictor!(self);
        let cams = p.window_cameras();
        for lm in self.lms.landmarks() {
            if let Some((p_w, lidar)) = p.landmark_w(lm, &cams) {
                let _ = self.out.landmarks.push(LandmarkPoint {
                    id: lm.id,
                    p_w,
                    lidar,
                });
            }
        }
    }

    /// [`Odometry::update`] of the estimator.
    pub(crate) fn update_output(&mut self) -> Result<Option<Output<'_>>, Error> {
        let Some(o) = self.update()? else {
            return Ok(None);
        };
        let keyframe = match o.keyframe {
            Some(report) => {
                self.record_keyframe_outputs();
                Some(KeyframeOutput {
                    report,
                    lidar_events: &self.events,
                    window: &self.out.window,
                    landmarks: &self.out.landmarks,
                })
            }
            None => None,
        };
        Ok(Some(Output {
            nav: o.nav,
            nav_covariance: self.nav_covariance(),
            ins: o.ins,
            keyframe,
            gap_bridged_s: o.gap_bridged_s,
            clock_jump_s: o.clock_jump_s,
            nav_withheld: o.nav_withheld,
        }))
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
        const TC: usize,
    > Odometry for Estimator<N, L, D, P, GW, GH, Q, TC>
{
    fn config(&self) -> &EstimatorConfig {
        &self.cfg
    }

    fn status(&self) -> Status {
        self.status
    }

    fn initialize(&mut self, state: NavState) -> Result<(), Error> {
        Estimator::initialize(self, state)
    }

    fn fast_path_seed(&self) -> Option<InsUpdate> {
        Estimator::fast_path_seed(self)
    }

    fn push_imu(&mut self, s: &ImuSample) -> Result<(), Error> {
        Estimator::push_imu(self, s)
    }

    fn end_input(&mut self) {
        Estimator::end_input(self);
    }

    fn push_frame<'a>(
        &'a mut self,
        t_cam_ns: i64,
        obs: &'a [FeatureObs],
    ) -> Result<FrameOutput<'a>, Error> {
        self.predictions_at(t_cam_ns);
        Estimator::push_frame(self, t_cam_ns, obs)?;
        Ok(FrameOutput {
            t_cam_ns,
            predictions: self.last_predictions(),
            tracks: obs,
            track_ages: &[],
            image: None,
            frame_error: None,
        })
    }

    fn push_image(&mut self, _t_cam_ns: i64, _image: &ImageView) -> Result<FrameOutput<'_>, Error> {
        Err(Error::InvalidConfig)
    }

    fn push_lidar(&mut self, points: &[LidarPoint]) -> Result<(), Error> {
        Estimator::push_lidar(self, points)
    }

    fn update(&mut self) -> Result<Option<Output<'_>>, Error> {
        self.update_output()
    }

    fn counters(&self) -> OdometryCounters {
        OdometryCounters {
            estimator: Estimator::counters(self),
            images: Default::default(),
        }
    }
}
