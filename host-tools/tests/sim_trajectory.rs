//! Carrier trajectories: analytic derivatives against numerical differentiation, and the speed /
//! attitude envelopes of each carrier.

use povins_core::math::log_so3;
use povins_host_tools::sim::scenario::{preset, Scenario};

const ALL: [Scenario; 3] = [Scenario::Robot, Scenario::Handheld, Scenario::Vehicle];

#[test]
fn analytic_velocity_acceleration_and_rate_match_numerical() {
    for sc in ALL {
        let traj = preset(sc, 1.0).trajectory;
        let h = 1e-5;
        // Static phase, ramp and cruising.
        for i in 0..300 {
            let t = 0.013 + 0.4 * i as f64;
            let k = traj.eval(t);
            let (km, kp) = (traj.eval(t - h), traj.eval(t + h));
            let v_num = (kp.p_wb - km.p_wb) / (2.0 * h);
            let a_num = (kp.v_wb - km.v_wb) / (2.0 * h);
            let w_num = log_so3(&(km.q_wb.inverse() * kp.q_wb)) / (2.0 * h);
            let scale = 1.0 + k.v_wb.norm();
            assert!(
                (k.v_wb - v_num).norm() < 1e-5 * scale,
                "{sc:?} v at t={t}: {:?} vs {:?}",
                k.v_wb,
                v_num
            );
            assert!((k.a_wb - a_num).norm() < 1e-4 * scale, "{sc:?} a at t={t}");
            assert!(
                (k.omega_b - w_num).norm() < 1e-6,
                "{sc:?} w at t={t}: {:?} vs {:?}",
                k.omega_b,
                w_num
            );
        }
    }
}

#[test]
fn carrier_envelopes() {
    for sc in ALL {
        let traj = preset(sc, 1.0).trajectory;
        let t_move = traj.warp.t_static + traj.warp.t_ramp;
        let (mut vmin, mut vmax, mut wmax, mut tilt_max) = (f64::INFINITY, 0.0f64, 0.0f64, 0.0f64);
        let mut t = t_move;
        while t < 200.0 {
            let k = traj.eval(t);
            let v = k.v_wb.norm();
            vmin = vmin.min(v);
            vmax = vmax.max(v);
            wmax = wmax.max(k.omega_b.norm());
            tilt_max = tilt_max.max(k.euler[1].abs()).max(k.euler[2].abs());
            t += 0.05;
        }
        match sc {
            Scenario::Robot => {
                assert!(vmax <= 1.5 && vmin > 0.5, "robot speed {vmin}..{vmax}");
                assert!(tilt_max < 5f64.to_radians(), "robot roll/pitch {tilt_max}");
            }
            Scenario::Handheld => {
                assert!(vmin > 0.5 && vmax < 2.0, "walking speed {vmin}..{vmax}");
                assert!(
                    wmax > 90f64.to_radians(),
                    "hand-held rotations too slow: {wmax}"
                );
            }
            Scenario::Vehicle => {
                assert!(vmin >= 15.0 && vmax <= 30.0, "vehicle speed {vmin}..{vmax}");
                assert!(tilt_max < 3f64.to_radians());
            }
            // Not in `ALL` (the MAV scenarios have their own envelopes).
            Scenario::Flight | Scenario::Fast => {}
        }
        // At rest during the static phase.
        let k0 = traj.eval(0.5);
        assert_eq!(k0.v_wb.norm(), 0.0);
        assert_eq!(k0.omega_b.norm(), 0.0);
    }
}
