//! The heading and the path carried across an IMU outage by the images. An IMU gap too long to bridge resets
//! the estimator; the next start continues from the last published position and yaw
//! ([`Estimator::continued`](super::Estimator)), so whatever the platform turned while the IMU
//! was silent, and until the new start, was lost: a hand-held camera turning 90 degrees in a 2 s
//! gap left the rest of the run rotated by 90 degrees (BENCHMARKS.md, "The heading across an IMU
//! outage"). The camera frames keep coming through such an outage; this chain of rotations
//! between them carries the heading instead.
//!
//! - Every frame pushed is kept (its raw observations, a copy) as the possible reference.
//! - The chain starts at the first frame pushed while the IMU is silent (its time more than
//!   `max_imu_dt_s` past the newest IMU sample pushed): the frame before it is the reference
//!   `c_ref`, with the newest IMU sample's time and rate (less the INS's gyro bias).
//! - Each later frame `F` is fitted to the chain keyframe `K` (first the reference) from their
//!   common tracks alone ([`crate::landmarks::relative_rotation`]), giving `R_{c_ref c_F} =
//!   R_{c_ref c_K} R_{c_K c_F}`; `F` becomes the keyframe once they share few tracks
//!   ([`KEY_MIN_COMMON`]; a longer baseline than frame to frame: fewer fits to accumulate).
//! - It goes on while the IMU is silent, while a reset waits for its new start, and for
//!   [`GRACE_NS`] after the IMU is back (a reset may be processed later than the frames are
//!   pushed), then it is dropped. A failed fit ends it for that outage.
//! - At the new start after a reset ([`OutageHeading::heading_change`]), the body's rotation
//!   from the resume state's time to the start's time is the reference's rate over the few ms
//!   to the reference frame, then `R_bc R_{c_ref c}(t) R_bc^T` (the chain interpolated at the
//!   start's time, or extrapolated from its last two frames by at most
//!   [`MAX_EXTRAPOLATION_NS`]). The start's yaw is the resume state's attitude turned by that
//!   rotation.
//! - The images give the direction of travel, not its scale: each fit's translation direction
//!   ([`crate::landmarks::relative_rotation::RotationFit::t_ab`], zero where the tracks show
//!   none) is the chord from the chain keyframe to the frame; the chords times their durations
//!   are the path at unit speed, which the start scales by the resume state's speed (the
//!   platform is taken to keep its speed, as a walker or a car does, not its direction).
//!
//! Counted in `counters.outage_motion_from_images`. Costs one relative-rotation fit per frame, and
//! only while the IMU is out.

use super::MAX_FEATURES;
use crate::camera::{FeatureObs, PinholeCamera};
use crate::landmarks::relative_rotation::{fit_relative_rotation, MIN_PAIRS};
use crate::math::{log_so3, quat_exp, Quat, Vec3};
use heapless::{Deque, Vec as HVec};

/// A chain keyframe is replaced by the newest frame once they share fewer tracks than this.
/// Chosen by measurement (BENCHMARKS.md, "The heading and the path across an IMU outage")
/// against a replacement at a share of the keyframe's tracks (0.3, 0.5, 0.7), at most 0.25 s
/// apart, or both rules: the lowest ATE on most of the 14 outages. A sparse front end (EuRoC's
/// 25 tracks) chains frame to frame.
const KEY_MIN_COMMON: usize = 40;
/// The chain's newest rotations kept (for the start's time): 2 s of frames at 30 Hz, more than
/// frames may lead the IMU (`max_frame_lead_s`, 1 s by default).
const RECENT: usize = 64;
/// The chain is dropped this long after the IMU came back without a reset, ns.
const GRACE_NS: i64 = 1_000_000_000;
/// The start may lie this far past the chain's newest frame (extrapolated), ns.
pub(super) const MAX_EXTRAPOLATION_NS: i64 = 150_000_000;
/// The resume state's time and the chain reference's IMU sample may differ by this much, ns.
const MAX_REF_OFFSET_NS: i64 = 100_000_000;
/// The frame kept as the reference may precede the first silent frame by this much, ns.
const MAX_REF_AGE_NS: i64 = 250_000_000;

/// Storage for a rotation not yet set (all bits zero; never used as a rotation).
const QUAT_ZERO: Quat = Quat::new_unchecked(nalgebra::Quaternion::new(0.0, 0.0, 0.0, 0.0));

