//! Camera observations: reprojection of the true landmarks with the true pose, wrong tracks,
//! occlusion.

use povins_core::camera::PinholeCamera;
use povins_core::math::Vec3;
use povins_host_tools::sim::camera::{project, CameraSim, TrackerParams};
use povins_host_tools::sim::rng::Rng;
use povins_host_tools::sim::scenario::{euroc_camera, preset};
use povins_host_tools::sim::scene::Landmarks;
use povins_host_tools::sim::trajectory::{TimeWarp, Trajectory};
use povins_host_tools::sim::world::{Material, Primitive, Shape, World};
use povins_host_tools::sim::{simulate, LidarKind, Scenario, SimConfig, T0_NS};
use povins_platform::dataset::Extrinsic;
use std::collections::BTreeMap;

fn pixel(
    cam: &PinholeCamera,
    t_bc: &Extrinsic,
    kin_p: Vec3,
    kin_q: povins_core::math::Quat,
    p_w: &Vec3,
) -> Option<[f64; 2]> {
    let q_wc = kin_q * t_bc.q_ab;
    let o_w = kin_p + kin_q * t_bc.p_ab;
    project(cam, &(q_wc.inverse() * (p_w - o_w)))
}

#[test]
fn observations_reproject_wrong_tracks_are_off_and_nothing_occluded_is_seen() {
    for (sc, td_ms) in [
        (Scenario::Handheld, 7.0),
        (Scenario::Robot, -4.0),
        (Scenario::Vehicle, 3.0),
    ] {
        let mut cfg = SimConfig::new(sc, 3, 12.0);
        cfg.lidar = Some(LidarKind::None);
        cfg.td_s = td_ms * 1e-3;
        cfg.wrong_track_rate = Some(0.05);
        let out = simulate(&cfg, &|_, _, _| {}).expect("simulate");
        let ds = &out.dataset;
        let truth = ds.sim_truth.as_ref().expect("sim truth");
        let lm: BTreeMap<u64, Vec3> = truth.landmarks_w.iter().copied().collect();
        let wrong: std::collections::BTreeSet<u64> = truth.wrong_tracks.iter().copied().collect();
        assert!(!wrong.is_empty(), "{sc:?}: no wrong tracks at rate 0.05");
        let mut max_off_wrong: BTreeMap<u64, f64> = BTreeMap::new();
        let (mut n, mut sum2, mut worst) = (0usize, 0.0, 0.0f64);
        for f in &ds.features {
            // Image time on the IMU clock: t_imu = t_cam + td.
            let t_imu_ns = f.t_ns + (ds.calib.td_s * 1e9).round() as i64;
            let k = out.trajectory.eval((t_imu_ns - T0_NS) as f64 * 1e-9);
            let o_w = k.p_wb + k.q_wb * ds.calib.t_bc.p_ab;
            for o in &f.obs {
                let p_w = lm[&o.id];
                let uv = pixel(&ds.calib.camera, &ds.calib.t_bc, k.p_wb, k.q_wb, &p_w);
                assert!(
                    uv.is_some() || wrong.contains(&o.id),
                    "{sc:?}: landmark {} behind the camera",
                    o.id
                );
                let e = uv.map_or(f64::INFINITY, |uv| {
                    ((o.u_px - uv[0]).powi(2) + (o.v_px - uv[1]).powi(2)).sqrt()
                });
                if wrong.contains(&o.id) {
                    let m = max_off_wrong.entry(o.id).or_insert(0.0);
                    *m = m.max(e);
                } else {
                    n += 1;
                    sum2 += e * e;
                    worst = worst.max(e);
                    // Nothing between the camera and an observed landmark.
                    let tol = 0.01 + 1e-4 * (p_w - o_w).norm();
                    assert!(
                        out.world.line_of_sight(&o_w, &p_w, tol),
                        "{sc:?}: occluded landmark {} observed",
                        o.id
                    );
                }
            }
        }
        let rms_per_axis = (sum2 / n as f64 / 2.0).sqrt();
        assert!(
            (rms_per_axis - 1.0).abs() < 0.05,
            "{sc:?}: pixel noise rms {rms_per_axis}"
        );
        assert!(worst < 6.0, "{sc:?}: correct track off by {worst} px");
        for id in &wrong {
            let m = max_off_wrong.get(id).copied().unwrap_or(0.0);
            assert!(
                m > 5.0,
                "{sc:?}: wrong track {id} stays on its landmark ({m} px)"
            );
        }
    }
}

