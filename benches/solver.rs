//! Criterion benches of the dense solver at sliding-window size (D = 166), of the camera
//! resection run once after a bridged IMU gap (`landmarks::resection`, a full window's 200
//! landmarks), and of the relative rotation run at each frame of an IMU outage
//! (`landmarks::relative_rotation`).
use criterion::{criterion_group, criterion_main, Criterion};
use povins::core::solver::{
    add_prior, schur_complement_in_place, sqrt_prior, JacobianBlock, Ldlt, NormalEquations,
    PivotFloor,
};
use std::hint::black_box;

const D: usize = 166;

/// Deterministic pseudo-random numbers in [-1, 1).
struct Rng(u64);
impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
}

/// 200 landmarks x 4 observations, each a 2-row residual over 3 pose blocks of width 6.
struct Observations {
    r: Vec<[f64; 2]>,
    jac: Vec<[[f64; 12]; 3]>,
    cols: Vec<[usize; 3]>,
}

fn observations(rng: &mut Rng) -> Observations {
    let mut o = Observations {
        r: vec![],
        jac: vec![],
        cols: vec![],
    };
    for l in 0..200 {
        for k in 0..4 {
            let host = l % 10;
            let anchor = (host + 1 + k % 3) % 10;
            let target = (host + 2 + k) % 10;
            o.r.push([rng.uniform(), rng.uniform()]);
            let mut j = [[0.0; 12]; 3];
            j.iter_mut().flatten().for_each(|v| *v = rng.uniform());
            o.jac.push(j);
            let target = if target == anchor || target == host {
                (target + 5) % 10
            } else {
                target
            };
            o.cols.push([15 * host, 15 * anchor, 15 * target]);
        }
    }
    o
}

fn accumulate(ne: &mut NormalEquations<D>, o: &Observations) {
    ne.reset(D).unwrap();
    for ((r, j), c) in o.r.iter().zip(&o.jac).zip(&o.cols) {
        let blocks = [
            JacobianBlock::new(c[0], 6, &j[0]),
            JacobianBlock::new(c[1], 6, &j[1]),
            JacobianBlock::new(c[2], 6, &j[2]),
        ];
        ne.add_blocks(r, &blocks).unwrap();
    }
    // IMU-like chain and a weak diagonal so every state is observed.
    for i in 0..D {
        ne.add_to_diagonal(i, 1.0).unwrap();
    }
}

fn bench_solver(c: &mut Criterion) {
    let mut rng = Rng(0x1234_5678_9abc_def1);
    let obs = observations(&mut rng);
    let mut ne = Box::new(NormalEquations::<D>::new());
    c.bench_function("solver/accumulate_800x2x18_d166", |b| {
        b.iter(|| accumulate(&mut ne, black_box(&obs)))
    });
    accumulate(&mut ne, &obs);

    let mut f = Box::new(Ldlt::<D>::new());
    let mut x = vec![0.0; D];
    c.bench_function("solver/ldlt_factor_solve_166", |b| {
        b.iter(|| {
            f.load(&ne).unwrap();
            let rep = f.factorize(PivotFloor::DEFAULT).unwrap();
            x.copy_from_slice(&ne.b[..D]);
            f.solve_in_place(&mut x).unwrap();
            black_box(rep)
        })
    });

    let mut work = Box::new(NormalEquations::<D>::new());
    c.bench_function("solver/schur_16_of_166", |b| {
        b.iter(|| {
            work.copy_from(&ne);
            black_box(schur_complement_in_place(&mut work, 16, PivotFloor::DEFAULT).unwrap())
        })
    });

    let mut j0 = Box::new([[0.0; D]; D]);
    let mut r0 = vec![0.0; D - 16];
    c.bench_function("solver/sqrt_prior_150", |b| {
        b.iter(|| {
            black_box(sqrt_prior(&work, PivotFloor::DEFAULT, &mut f, &mut j0, &mut r0).unwrap())
        })
    });

    let cols: Vec<usize> = (0..D - 16).collect();
    let dx = vec![1e-3; D - 16];
    let mut target = Box::new(NormalEquations::<D>::new());
    c.bench_function("solver/add_prior_150", |b| {
        b.iter(|| {
            target.reset(D).unwrap();
            add_prior(&mut target, &j0, &r0, &dx, &cols).unwrap();
        })
    });
}