/// The chain (module docs). All bits zero when empty, as [`super::Estimator::empty`] needs.
#[derive(Debug, Clone)]
pub(super) struct OutageHeading {
    /// The newest frame pushed: its IMU time and raw observations.
    last_t_ns: i64,
    last: HVec<FeatureObs, MAX_FEATURES>,
    /// A chain runs (`active`) and every fit so far succeeded (`valid`).
    active: bool,
    valid: bool,
    /// IMU time of the reference frame; time and body rate (bias removed) of the newest IMU
    /// sample when the chain started.
    ref_t_ns: i64,
    ref_imu_t_ns: i64,
    w_ref_b: Vec3,
    /// The chain keyframe: `R_{c_ref c_K}` and its bearings, sorted by track id.
    q_ref_key: Quat,
    key: HVec<(u64, Vec3), MAX_FEATURES>,
    /// `R_{c_K c_F}` of the newest frame (the next fit's start).
    q_key_last: Quat,
    /// IMU time of the chain keyframe; the path the camera took to it from the reference at
    /// unit speed, in `c_ref` (s: times a speed gives metres); the newest frame's direction
    /// from the keyframe (unit in `c_K`, zero where the tracks did not show it).
    key_t_ns: i64,
    path_ref_key_s: Vec3,
    dir_key_last: Vec3,
    /// The newest chain frames: IMU time and `R_{c_ref c_F}`.
    recent: Deque<(i64, Quat), RECENT>,
    /// IMU time of the newest frame pushed while the IMU was silent.
    last_silent_ns: i64,
    /// The fit's scratch: common bearings `(in K, in F)`.
    pairs: HVec<(Vec3, Vec3), MAX_FEATURES>,
}

/// What the images showed across an outage ([`OutageHeading::heading_change`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct OutageMotion {
    /// The body's rotation from the resume state to the start, `R_{b0 b1}`.
    pub q_b0b1: Quat,
    /// The camera's path over the same span at unit speed, in the body frame at the resume
    /// state (chords between the chain keyframes along their directions in the images), s.
    pub path_b0_s: Vec3,
}

/// What the chain needs of the estimator at a frame push.
pub(super) struct FrameContext<'a> {
    /// The frame's IMU time (camera time plus the delay), ns.
    pub t_ns: i64,
    /// The frame's observations (raw pixels).
    pub obs: &'a [FeatureObs],
    /// The newest IMU sample pushed: time, ns, and body rate less the gyro bias, rad/s.
    pub newest_imu: Option<(i64, Vec3)>,
    /// The IMU counts as silent past this long after its newest sample, ns.
    pub max_imu_dt_ns: i64,
    /// A reset waits for its start (the chain must go on).
    pub reset_pending: bool,
    /// The camera (undistortion) and one bearing's standard deviation, rad.
    pub camera: &'a PinholeCamera,
    pub sigma_rad: f64,
}

impl OutageHeading {
    /// Empty (all bits zero).
    pub(super) const fn new() -> Self {
        OutageHeading {
            last_t_ns: 0,
            last: HVec::new(),
            active: false,
            valid: false,
            ref_t_ns: 0,
            ref_imu_t_ns: 0,
            w_ref_b: crate::math::VEC3_ZERO,
            q_ref_key: QUAT_ZERO,
            key: HVec::new(),
            q_key_last: QUAT_ZERO,
            key_t_ns: 0,
            path_ref_key_s: crate::math::VEC3_ZERO,
            dir_key_last: crate::math::VEC3_ZERO,
            recent: Deque::new(),
            last_silent_ns: 0,
            pairs: HVec::new(),
        }
    }

    /// Forgets everything (a new configuration).
    pub(super) fn clear(&mut self) {
        self.last.clear();
        self.last_t_ns = 0;
        self.stop();
    }

    fn stop(&mut self) {
        self.active = false;
        self.valid = false;
        self.key.clear();
        self.recent.clear();
    }

