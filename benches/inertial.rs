//! Criterion benches of the inertial layer: INS propagation and preintegration per IMU sample,
//! and the whitened residual + Jacobian evaluation of one preintegration factor.
use criterion::{criterion_group, criterion_main, Criterion};
use povins::core::inertial::{
    ImuNoise, ImuSample, Ins, InsConfig, Mat15, NavState, PreintConfig, Preintegration, Vec15,
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

criterion_group!(benches, bench_ins, bench_preint);
criterion_main!(benches);
