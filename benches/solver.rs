//! Criterion benches of the dense solver at sliding-window size (D = 166).
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

criterion_group!(benches, bench_solver);
criterion_main!(benches);
