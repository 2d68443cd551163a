//! In-motion initialization: gravity direction and velocity from the camera frames and IMU
//! samples seen while waiting, for a start that gives no rest period.
//!
//! Frames: the initializer keeps up to `K` "init frames" (at least `min_spacing_s` apart, spanning
//! at most `max_span_s`), each with its tracks' unit bearings in the camera (`u_c`, sorted by track
//! id, at most `F`), and the IMU samples since the oldest (at most `M`). Everything is expressed
//! in the oldest init frame's body frame `b0` at its time `t = 0`.
//!
//! Model (pose-only, linear, [`solve`]): the IMU integrated from `b0` (gyro bias `bg`, the
//! accelerometer bias taken as 0: over 1-2 s it cannot be told from a tilt of the gravity) gives
//! each frame's `R_i = R_b0bi`, `Dp_i`, `Dv_i`; with the unknowns `x = (v0, g)` (the velocity and
//! the gravity vector in `b0`) the body position is `p_i = v0 t_i + g t_i^2 / 2 + Dp_i` and the
//! camera centre `c_i = p_i + R_i p_bc`, and the bearing of track `j` is `m_ij = R_i R_bc u_ij`.
//! For a track seen in at least 3 frames with its first view `l` and the view `r` of largest
//! parallax `|m_l x m_r|`, the depth in `l` is linear in the centres,
//! `d_l = ((m_r x m_l) x m_r)^T (c_r - c_l) / |m_r x m_l|^2`, and every other view gives
//! `[m_i]x ((c_l - c_i) + m_l d_l) = 0`, linear in `x`. The normal equations (whitened by the
//! bearing noise times the distance, Huber-reweighted) give `x`; then `g` is refined on the
//! sphere `|g| = gravity` (two tangent unknowns, as VINS-Mono's `RefineGravity`).
//!
//! A degenerate start is refused with its [`Refusal`] and tried again at the next init frame
//! (at most one solve per init frame): too few tracks, too little rotation-compensated
//! parallax (pure rotation, rest), an ill-conditioned solution (constant velocity: the scale of
//! `v0` needs an acceleration), a gravity norm far from the configured one, or large residuals.

mod solve;
#[cfg(test)]
mod tests;

use super::imu::ImuSample;
use super::state::NavState;
use crate::camera::CameraExtrinsic;
use crate::math::{exp_so3, quat_exp, Mat3, Vec3};
use heapless::{Deque, Vec as HVec};

pub use solve::Solution;

/// Thresholds of the in-motion initializer.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct MotionInitConfig {
    /// Smallest time between two init frames, s.
    pub min_spacing_s: f64,
    /// Largest time between the oldest and the newest init frame, s.
    pub max_span_s: f64,
    /// Init frames needed before a solve is tried.
    pub min_frames: u32,
    /// Tracks seen in at least 3 init frames with a rotation-compensated parallax of at least
    /// `min_parallax_rad` needed for a solve.
    pub min_tracks: u32,
    /// Smallest parallax `|m_l x m_r|` of a track that enters the solve, rad.
    pub min_parallax_rad: f64,
    /// Standard deviation of a bearing, rad (pixel noise over the focal length).
    pub sigma_rad: f64,
    /// Smallest RMS spread of the init intervals' mean specific force in `b0`, m/s^2 (below:
    /// refused as ill-conditioned; an unchanging acceleration is a tilt of the gravity).
    pub min_accel_excitation_mps2: f64,
    /// Largest posterior standard deviation of the velocity (each axis), m/s.
    pub max_velocity_std_mps: f64,
    /// Largest posterior standard deviation of the velocity along itself, relative to the
    /// speed (the scale).
    pub max_velocity_rel_std: f64,
    /// Largest posterior standard deviation of the gravity direction, rad.
    pub max_gravity_std_rad: f64,
    /// Largest relative difference of the unconstrained gravity norm to the configured one.
    /// A start that mistakes a steady acceleration for gravity (a car in a steady turn: the
    /// solutions `(lambda v0, g + (1 - lambda) a)` fit the images alike) tilts and lengthens
    /// gravity: 2.8% on the simulated vehicle's turn, 16.6 m/s and 2.3 m/s^2 sideways, which
    /// started at 0.7 m/s with 10% here. Correct starts are off by about the accelerometer
    /// bias along gravity (taken as 0 here): seeds whose bias is 1% of g or more wait seconds
    /// for a solve within 1%, and 2% starts the vehicle wrong on 6 of 10 seeds (BENCHMARKS.md,
    /// "In-motion starts over 10 seeds").
    pub max_gravity_norm_error: f64,
    /// Largest RMS of the whitened residuals of the inliers, in sigmas.
    pub max_residual_sigmas: f64,
    /// Smallest share of inlier views (whitened residual within 3 sigmas).
    pub min_inlier_ratio: f64,
}

