//! Per-frame track processing: validation, undistortion and feature velocities.
//!
//! The time-delay correction `x' = x - (td - td0) v` needs each observation's velocity `v` on the
//! normalized plane (1/s). It is the regressor of the delay in the least-squares problem, so two
//! properties matter:
//!
//! - **It must not contain the observation's own noise.** A velocity `(x_k - x_{k-1}) / dt`
//!   carries the current observation's noise, so the gradient of the reprojection error with
//!   respect to the delay, `-v . r`, has the nonzero mean `2 sigma^2 / dt` per observation and
//!   biases the delay towards the future (by `2 sigma^2 / (dt |v|^2 + 4 sigma^2 / dt)`: about 20
//!   ms for a slowly moving camera at 20 Hz with 1 px noise, measured).
//! - **It must not be noisy at all.** A regressor with noise of its own (errors in variables)
//!   shrinks the estimate towards zero by `|v|^2 / (|v|^2 + var(noise))`. A finite difference of
//!   two earlier frames has the variance `2 sigma^2 / dt^2` (1 px at 20 Hz and f = 460 px: 0.06
//!   /s, as fast as a slowly moving camera's features), so a calm flight's delay estimate stalled
//!   at 50-60% of the true delay (-20 -> -10 ms, +30 -> +18 ms after 60 s), while a hand-held
//!   rig's fast rotations hid it.
//!
//! So the velocity is split, and each part comes from the motion of the camera, which the INS
//! knows without pixel noise:
//!
//! - the **rotational flow** of a camera turning at `w` (camera frame),
//!   `dx/dt = x y w_x - (1 + x^2) w_y + y w_z`, `dy/dt = (1 + y^2) w_x - x y w_y - x w_z`;
//! - the **translational flow** of a camera moving at `v` (camera frame) past a point at inverse
//!   depth `rho`: `rho g` with `g = (x v_z - v_x, y v_z - v_y)`. Each track keeps an estimate of
//!   its `rho`: a weighted least-squares fit of `rho g` to the finite differences of its earlier
//!   frames minus their rotational flow, with a forgetting time of [`INVERSE_DEPTH_TAU_S`], and
//!   propagated between frames by its dynamics `d rho / dt = rho (w_x y - w_y x) + rho^2 v_z`. It
//!   starts at 0 (far away: no translational flow) with the weight [`INVERSE_DEPTH_PRIOR_WEIGHT`],
//!   so a track seen only while the camera turns in place keeps a rotational flow alone.
//!
//! The current observation never enters its own velocity: the flows are evaluated where the
//! previous frame's position and velocity put the point (only a new track, without a previous
//! frame, uses its own observation). Even the flows' coefficients matter: a slowly moving camera's
//! features move so little that their dependence on `x` biased a robot's delay by +5 ms. A track
//! after a time jump starts again.
//!
//! **Rolling shutter** ([`PinholeCamera::readout_s`]): a row is read out
//! [`PinholeCamera::row_time_s`] after the frame's stamp. Each observation is moved at ingestion
//! to where the camera at the stamp sees it ([`super::rolling_shutter`]), with the track's
//! inverse depth (a new track: the mean of the fitted ones), so everything downstream
//! (velocities, the delay's correction, the factors) sees a global-shutter frame.

use super::rolling_shutter::transfer_to_stamp;
use crate::camera::{FeatureObs, PinholeCamera};
use crate::Error;
use heapless::Vec;

/// Forgetting time of a track's inverse-depth fit, s: its dynamics are propagated, so this only
/// has to absorb the model's errors (a camera velocity that is not exact, a moving point).
pub const INVERSE_DEPTH_TAU_S: f64 = 1.0;

/// Weight of the prior `rho = 0` of a new track, in the units of `|g|^2` ((m/s)^2 on the normalized
/// plane): a finite difference taken at 0.1 m/s of translation weighs as much.
pub const INVERSE_DEPTH_PRIOR_WEIGHT: f64 = 0.01;

/// Largest inverse depth a track's fit may reach, 1/m (10 cm).
pub const MAX_INVERSE_DEPTH: f64 = 10.0;