    /// One frame pushed (module docs): starts, extends or ends the chain, then keeps the frame
    /// as the newest. Frames not after the newest one are ignored.
    pub(super) fn push(&mut self, f: &FrameContext<'_>) {
        if !self.last.is_empty() && f.t_ns <= self.last_t_ns {
            return;
        }
        let silent = f
            .newest_imu
            .is_some_and(|(t, _)| f.t_ns.saturating_sub(t) > f.max_imu_dt_ns);
        if silent {
            self.last_silent_ns = f.t_ns;
        }
        if !self.active && silent {
            self.start(f);
        } else if self.active {
            let over = !silent
                && !f.reset_pending
                && f.t_ns.saturating_sub(self.last_silent_ns) > GRACE_NS;
            if over {
                self.stop();
            } else if self.valid {
                self.valid = self.extend(f).is_some();
            }
        }
        self.last.clear();
        for o in f.obs.iter().take(MAX_FEATURES) {
            // At most MAX_FEATURES: cannot fail.
            let _ = self.last.push(*o);
        }
        self.last_t_ns = f.t_ns;
    }

    /// Starts a chain at the first silent frame `f`, the newest frame kept being the reference.
    fn start(&mut self, f: &FrameContext<'_>) {
        self.stop();
        let Some((imu_t, w_b)) = f.newest_imu else {
            return;
        };
        self.active = true;
        let fresh = !self.last.is_empty()
            && f.t_ns.saturating_sub(self.last_t_ns) <= MAX_REF_AGE_NS
            && w_b.iter().all(|x| x.is_finite());
        if !fresh {
            return;
        }
        self.ref_t_ns = self.last_t_ns;
        self.ref_imu_t_ns = imu_t;
        self.w_ref_b = w_b;
        self.q_ref_key = Quat::identity();
        self.q_key_last = Quat::identity();
        self.key_t_ns = self.ref_t_ns;
        self.path_ref_key_s = Vec3::zeros();
        self.dir_key_last = Vec3::zeros();
        let _ = self.recent.push_back((self.ref_t_ns, Quat::identity()));
        let last = core::mem::take(&mut self.last);
        self.valid = set_key(&mut self.key, &last, f.camera);
        self.last = last;
        if self.valid {
            self.valid = self.extend(f).is_some();
        }
    }

    /// Fits frame `f` to the chain keyframe; `None` when the fit fails.
    fn extend(&mut self, f: &FrameContext<'_>) -> Option<()> {
        self.pairs.clear();
        for o in f.obs {
            let Ok(k) = self.key.binary_search_by_key(&o.id, |(id, _)| *id) else {
                continue;
            };
            let (Some((_, a)), Ok(b)) = (self.key.get(k), f.camera.undistort(o.u_px, o.v_px))
            else {
                continue;
            };
            let _ = self.pairs.push((*a, b.normalize()));
        }
        if self.pairs.len() < MIN_PAIRS {
            return None;
        }
        let fit = fit_relative_rotation(&self.pairs, &self.q_key_last, f.sigma_rad)?;
        let q_ref_f = self.q_ref_key * fit.q_ab;
        if self.recent.is_full() {
            let _ = self.recent.pop_front();
        }
        // Not full (made room above): cannot fail.
        let _ = self.recent.push_back((f.t_ns, q_ref_f));
        self.q_key_last = fit.q_ab;
        self.dir_key_last = fit.t_ab;
        if self.pairs.len() < KEY_MIN_COMMON {
            // The frame becomes the keyframe: its own bearings; the segment's chord joins the
            // path.
            self.path_ref_key_s += self.segment_s(f.t_ns);
            self.key_t_ns = f.t_ns;
            self.dir_key_last = Vec3::zeros();
            self.q_ref_key = q_ref_f;
            self.q_key_last = Quat::identity();
            if !set_key(&mut self.key, f.obs, f.camera) {
                return None;
            }
        }
        Some(())
    }

    /// The chord from the chain keyframe to the newest frame at unit speed, in `c_ref`, up to
    /// IMU time `t_ns`, s.
    fn segment_s(&self, t_ns: i64) -> Vec3 {
        let dt_s = t_ns.saturating_sub(self.key_t_ns).max(0) as f64 * 1e-9;
        self.q_ref_key * self.dir_key_last * dt_s
    }

