//! Preintegration consistency on a real car (comma2k19 highway segment, phone IMU at ~104 Hz,
//! comma's post-processed GNSS/INS pose as ground truth).
//!
//! Frames: the world is ENU anchored at the first pose (converted from the local NED of the TUM
//! file, velocity from the ECEF file rotated into that NED), so gravity is along -z as the core
//! expects; the body is the device frame (x forward, y right, z down), in which the IMU reports
//! specific force `(0, 0, -g)` at rest. Earth rotation and Coriolis (~2.5e-3 m/s^2 at 17 m/s) are
//! neglected; they are far below the vibration noise.
//!
//! Noise model (phone IMU, no datasheet): effective white-noise densities from the data,
//! `std(x_k - x_{k-1}) / sqrt(2) * sqrt(dt)` per axis (rms over axes): first differences at
//! 104 Hz remove the slow car dynamics and keep sensor noise plus road/engine vibration, which is
//! what the preintegration must treat as noise. Bias random walks: 1e-4 rad/s^2/sqrt(Hz) and
//! 1e-3 m/s^3/sqrt(Hz) (consumer MEMS class; negligible over <= 1 s windows next to the white
//! noise). Gyro: comma already removed its bias (bg = 0). Accel bias: unknown, so it is
//! estimated as one constant by least squares on the velocity residuals of all windows
//! (`r_v(ba) ~ r_v(0) - J_v_ba ba`) and then used as the linearization bias; the NSE is reported
//! with and without it.

mod inertial_common;

use inertial_common::{comma, interp};
use nalgebra::{Matrix3, SMatrix, SVector};
use povins_core::inertial::{
    ImuNoise, ImuSample, Mat15, NavState, PreintConfig, Preintegration, Vec15,
};
use povins_core::math::Vec3;

const G: f64 = 9.81;

fn diff_density(imu: &[ImuSample], f: impl Fn(&ImuSample) -> Vec3) -> f64 {
    let mut var = 0.0;
    let mut dt_sum = 0.0;
    for w in imu.windows(2) {
        var += (f(&w[1]) - f(&w[0])).norm_squared();
        dt_sum += (w[1].t_ns - w[0].t_ns) as f64 * 1e-9;
    }
    let n = (imu.len() - 1) as f64;
    let sigma = (var / (3.0 * n) / 2.0).sqrt();
    sigma * (dt_sum / n).sqrt()
}

fn nse<const D: usize>(cov: &Mat15, r: &Vec15, o: usize) -> f64 {
    let p: SMatrix<f64, D, D> = cov.fixed_view::<D, D>(o, o).into_owned();
    let rr: SVector<f64, D> = r.fixed_rows::<D>(o).into_owned();
    let x = p.cholesky().expect("block covariance is PD").solve(&rr);
    rr.dot(&x)
}

/// Consecutive windows of 0.3-1 s: `(start, end)` sample indices with ground truth at both ends.
fn windows(imu: &[ImuSample], gt: &[NavState]) -> Vec<(usize, usize)> {
    let lengths = [31usize, 52, 73, 104];
    let mut out = Vec::new();
    let (mut start, mut k) = (0usize, 0usize);
    while start + 104 < imu.len() {
        let end = start + lengths[k % lengths.len()];
        k += 1;
        if interp(gt, imu[start].t_ns).is_some() && interp(gt, imu[end].t_ns).is_some() {
            out.push((start, end));
        }
        start = end;
    }
    out
}

struct Run {
    all: f64,
    p: f64,
    v: f64,
    th: f64,
    /// `sum J_v_ba^T J_v_ba`, `sum J_v_ba^T r_v` for the accel-bias least squares.
    jtj: Matrix3<f64>,
    jtr: Vec3,
    n: usize,
}