/// The camera's motion at a frame, from the INS (camera frame `c`).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct CameraMotion {
    /// Angular rate of the camera, in `c`, rad/s.
    pub w_c_rps: [f64; 3],
    /// Velocity of the camera's origin relative to the world, in `c`, m/s.
    pub v_c_mps: [f64; 3],
    /// Angular acceleration of the camera, in `c`, rad/s^2 (for a rolling shutter's rows; zero
    /// when unknown).
    pub dw_c_rps2: [f64; 3],
}

impl CameraMotion {
    /// At rest (also the motion assumed before the INS starts).
    pub const ZERO: CameraMotion = CameraMotion {
        w_c_rps: [0.0; 3],
        v_c_mps: [0.0; 3],
        dw_c_rps2: [0.0; 3],
    };
}

/// Translational flow per unit inverse depth, `g = (x v_z - v_x, y v_z - v_y)`, on the normalized
/// plane at `x` for a camera moving at `v_c` (camera frame), m/s.
pub fn translational_flow_per_inverse_depth(x: [f64; 2], v_c: [f64; 3]) -> [f64; 2] {
    [x[0] * v_c[2] - v_c[0], x[1] * v_c[2] - v_c[1]]
}

/// Rotational flow `dx/dt` on the normalized plane at `x` of a camera turning at `w_c` (rad/s, in
/// the camera frame), 1/s.
pub fn rotational_flow(x: [f64; 2], w_c: [f64; 3]) -> [f64; 2] {
    let [x, y] = x;
    let [wx, wy, wz] = w_c;
    [
        x * y * wx - (1.0 + x * x) * wy + y * wz,
        (1.0 + y * y) * wx - x * y * wy - x * wz,
    ]
}

/// A validated observation on the normalized image plane (`z = 1`) of the camera.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct NormalizedObs {
    /// Track id.
    pub id: u64,
    /// Undistorted normalized coordinates `(x/z, y/z)`.
    pub x_n: [f64; 2],
    /// Velocity of `x_n`, 1/s (zero for a new track).
    pub vel: [f64; 2],
    /// Capture time of the observation's image row relative to the frame's stamp, s
    /// ([`PinholeCamera::row_time_s`]: 0 for a global shutter). `x_n` is already moved to the
    /// stamp's time ([`super::rolling_shutter::transfer_to_stamp`]); this says from how far.
    pub row_dt_s: f64,
}

/// What happened to the observations of one frame (rejections are counted, never silent).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FrameStats {
    /// Observations offered.
    pub received: u32,
    /// Observations kept.
    pub accepted: u32,
    /// NaN or infinite pixel coordinates.
    pub rejected_nonfinite: u32,
    /// Outside the image (with a one-pixel margin).
    pub rejected_out_of_image: u32,
    /// Repeated id within the frame (the first occurrence is kept).
    pub rejected_duplicate: u32,
    /// Undistortion failed to converge.
    pub rejected_undistort: u32,
    /// More observations than the frame capacity.
    pub rejected_capacity: u32,
}

/// A track's last observation with its inverse-depth fit.
#[derive(Debug, Clone, Copy, PartialEq)]
struct TrackState {
    obs: NormalizedObs,
    /// Inverse depth of the point at this frame, 1/m.
    rho: f64,
    /// Weight of `rho` (information of the fit), `|g|^2` units.
    w: f64,
}

/// Remembers the two previous frames' observations (and their camera rates) to give velocities to
/// the next one.
#[derive(Clone)]
pub struct TrackTable<const F: usize> {
    prev: Vec<TrackState, F>,
    prev_t_ns: Option<i64>,
    prev_motion: CameraMotion,
    prev2: Vec<NormalizedObs, F>,
    prev2_t_ns: Option<i64>,
    prev2_motion: CameraMotion,
    /// The frame being processed (swapped into `prev`; a member so that no stack copy is needed).
    cur: Vec<TrackState, F>,
    max_gap_ns: i64,
}

impl<const F: usize> TrackTable<F> {
    /// A table that treats frames further apart than `max_gap_s` as a restart of all tracks.
    pub const fn new(max_gap_s: f64) -> Self {
        TrackTable {
            prev: Vec::new(),
            prev_t_ns: None,
            prev_motion: CameraMotion::ZERO,
            prev2: Vec::new(),
            prev2_t_ns: None,
            prev2_motion: CameraMotion::ZERO,
            cur: Vec::new(),
            max_gap_ns: (max_gap_s * 1e9) as i64,
        }
    }

