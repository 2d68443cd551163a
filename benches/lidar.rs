//! Criterion benches of the LiDAR layer: de-skew and store a 10k-point Livox-like sweep, build
//! the sphere grid from 50k buffered points, and 100 feature associations.
use criterion::{criterion_group, criterion_main, Criterion};
use povins::core::camera::Vec2;
use povins::core::inertial::{InsWindow, NavState};
use povins::core::lidar::association::{GRID_H, GRID_W};
use povins::core::lidar::buffer::MAX_LIDAR_POINTS;
use povins::core::lidar::{
    AssociationConfig, LidarConfig, LidarExtrinsic, LidarPoint, PointBuffer, SphereGrid,
};
use povins::core::math::{quat_exp, Quat, Vec3};
use std::hint::black_box;

const MS: i64 = 1_000_000;
const SWEEP: usize = 10_000;

/// Walking at 1 m/s and turning at 0.3 rad/s.
fn pose(t_ns: i64) -> (Vec3, Quat) {
    let t = t_ns as f64 * 1e-9;
    (
        Vec3::new(1.0 * t, 0.2 * t, 1.0),
        quat_exp(&Vec3::new(0.0, 0.0, 0.3 * t)),
    )
}

fn ins() -> InsWindow<256> {
    let mut w = InsWindow::new();
    for k in 0..=200 {
        let (p, q) = pose(k * 5 * MS);
        w.push(NavState {
            p_wb: p,
            q_wb: q,
            ..NavState::identity(k * 5 * MS)
        })
        .unwrap();
    }
    w
}

fn cfg() -> LidarConfig {
    LidarConfig {
        extrinsic: LidarExtrinsic {
            q_bl: quat_exp(&Vec3::new(0.01, -0.02, 0.03)),
            p_bl: Vec3::new(0.05, 0.05, 0.1),
        },
        td_l_s: 0.002,
        ..LidarConfig::default()
    }
}

/// Livox-like rosette sweep starting at `t0_ns` (100 kHz, 70.4 deg FoV) in a 16 x 12 x 5 m room.
fn sweep(t0_ns: i64) -> Vec<LidarPoint> {
    let c = cfg();
    let (w1, w2) = (
        2.0 * std::f64::consts::PI * 121.57,
        2.0 * std::f64::consts::PI * 77.73,
    );
    let half = 35.2f64.to_radians();
    (0..SWEEP as i64)
        .map(|i| {
            let t_ns = t0_ns + i * 10_000;
            let t = t_ns as f64 * 1e-9;
            let zx = 0.5 * half * ((w1 * t).cos() + (w2 * t).cos());
            let zy = 0.5 * half * ((w1 * t).sin() - (w2 * t).sin());
            let (rho, phi) = (zx.hypot(zy), zy.atan2(zx));
            let d_l = Vec3::new(rho.cos(), rho.sin() * phi.cos(), rho.sin() * phi.sin());
            let (p_wb, q_wb) = pose(t_ns + 2 * MS);
            let (o, q_wl) = (p_wb + q_wb * c.extrinsic.p_bl, q_wb * c.extrinsic.q_bl);
            let d = q_wl * d_l;
            let (lo, hi) = (Vec3::new(-6.0, -6.0, -0.5), Vec3::new(10.0, 6.0, 4.5));
            let r = (0..3)
                .filter(|&a| d[a] != 0.0)
                .flat_map(|a| [(lo[a] - o[a]) / d[a], (hi[a] - o[a]) / d[a]])
                .filter(|&r| r > 0.0)
                .fold(f64::INFINITY, f64::min);
            let p_l = d_l * r;
            LidarPoint {
                t_ns,
                p_l: [p_l.x as f32, p_l.y as f32, p_l.z as f32],
                intensity: 1.0,
            }
        })
        .collect()
}

fn camera(t_ns: i64) -> (Vec3, Quat) {
    let (p_wb, q_wb) = pose(t_ns);
    let r_bc = povins::core::math::Mat3::new(0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0);
    let q_bc = Quat::from_matrix(&r_bc);
    (p_wb + q_wb * Vec3::new(0.2, 0.0, 0.1), q_wb * q_bc)
}

fn bench_lidar(c: &mut Criterion) {
    let ins = ins();
    let cfg = cfg();
    let sweeps: Vec<Vec<LidarPoint>> = (0..5).map(|k| sweep(100 * MS * k + 10 * MS)).collect();

    c.bench_function("lidar_push_scan_10k_points", |b| {
        let mut buf = Box::new(PointBuffer::<MAX_LIDAR_POINTS>::new());
        let mut k = 0;
        b.iter(|| {
            k = (k + 1) % sweeps.len();
            black_box(buf.push_scan(black_box(&sweeps[k]), &ins, &cfg))
        })
    });

    let mut buf = Box::new(PointBuffer::<MAX_LIDAR_POINTS>::new());
    for s in &sweeps {
        buf.push_scan(s, &ins, &cfg);
    }
    assert_eq!(buf.len(), 5 * SWEEP);
    let t_kf = 510 * MS;
    let (p_wc, q_wc) = camera(t_kf);
    let acfg = AssociationConfig::default();
    let mut grid = Box::new(SphereGrid::<GRID_W, GRID_H>::new());
    c.bench_function("lidar_grid_build_50k_points", |b| {
        b.iter(|| black_box(grid.build(&buf, &p_wc, &q_wc, black_box(t_kf), &acfg)))
    });

    let st = grid.build(&buf, &p_wc, &q_wc, t_kf, &acfg);
    assert_eq!(st.points as usize, 5 * SWEEP);
    let bearings: Vec<Vec2> = (0..100)
        .map(|i| Vec2::new(-0.45 + 0.1 * (i % 10) as f64, -0.45 + 0.1 * (i / 10) as f64))
        .collect();
    let ok = bearings
        .iter()
        .filter(|x| grid.associate(x, &acfg).is_ok())
        .count();
    assert!(ok > 80, "only {ok} of 100 bearings associated");
    c.bench_function("lidar_associate_100_bearings", |b| {
        b.iter(|| {
            bearings
                .iter()
                .filter(|x| grid.associate(black_box(x), &acfg).is_ok())
                .count()
        })
    });
}

criterion_group!(benches, bench_lidar);
criterion_main!(benches);