fn run(imu: &[ImuSample], gt: &[NavState], noise: ImuNoise, ba: Vec3) -> Run {
    let mut out = Run {
        all: 0.0,
        p: 0.0,
        v: 0.0,
        th: 0.0,
        jtj: Matrix3::zeros(),
        jtr: Vec3::zeros(),
        n: 0,
    };
    let (mut r, mut ji, mut jj) = (Vec15::zeros(), Mat15::zeros(), Mat15::zeros());
    let cfg = PreintConfig {
        max_dt_s: 0.05,
        ..PreintConfig::DEFAULT
    };
    for (s, e) in windows(imu, gt) {
        let mut xi = interp(gt, imu[s].t_ns).unwrap();
        let mut xj = interp(gt, imu[e].t_ns).unwrap();
        xi.ba = ba;
        xj.ba = ba;
        let mut pre = Preintegration::<128>::new(noise, cfg, &imu[s], Vec3::zeros(), ba).unwrap();
        for smp in &imu[s + 1..=e] {
            pre.push(smp).unwrap();
        }
        pre.evaluate_raw(&xi, &xj, G, &mut r, &mut ji, &mut jj)
            .unwrap();
        let cov = pre.covariance();
        out.all += nse::<9>(cov, &r, 0);
        out.p += nse::<3>(cov, &r, 0);
        out.v += nse::<3>(cov, &r, 3);
        out.th += nse::<3>(cov, &r, 6);
        let jv = pre.bias_jacobians().3;
        out.jtj += jv.transpose() * jv;
        out.jtr += jv.transpose() * r.fixed_rows::<3>(3);
        out.n += 1;
    }
    let n = out.n as f64;
    out.all /= n;
    out.p /= n;
    out.v /= n;
    out.th /= n;
    out
}

#[test]
fn car_preintegration_covariance_is_consistent() {
    let data = comma();
    let (imu, gt) = (&data.imu, &data.gt);
    assert!(imu.len() > 6000 && gt.len() > 1100);
    // Ground-truth velocity (from ECEF) agrees with differenced positions: frames are right.
    let mut dv_max = 0.0f64;
    for w in gt.windows(3) {
        let fd = (w[2].p_wb - w[0].p_wb) / ((w[2].t_ns - w[0].t_ns) as f64 * 1e-9);
        dv_max = dv_max.max((fd - w[1].v_wb).norm());
    }
    assert!(
        dv_max < 0.5,
        "GT velocity vs differenced position: {dv_max} m/s"
    );

    let g_d = diff_density(imu, |s| s.gyro_rps);
    let a_d = diff_density(imu, |s| s.accel_mps2);
    let noise = ImuNoise {
        gyro_noise_density: g_d,
        accel_noise_density: a_d,
        gyro_bias_rw: 1e-4,
        accel_bias_rw: 1e-3,
        bias_corr_time_s: None,
    };
    let zero = run(imu, gt, noise, Vec3::zeros());
    // r_v(ba) = r_v(0) - J ba  =>  ba = (J^T J)^-1 J^T r_v(0).
    let ba = zero.jtj.try_inverse().unwrap() * zero.jtr;
    let est = run(imu, gt, noise, ba);
    println!(
        "comma2k19: effective densities gyro {g_d:.2e} rad/s/sqrt(Hz), accel {a_d:.2e} m/s^2/sqrt(Hz); \
         GT velocity vs differenced positions max {dv_max:.3} m/s; estimated accel bias {:?} m/s^2"
        , ba.as_slice()
    );
    for (label, r) in [("ba = 0", &zero), ("ba estimated", &est)] {
        println!(
            "comma2k19 preintegration NSE, {label}, {} windows (0.3-1 s): 9-dof {:.2} (ideal 9), \
             dp {:.2}, dv {:.2}, dtheta {:.2} (ideal 3 each)",
            r.n, r.all, r.p, r.v, r.th
        );
    }
    assert!(est.n > 80);
    // Removing the bias must help the velocity block.
    assert!(est.v < zero.v);
    // Consistency band with the estimated bias: [0.2, 5] x dof, overall and per block.
    assert!((1.8..=45.0).contains(&est.all), "9-dof NSE {}", est.all);
    for (name, x) in [("dp", est.p), ("dv", est.v), ("dtheta", est.th)] {
        assert!((0.6..=15.0).contains(&x), "{name} NSE {x}");
    }
}
