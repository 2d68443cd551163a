//! Smooth carrier trajectories with exact analytic derivatives.
//!
//! The path is a function of a warped time `s(t)`: every coordinate and every attitude offset is
//! a sum of sinusoids `A sin(w s + phi)` of `s`, so all derivatives in `s` are closed forms.
//! The warp makes the carrier stand still for `t_static`, then ramps the path speed with a
//! quintic smoothstep over `t_ramp`:
//!
//! ```text
//! u = (t - t_static) / t_ramp,  s'(t) = 10u^3 - 15u^4 + 6u^5   (0 before, 1 after)
//! s(t)  = t_ramp (2.5u^4 - 3u^5 + u^6),   s''(t) = 30 u^2 (1-u)^2 / t_ramp
//! ```
//!
//! Chain rule: `v = p'(s) s'`, `a = p''(s) s'^2 + p'(s) s''`.
//!
//! Attitude is ZYX Euler `R_wb = Rz(yaw) Ry(pitch) Rx(roll)` (body x forward, y left, z up).
//! Yaw and pitch follow the path tangent when the path is "steered" (wheeled carriers), plus
//! offsets: `yaw = atan2(y', x') + dyaw(s)`, `pitch = -atan2(z', h) + dpitch(s)` with
//! `h = |(x', y')|`, whose `s`-derivatives are
//!
//! ```text
//! d yaw_path/ds   = (x' y'' - y' x'') / h^2
//! d pitch_path/ds = -(h z'' - z' h') / (h^2 + z'^2),   h' = (x' x'' + y' y'') / h
//! ```
//!
//! and the body angular rate follows exactly from the Euler rates:
//!
//! ```text
//! w_b = [ roll' - yaw' sin(pitch),
//!         pitch' cos(roll) + yaw' cos(pitch) sin(roll),
//!        -pitch' sin(roll) + yaw' cos(pitch) cos(roll) ]
//! ```

use povins_core::math::{Mat3, Quat, Vec3};

/// One term `amp * sin(freq * s + phase)`; `freq` in rad per unit of `s` (seconds after the ramp).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sinusoid {
    /// Amplitude (m or rad).
    pub amp: f64,
    /// Angular frequency, rad/s.
    pub freq: f64,
    /// Phase, rad.
    pub phase: f64,
}

impl Sinusoid {
    /// Shorthand constructor.
    pub const fn new(amp: f64, freq: f64, phase: f64) -> Self {
        Sinusoid { amp, freq, phase }
    }
}

/// Value and first two derivatives of a sum of sinusoids at `s`.
fn sum_eval(terms: &[Sinusoid], offset: f64, s: f64) -> [f64; 3] {
    let mut out = [offset, 0.0, 0.0];
    for t in terms {
        let a = t.freq * s + t.phase;
        let (sn, cs) = (libm::sin(a), libm::cos(a));
        out[0] += t.amp * sn;
        out[1] += t.amp * t.freq * cs;
        out[2] -= t.amp * t.freq * t.freq * sn;
    }
    out
}

/// Start-up time warp: at rest for `t_static`, then a smooth ramp to unit path speed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimeWarp {
    /// Time at rest, s.
    pub t_static: f64,
    /// Ramp duration, s (> 0).
    pub t_ramp: f64,
}

impl TimeWarp {
    /// `(s, s', s'')` at time `t` (seconds from the start of the sequence).
    pub fn eval(&self, t: f64) -> [f64; 3] {
        let tr = self.t_ramp.max(1e-9);
        if t <= self.t_static {
            return [0.0, 0.0, 0.0];
        }
        let u = (t - self.t_static) / tr;
        if u >= 1.0 {
            return [t - self.t_static - 0.5 * tr, 1.0, 0.0];
        }
        let u2 = u * u;
        let u3 = u2 * u;
        let s = tr * u2 * u2 * (2.5 - 3.0 * u + u2);
        let sd = u3 * (10.0 - 15.0 * u + 6.0 * u2);
        let sdd = 30.0 * u2 * (1.0 - u) * (1.0 - u) / tr;
        [s, sd, sdd]
    }
}