    /// At a start after a reset: what the images show from the resume state's time `t0_ns` to
    /// the start's time `t1_ns` (module docs), with the camera-to-body rotation `q_bc`; `None`
    /// when no valid chain spans them. Ends the chain either way.
    pub(super) fn heading_change(
        &mut self,
        t0_ns: i64,
        t1_ns: i64,
        q_bc: &Quat,
    ) -> Option<OutageMotion> {
        let usable = self.active
            && self.valid
            && (t0_ns.saturating_sub(self.ref_imu_t_ns)).abs() <= MAX_REF_OFFSET_NS;
        let q_c = usable.then(|| self.chain_at(t1_ns)).flatten();
        let path_c_s = self.path_ref_key_s + self.segment_s(t1_ns);
        self.stop();
        let q_c = q_c?;
        // The few ms from the resume state to the reference frame, at the reference's rate.
        let lead_s = self.ref_t_ns.saturating_sub(t0_ns) as f64 * 1e-9;
        let q_lead = quat_exp(&(self.w_ref_b * lead_s));
        Some(OutageMotion {
            q_b0b1: q_lead * *q_bc * q_c * q_bc.inverse(),
            path_b0_s: q_lead * *q_bc * path_c_s,
        })
    }

    /// `R_{c_ref c}` at IMU time `t_ns`: interpolated between the chain's frames around it, or
    /// extrapolated from the newest two by at most [`MAX_EXTRAPOLATION_NS`]; `None` before the
    /// oldest frame kept.
    fn chain_at(&self, t_ns: i64) -> Option<Quat> {
        let mut prev: Option<(i64, Quat)> = None;
        for &(t, q) in self.recent.iter() {
            if t >= t_ns {
                let (t0, q0) = match prev {
                    Some(p) => p,
                    None if t == t_ns => (t, q),
                    None => return None,
                };
                return Some(slerp_at(t0, &q0, t, &q, t_ns));
            }
            prev = Some((t, q));
        }
        let (t1, q1) = prev?;
        if t_ns.saturating_sub(t1) > MAX_EXTRAPOLATION_NS {
            return None;
        }
        let n = self.recent.len();
        let (t0, q0) = if n >= 2 {
            self.recent.iter().nth(n - 2).copied()?
        } else {
            (t1, q1)
        };
        Some(slerp_at(t0, &q0, t1, &q1, t_ns))
    }
}

/// The rotation at `t` on the geodesic through `(t0, q0)` and `(t1, q1)` (`q0` when they
/// coincide in time); extrapolates past `t1`.
fn slerp_at(t0: i64, q0: &Quat, t1: i64, q1: &Quat, t: i64) -> Quat {
    let span = t1.saturating_sub(t0);
    if span <= 0 {
        return *q1;
    }
    let s = t.saturating_sub(t0) as f64 / span as f64;
    q0 * quat_exp(&(log_so3(&(q0.inverse() * q1)) * s))
}

/// The keyframe's bearings from its raw observations, sorted by track id (duplicates dropped);
/// false with fewer than [`MIN_PAIRS`].
fn set_key(
    key: &mut HVec<(u64, Vec3), MAX_FEATURES>,
    obs: &[FeatureObs],
    camera: &PinholeCamera,
) -> bool {
    key.clear();
    for o in obs {
        if let Ok(x) = camera.undistort(o.u_px, o.v_px) {
            let _ = key.push((o.id, x.normalize()));
        }
    }
    key.sort_unstable_by_key(|(id, _)| *id);
    let mut kept = 0;
    for i in 0..key.len() {
        let id = key.get(i).map(|k| k.0);
        let dup = kept > 0 && id == key.get(kept - 1).map(|k| k.0);
        if !dup {
            key.swap(kept, i);
            kept += 1;
        }
    }
    key.truncate(kept);
    key.len() >= MIN_PAIRS
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
    > super::Estimator<N, L, D, P, GW, GH, Q, TC>
{
    /// A frame pushed at camera time `t_cam_ns` (on the estimator's clock) with `obs`: the
    /// outage chain's step (module docs).
    pub(super) fn outage_frame(&mut self, t_cam_ns: i64, obs: &[FeatureObs]) {
        let td_ns = (self.current_td() * 1e9) as i64;
        let bg = self.ins.as_ref().map_or(Vec3::zeros(), |i| i.state().bg);
        let newest_imu = self
            .imu_in
            .back()
            .or(self.last_imu.as_ref())
            .map(|s| (s.t_ns, s.gyro_rps - bg));
        let ctx = FrameContext {
            t_ns: t_cam_ns.saturating_add(td_ns),
            obs,
            newest_imu,
            max_imu_dt_ns: (self.cfg.max_imu_dt_s * 1e9) as i64,
            reset_pending: self.resume.is_some() && self.status == super::Status::WaitingForInit,
            camera: &self.cfg.camera,
            sigma_rad: self.cfg.sigma_px / self.focal_px(),
        };
        self.outage.push(&ctx);
    }
}