    /// Forgets all tracks (e.g. after a reset of the estimator).
    pub fn clear(&mut self) {
        self.prev.clear();
        self.prev_t_ns = None;
        self.prev2.clear();
        self.prev2_t_ns = None;
    }

    /// Back to the state [`TrackTable::new`] builds with `max_gap_s`, in place.
    pub fn reset_to_new(&mut self, max_gap_s: f64) {
        self.clear();
        self.max_gap_ns = (max_gap_s * 1e9) as i64;
    }

    /// Validates and undistorts a frame into `out` (sorted by id) and gives each observation its
    /// velocity; `motion` is the camera's motion at the frame (from the INS; zero before it
    /// starts). Returns [`Error::TimeNotIncreasing`] (and changes nothing) if the
    /// frame is not newer than the last.
    pub fn process(
        &mut self,
        t_ns: i64,
        obs: &[FeatureObs],
        camera: &PinholeCamera,
        motion: CameraMotion,
        out: &mut Vec<NormalizedObs, F>,
    ) -> Result<FrameStats, Error> {
        if let Some(p) = self.prev_t_ns {
            if t_ns <= p {
                return Err(Error::TimeNotIncreasing);
            }
        }
        out.clear();
        let mut st = FrameStats {
            received: obs.len().min(u32::MAX as usize) as u32,
            ..Default::default()
        };
        let (w, h) = (camera.width as f64, camera.height as f64);
        for o in obs {
            if !(o.u_px.is_finite() && o.v_px.is_finite()) {
                st.rejected_nonfinite += 1;
                continue;
            }
            if o.u_px < -1.0 || o.v_px < -1.0 || o.u_px > w || o.v_px > h {
                st.rejected_out_of_image += 1;
                continue;
            }
            let x = match camera.undistort(o.u_px, o.v_px) {
                Ok(x) => x,
                Err(_) => {
                    st.rejected_undistort += 1;
                    continue;
                }
            };
            let n = NormalizedObs {
                id: o.id,
                x_n: [x.x, x.y],
                vel: [0.0; 2],
                row_dt_s: camera.row_time_s(o.v_px),
            };
            if out.push(n).is_err() {
                st.rejected_capacity += 1;
            }
        }
        // Stable sort keeps the first occurrence of a repeated id first, so dedup is deterministic.
        sort_by_id(out);
        let mut k = 0;
        for i in 0..out.len() {
            if k > 0 && out[k - 1].id == out[i].id {
                st.rejected_duplicate += 1;
                continue;
            }
            out[k] = out[i];
            k += 1;
        }
        out.truncate(k);

        self.set_velocities(t_ns, motion, out);
        st.accepted = out.len() as u32;
        Ok(st)
    }
}