#[test]
fn a_rolling_shutter_sees_each_feature_at_its_rows_time() {
    // Hand-held (fast rotations), 30 ms readout, no pixel noise: every observation is the
    // projection with the pose at its own row's time (to the simulator's fixed-point steps),
    // and not the middle row's pose.
    let mut cfg = SimConfig::new(Scenario::Handheld, 2, 8.0);
    cfg.lidar = Some(LidarKind::None);
    cfg.wrong_track_rate = Some(0.0);
    cfg.pixel_noise_px = 0.0;
    cfg.td_s = 5e-3;
    cfg.readout_s = 0.03;
    let out = simulate(&cfg, &|_, _, _| {}).expect("simulate");
    let ds = &out.dataset;
    let cam = &ds.calib.camera;
    assert_eq!(cam.readout_s, 0.03, "the calibration carries the readout");
    let truth = ds.sim_truth.as_ref().expect("sim truth");
    let lm: BTreeMap<u64, Vec3> = truth.landmarks_w.iter().copied().collect();
    let (mut n, mut worst_rs, mut worst_gs) = (0usize, 0.0f64, 0.0f64);
    for f in &ds.features {
        let t_s = (f.t_ns + (ds.calib.td_s * 1e9).round() as i64 - T0_NS) as f64 * 1e-9;
        let mid = out.trajectory.eval(t_s);
        for o in &f.obs {
            let row = out.trajectory.eval(t_s + cam.row_time_s(o.v_px));
            let off = |k: &povins_host_tools::sim::trajectory::Kinematics| {
                pixel(cam, &ds.calib.t_bc, k.p_wb, k.q_wb, &lm[&o.id])
                    .map_or(f64::INFINITY, |uv| (o.u_px - uv[0]).hypot(o.v_px - uv[1]))
            };
            n += 1;
            worst_rs = worst_rs.max(off(&row));
            worst_gs = worst_gs.max(off(&mid));
        }
    }
    assert!(n > 10_000, "{n} observations");
    // Three fixed-point steps: within 0.02 px (0.014 px measured).
    assert!(worst_rs < 0.02, "off its row's projection by {worst_rs} px");
    assert!(
        worst_gs > 3.0,
        "the middle row's pose explains every row to {worst_gs} px: no rolling shutter"
    );
}

