//! IMU model: residual statistics against the configured noise, and exact integration of the
//! ideal IMU reproducing the ground truth.

use nalgebra::Quaternion;
use povins_core::math::{Quat, Vec3};
use povins_host_tools::sim::imu::{discrete_noise_std, simulate_imu, ImuPreset};
use povins_host_tools::sim::rng::Rng;
use povins_host_tools::sim::scenario::{preset, Scenario};
use povins_host_tools::sim::trajectory::Trajectory;

const G: f64 = 9.81;

#[test]
fn residuals_have_the_configured_std_per_axis() {
    for (sc, imu) in [
        (Scenario::Robot, ImuPreset::adis16465()),
        (Scenario::Handheld, ImuPreset::bmi088()),
        (Scenario::Vehicle, ImuPreset::stim300()),
    ] {
        let traj = preset(sc, 1.0).trajectory;
        let n = 60_000; // 300 s at 200 Hz
        let run = simulate_imu(&traj, &imu, 200.0, n, 0, G, &mut Rng::new(42));
        let (sg, sa) = discrete_noise_std(&imu.noise, 200.0);
        let mut s2 = [[0.0f64; 3]; 2];
        let mut s1 = [[0.0f64; 3]; 2];
        for (m, gt) in run.imu.iter().zip(&run.ground_truth) {
            let k = traj.eval(m.t_ns as f64 * 1e-9);
            let rg = m.gyro_rps - k.omega_b - gt.bg;
            let ra = m.accel_mps2 - k.specific_force_b(G) - gt.ba;
            for i in 0..3 {
                s1[0][i] += rg[i];
                s1[1][i] += ra[i];
                s2[0][i] += rg[i] * rg[i];
                s2[1][i] += ra[i] * ra[i];
            }
        }
        for i in 0..3 {
            let std_g = (s2[0][i] / n as f64).sqrt();
            let std_a = (s2[1][i] / n as f64).sqrt();
            assert!(
                (std_g / sg - 1.0).abs() < 0.03,
                "{} gyro axis {i}: {std_g} vs {sg}",
                imu.name
            );
            assert!(
                (std_a / sa - 1.0).abs() < 0.03,
                "{} accel axis {i}: {std_a} vs {sa}",
                imu.name
            );
            assert!(
                (s1[0][i] / n as f64).abs() < 0.02 * sg,
                "gyro residual mean"
            );
            assert!(
                (s1[1][i] / n as f64).abs() < 0.02 * sa,
                "accel residual mean"
            );
        }
        // Biases start away from zero and wander.
        let b0 = &run.ground_truth[0];
        let b1 = &run.ground_truth[n - 1];
        assert!(b0.bg.norm() > 0.0 && b0.ba.norm() > 0.0);
        assert!((b1.bg - b0.bg).norm() > 0.0 && (b1.ba - b0.ba).norm() > 0.0);
    }
}

/// Classic RK4 on the state `(p, v, q)` (quaternion as 4 components, renormalized after each
/// step) with `p' = v, v' = R(q) f - g e_z, q' = q (0, w) / 2`, fed by the ideal IMU signals.
fn integrate_ideal(traj: &Trajectory, t0: f64, t1: f64, dt: f64) -> (Vec3, Quat, Vec3) {
    type State = (Vec3, Vec3, Quaternion<f64>);
    let deriv = |t: f64, y: &State| -> State {
        let k = traj.eval(t);
        let f = k.specific_force_b(G);
        let qn = Quat::new_normalize(y.2);
        let w = Quaternion::new(0.0, k.omega_b.x, k.omega_b.y, k.omega_b.z);
        (y.1, qn * f - Vec3::new(0.0, 0.0, G), y.2 * w * 0.5)
    };
    let add =
        |y: &State, d: &State, h: f64| -> State { (y.0 + d.0 * h, y.1 + d.1 * h, y.2 + d.2 * h) };
    let k0 = traj.eval(t0);
    let mut y: State = (k0.p_wb, k0.v_wb, *k0.q_wb.quaternion());
    let steps = ((t1 - t0) / dt).round() as usize;
    for i in 0..steps {
        let t = t0 + i as f64 * dt;
        let d1 = deriv(t, &y);
        let d2 = deriv(t + 0.5 * dt, &add(&y, &d1, 0.5 * dt));
        let d3 = deriv(t + 0.5 * dt, &add(&y, &d2, 0.5 * dt));
        let d4 = deriv(t + dt, &add(&y, &d3, dt));
        y.0 += (d1.0 + d2.0 * 2.0 + d3.0 * 2.0 + d4.0) * (dt / 6.0);
        y.1 += (d1.1 + d2.1 * 2.0 + d3.1 * 2.0 + d4.1) * (dt / 6.0);
        y.2 += (d1.2 + d2.2 * 2.0 + d3.2 * 2.0 + d4.2) * (dt / 6.0);
        y.2 = y.2.normalize();
    }
    (y.0, Quat::new_normalize(y.2), y.1)
}

#[test]
fn ideal_imu_integration_reproduces_ground_truth() {
    for sc in [Scenario::Robot, Scenario::Handheld, Scenario::Vehicle] {
        let traj = preset(sc, 1.0).trajectory;
        let (t0, t1) = (0.0, 30.0);
        let (p, q, v) = integrate_ideal(&traj, t0, t1, 1.0 / 200.0);
        let k = traj.eval(t1);
        let ep = (p - k.p_wb).norm();
        let ev = (v - k.v_wb).norm();
        let eq = povins_core::math::log_so3(&(k.q_wb.inverse() * q)).norm();
        assert!(ep < 1e-4, "{sc:?} position error {ep}");
        assert!(ev < 1e-5, "{sc:?} velocity error {ev}");
        assert!(eq < 1e-7, "{sc:?} attitude error {eq}");
    }
}