impl<const F: usize> TrackTable<F> {
    /// Gives `out` its velocities (rotational plus translational flow at `motion`, with each
    /// track's inverse-depth fit updated by the finite difference of the two previous frames) and
    /// makes it the previous frame.
    fn set_velocities(&mut self, t_ns: i64, motion: CameraMotion, out: &mut Vec<NormalizedObs, F>) {
        let recent =
            |a: Option<i64>, b: i64| a.is_some_and(|a| b.saturating_sub(a) <= self.max_gap_ns);
        let prev_ok = recent(self.prev_t_ns, t_ns);
        // A new finite difference needs the two previous frames, both recent enough.
        let diff = match (self.prev_t_ns, self.prev2_t_ns) {
            (Some(t1), Some(t2)) if prev_ok && recent(Some(t2), t1) => {
                let dt_s = t1.saturating_sub(t2) as f64 * 1e-9;
                let (m1, m2) = (&self.prev_motion, &self.prev2_motion);
                let mid = CameraMotion {
                    w_c_rps: core::array::from_fn(|i| 0.5 * (m1.w_c_rps[i] + m2.w_c_rps[i])),
                    v_c_mps: core::array::from_fn(|i| 0.5 * (m1.v_c_mps[i] + m2.v_c_mps[i])),
                    dw_c_rps2: [0.0; 3],
                };
                Some((dt_s, mid))
            }
            _ => None,
        };
        let dt_s = self
            .prev_t_ns
            .map_or(0.0, |t1| t_ns.saturating_sub(t1) as f64 * 1e-9);
        let forget = libm::exp(-dt_s / INVERSE_DEPTH_TAU_S);
        // A new track's inverse depth for a rolling shutter's transfer: the mean of the fitted
        // tracks' (its own fit starts at 0, "far", which would leave the translation's shift out).
        let rho_new = if out.iter().any(|o| o.row_dt_s != 0.0) {
            let (mut n, mut sum) = (0.0, 0.0);
            for p in self
                .prev
                .iter()
                .filter(|p| p.w > INVERSE_DEPTH_PRIOR_WEIGHT)
            {
                n += 1.0;
                sum += p.rho;
            }
            if n > 0.0 {
                sum / n
            } else {
                0.0
            }
        } else {
            0.0
        };
        self.cur.clear();
        for o in out.iter_mut() {
            let p1 = if prev_ok {
                self.prev
                    .binary_search_by(|p| p.obs.id.cmp(&o.id))
                    .ok()
                    .and_then(|i| self.prev.get(i))
            } else {
                None
            };
            let p2 = diff.and_then(|_| {
                self.prev2
                    .binary_search_by(|p| p.id.cmp(&o.id))
                    .ok()
                    .and_then(|i| self.prev2.get(i))
            });
            let (rho, w) = match p1 {
                Some(p1) => {
                    let (mut rho, mut w) = (p1.rho, p1.w);
                    if let (Some((dt12_s, mid)), Some(p2)) = (diff, p2) {
                        (rho, w) = fit_inverse_depth(rho, w, &p1.obs.x_n, &p2.x_n, dt12_s, &mid);
                    }
                    (
                        propagate_inverse_depth(rho, &p1.obs.x_n, &motion, dt_s),
                        w * forget,
                    )
                }
                None => (0.0, INVERSE_DEPTH_PRIOR_WEIGHT),
            };
            if o.row_dt_s != 0.0 {
                let rho_t = if p1.is_some() { rho } else { rho_new };
                let m = &motion;
                o.x_n =
                    transfer_to_stamp(o.x_n, o.row_dt_s, rho_t, m.w_c_rps, m.dw_c_rps2, m.v_c_mps);
            }
            // The flows are evaluated where the previous frame predicts the point, not at the
            // current observation: a slow camera's features move so little that even the flows'
            // dependence on `x` correlates the regressor with the observation's noise enough to
            // bias the delay by milliseconds (a robot: +5 ms for a true 0). A new track has no
            // prediction and uses its observation.
            let at = p1.map_or(o.x_n, |p| {
                [
                    p.obs.x_n[0] + p.obs.vel[0] * dt_s,
                    p.obs.x_n[1] + p.obs.vel[1] * dt_s,
                ]
            });
            let rot = rotational_flow(at, motion.w_c_rps);
            let g = translational_flow_per_inverse_depth(at, motion.v_c_mps);
            o.vel = [rot[0] + rho * g[0], rot[1] + rho * g[1]];
            // Same capacity as `out`: cannot fail, and a failure would only drop a velocity.
            let _ = self.cur.push(TrackState { obs: *o, rho, w });
        }
        self.prev2.clear();
        for p in self.prev.iter() {
            // Same capacity: cannot fail.
            let _ = self.prev2.push(p.obs);
        }
        self.prev2_t_ns = self.prev_t_ns;
        self.prev2_motion = self.prev_motion;
        core::mem::swap(&mut self.prev, &mut self.cur);
        self.prev_t_ns = Some(t_ns);
        self.prev_motion = motion;
    }
}

