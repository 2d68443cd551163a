//! Criterion benches of the inertial layer (filled by the inertial issue).
use criterion::{criterion_group, criterion_main, Criterion};

fn bench_placeholder(c: &mut Criterion) {
    c.bench_function("so3_exp", |b| {
        let phi = nalgebra::Vector3::new(0.1, -0.2, 0.3);
        b.iter(|| povins::core::math::quat_exp(std::hint::black_box(&phi)))
    });
}

criterion_group!(benches, bench_placeholder);
criterion_main!(benches);