/// A carrier trajectory (see the module docs for the math).
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    /// Constant part of the position, m.
    pub p0: Vec3,
    /// Sinusoids of x, y, z of the body origin in `w`.
    pub pos: [Vec<Sinusoid>; 3],
    /// Attitude offsets (yaw, pitch, roll), rad.
    pub att: [Vec<Sinusoid>; 3],
    /// Constant attitude offsets (yaw, pitch, roll), rad.
    pub att0: [f64; 3],
    /// Yaw and pitch follow the path tangent.
    pub steered: bool,
    /// Start-up warp.
    pub warp: TimeWarp,
}

/// The full kinematic state of the body at one time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Kinematics {
    /// Position of the body in `w`, m.
    pub p_wb: Vec3,
    /// Velocity in `w`, m/s.
    pub v_wb: Vec3,
    /// Acceleration in `w`, m/s^2.
    pub a_wb: Vec3,
    /// Rotation body -> world.
    pub q_wb: Quat,
    /// Same as a matrix.
    pub r_wb: Mat3,
    /// Angular rate of `b` w.r.t. `w`, in `b`, rad/s.
    pub omega_b: Vec3,
    /// ZYX Euler angles (yaw, pitch, roll), rad.
    pub euler: [f64; 3],
}

impl Kinematics {
    /// Ideal (noise- and bias-free) specific force in `b`: `R_wb^T (a + g e_z)`.
    pub fn specific_force_b(&self, gravity_mps2: f64) -> Vec3 {
        self.r_wb.transpose() * (self.a_wb + Vec3::new(0.0, 0.0, gravity_mps2))
    }
}

/// `Rz(yaw) Ry(pitch) Rx(roll)` as a quaternion.
pub fn quat_from_euler(yaw: f64, pitch: f64, roll: f64) -> Quat {
    let (sy, cy) = (libm::sin(0.5 * yaw), libm::cos(0.5 * yaw));
    let (sp, cp) = (libm::sin(0.5 * pitch), libm::cos(0.5 * pitch));
    let (sr, cr) = (libm::sin(0.5 * roll), libm::cos(0.5 * roll));
    Quat::new_unchecked(nalgebra::Quaternion::new(
        cy * cp * cr + sy * sp * sr,
        cy * cp * sr - sy * sp * cr,
        cy * sp * cr + sy * cp * sr,
        sy * cp * cr - cy * sp * sr,
    ))
}

impl Trajectory {
    /// Position and its first two `s`-derivatives at path parameter `s`.
    pub fn path(&self, s: f64) -> [Vec3; 3] {
        let x = sum_eval(&self.pos[0], self.p0.x, s);
        let y = sum_eval(&self.pos[1], self.p0.y, s);
        let z = sum_eval(&self.pos[2], self.p0.z, s);
        [
            Vec3::new(x[0], y[0], z[0]),
            Vec3::new(x[1], y[1], z[1]),
            Vec3::new(x[2], y[2], z[2]),
        ]
    }