/// Updates the inverse-depth fit `(rho, w)` with the finite difference from `x2` to `x1` over
/// `dt_s` at the camera motion `mid` (between the two frames): the least-squares `rho` of
/// `w (rho - rho_prior)^2 + |f - rho g|^2`, `f` the finite difference minus its rotational flow.
fn fit_inverse_depth(
    rho: f64,
    w: f64,
    x1: &[f64; 2],
    x2: &[f64; 2],
    dt_s: f64,
    mid: &CameraMotion,
) -> (f64, f64) {
    if dt_s <= 0.0 {
        return (rho, w);
    }
    let xm = [0.5 * (x1[0] + x2[0]), 0.5 * (x1[1] + x2[1])];
    let rot = rotational_flow(xm, mid.w_c_rps);
    let f = [
        (x1[0] - x2[0]) / dt_s - rot[0],
        (x1[1] - x2[1]) / dt_s - rot[1],
    ];
    let g = translational_flow_per_inverse_depth(xm, mid.v_c_mps);
    let gg = g[0] * g[0] + g[1] * g[1];
    let w_new = w + gg;
    if !(w_new > 0.0 && w_new.is_finite()) {
        return (rho, w);
    }
    let rho_new = (w * rho + g[0] * f[0] + g[1] * f[1]) / w_new;
    if rho_new.is_finite() {
        (rho_new.clamp(0.0, MAX_INVERSE_DEPTH), w_new)
    } else {
        (rho, w)
    }
}

/// Carries an inverse depth seen at `x` over `dt_s` of the camera motion `m`:
/// `d rho / dt = rho (w_x y - w_y x) + rho^2 v_z`, one Euler step, kept within
/// `[0, MAX_INVERSE_DEPTH]`.
fn propagate_inverse_depth(rho: f64, x: &[f64; 2], m: &CameraMotion, dt_s: f64) -> f64 {
    let [wx, wy, _] = m.w_c_rps;
    let d = rho * (wx * x[1] - wy * x[0]) + rho * rho * m.v_c_mps[2];
    let r = rho + dt_s * d;
    if r.is_finite() {
        r.clamp(0.0, MAX_INVERSE_DEPTH)
    } else {
        rho
    }
}