impl MotionInitConfig {
    /// Defaults for a 30 Hz camera and a consumer MEMS IMU.
    pub const DEFAULT: MotionInitConfig = MotionInitConfig {
        min_spacing_s: 0.1,
        max_span_s: 2.0,
        min_frames: 6,
        min_tracks: 20,
        min_parallax_rad: 0.02,
        sigma_rad: 0.004,
        // Measured on the simulator (0.15 s intervals, 1.35 s): the vehicle's first seconds
        // 0.022-0.037, calm flights 0.043-0.14, hand-held 1.3.
        min_accel_excitation_mps2: 0.03,
        max_velocity_std_mps: 0.1,
        max_velocity_rel_std: 0.05,
        max_gravity_std_rad: 0.03,
        max_gravity_norm_error: 0.01,
        // The unestimated gyro bias bends the bearings over the span: on the simulator's
        // EuRoC-like IMU about half the views are within 3 sigmas.
        max_residual_sigmas: 2.5,
        min_inlier_ratio: 0.3,
    };

    /// Whether every threshold is in its range ([`Self::check_ranges`]).
    pub fn is_valid(&self) -> bool {
        crate::ranges::first_invalid(|r| self.check_ranges(r)).is_none()
    }

    /// The range checks (`[init.motion]`).
    pub fn check_ranges(&self, r: &mut crate::ranges::Ranges<'_>) {
        r.positive("init.motion.min_spacing_s", self.min_spacing_s);
        r.positive("init.motion.max_span_s", self.max_span_s);
        r.check(
            "init.motion.max_span_s",
            self.max_span_s,
            "> init.motion.min_spacing_s",
            self.max_span_s > self.min_spacing_s,
        );
        r.check(
            "init.motion.min_frames",
            self.min_frames as f64,
            ">= 3",
            self.min_frames >= 3,
        );
        r.check(
            "init.motion.min_tracks",
            self.min_tracks as f64,
            ">= 3",
            self.min_tracks >= 3,
        );
        r.non_negative("init.motion.min_parallax_rad", self.min_parallax_rad);
        r.positive("init.motion.sigma_rad", self.sigma_rad);
        let excitation = self.min_accel_excitation_mps2;
        r.non_negative("init.motion.min_accel_excitation_mps2", excitation);
        r.positive(
            "init.motion.max_velocity_std_mps",
            self.max_velocity_std_mps,
        );
        r.positive(
            "init.motion.max_velocity_rel_std",
            self.max_velocity_rel_std,
        );
        r.positive("init.motion.max_gravity_std_rad", self.max_gravity_std_rad);
        r.positive(
            "init.motion.max_gravity_norm_error",
            self.max_gravity_norm_error,
        );
        r.positive("init.motion.max_residual_sigmas", self.max_residual_sigmas);
        let inliers = self.min_inlier_ratio;
        r.within("init.motion.min_inlier_ratio", inliers, 0.0, 1.0, "0..=1");
    }
}

