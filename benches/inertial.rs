//! Criterion benches of the inertial layer: INS propagation and preintegration per IMU sample,
//! the whitened residual + Jacobian evaluation of one preintegration factor, and the in-motion
//! initializer's solve at the estimator's capacities (its worst case per keyframe).
use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use povins::core::camera::CameraExtrinsic;
use povins::core::estimator::{INIT_SAMPLES, MAX_FEATURES, MOTION_INIT_FRAMES};
use povins::core::inertial::{
    ImuNoise, ImuSample, Ins, InsConfig, Mat15, MotionInitConfig, MotionInitializer, NavState,
    PreintConfig, Preintegration, Vec15,
};
use povins::core::math::{quat_exp, Vec3};
use std::hint::black_box;

fn sample(k: i64) -> ImuSample {
    let t = k as f64 * 0.005;
    ImuSample {
        t_ns: k * 5_000_000,
        gyro_rps: Vec3::new(0.5 * (1.3 * t).sin(), 0.3 * (0.7 * t).cos(), 0.2),
        accel_mps2: Vec3::new(1.0 + t.sin(), 0.5 * (2.0 * t).cos(), 9.81),
    }
}

fn bench_ins(c: &mut Criterion) {
    let samples: Vec<ImuSample> = (0..100_000).map(sample).collect();
    c.bench_function("ins_propagate_per_sample", |b| {
        let mut ins = Ins::new(InsConfig::DEFAULT, NavState::identity(0)).unwrap();
        let mut k = 0usize;
        b.iter(|| {
            k += 1;
            if k == samples.len() {
                k = 1;
                ins = Ins::new(InsConfig::DEFAULT, NavState::identity(0)).unwrap();
            }
            black_box(ins.propagate(black_box(&samples[k])).is_ok())
        })
    });
}

fn bench_preint(c: &mut Criterion) {
    let samples: Vec<ImuSample> = (0..201).map(sample).collect();
    let mut pre = Box::new(
        Preintegration::<256>::new(
            ImuNoise::EUROC_ADIS16448,
            PreintConfig::DEFAULT,
            &samples[0],
            Vec3::zeros(),
            Vec3::zeros(),
        )
        .unwrap(),
    );
    c.bench_function("preintegration_push_per_sample", |b| {
        let mut k = 0usize;
        b.iter(|| {
            k += 1;
            if k == samples.len() {
                k = 1;
                pre.reset(&samples[0], Vec3::zeros(), Vec3::zeros())
                    .unwrap();
            }
            black_box(pre.push(black_box(&samples[k])).is_ok())
        })
    });

    pre.reset(&samples[0], Vec3::zeros(), Vec3::zeros())
        .unwrap();
    for s in &samples[1..101] {
        pre.push(s).unwrap();
    }
    let xi = NavState::identity(0);
    let xj = NavState {
        p_wb: Vec3::new(0.3, 0.1, 0.0),
        q_wb: quat_exp(&Vec3::new(0.1, 0.0, 0.2)),
        v_wb: Vec3::new(0.5, 0.1, 0.0),
        ..NavState::identity(500_000_000)
    };
    let (mut r, mut ji, mut jj) = (
        Box::new(Vec15::zeros()),
        Box::new(Mat15::zeros()),
        Box::new(Mat15::zeros()),
    );
    c.bench_function("preintegration_evaluate_whitened", |b| {
        b.iter(|| {
            black_box(
                pre.evaluate(
                    black_box(&xi),
                    black_box(&xj),
                    9.81,
                    &mut r,
                    &mut ji,
                    &mut jj,
                )
                .is_ok(),
            )
        })
    });
    c.bench_function("preintegration_evaluate_raw", |b| {
        b.iter(|| {
            black_box(
                pre.evaluate_raw(
                    black_box(&xi),
                    black_box(&xj),
                    9.81,
                    &mut r,
                    &mut ji,
                    &mut jj,
                )
                .is_ok(),
            )
        })
    });
}