/// Insertion sort by id: stable, allocation-free, and fast for the nearly sorted frames a
/// tracker produces.
fn sort_by_id(v: &mut [NormalizedObs]) {
    for i in 1..v.len() {
        let x = v[i];
        let mut j = i;
        while j > 0 && v[j - 1].id > x.id {
            v[j] = v[j - 1];
            j -= 1;
        }
        v[j] = x;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Distortion;

    fn cam() -> PinholeCamera {
        PinholeCamera {
            readout_s: 0.0,
            width: 640,
            height: 480,
            fx: 400.0,
            fy: 400.0,
            cx: 320.0,
            cy: 240.0,
            distortion: Distortion::None,
        }
    }

    fn o(id: u64, u: f64, v: f64) -> FeatureObs {
        FeatureObs {
            id,
            u_px: u,
            v_px: v,
        }
    }

    #[test]
    fn bad_observations_are_counted_and_velocities_follow_tracks() {
        let mut t: TrackTable<8> = TrackTable::new(0.5);
        let mut out = Vec::new();
        let s = t
            .process(
                0,
                &[
                    o(5, 320.0, 240.0),
                    o(2, f64::NAN, 1.0),
                    o(3, 1e6, 1.0),
                    o(5, 1.0, 1.0),
                    o(1, 360.0, 240.0),
                ],
                &cam(),
                CameraMotion::default(),
                &mut out,
            )
            .unwrap();
        assert_eq!((s.received, s.accepted), (5, 2));
        assert_eq!(
            (
                s.rejected_nonfinite,
                s.rejected_out_of_image,
                s.rejected_duplicate
            ),
            (1, 1, 1)
        );
        assert_eq!(
            out.iter().map(|x| x.id).collect::<Vec<u64, 8>>().as_slice(),
            &[1, 5]
        );
        // The first occurrence of the repeated id 5 was kept.
        assert_eq!(out[1].x_n, [0.0, 0.0]);
        assert_eq!(out[1].vel, [0.0, 0.0]);

        let s = t
            .process(
                100_000_000,
                &[o(5, 360.0, 240.0), o(9, 1.0, 1.0)],
                &cam(),
                CameraMotion::default(),
                &mut out,
            )
            .unwrap();
        assert_eq!(s.accepted, 2);
        // Only one earlier frame: no velocity yet (the current observation is never used).
        assert_eq!(out[0].vel, [0.0, 0.0]);
        assert_eq!(out[1].vel, [0.0, 0.0]);
        // Third frame: the track moved 40 px in 0.1 s, but the camera (as the INS says) neither
        // turns nor moves: a point that moves by itself gets no velocity (it would be culled).
        t.process(
            150_000_000,
            &[o(5, 600.0, 300.0)],
            &cam(),
            CameraMotion::default(),
            &mut out,
        )
        .unwrap();
        assert_eq!(out[0].vel, [0.0, 0.0]);

        assert_eq!(
            t.process(150_000_000, &[], &cam(), CameraMotion::default(), &mut out),
            Err(Error::TimeNotIncreasing)
        );
        // After a gap longer than 0.5 s, tracks restart with zero velocity.
        t.process(
            2_000_000_000,
            &[o(5, 400.0, 240.0)],
            &cam(),
            CameraMotion::default(),
            &mut out,
        )
        .unwrap();
        assert_eq!(out[0].vel, [0.0, 0.0]);
        // Capacity: 8 slots, 10 valid observations.
        let many: Vec<FeatureObs, 10> = (0..10).map(|i| o(i, 10.0 + i as f64, 10.0)).collect();
        let s = t
            .process(
                2_050_000_000,
                &many,
                &cam(),
                CameraMotion::default(),
                &mut out,
            )
            .unwrap();
        assert_eq!((s.accepted, s.rejected_capacity), (8, 2));
    }

    /// Observations of world points `pts` (camera frame at t = 0) by a camera turning at `w`
    /// (rad/s, camera frame, constant) and moving at `v` (m/s, in the camera frame at t = 0), at
    /// time `t` s, as normalized points, plus their exact time derivative.
    fn view(
        pts: &[[f64; 3]],
        w: [f64; 3],
        v: [f64; 3],
        t: f64,
    ) -> (Vec<[f64; 2], 16>, Vec<[f64; 2], 16>, [f64; 3]) {
        use crate::math::{quat_exp, Vec3};
        let at = |t: f64| -> Vec<[f64; 2], 16> {
            let q = quat_exp(&(Vec3::new(w[0], w[1], w[2]) * t));
            let c = Vec3::new(v[0], v[1], v[2]) * t;
            pts.iter()
                .map(|p| {
                    let pc = q.inverse() * (Vec3::new(p[0], p[1], p[2]) - c);
                    [pc.x / pc.z, pc.y / pc.z]
                })
                .collect()
        };
        let h = 1e-5;
        let (a, b) = (at(t + h), at(t - h));
        let d = a
            .iter()
            .zip(b.iter())
            .map(|(a, b)| [(a[0] - b[0]) / (2.0 * h), (a[1] - b[1]) / (2.0 * h)])
            .collect();
        let q = quat_exp(&(Vec3::new(w[0], w[1], w[2]) * t));
        let v_c = q.inverse() * Vec3::new(v[0], v[1], v[2]);
        (at(t), d, [v_c.x, v_c.y, v_c.z])
    }

    fn feed(
        t: &mut TrackTable<16>,
        k: i64,
        x: &[[f64; 2]],
        motion: CameraMotion,
        noise: &mut impl FnMut() -> f64,
    ) -> Vec<NormalizedObs, 16> {
        let c = cam();
        let obs: Vec<FeatureObs, 16> = x
            .iter()
            .enumerate()
            .map(|(i, x)| {
                o(
                    i as u64 + 1,
                    c.cx + c.fx * x[0] + noise(),
                    c.cy + c.fy * x[1] + noise(),
                )
            })
            .collect();
        let mut out = Vec::new();
        t.process(k * 50_000_000, &obs, &c, motion, &mut out)
            .unwrap();
        out
    }

    const PTS: [[f64; 3]; 6] = [
        [0.5, 0.2, 3.0],
        [-1.0, 0.4, 5.0],
        [0.3, -0.6, 2.0],
        [-0.2, -0.1, 8.0],
        [1.2, 0.8, 6.0],
        [0.0, 0.0, 4.0],
    ];

    fn motion(w: [f64; 3], v_c: [f64; 3]) -> CameraMotion {
        CameraMotion {
            w_c_rps: w,
            v_c_mps: v_c,
            dw_c_rps2: [0.0; 3],
        }
    }

    fn lcg_noise(mut seed: u64) -> impl FnMut() -> f64 {
        move || {
            // Sum of 4 uniforms, scaled to unit variance.
            let mut acc = 0.0;
            for _ in 0..4 {
                seed = seed
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                acc += (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
            }
            acc * 3.0f64.sqrt()
        }
    }

    #[test]
    fn a_turning_camera_gets_the_rotational_flow_from_the_gyro_from_the_first_frame() {
        let w = [0.4, -0.9, 0.3];
        let mut t: TrackTable<16> = TrackTable::new(0.5);
        for k in 0..8 {
            let (x, d, v_c) = view(&PTS, w, [0.0; 3], k as f64 * 0.05);
            let out = feed(&mut t, k, &x, motion(w, v_c), &mut || 0.0);
            // Exact on a track's first frame (evaluated at its observation); then evaluated at
            // the point's predicted position, off by the prediction's second-order error (here
            // about 1e-3 of flows near 1 /s).
            let tol = if k == 0 { 1e-8 } else { 3e-3 };
            for o in out.iter() {
                let d = d[(o.id - 1) as usize];
                assert!(
                    (o.vel[0] - d[0]).abs() < tol && (o.vel[1] - d[1]).abs() < tol,
                    "frame {k} track {}: {:?} vs {:?}",
                    o.id,
                    o.vel,
                    d
                );
            }
        }
    }

    #[test]
    fn the_translational_flow_comes_from_each_tracks_inverse_depth_not_from_noisy_differences() {
        // A camera translating and turning, 1 px noise at f = 400 px, 20 Hz: a finite difference
        // of two frames has the noise 2 sigma^2 / dt^2 = 5e-3 (1/s)^2 per axis, about the square
        // of these features' flows. The regressor of the delay must be much quieter, or the delay
        // estimate shrinks towards zero.
        let (w, v) = ([0.0, 0.3, 0.05], [0.4, 0.0, 0.6]);
        let mut noise = lcg_noise(12345);
        let mut t: TrackTable<16> = TrackTable::new(0.5);
        let (mut err2, mut flow2, mut n) = (0.0, 0.0, 0);
        for k in 0..60 {
            let (x, d, v_c) = view(&PTS, w, v, k as f64 * 0.05);
            let out = feed(&mut t, k, &x, motion(w, v_c), &mut noise);
            if k >= 20 {
                for o in out.iter() {
                    let d = d[(o.id - 1) as usize];
                    err2 += (o.vel[0] - d[0]).powi(2) + (o.vel[1] - d[1]).powi(2);
                    flow2 += d[0] * d[0] + d[1] * d[1];
                    n += 2;
                }
            }
        }
        let fd_var = 2.0 * (1.0f64 / 400.0).powi(2) / 0.05f64.powi(2);
        let (mse, ms_flow) = (err2 / n as f64, flow2 / n as f64);
        assert!(
            mse < 0.02 * fd_var && mse < 0.01 * ms_flow,
            "velocity error {mse:.2e} against a finite difference's {fd_var:.2e} (flow {ms_flow:.2e})"
        );
    }

    #[test]
    fn an_observation_does_not_enter_its_own_velocity() {
        let (w, v) = ([0.1, 0.2, 0.0], [0.3, 0.1, 0.5]);
        let mut base: TrackTable<16> = TrackTable::new(0.5);
        for k in 0..10 {
            let (x, _, v_c) = view(&PTS, w, v, k as f64 * 0.05);
            feed(&mut base, k, &x, motion(w, v_c), &mut || 0.0);
        }
        let (x, _, v_c) = view(&PTS, w, v, 0.5);
        let mut a = base.clone();
        let va = feed(&mut a, 10, &x, motion(w, v_c), &mut || 0.0);
        let mut b = base.clone();
        let vb = feed(&mut b, 10, &x, motion(w, v_c), &mut || 2.0);
        assert_eq!(va.len(), vb.len());
        for (a, b) in va.iter().zip(vb.iter()) {
            // 2 px of error in the current observation does not move its velocity at all.
            assert_eq!(a.vel, b.vel, "track {}", a.id);
            assert_ne!(a.x_n, b.x_n);
        }
    }
}
