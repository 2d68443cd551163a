//! The solver on exact synthetic data: an accelerating, rotating trajectory seen by a camera
//! with a lever arm, and the degenerate starts it must refuse.
//! (Compiled only with `#[cfg(test)]`: the parent declares the module so.)

use super::*;
use crate::math::Quat;

type Init = MotionInitializer<10, 128, 1024>;
const G: f64 = 9.81;
const DT_NS: i64 = 5_000_000;
const SAMPLES: i64 = 340;

fn frame_times() -> impl Iterator<Item = i64> {
    // Not on the sample grid: the integration interpolates.
    (0..10).map(|k| 102_500_000 + k * 150_000_000)
}

fn ext() -> CameraExtrinsic {
    // Camera z along body x, a lever arm.
    let q_bc = quat_exp(&Vec3::new(0.0, core::f64::consts::FRAC_PI_2, 0.0))
        * quat_exp(&Vec3::new(0.0, 0.0, -core::f64::consts::FRAC_PI_2));
    CameraExtrinsic {
        p_bc: Vec3::new(0.05, 0.01, -0.02),
        q_bc,
    }
}

fn g_true() -> Vec3 {
    Vec3::new(0.8, -0.5, -9.7).normalize() * G
}

/// Deterministic numbers in [-1, 1].
fn lcg(state: &mut u64) -> f64 {
    *state = state
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    ((*state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
}

struct Case {
    signal: fn(f64) -> (Vec3, Vec3),
    v0: Vec3,
    bg: Vec3,
    /// The accelerometer's bias in the samples.
    ba: Vec3,
    landmarks: usize,
    range_m: f64,
}

fn accelerating(t: f64) -> (Vec3, Vec3) {
    let gyro = Vec3::new(
        0.3 * libm::sin(2.0 * t),
        0.4 * libm::cos(1.5 * t),
        0.2 + 0.1 * libm::sin(3.0 * t),
    );
    let f = Vec3::new(
        1.5 * libm::sin(2.5 * t),
        1.0 * libm::cos(1.7 * t) + 0.3,
        G + 0.8 * libm::sin(3.1 * t),
    );
    (gyro, f)
}

fn sample(case: &Case, k: i64) -> ImuSample {
    let (gyro, f) = (case.signal)(k as f64 * DT_NS as f64 * 1e-9);
    ImuSample {
        t_ns: k * DT_NS,
        gyro_rps: gyro + case.bg,
        accel_mps2: f + case.ba,
    }
}

/// The truth: the same integration over every frame.
fn truth(case: &Case) -> ([Pre; 10], Init) {
    let mut a = Init::new(MotionInitConfig::DEFAULT);
    let mut times = frame_times().peekable();
    for k in 0..SAMPLES {
        let s = sample(case, k);
        while let Some(t) = times.next_if(|t| *t <= s.t_ns) {
            assert!(a.push_frame(t, core::iter::empty()));
        }
        a.push_imu(&s);
    }
    let mut pre = [Pre::ZERO; 10];
    a.accel_bias = case.ba;
    a.integrate(&case.bg, &mut pre).unwrap();
    (pre, a)
}

/// Runs the initializer in time order; the first solution, or the last refusal.
fn run(case: &Case) -> Result<Option<(NavState, Solution)>, Refusal> {
    run_with_bias(case, &case.bg, None)
}

/// [`run`] with `bg` as the solver's gyro-bias guess, and `known_ba` (both biases known).
fn run_with_bias(
    case: &Case,
    bg: &Vec3,
    known_ba: Option<&Vec3>,
) -> Result<Option<(NavState, Solution)>, Refusal> {
    let (pre, _) = truth(case);
    let ext = ext();
    let r_bc = ext.q_bc.to_rotation_matrix().into_inner();
    let mut rng = 7u64;
    let mut pts = [Vec3::zeros(); 200];
    for p in pts.iter_mut().take(case.landmarks) {
        let (x, y, z) = (lcg(&mut rng), lcg(&mut rng), lcg(&mut rng));
        let c = Vec3::new(x * 0.6, y * 0.5, 1.0) * case.range_m * (1.5 + z);
        *p = pre[0].r * (r_bc * c + ext.p_bc);
    }
    let mut init = Init::new(MotionInitConfig::DEFAULT);
    let mut times = frame_times().enumerate().peekable();
    let mut last = Ok(None);
    for k in 0..SAMPLES {
        let s = sample(case, k);
        while let Some((i, t)) = times.next_if(|(_, t)| *t <= s.t_ns) {
            let p = &pre[i];
            let p_b = case.v0 * p.t_s + g_true() * (0.5 * p.t_s * p.t_s) + p.dp;
            let c = p_b + p.r * ext.p_bc;
            let r_b0c = p.r * r_bc;
            let obs = pts
                .iter()
                .take(case.landmarks)
                .enumerate()
                .filter_map(|(j, x)| {
                    let u = r_b0c.transpose() * (x - c);
                    (u.z > 0.2).then_some((j as u64 * 3 + 1, [u.x / u.z, u.y / u.z]))
                });
            init.push_frame(t, obs);
        }
        init.push_imu(&s);
        match init.try_solve(&ext, G, bg, known_ba) {
            Ok(Some(x)) => return Ok(Some(x)),
            Ok(None) => {}
            Err(e) => last = Err(e),
        }
    }
    last
}

fn moving() -> Case {
    Case {
        signal: accelerating,
        v0: Vec3::new(1.0, 0.3, -0.2),
        bg: Vec3::new(0.01, -0.02, 0.005),
        ba: Vec3::zeros(),
        landmarks: 120,
        range_m: 4.0,
    }
}

#[test]
fn recovers_velocity_and_gravity_exactly() {
    let case = moving();
    let (state, sol) = run(&case).unwrap().expect("must initialize");
    assert!((sol.v0_b0 - case.v0).norm() < 1e-6, "{:?}", sol.v0_b0);
    assert!((sol.g_b0 - g_true()).norm() < 1e-6, "{:?}", sol.g_b0);
    assert!((sol.g_norm_free_mps2 - G).abs() < 1e-6);
    assert!(sol.rms_sigmas < 1e-3 && sol.inlier_ratio == 1.0);
    // The state at the newest sample: leveled, with the velocity the truth has there.
    let end = sol.end;
    let g_end = end.r.transpose() * g_true();
    let g_w = state.q_wb * g_end;
    assert!((g_w - Vec3::new(0.0, 0.0, -G)).norm() < 1e-6, "{g_w:?}");
    let v_true = case.v0 + g_true() * end.t_s + end.dv;
    assert!((state.v_wb.norm() - v_true.norm()).abs() < 1e-6);
    assert!((state.bg - case.bg).norm() < 1e-9, "{:?}", state.bg);
    // Yaw zero: the body x axis of b0 has no world y component.
    let q_wb0 = state.q_wb * Quat::from_matrix(&end.r).inverse();
    assert!((q_wb0 * Vec3::x()).y.abs() < 1e-9);
}

#[test]
fn integrates_with_a_known_accelerometer_bias() {
    // 0.15 m/s^2 of accelerometer bias, as large as a calm flight's accelerations.
    let case = Case {
        ba: Vec3::new(0.1, -0.05, 0.1),
        ..moving()
    };
    let (state, sol) = run_with_bias(&case, &case.bg, Some(&case.ba))
        .unwrap()
        .expect("must initialize");
    assert!((sol.v0_b0 - case.v0).norm() < 1e-6, "{:?}", sol.v0_b0);
    assert!((sol.g_b0 - g_true()).norm() < 1e-6, "{:?}", sol.g_b0);
    assert_eq!((state.bg, state.ba), (case.bg, case.ba));
    // Known biases are held: a wrong gyro bias stays wrong.
    let wrong = case.bg + Vec3::new(0.002, 0.0, 0.0);
    let (held, _) = run_with_bias(&case, &wrong, Some(&case.ba))
        .unwrap()
        .expect("a small error still starts");
    assert_eq!(held.bg, wrong);
    // Not told it, the solve takes part of it for gravity (0.05 m/s^2: a 0.3 degree tilt).
    let (blind, sol) = run_with_bias(&case, &case.bg, None)
        .unwrap()
        .expect("must initialize");
    assert!((sol.g_b0 - g_true()).norm() > 0.03, "{:?}", sol.g_b0);
    assert_eq!(blind.ba, Vec3::zeros());
}

#[test]
fn estimates_the_gyro_bias() {
    // The solver starts from a zero gyro bias; the truth is 23 mrad/s.
    let case = moving();
    let (state, sol) = run_with_bias(&case, &Vec3::zeros(), None)
        .unwrap()
        .expect("must initialize");
    assert!((sol.bg - case.bg).norm() < 1e-6, "{:?}", sol.bg);
    assert_eq!(state.bg, sol.bg);
    assert!((sol.v0_b0 - case.v0).norm() < 1e-5, "{:?}", sol.v0_b0);
    assert!((sol.g_b0 - g_true()).norm() < 1e-5, "{:?}", sol.g_b0);
}

#[test]
fn refuses_rest_and_pure_rotation() {
    fn rotating(t: f64) -> (Vec3, Vec3) {
        // Constant rate about a fixed axis: R(t) = Exp(w t); the specific force cancels gravity.
        let w = Vec3::new(0.3, -0.2, 0.5);
        (w, -(exp_so3(&(w * t)).transpose() * g_true()))
    }
    fn resting(_: f64) -> (Vec3, Vec3) {
        (Vec3::zeros(), -g_true())
    }
    let case = |signal| Case {
        signal,
        v0: Vec3::zeros(),
        bg: Vec3::zeros(),
        ba: Vec3::zeros(),
        landmarks: 120,
        range_m: 4.0,
    };
    assert_eq!(run(&case(resting)).err(), Some(Refusal::LowParallax));
    // The lever arm gives the nearest points a little parallax: too few of them, or (when
    // enough pass) a velocity whose scale nothing observes.
    let r = run(&case(rotating)).err();
    assert!(
        matches!(r, Some(Refusal::LowParallax | Refusal::IllConditioned)),
        "{r:?}"
    );
}

#[test]
fn refuses_constant_velocity() {
    fn cruising(_: f64) -> (Vec3, Vec3) {
        (Vec3::zeros(), -g_true())
    }
    let case = Case {
        signal: cruising,
        v0: Vec3::new(3.0, 0.5, 0.0),
        bg: Vec3::zeros(),
        ba: Vec3::zeros(),
        landmarks: 120,
        range_m: 4.0,
    };
    assert_eq!(run(&case).err(), Some(Refusal::IllConditioned));
}

#[test]
fn refuses_too_few_tracks() {
    let case = Case {
        landmarks: 12,
        ..moving()
    };
    assert_eq!(run(&case).err(), Some(Refusal::TooFewTracks));
}

#[test]
fn garbage_never_panics() {
    let mut init = Init::new(MotionInitConfig {
        min_frames: 3,
        min_tracks: 3,
        ..MotionInitConfig::DEFAULT
    });
    let mut rng = 3u64;
    let bad = [
        f64::NAN,
        f64::INFINITY,
        -f64::INFINITY,
        1e300,
        -1e300,
        0.0,
        1e-300,
    ];
    for k in 0..400i64 {
        let t = k * DT_NS;
        if k % 20 == 0 {
            let obs = (0..100u64).map(|j| {
                let a = lcg(&mut rng);
                let pick = |v: f64| bad[((v.abs() * 1e6) as usize) % bad.len()];
                let x = if a > 0.5 {
                    [pick(a), a]
                } else {
                    [a * 3.0, lcg(&mut rng)]
                };
                (j % 40, x)
            });
            init.push_frame(t, obs);
        }
        let v = lcg(&mut rng);
        let s = ImuSample {
            t_ns: t,
            gyro_rps: Vec3::new(v * 30.0, bad[k as usize % bad.len()], 0.1),
            accel_mps2: Vec3::new(v * 1e3, 9.81, 1e200),
        };
        init.push_imu(&s);
        for g in [G, f64::NAN, -1.0] {
            if let Ok(Some((st, _))) = init.try_solve(&ext(), g, &Vec3::zeros(), None) {
                assert!(st.v_wb.iter().all(|x| x.is_finite()));
            }
        }
    }
}