/// The estimator's in-motion initializer, full: `MOTION_INIT_FRAMES` init frames 0.2 s apart,
/// each seeing all `MAX_FEATURES` tracks, and `INIT_SAMPLES` IMU samples at 500 Hz, on an exact
/// accelerating and rotating trajectory (so the solve runs to the end: the linear solve, the
/// sphere refinement and the gyro bias's Gauss-Newton, and returns a state). The estimator
/// tries at most one such solve per keyframe while it waits to start.
fn bench_motion_init(c: &mut Criterion) {
    type Init = MotionInitializer<MOTION_INIT_FRAMES, MAX_FEATURES, INIT_SAMPLES>;
    const DT_NS: i64 = 2_000_000;
    let w_b = Vec3::new(0.05, 0.1, 0.2);
    // Body pose at t: R_wb = exp(w t), p_wb analytic; the specific force follows exactly.
    let p_wb = |t: f64| {
        Vec3::new(
            t + 0.5 * (2.0 * t).sin(),
            0.3 * (3.0 * t).sin(),
            0.2 * (2.5 * t).sin(),
        )
    };
    let a_w = |t: f64| {
        Vec3::new(
            -2.0 * (2.0 * t).sin(),
            -2.7 * (3.0 * t).sin(),
            -1.25 * (2.5 * t).sin(),
        )
    };
    // Camera z along body x, with a lever arm.
    let ext = CameraExtrinsic {
        p_bc: Vec3::new(0.05, 0.01, -0.02),
        q_bc: quat_exp(&Vec3::new(0.0, std::f64::consts::FRAC_PI_2, 0.0))
            * quat_exp(&Vec3::new(0.0, 0.0, -std::f64::consts::FRAC_PI_2)),
    };
    let mut seed = 7u64;
    let mut rnd = move || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    let landmarks: Vec<Vec3> = (0..MAX_FEATURES)
        .map(|_| Vec3::new(6.0 + 4.0 * rnd(), 6.0 * rnd() - 3.0, 4.0 * rnd() - 2.0))
        .collect();
    let mut init = Box::new(Init::new(MotionInitConfig::DEFAULT));
    let frame_ns = |k: i64| 1_000_000 + k * 200_000_000;
    let mut next_frame = 0i64;
    for k in 0..INIT_SAMPLES as i64 {
        let t_ns = k * DT_NS;
        while next_frame < MOTION_INIT_FRAMES as i64 && frame_ns(next_frame) <= t_ns {
            let tf = frame_ns(next_frame) as f64 * 1e-9;
            let q_wb = quat_exp(&(w_b * tf));
            let obs = landmarks.iter().enumerate().filter_map(|(id, x_w)| {
                let x_b = q_wb.inverse() * (x_w - p_wb(tf));
                let x_c = ext.q_bc.inverse() * (x_b - ext.p_bc);
                (x_c.z > 0.1).then(|| (id as u64, [x_c.x / x_c.z, x_c.y / x_c.z]))
            });
            assert!(init.push_frame(frame_ns(next_frame), obs));
            next_frame += 1;
        }
        let t = t_ns as f64 * 1e-9;
        let q_wb = quat_exp(&(w_b * t));
        init.push_imu(&ImuSample {
            t_ns,
            gyro_rps: w_b,
            accel_mps2: q_wb.inverse() * (a_w(t) + Vec3::new(0.0, 0.0, 9.81)),
        });
    }
    assert_eq!(init.frames(), MOTION_INIT_FRAMES);
    let solved = init.clone().try_solve(&ext, 9.81, &Vec3::zeros(), None);
    assert!(
        matches!(solved, Ok(Some(_))),
        "the worst case must run the whole solve: {solved:?}"
    );
    c.bench_function("motion_init_solve_full", |b| {
        b.iter_batched_ref(
            || init.clone(),
            |i| black_box(i.try_solve(&ext, 9.81, &Vec3::zeros(), None).is_ok()),
            BatchSize::LargeInput,
        )
    });
}

criterion_group!(benches, bench_ins, bench_preint, bench_motion_init);
criterion_main!(benches);
