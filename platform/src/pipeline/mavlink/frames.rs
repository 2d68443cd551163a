//! From povins' frames to PX4's and ArduPilot's: the world `w` (z up) to the local FRD frame
//! `L`, the body `b` (the IMU frame) to the vehicle's FRD body `v`.
//!
//! - `L` (MAVLink `MAV_FRAME_LOCAL_FRD`): origin and x axis those of `w`, y and z flipped:
//!   `R_Lw = diag(1, -1, -1)`, a 180° rotation about x. `w` is gravity-aligned with z up, so
//!   `L` is gravity-aligned with z down; its yaw is the estimator's (arbitrary at
//!   initialization, not north): the autopilot aligns it (PX4 EKF2 and ArduPilot do so for
//!   external vision in a local FRD frame).
//! - `v` (the vehicle's body, forward-right-down): [`BodyAxes`] names which IMU axis points
//!   forward, right and down; `R_bv` has those axes as columns. The default `x,-y,-z` is an IMU
//!   mounted forward-left-up (ROS REP-103).
//! - Position: of the IMU (the body origin; a lever arm to the vehicle's reference point is
//!   the autopilot's sensor offset parameter). Velocity: in `v` (`MAV_FRAME_BODY_FRD`).

use povins_core::inertial::{InsCovariance, NavState};
use povins_core::math::{Mat3, Quat, Vec3};

/// The vehicle's forward, right and down axes in the IMU frame, each a signed IMU axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyAxes {
    /// `R_bv`: vehicle FRD -> IMU body, columns forward, right, down.
    pub r_bv: Mat3,
}

impl Default for BodyAxes {
    /// `x,-y,-z`: the IMU is forward-left-up.
    fn default() -> Self {
        BodyAxes {
            r_bv: Mat3::from_diagonal(&Vec3::new(1.0, -1.0, -1.0)),
        }
    }
}

impl BodyAxes {
    /// Parses `F,R,D`, each `x`, `y` or `z` with an optional sign (`x,-y,-z`: forward is the
    /// IMU's +x, right its -y, down its -z). The three must form a right-handed frame.
    pub fn parse(s: &str) -> Result<BodyAxes, String> {
        let parts: Vec<&str> = s.split(',').map(str::trim).collect();
        if parts.len() != 3 {
            return Err(format!(
                "body axes `{s}`: expected three signed IMU axes forward,right,down (e.g. x,-y,-z)"
            ));
        }
        let mut r_bv = Mat3::zeros();
        for (col, p) in parts.iter().enumerate() {
            let (sign, axis) = match p.strip_prefix('-') {
                Some(a) => (-1.0, a),
                None => (1.0, p.strip_prefix('+').unwrap_or(p)),
            };
            let row = match axis {
                "x" => 0,
                "y" => 1,
                "z" => 2,
                _ => {
                    return Err(format!(
                        "body axes `{s}`: `{p}` is not one of x, y, z with an optional sign"
                    ))
                }
            };
            r_bv[(row, col)] = sign;
        }
        if (r_bv.determinant() - 1.0).abs() > 1e-9 {
            return Err(format!(
                "body axes `{s}`: forward, right, down must be three different axes forming a \
                 right-handed frame (forward x right = down)"
            ));
        }
        Ok(BodyAxes { r_bv })
    }
}

/// `R_Lw`: the world (z up) to the local FRD frame.
fn r_lw() -> Mat3 {
    Mat3::from_diagonal(&Vec3::new(1.0, -1.0, -1.0))
}

/// The pose and velocity of one state in MAVLink's frames.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrdPose {
    /// The IMU's position in `L`, m.
    pub p_l: Vec3,
    /// Attitude of `v` in `L` (`R_Lv`), as MAVLink's `q` (w, x, y, z).
    pub q_lv: Quat,
    /// Velocity in `v`, m/s.
    pub v_v: Vec3,
}

/// `nav` in `L` and `v`.
pub fn to_frd(nav: &NavState, axes: &BodyAxes) -> FrdPose {
    let r_lw = r_lw();
    let r_wb = nav.q_wb.to_rotation_matrix().into_inner();
    let r_lv = r_lw * r_wb * axes.r_bv;
    FrdPose {
        p_l: r_lw * nav.p_wb,
        q_lv: Quat::from_matrix(&r_lv),
        v_v: r_lv.transpose() * (r_lw * nav.v_wb),
    }
}