/// The resection from 0.3 rad and 0.3 m off: 200 landmarks 2-8 m away, 1 px of noise at 460 px,
/// every tenth a wrong track 20-40 px off (the worst case the estimator hands it: `L` = 200).
fn bench_resection(c: &mut Criterion) {
    use povins::core::camera::CameraPose;
    use povins::core::landmarks::resection::fit_camera_pose;
    use povins::core::math::{quat_exp, Quat, Vec3};
    let mut rng = Rng(0x0bad_cafe_1234_5678);
    let truth = CameraPose {
        p_wc: Vec3::new(1.0, -2.0, 0.5),
        q_wc: Quat::from_euler_angles(0.3, -0.2, 1.0),
    };
    let focal = 460.0;
    let pts: Vec<(Vec3, [f64; 2])> = (0..200)
        .map(|k| {
            let p_c = Vec3::new(
                2.0 * rng.uniform(),
                1.5 * rng.uniform(),
                5.0 + 3.0 * rng.uniform(),
            );
            let mut x = [
                p_c.x / p_c.z + rng.uniform() / focal,
                p_c.y / p_c.z + rng.uniform() / focal,
            ];
            if k % 10 == 0 {
                x[0] += (30.0 + 10.0 * rng.uniform()) / focal;
            }
            (truth.q_wc * p_c + truth.p_wc, x)
        })
        .collect();
    let init = CameraPose {
        p_wc: truth.p_wc + Vec3::new(0.2, -0.15, 0.15),
        q_wc: truth.q_wc * quat_exp(&Vec3::new(0.2, -0.15, 0.15)),
    };
    let fit = fit_camera_pose(&pts, &init, focal).expect("a fit");
    assert!(fit.inliers >= 175 && (fit.pose.p_wc - truth.p_wc).norm() < 0.05);
    c.bench_function("resection/fit_200_points", |b| {
        b.iter(|| black_box(fit_camera_pose(black_box(&pts), &init, focal)))
    });
}

/// The relative rotation of one frame of the outage chain (`landmarks::relative_rotation`): 200
/// common tracks of landmarks 1.5-8 m away, a 10 cm forward and 3 cm sideways move and a
/// 5-degree turn, 1 px of noise at 460 px, every twentieth a wrong track; started at identity.
fn bench_relative_rotation(c: &mut Criterion) {
    use povins::core::landmarks::relative_rotation::fit_relative_rotation;
    use povins::core::math::{log_so3, quat_exp, Quat, Vec3};
    let mut rng = Rng(0x5eed_0f0a_7a9e);
    let q_ab = quat_exp(&Vec3::new(0.03, 0.07, -0.02));
    let t_ab = Vec3::new(0.03, 0.0, 0.1);
    let focal = 460.0;
    let pairs: Vec<(Vec3, Vec3)> = (0..200)
        .map(|k| {
            let p_a = Vec3::new(
                3.0 * rng.uniform(),
                2.0 * rng.uniform(),
                4.75 + 3.25 * rng.uniform(),
            );
            let p_b = q_ab.inverse() * (p_a - t_ab);
            let mut bearing = |p: Vec3| {
                Vec3::new(
                    p.x / p.z + rng.uniform() / focal,
                    p.y / p.z + rng.uniform() / focal,
                    1.0,
                )
                .normalize()
            };
            let a = bearing(p_a);
            let b = if k % 20 == 0 {
                Vec3::new(0.5 * rng.uniform(), 0.4 * rng.uniform(), 1.0).normalize()
            } else {
                bearing(p_b)
            };
            (a, b)
        })
        .collect();
    let sigma = 1.0 / focal;
    let fit = fit_relative_rotation(&pairs, &Quat::identity(), sigma).expect("a fit");
    assert!(
        log_so3(&(fit.q_ab.inverse() * q_ab)).norm() < 0.01,
        "{fit:?}"
    );
    c.bench_function("relative_rotation/fit_200_tracks", |b| {
        b.iter(|| {
            black_box(fit_relative_rotation(
                black_box(&pairs),
                &Quat::identity(),
                sigma,
            ))
        })
    });
}

criterion_group!(
    benches,
    bench_solver,
    bench_resection,
    bench_relative_rotation
);
criterion_main!(benches);
