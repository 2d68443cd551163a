//! Shared loaders for the inertial data tests: EuRoC IMU / ground-truth CSVs and the comma2k19
//! highway segment, plus ground-truth interpolation. Missing data fails loudly.
#![allow(dead_code)]

use nalgebra::{Matrix3, Quaternion};
use povins_core::inertial::{ImuSample, NavState};
use povins_core::math::{log_so3, quat_exp, Quat, Vec3};
use std::path::PathBuf;

/// The repository's small test data (`tests/data`, see its README).
pub fn data_dir() -> PathBuf {
    let p = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../tests/data"));
    assert!(p.is_dir(), "test data folder {} is missing", p.display());
    p
}

/// EuRoC V1_01's whole-flight IMU and ground truth (`euroc-v101-images-at-rest` without images).
pub fn euroc_dir() -> PathBuf {
    data_dir().join("euroc-v101-imu-145s/mav0")
}

fn read_lines(path: &PathBuf) -> Vec<String> {
    let text = std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    text.lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .map(String::from)
        .collect()
}

fn nums(l: &str, sep: char) -> Vec<f64> {
    l.split(sep)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.trim()
                .parse::<f64>()
                .unwrap_or_else(|_| panic!("bad number {s:?} in {l:?}"))
        })
        .collect()
}

/// EuRoC `imu0/data.csv`.
pub fn euroc_imu() -> Vec<ImuSample> {
    read_lines(&euroc_dir().join("imu0/data.csv"))
        .iter()
        .map(|l| {
            let t_ns: i64 = l.split(',').next().unwrap().trim().parse().unwrap();
            let v = nums(l, ',');
            ImuSample {
                t_ns,
                gyro_rps: Vec3::new(v[1], v[2], v[3]),
                accel_mps2: Vec3::new(v[4], v[5], v[6]),
            }
        })
        .collect()
}

/// EuRoC `state_groundtruth_estimate0/data.csv`.
pub fn euroc_gt() -> Vec<NavState> {
    read_lines(&euroc_dir().join("state_groundtruth_estimate0/data.csv"))
        .iter()
        .map(|l| {
            let t_ns: i64 = l.split(',').next().unwrap().trim().parse().unwrap();
            let v = nums(l, ',');
            NavState {
                t_ns,
                p_wb: Vec3::new(v[1], v[2], v[3]),
                q_wb: Quat::from_quaternion(Quaternion::new(v[4], v[5], v[6], v[7])),
                v_wb: Vec3::new(v[8], v[9], v[10]),
                bg: Vec3::new(v[11], v[12], v[13]),
                ba: Vec3::new(v[14], v[15], v[16]),
            }
        })
        .collect()
}

/// Ground truth at `t_ns` (linear in p, v, biases; slerp in q); `None` outside its span.
pub fn interp(gt: &[NavState], t_ns: i64) -> Option<NavState> {
    let k = gt.partition_point(|s| s.t_ns < t_ns);
    if k >= gt.len() {
        return None;
    }
    if gt[k].t_ns == t_ns {
        return Some(gt[k]);
    }
    if k == 0 {
        return None;
    }
    let (a, b) = (&gt[k - 1], &gt[k]);
    let s = (t_ns - a.t_ns) as f64 / (b.t_ns - a.t_ns) as f64;
    let lin = |x: &Vec3, y: &Vec3| x * (1.0 - s) + y * s;
    Some(NavState {
        t_ns,
        p_wb: lin(&a.p_wb, &b.p_wb),
        q_wb: a.q_wb * quat_exp(&(log_so3(&(a.q_wb.inverse() * b.q_wb)) * s)),
        v_wb: lin(&a.v_wb, &b.v_wb),
        bg: lin(&a.bg, &b.bg),
        ba: lin(&a.ba, &b.ba),
    })
}

/// comma2k19 highway segment converted to the core's conventions: world ENU (z up) anchored
/// at the first pose, body = device frame (x fwd, y right, z down) as the IMU reports it.
pub struct Comma {
    pub imu: Vec<ImuSample>,
    /// Pose and velocity; biases zero (unknown).
    pub gt: Vec<NavState>,
}

fn secs_to_ns(s: &str) -> i64 {
    let (i, f) = s.split_once('.').unwrap_or((s, ""));
    let mut frac = String::from(f);
    while frac.len() < 9 {
        frac.push('0');
    }
    i.parse::<i64>().unwrap() * 1_000_000_000 + frac[..9].parse::<i64>().unwrap()
}

pub fn comma() -> Comma {
    let dir = data_dir().join("comma2k19-highway-imu");
    let imu = read_lines(&dir.join("imu.csv"))
        .iter()
        .map(|l| {
            let t_ns = secs_to_ns(l.split(',').next().unwrap().trim());
            let v = nums(l, ',');
            ImuSample {
                t_ns,
                gyro_rps: Vec3::new(v[1], v[2], v[3]),
                accel_mps2: Vec3::new(v[4], v[5], v[6]),
            }
        })
        .collect();
    // lat0/lon0 of the local NED frame from the TUM header.
    let tum_path = dir.join("groundtruth_local_ned_tum.txt");
    let header = std::fs::read_to_string(&tum_path).unwrap();
    let h = header.lines().next().unwrap();
    let grab = |key: &str| -> f64 {
        let s = &h[h.find(key).unwrap() + key.len()..];
        s.split_whitespace().next().unwrap().parse().unwrap()
    };
    let (lat, lon) = (grab("lat0=").to_radians(), grab("lon0=").to_radians());
    let (sl, cl, so, co) = (lat.sin(), lat.cos(), lon.sin(), lon.cos());
    let r_ned_ecef = Matrix3::new(
        -sl * co,
        -sl * so,
        cl, //
        -so,
        co,
        0.0, //
        -cl * co,
        -cl * so,
        -sl,
    );
    let r_enu_ned = Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0);
    let q_enu_ned = Quat::from_matrix(&r_enu_ned);
    let tum = read_lines(&tum_path);
    let ecef = read_lines(&dir.join("groundtruth_ecef.csv"));
    assert_eq!(
        tum.len(),
        ecef.len(),
        "TUM and ECEF ground truth differ in length"
    );
    let gt = tum
        .iter()
        .zip(ecef.iter())
        .map(|(lt, le)| {
            let t_ns = secs_to_ns(lt.split_whitespace().next().unwrap());
            assert_eq!(t_ns, secs_to_ns(le.split(',').next().unwrap()));
            let v = nums(lt, ' ');
            let e = nums(le, ',');
            let q_ned_b = Quat::from_quaternion(Quaternion::new(v[7], v[4], v[5], v[6]));
            let v_ned = r_ned_ecef * Vec3::new(e[8], e[9], e[10]);
            NavState {
                t_ns,
                p_wb: r_enu_ned * Vec3::new(v[1], v[2], v[3]),
                q_wb: q_enu_ned * q_ned_b,
                v_wb: r_enu_ned * v_ned,
                bg: Vec3::zeros(),
                ba: Vec3::zeros(),
            }
        })
        .collect();
    Comma { imu, gt }
}

/// Rotation angle between two attitudes, rad.
pub fn att_err(a: &Quat, b: &Quat) -> f64 {
    log_so3(&(a.inverse() * *b)).norm()
}