/// The covariances `ODOMETRY` carries, in its order: the upper triangles, row by row, of the
/// pose's 6x6 (`x, y, z` in `L`, then the attitude error as a rotation about `L`'s fixed x, y, z
/// axes, as ROS's `nav_msgs/Odometry` has it: for small errors the roll, pitch and yaw errors
/// at level attitude) and of the velocity's 6x6 (`vx, vy, vz` in `v`, then the angular
/// speeds, which povins does not send: their rows are NaN). m^2, rad^2, (m/s)^2.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrdCovariance {
    /// `pose_covariance` (and `VISION_POSITION_ESTIMATE`'s `covariance`).
    pub pose: [f32; 21],
    /// `velocity_covariance`.
    pub velocity: [f32; 21],
}

/// The Jacobian of `[p_L, phi_L, v_v]` ([`to_frd`]; `phi_L` the attitude error about `L`'s
/// axes) with respect to povins' error state `[p, theta, v]` (`p_wb + dp`, `R_wb Exp(theta)`,
/// `v_wb + dv`): `dp_L = R_Lw dp`, `dphi_L = R_Lw R_wb theta`,
/// `dv_v = R_bv^T (R_wb^T dv + [v_b]x theta)`.
pub fn frd_jacobian(nav: &NavState, axes: &BodyAxes) -> nalgebra::SMatrix<f64, 9, 9> {
    let r_lw = r_lw();
    let r_wb = nav.q_wb.to_rotation_matrix().into_inner();
    let v_b = r_wb.transpose() * nav.v_wb;
    let r_vb = axes.r_bv.transpose();
    let mut j = nalgebra::SMatrix::<f64, 9, 9>::zeros();
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&r_lw);
    j.fixed_view_mut::<3, 3>(3, 3).copy_from(&(r_lw * r_wb));
    j.fixed_view_mut::<3, 3>(6, 3)
        .copy_from(&(r_vb * povins_core::math::skew(&v_b)));
    j.fixed_view_mut::<3, 3>(6, 6)
        .copy_from(&(r_vb * r_wb.transpose()));
    j
}

/// `cov` (povins' error state of `nav`) in `ODOMETRY`'s frames and order ([`FrdCovariance`]).
pub fn covariance_to_frd(nav: &NavState, cov: &InsCovariance, axes: &BodyAxes) -> FrdCovariance {
    let p15 = cov.state_order();
    let p9: nalgebra::SMatrix<f64, 9, 9> = p15.fixed_view::<9, 9>(0, 0).into_owned();
    let j = frd_jacobian(nav, axes);
    let c = j * p9 * j.transpose();
    let upper = |off: usize, known: usize| {
        let mut out = [0.0f32; 21];
        let mut k = 0;
        for r in 0..6 {
            for col in r..6 {
                out[k] = if r < known && col < known {
                    c[(off + r, off + col)] as f32
                } else {
                    f32::NAN
                };
                k += 1;
            }
        }
        out
    };
    FrdCovariance {
        pose: upper(0, 6),
        velocity: upper(6, 3),
    }
}

