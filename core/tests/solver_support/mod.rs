//! Shared helpers of the solver integration tests: a deterministic RNG and an independent dense
#![allow(clippy::needless_range_loop)] // dense reference math reads best with indices
//! reference (Gaussian elimination with partial pivoting on `Vec`s).
#![allow(dead_code)]

use povins_core::solver::NormalEquations;

/// xorshift64* : deterministic, good enough for test matrices.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    /// Uniform in [-1, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
}

pub type Dense = Vec<Vec<f64>>;

pub fn zeros(r: usize, c: usize) -> Dense {
    vec![vec![0.0; c]; r]
}

pub fn random(rng: &mut Rng, r: usize, c: usize) -> Dense {
    (0..r)
        .map(|_| (0..c).map(|_| rng.uniform()).collect())
        .collect()
}

/// `A^T A + shift I` of a random `rows x n` `A`.
pub fn random_spd(rng: &mut Rng, n: usize, rows: usize, shift: f64) -> Dense {
    let a = random(rng, rows, n);
    let mut h = ata(&a);
    for (i, row) in h.iter_mut().enumerate() {
        row[i] += shift;
    }
    h
}

pub fn ata(a: &Dense) -> Dense {
    let n = a.first().map_or(0, |r| r.len());
    let mut h = zeros(n, n);
    for row in a {
        for i in 0..n {
            for j in 0..n {
                h[i][j] += row[i] * row[j];
            }
        }
    }
    h
}

pub fn matvec(a: &Dense, x: &[f64]) -> Vec<f64> {
    a.iter()
        .map(|row| row.iter().zip(x).map(|(a, b)| a * b).sum())
        .collect()
}

pub fn transpose_matvec(a: &Dense, x: &[f64]) -> Vec<f64> {
    let n = a.first().map_or(0, |r| r.len());
    let mut y = vec![0.0; n];
    for (row, xi) in a.iter().zip(x) {
        for (yj, aij) in y.iter_mut().zip(row) {
            *yj += aij * xi;
        }
    }
    y
}

/// Reference solve of a general square system (partial pivoting).
pub fn gauss_solve(a: &Dense, b: &[f64]) -> Vec<f64> {
    let n = b.len();
    let mut m: Dense = a.to_vec();
    let mut x = b.to_vec();
    for k in 0..n {
        let p = (k..n)
            .max_by(|&i, &j| m[i][k].abs().partial_cmp(&m[j][k].abs()).unwrap())
            .unwrap();
        m.swap(k, p);
        x.swap(k, p);
        for i in k + 1..n {
            let f = m[i][k] / m[k][k];
            for j in k..n {
                m[i][j] -= f * m[k][j];
            }
            x[i] -= f * x[k];
        }
    }
    for k in (0..n).rev() {
        let s: f64 = (k + 1..n).map(|j| m[k][j] * x[j]).sum();
        x[k] = (x[k] - s) / m[k][k];
    }
    x
}

/// Loads the upper triangle of a dense symmetric matrix into `ne` (lower left as garbage to
/// prove it is never read) and sets `b`.
pub fn load_ne<const D: usize>(ne: &mut NormalEquations<D>, h: &Dense, b: &[f64]) {
    let n = b.len();
    ne.reset(n).unwrap();
    for i in 0..n {
        for j in 0..n {
            ne.h[i][j] = if i <= j { h[i][j] } else { f64::NAN };
        }
        ne.b[i] = b[i];
    }
}

/// Full symmetric dense copy of the active block of `ne`.
pub fn ne_dense<const D: usize>(ne: &NormalEquations<D>) -> Dense {
    let n = ne.dim();
    (0..n)
        .map(|i| (0..n).map(|j| ne.get(i, j).unwrap()).collect())
        .collect()
}

pub fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

pub fn max_abs(a: &[f64]) -> f64 {
    a.iter().map(|x| x.abs()).fold(0.0, f64::max)
}