impl Default for MotionInitConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Why a solve refused to start the INS.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Refusal {
    /// Fewer than `min_tracks` tracks seen in at least 3 init frames.
    TooFewTracks,
    /// Fewer than `min_tracks` of them with `min_parallax_rad` (pure rotation, rest).
    LowParallax,
    /// Singular normal equations, or the velocity or the gravity direction too uncertain
    /// (constant velocity, too little motion).
    IllConditioned,
    /// The unconstrained gravity norm is far from the configured one.
    GravityNorm,
    /// Residuals too large, or too few inliers.
    Residual,
    /// Non-finite numbers (garbage input).
    NonFinite,
}

/// One init frame: its IMU time and its tracks' unit bearings in the camera, sorted by id.
#[derive(Debug, Clone)]
pub(crate) struct InitFrame<const F: usize> {
    t_ns: i64,
    obs: HVec<(u64, Vec3), F>,
}

impl<const F: usize> InitFrame<F> {
    const fn new() -> Self {
        InitFrame {
            t_ns: 0,
            obs: HVec::new(),
        }
    }
}

/// The IMU integrated from the oldest init frame to one time (in `b0`; see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Pre {
    t_s: f64,
    r: Mat3,
    dp: Vec3,
    dv: Vec3,
}

impl Pre {
    const ZERO: Pre = Pre {
        t_s: 0.0,
        r: Mat3::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        dp: crate::math::VEC3_ZERO,
        dv: crate::math::VEC3_ZERO,
    };
}

/// The in-motion initializer: up to `K` init frames of up to `F` tracks, `M` IMU samples (see
/// the module docs). All storage inline; `const` empty so it can live in a `static`.
#[derive(Debug, Clone)]
pub struct MotionInitializer<const K: usize, const F: usize, const M: usize> {
    cfg: MotionInitConfig,
    /// Ring of init frames: `frames[(head + i) % K]`, `i < len`, oldest first.
    frames: [InitFrame<F>; K],
    head: usize,
    len: usize,
    imu: Deque<ImuSample, M>,
    /// IMU time of the newest init frame already solved (one solve per init frame).
    solved_ns: i64,
    /// The accelerometer bias the solve integrates with (held, not estimated), m/s^2.
    accel_bias: Vec3,
    /// The gyro bias given to the solve is known: held, not refined.
    hold_gyro_bias: bool,
    /// Scratch of the solve (see [`solve`]).
    scratch: solve::Scratch<K, F>,
}

impl<const K: usize, const F: usize, const M: usize> MotionInitializer<K, F, M> {
    /// An empty initializer with `cfg` (not checked: see [`MotionInitConfig::is_valid`]).
    pub const fn new(cfg: MotionInitConfig) -> Self {
        MotionInitializer {
            cfg,
            frames: [const { InitFrame::new() }; K],
            head: 0,
            len: 0,
            imu: Deque::new(),
            solved_ns: 0,
            accel_bias: crate::math::VEC3_ZERO,
            hold_gyro_bias: false,
            scratch: solve::Scratch::new(),
        }
    }

    /// Drops every frame and sample and takes `cfg`.
    pub fn reset(&mut self, cfg: MotionInitConfig) {
        self.cfg = cfg;
        self.head = 0;
        self.len = 0;
        self.imu.clear();
        self.solved_ns = 0;
        self.accel_bias = Vec3::zeros();
        self.hold_gyro_bias = false;
    }

    /// Init frames held.
    pub fn frames(&self) -> usize {
        self.len
    }

    fn frame(&self, i: usize) -> Option<&InitFrame<F>> {
        (i < self.len).then(|| self.frames.get((self.head + i) % K))?
    }

    fn drop_oldest(&mut self) {
        if self.len > 0 {
            self.head = (self.head + 1) % K.max(1);
            self.len -= 1;
        }
    }