/// The inverse of [`to_frd`]: `(p_wb, q_wb, v_wb)` from a pose in `L` and `v` (what a receiver
/// does to compare with povins' trajectory).
pub fn from_frd(f: &FrdPose, axes: &BodyAxes) -> (Vec3, Quat, Vec3) {
    let r_wl = r_lw().transpose();
    let r_lv = f.q_lv.to_rotation_matrix().into_inner();
    let r_wb = r_wl * r_lv * axes.r_bv.transpose();
    (
        r_wl * f.p_l,
        Quat::from_matrix(&r_wb),
        r_wl * (r_lv * f.v_v),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn nav() -> NavState {
        NavState {
            t_ns: 1,
            p_wb: Vec3::new(1.0, 2.0, 3.0),
            q_wb: Quat::from_euler_angles(0.1, -0.2, 0.7),
            v_wb: Vec3::new(0.5, -0.25, 0.125),
            bg: Vec3::zeros(),
            ba: Vec3::zeros(),
        }
    }

    /// The Jacobian of the conversion against central differences of [`to_frd`] over povins'
    /// error state, with a body mounted other than the default; the covariance's unknown
    /// angular-speed rows are NaN and the rest the Jacobian's congruence.
    #[test]
    fn frd_jacobian_matches_numerical() {
        use povins_core::inertial::{ImuNoise, Mat15};
        use povins_core::math::{log_so3, quat_exp};
        let axes = BodyAxes::parse("y,x,-z").unwrap();
        let x = nav();
        let f0 = to_frd(&x, &axes);
        let j = frd_jacobian(&x, &axes);
        let h = 1e-6;
        let out = |d: &[f64; 9]| {
            let mut y = x;
            y.p_wb += Vec3::new(d[0], d[1], d[2]);
            y.q_wb *= quat_exp(&Vec3::new(d[3], d[4], d[5]));
            y.v_wb += Vec3::new(d[6], d[7], d[8]);
            let f = to_frd(&y, &axes);
            let phi = log_so3(&(f.q_lv * f0.q_lv.inverse()));
            let e = [f.p_l - f0.p_l, phi, f.v_v - f0.v_v];
            let mut v = [0.0; 9];
            for (k, e) in e.iter().enumerate() {
                v[3 * k..3 * k + 3].copy_from_slice(e.as_slice());
            }
            v
        };
        for c in 0..9 {
            let mut d = [0.0; 9];
            d[c] = h;
            let plus = out(&d);
            d[c] = -h;
            let minus = out(&d);
            for r in 0..9 {
                let num = (plus[r] - minus[r]) / (2.0 * h);
                assert!(
                    (num - j[(r, c)]).abs() < 1e-7,
                    "({r},{c}): {num} vs {}",
                    j[(r, c)]
                );
            }
        }
        let mut p = Mat15::zeros();
        for i in 0..15 {
            p[(i, i)] = 1e-4 * (1 + i) as f64;
        }
        p[(2, 7)] = 2e-5;
        p[(7, 2)] = 2e-5;
        let noise = ImuNoise {
            gyro_noise_density: 1e-3,
            accel_noise_density: 1e-2,
            gyro_bias_rw: 1e-5,
            accel_bias_rw: 1e-4,
            bias_corr_time_s: None,
        };
        let c = covariance_to_frd(&x, &InsCovariance::new(&p, noise).unwrap(), &axes);
        let full = j * p.fixed_view::<9, 9>(0, 0) * j.transpose();
        // Pose: x-x, x-y (row 0), roll-roll (index 15), yaw-yaw (20).
        assert_eq!(c.pose[0], full[(0, 0)] as f32);
        assert_eq!(c.pose[1], full[(0, 1)] as f32);
        assert_eq!(c.pose[15], full[(3, 3)] as f32);
        assert_eq!(c.pose[20], full[(5, 5)] as f32);
        // Velocity: vx-vx, vy-vz (index 7), then NaN where an angular speed is involved.
        assert_eq!(c.velocity[0], full[(6, 6)] as f32);
        assert_eq!(c.velocity[7], full[(7, 8)] as f32);
        assert!(c.velocity[3].is_nan() && c.velocity[12].is_nan() && c.velocity[20].is_nan());
        assert!(c.velocity[..3].iter().all(|v| v.is_finite()));
    }

    #[test]
    fn parse_accepts_right_handed_axes_only() {
        assert_eq!(BodyAxes::parse("x,-y,-z").unwrap(), BodyAxes::default());
        assert_eq!(BodyAxes::parse("+x, y, z").unwrap().r_bv, Mat3::identity());
        // EuRoC's ADIS16448: x up, y right, z forward -> forward z, right y, down -x.
        let e = BodyAxes::parse("z,y,-x").unwrap();
        assert_eq!(e.r_bv.column(0), Vec3::new(0.0, 0.0, 1.0));
        for bad in ["x,y", "x,y,y", "x,y,-z", "x,w,z", "", "x,y,z,x"] {
            assert!(BodyAxes::parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn a_level_flu_body_facing_world_x_is_the_identity_in_frd() {
        let mut n = nav();
        n.q_wb = Quat::identity();
        let f = to_frd(&n, &BodyAxes::default());
        assert!(f.q_lv.angle() < 1e-12);
        assert_eq!(f.p_l, Vec3::new(1.0, -2.0, -3.0));
        // Velocity (0.5, -0.25, 0.125) in FLU is (0.5, 0.25, -0.125) in FRD.
        assert!((f.v_v - Vec3::new(0.5, 0.25, -0.125)).norm() < 1e-12);
    }

    #[test]
    fn yaw_to_the_left_is_negative_yaw_in_frd() {
        let mut n = nav();
        n.q_wb = Quat::from_euler_angles(0.0, 0.0, 0.3);
        let f = to_frd(&n, &BodyAxes::default());
        let (_, _, yaw) = f.q_lv.euler_angles();
        assert!((yaw + 0.3).abs() < 1e-12, "{yaw}");
    }

    #[test]
    fn to_frd_and_back_is_the_identity_for_any_axes() {
        for axes in ["x,-y,-z", "x,y,z", "z,y,-x", "-y,x,z"] {
            let a = BodyAxes::parse(axes).unwrap();
            let n = nav();
            let (p, q, v) = from_frd(&to_frd(&n, &a), &a);
            assert!((p - n.p_wb).norm() < 1e-12, "{axes}");
            assert!(q.angle_to(&n.q_wb) < 1e-12, "{axes}");
            assert!((v - n.v_wb).norm() < 1e-12, "{axes}");
            // The speed is a frame-independent check of the velocity's rotation.
            assert!((to_frd(&n, &a).v_v.norm() - n.v_wb.norm()).abs() < 1e-12);
        }
    }
}