    /// The kinematic state at time `t_s` (seconds from the start of the sequence).
    pub fn eval(&self, t_s: f64) -> Kinematics {
        let [s, sd, sdd] = self.warp.eval(t_s);
        let [p, dp, ddp] = self.path(s);
        let v = dp * sd;
        let a = ddp * (sd * sd) + dp * sdd;

        // Euler angles and their s-derivatives.
        let mut e = [0.0; 3];
        let mut de = [0.0; 3];
        for k in 0..3 {
            let r = sum_eval(&self.att[k], self.att0[k], s);
            e[k] = r[0];
            de[k] = r[1];
        }
        if self.steered {
            let h2 = dp.x * dp.x + dp.y * dp.y;
            let h = libm::sqrt(h2);
            e[0] += libm::atan2(dp.y, dp.x);
            de[0] += (dp.x * ddp.y - dp.y * ddp.x) / h2;
            let dh = (dp.x * ddp.x + dp.y * ddp.y) / h;
            e[1] += -libm::atan2(dp.z, h);
            de[1] += -(h * ddp.z - dp.z * dh) / (h2 + dp.z * dp.z);
        }
        let [yaw, pitch, roll] = e;
        let (yd, pd, rd) = (de[0] * sd, de[1] * sd, de[2] * sd);
        let (sp, cp) = (libm::sin(pitch), libm::cos(pitch));
        let (sr, cr) = (libm::sin(roll), libm::cos(roll));
        let omega_b = Vec3::new(
            rd - yd * sp,
            pd * cr + yd * cp * sr,
            -pd * sr + yd * cp * cr,
        );
        let q = quat_from_euler(yaw, pitch, roll);
        Kinematics {
            p_wb: p,
            v_wb: v,
            a_wb: a,
            q_wb: q,
            r_wb: q.to_rotation_matrix().into_inner(),
            omega_b,
            euler: e,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use povins_core::math::log_so3;

    fn test_traj() -> Trajectory {
        Trajectory {
            p0: Vec3::new(1.0, -2.0, 1.5),
            pos: [
                vec![Sinusoid::new(10.0, 0.1, 1.0), Sinusoid::new(0.5, 0.7, 0.2)],
                vec![Sinusoid::new(8.0, 0.1, 0.0), Sinusoid::new(0.3, 1.3, 0.4)],
                vec![Sinusoid::new(0.2, 0.5, 0.0)],
            ],
            att: [
                vec![Sinusoid::new(0.6, 1.7, 0.3)],
                vec![Sinusoid::new(0.2, 2.3, 0.1)],
                vec![Sinusoid::new(0.3, 1.1, 0.9)],
            ],
            att0: [0.0, 0.05, 0.0],
            steered: true,
            warp: TimeWarp {
                t_static: 0.5,
                t_ramp: 2.0,
            },
        }
    }

    #[test]
    fn quat_matches_euler_matrix() {
        let (y, p, r) = (0.7, -0.3, 1.1);
        let q = quat_from_euler(y, p, r);
        let m = nalgebra::Rotation3::from_axis_angle(&Vec3::z_axis(), y)
            * nalgebra::Rotation3::from_axis_angle(&Vec3::y_axis(), p)
            * nalgebra::Rotation3::from_axis_angle(&Vec3::x_axis(), r);
        assert!((q.to_rotation_matrix().into_inner() - m.into_inner()).norm() < 1e-12);
    }

    #[test]
    fn warp_derivatives_are_consistent() {
        let w = TimeWarp {
            t_static: 1.0,
            t_ramp: 3.0,
        };
        let h = 1e-5;
        for &t in &[0.5, 1.2, 2.0, 3.9, 4.5, 10.0] {
            let [_, sd, sdd] = w.eval(t);
            let num_sd = (w.eval(t + h)[0] - w.eval(t - h)[0]) / (2.0 * h);
            let num_sdd = (w.eval(t + h)[1] - w.eval(t - h)[1]) / (2.0 * h);
            assert!((sd - num_sd).abs() < 1e-8, "t={t}: {sd} vs {num_sd}");
            assert!((sdd - num_sdd).abs() < 1e-6, "t={t}: {sdd} vs {num_sdd}");
        }
        // Continuity at the ramp end.
        let a = w.eval(4.0 - 1e-9);
        let b = w.eval(4.0 + 1e-9);
        assert!((a[0] - b[0]).abs() < 1e-8 && (a[1] - b[1]).abs() < 1e-8);
    }

    #[test]
    fn analytic_derivatives_match_numerical() {
        let tr = test_traj();
        let h = 1e-5;
        for i in 0..40 {
            let t = 0.3 + 0.77 * i as f64;
            let k = tr.eval(t);
            let (km, kp) = (tr.eval(t - h), tr.eval(t + h));
            let v_num = (kp.p_wb - km.p_wb) / (2.0 * h);
            let a_num = (kp.v_wb - km.v_wb) / (2.0 * h);
            let w_num = log_so3(&(km.q_wb.inverse() * kp.q_wb)) / (2.0 * h);
            assert!((k.v_wb - v_num).norm() < 1e-6, "v at {t}");
            assert!((k.a_wb - a_num).norm() < 1e-5, "a at {t}");
            assert!(
                (k.omega_b - w_num).norm() < 1e-6,
                "w at {t}: {:?} {:?}",
                k.omega_b,
                w_num
            );
        }
    }

    #[test]
    fn static_phase_is_static() {
        let k = test_traj().eval(0.2);
        assert_eq!(k.v_wb, Vec3::zeros());
        assert_eq!(k.a_wb, Vec3::zeros());
        assert_eq!(k.omega_b, Vec3::zeros());
    }
}