#[test]
fn landmark_hidden_behind_a_box_is_never_observed() {
    // Camera at rest at the origin looking along +x (body x), a box in front hides part of a wall.
    let world = World::new(
        vec![
            Primitive {
                shape: Shape::Box {
                    min: Vec3::new(5.0, -1.0, 0.0),
                    max: Vec3::new(6.0, 1.0, 3.0),
                },
                material: Material::Building,
            },
            Primitive {
                shape: Shape::Box {
                    min: Vec3::new(15.0, -20.0, 0.0),
                    max: Vec3::new(16.0, 20.0, 10.0),
                },
                material: Material::Building,
            },
        ],
        [-30.0, -30.0, 30.0, 30.0],
        4.0,
    );
    // Wall landmarks: a grid on the wall face x = 15; box-face landmarks on x = 5.
    let (mut p, mut n, mut s) = (Vec::new(), Vec::new(), Vec::new());
    for iy in -8..=8 {
        for iz in 1..8 {
            p.push(Vec3::new(15.0, iy as f64 * 0.7, iz as f64 * 0.6));
            n.push(Vec3::new(-1.0, 0.0, 0.0));
            s.push(2);
        }
    }
    for iy in -2..=2 {
        p.push(Vec3::new(5.0, iy as f64 * 0.4, 1.5));
        n.push(Vec3::new(-1.0, 0.0, 0.0));
        s.push(1);
    }
    // On the box face 1 cm from its vertical edge: an occlusion-boundary landmark.
    let edge_lm = Vec3::new(5.0, 0.99, 1.5);
    p.push(edge_lm);
    n.push(Vec3::new(-1.0, 0.0, 0.0));
    s.push(1);
    let lms = Landmarks::new(p.clone(), n, s, world.bounds(), 4.0);
    let traj = Trajectory {
        p0: Vec3::new(0.0, 0.0, 1.5),
        pos: [vec![], vec![], vec![]],
        att: [vec![], vec![], vec![]],
        att0: [0.0; 3],
        steered: false,
        warp: TimeWarp {
            t_static: 1e9,
            t_ramp: 1.0,
        },
    };
    let params = TrackerParams {
        max_features: 500,
        min_dist_px: 1.0,
        depth_range_m: (0.1, 50.0),
        border_px: 2.0,
        max_incidence_rad: 1.5,
        base_loss: 0.0,
        loss_per_px: 0.0,
        wrong_track_rate: 0.0,
        pixel_noise_px: 0.0,
        edge_angle_rad: 0.01,
        max_track_frames: None,
    };
    let t_bc = preset(Scenario::Robot, 0.0).t_bc;
    let t_bc = Extrinsic {
        q_ab: t_bc.q_ab,
        p_ab: Vec3::zeros(),
    };
    let mut cam = CameraSim::new(&world, &lms, euroc_camera(), &t_bc, params, Rng::new(1));
    let frame = cam.step(&traj.eval(0.0), 0, &|dt| traj.eval(dt));
    let truth = cam.finish();
    let seen: Vec<Vec3> = frame
        .obs
        .iter()
        .map(|o| truth.landmarks_w[(o.id - 1) as usize].1)
        .collect();
    let eye = Vec3::new(0.0, 0.0, 1.5);
    let mut hidden = 0;
    for q in &p {
        // Hidden iff the straight line from the eye crosses the box x in [5, 6], |y| <= 1, z <= 3.
        let f = 5.0 / q.x;
        let (y, z) = (eye.y + (q.y - eye.y) * f, eye.z + (q.z - eye.z) * f);
        let blocked = q.x > 6.0 && y.abs() <= 1.0 && z <= 3.0;
        let observed = seen.iter().any(|s| (s - q).norm() < 1e-12);
        let in_view = pixel(&euroc_camera(), &t_bc, eye, traj.eval(0.0).q_wb, q)
            .is_some_and(|uv| uv[0] > 2.0 && uv[0] < 749.0 && uv[1] > 2.0 && uv[1] < 477.0);
        if blocked {
            hidden += 1;
            assert!(!observed, "occluded landmark {q:?} observed");
        } else if in_view {
            assert!(observed, "visible landmark {q:?} not observed");
        }
    }
    assert!(hidden >= 5, "test geometry hides too little ({hidden})");
    // Exactly the landmark next to the box edge is flagged as an edge feature.
    let edge_pos: Vec<Vec3> = truth
        .edge_features
        .iter()
        .map(|&id| truth.landmarks_w[(id - 1) as usize].1)
        .collect();
    assert!(
        edge_pos.iter().any(|q| (q - edge_lm).norm() < 1e-12),
        "edge landmark not flagged"
    );
    for q in &edge_pos {
        // Wall landmarks next to the box silhouette may also qualify; face-centre ones must not.
        assert!(
            !(q.x == 5.0 && q.y.abs() < 0.5),
            "interior face landmark {q:?} flagged as edge"
        );
    }
}