    /// Offers a camera frame at IMU time `t_ns` with its tracks `(id, undistorted normalized
    /// x/z, y/z)`. Kept as an init frame when at least `min_spacing_s` after the newest one (the
    /// oldest ones dropped to keep `K` frames within `max_span_s`); non-finite observations
    /// and repeated ids are skipped. Returns whether it was kept.
    pub fn push_frame(&mut self, t_ns: i64, obs: impl Iterator<Item = (u64, [f64; 2])>) -> bool {
        if K == 0 {
            return false;
        }
        let spacing_ns = (self.cfg.min_spacing_s * 1e9) as i64;
        if let Some(last) = self.len.checked_sub(1).and_then(|i| self.frame(i)) {
            if t_ns < last.t_ns.saturating_add(spacing_ns) {
                return false;
            }
        }
        let span_ns = (self.cfg.max_span_s * 1e9) as i64;
        while self
            .frame(0)
            .is_some_and(|f| t_ns.saturating_sub(f.t_ns) > span_ns)
            || self.len == K
        {
            self.drop_oldest();
        }
        let slot = (self.head + self.len) % K;
        let Some(f) = self.frames.get_mut(slot) else {
            return false;
        };
        f.t_ns = t_ns;
        f.obs.clear();
        for (id, x) in obs {
            let u = Vec3::new(x[0], x[1], 1.0);
            let n = u.norm();
            if !(n.is_finite() && n > 0.0) || f.obs.push((id, u / n)).is_err() {
                continue;
            }
        }
        f.obs.sort_unstable_by_key(|o| o.0);
        // Repeated ids: keep none of them twice (the first after sorting).
        let mut k = 1;
        while k < f.obs.len() {
            if f.obs.get(k).map(|o| o.0) == f.obs.get(k - 1).map(|o| o.0) {
                f.obs.remove(k);
            } else {
                k += 1;
            }
        }
        self.len += 1;
        true
    }

    /// Takes one IMU sample (non-finite or non-increasing samples are ignored). Samples older
    /// than needed are dropped; when the buffer is full, the oldest sample goes and with it the
    /// init frames it no longer covers.
    pub fn push_imu(&mut self, s: &ImuSample) {
        if !s.is_finite() || self.imu.back().is_some_and(|b| s.t_ns <= b.t_ns) {
            return;
        }
        // Keep one sample at or before the oldest frame (the integration starts there).
        let t0 = self.frame(0).map_or(s.t_ns, |f| f.t_ns);
        while self
            .imu
            .iter()
            .nth(1)
            .is_some_and(|second| second.t_ns <= t0)
        {
            let _ = self.imu.pop_front();
        }
        if self.imu.is_full() {
            let _ = self.imu.pop_front();
            let first = self.imu.front().map_or(i64::MAX, |f| f.t_ns);
            while self.frame(0).is_some_and(|f| f.t_ns < first) {
                self.drop_oldest();
            }
        }
        let _ = self.imu.push_back(*s);
    }

    /// Solves when a new init frame is covered by the IMU (at most once per init frame) and
    /// `min_frames` are held: `Ok(Some)` the state at the newest IMU sample (leveled, yaw 0,
    /// position 0), `Ok(None)` nothing to try, `Err` the refusal.
    ///
    /// Biases: without `known_ba` the gyro bias is refined from `bg` with the solve and the
    /// accelerometer bias taken as 0 (the state's are those); with it both are known and held
    /// (the frames integrated with `bg` and `known_ba`, the state's biases those).
    pub fn try_solve(
        &mut self,
        ext: &CameraExtrinsic,
        gravity_mps2: f64,
        bg: &Vec3,
        known_ba: Option<&Vec3>,
    ) -> Result<Option<(NavState, Solution)>, Refusal> {
        let Some(newest) = self.len.checked_sub(1).and_then(|i| self.frame(i)) else {
            return Ok(None);
        };
        let t_new = newest.t_ns;
        let Some(last) = self.imu.back().copied() else {
            return Ok(None);
        };
        if (self.len as u32) < self.cfg.min_frames || t_new > last.t_ns || t_new == self.solved_ns {
            return Ok(None);
        }
        self.solved_ns = t_new;
        self.accel_bias = known_ba.copied().unwrap_or_else(Vec3::zeros);
        self.hold_gyro_bias = known_ba.is_some();
        let sol = self.solve(ext, gravity_mps2, bg)?;
        let end = sol.end;
        // The world frame: gravity along -z, yaw 0 (as the static initializer's leveling).
        let f = -sol.g_b0;
        let roll = libm::atan2(f.y, f.z);
        let pitch = libm::atan2(-f.x, libm::sqrt(f.y * f.y + f.z * f.z));
        let q_wb0 = quat_exp(&Vec3::new(0.0, pitch, 0.0)) * quat_exp(&Vec3::new(roll, 0.0, 0.0));
        let r_wb0 = q_wb0.to_rotation_matrix().into_inner();
        let r_wb = r_wb0 * end.r;
        let q_wb = crate::math::Quat::from_matrix(&r_wb);
        let v_b0 = sol.v0_b0 + sol.g_b0 * end.t_s + end.dv;
        let state = NavState {
            t_ns: last.t_ns,
            p_wb: Vec3::zeros(),
            q_wb,
            v_wb: r_wb0 * v_b0,
            bg: sol.bg,
            ba: self.accel_bias,
        };
        let finite = state
            .v_wb
            .iter()
            .chain(q_wb.coords.iter())
            .all(|x| x.is_finite());
        if !finite {
            return Err(Refusal::NonFinite);
        }
        Ok(Some((state, sol)))
    }

    /// The IMU integrated (gyro bias `bg`) from the oldest init frame to each init frame and to
    /// the newest sample, into `out[..len + 1]`; `None` when the samples do not cover them.
    fn integrate(&self, bg: &Vec3, out: &mut [Pre; K]) -> Option<Pre> {
        let t0 = self.frame(0)?.t_ns;
        let t_end = self.imu.back()?.t_ns;
        if self.imu.front()?.t_ns > t0 {
            return None;
        }
        let mut st = Pre {
            t_s: 0.0,
            r: Mat3::identity(),
            dp: Vec3::zeros(),
            dv: Vec3::zeros(),
        };
        *out.get_mut(0)? = st;
        let mut ev = 1; // the next event: init frame `ev`, or the end once `ev == len`
        let event = |ev: usize| -> i64 {
            if ev < self.len {
                self.frame(ev).map_or(i64::MAX, |f| f.t_ns)
            } else {
                t_end
            }
        };
        let mut prev: Option<&ImuSample> = None;
        for b in self.imu.iter() {
            let Some(a) = prev.replace(b) else {
                continue;
            };
            if b.t_ns <= t0 {
                continue;
            }
            let mut tc = a.t_ns.max(t0);
            loop {
                let target = event(ev);
                let te = target.min(b.t_ns);
                if te > tc {
                    step(a, b, tc, te, t0, (bg, &self.accel_bias), &mut st);
                }
                tc = te;
                if target > b.t_ns {
                    break;
                }
                if ev >= self.len {
                    return Some(st);
                }
                *out.get_mut(ev)? = st;
                ev += 1;
            }
        }
        None
    }
}

/// One integration step of the linearly interpolated sample pair `(a, b)` over `[tc, te]`
/// (midpoint rule), times from `t0`.
fn step(
    a: &ImuSample,
    b: &ImuSample,
    tc: i64,
    te: i64,
    t0: i64,
    bias: (&Vec3, &Vec3),
    st: &mut Pre,
) {
    let (bg, ba) = bias;
    let dt = (te - tc) as f64 * 1e-9;
    let span = (b.t_ns - a.t_ns) as f64;
    let tm = 0.5 * ((tc - a.t_ns) as f64 + (te - a.t_ns) as f64);
    let w = if span > 0.0 { tm / span } else { 1.0 };
    let gyro = a.gyro_rps + (b.gyro_rps - a.gyro_rps) * w - bg;
    let acc = a.accel_mps2 + (b.accel_mps2 - a.accel_mps2) * w - ba;
    let r_half = st.r * exp_so3(&(gyro * (0.5 * dt)));
    let a_b0 = r_half * acc;
    st.dp += st.dv * dt + a_b0 * (0.5 * dt * dt);
    st.dv += a_b0 * dt;
    st.r *= exp_so3(&(gyro * dt));
    st.t_s = (te - t0) as f64 * 1e-9;
}
