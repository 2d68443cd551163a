//! The marginalization prior in square-root form, `r = r0 + J0 (x [-] x0)`, over a list of state
//! blocks at fixed linearization points `x0`.
//!
//! `x [-] x0` per block: keyframe `[p - p0, Log(R0^T R), v - v0, bg - bg0, ba - ba0]`, extrinsic
//! `[p - p0, Log(R0^T R)]`, delay `td - td0`, matching the right-perturbation error states.

use super::window::{Block, Layout};
use crate::camera::CameraExtrinsic;
use crate::inertial::NavState;
use crate::math::{jr_inv_so3, log_so3, Vec3};
use crate::solver::NormalEquations;
use crate::Error;
use heapless::Vec as HVec;

/// Linearization point of one prior block.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LinPoint {
    /// A keyframe state.
    Kf(NavState),
    /// The extrinsic.
    Ext(CameraExtrinsic),
    /// A time delay, s.
    Td(f64),
}

/// Error of a keyframe state w.r.t. a linearization point, written into `out[..15]`.
pub fn kf_minus(x: &NavState, x0: &NavState, out: &mut [f64]) {
    let th = log_so3(&(x0.q_wb.inverse() * x.q_wb));
    let parts = [
        x.p_wb - x0.p_wb,
        th,
        x.v_wb - x0.v_wb,
        x.bg - x0.bg,
        x.ba - x0.ba,
    ];
    for (chunk, v) in out.chunks_mut(3).zip(parts.iter()) {
        for (o, e) in chunk.iter_mut().zip(v.iter()) {
            *o = *e;
        }
    }
}

/// Error of an extrinsic w.r.t. a linearization point, written into `out[..6]`.
pub fn ext_minus(x: &CameraExtrinsic, x0: &CameraExtrinsic, out: &mut [f64]) {
    let th = log_so3(&(x0.q_bc.inverse() * x.q_bc));
    let parts = [x.p_bc - x0.p_bc, th];
    for (chunk, v) in out.chunks_mut(3).zip(parts.iter()) {
        for (o, e) in chunk.iter_mut().zip(v.iter()) {
            *o = *e;
        }
    }
}

/// Most blocks a prior can span (`2 N + 1` for a window of `N`).
pub const MAX_PRIOR_BLOCKS: usize = 64;

/// The square-root marginalization prior of a window of `N` keyframes, capacity `D` dimensions.
#[derive(Clone)]
pub struct MargPrior<const D: usize, const N: usize> {
    /// `J0` (upper triangular, rows/columns `0..dim`).
    pub j0: [[f64; D]; D],
    /// `r0`.
    pub r0: [f64; D],
    /// `H0 = J0^T J0` (full symmetric), `g0 = J0^T r0`, `c0 = r0^T r0`: the prior's quadratic
    /// model, so that evaluating it costs `O(p^2)` instead of `O(p^3)`.
    h0: [[f64; D]; D],
    g0: [f64; D],
    c0: f64,
    /// Scratch of [`MargPrior::add_to`]: `H0` mapped through `Jr^-1` on rotation blocks.
    h_eff: [[f64; D]; D],
    /// Blocks in prior order with their linearization points.
    pub blocks: HVec<(Block, LinPoint), MAX_PRIOR_BLOCKS>,
    dim: usize,
}

impl<const D: usize, const N: usize> Default for MargPrior<D, N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const D: usize, const N: usize> MargPrior<D, N> {
    /// No prior.
    pub const fn new() -> Self {
        MargPrior {
            j0: [[0.0; D]; D],
            r0: [0.0; D],
            h0: [[0.0; D]; D],
            g0: [0.0; D],
            c0: 0.0,
            h_eff: [[0.0; D]; D],
            blocks: HVec::new(),
            dim: 0,
        }
    }

    /// Dimension (0 = inactive).
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Drops the prior.
    pub fn clear(&mut self) {
        self.dim = 0;
        self.blocks.clear();
    }

    /// Back to the state [`MargPrior::new`] builds (every buffer zeroed), in place.
    pub fn reset_to_new(&mut self) {
        self.clear();
        for row in self
            .j0
            .iter_mut()
            .chain(self.h0.iter_mut())
            .chain(self.h_eff.iter_mut())
        {
            row.fill(0.0);
        }
        self.r0.fill(0.0);
        self.g0.fill(0.0);
        self.c0 = 0.0;
    }

    /// Activates the prior after `j0`, `r0` and `blocks` were written, with `h_star` the
    /// marginal system they came from (`J0^T J0 = H*`, `J0^T r0 = -b*`, upper triangle of `H*`).
    pub fn set_dim(&mut self, dim: usize, h_star: &NormalEquations<D>) -> Result<(), Error> {
        let total: usize = self.blocks.iter().map(|(b, _)| b.dim()).sum();
        if dim > D || total != dim || h_star.dim() != dim {
            return Err(Error::DimensionMismatch);
        }
        for i in 0..dim {
            for j in i..dim {
                let v = h_star
                    .h
                    .get(i)
                    .and_then(|r| r.get(j))
                    .copied()
                    .unwrap_or(0.0);
                if let Some(x) = self.h0.get_mut(i).and_then(|r| r.get_mut(j)) {
                    *x = v;
                }
                if let Some(x) = self.h0.get_mut(j).and_then(|r| r.get_mut(i)) {
                    *x = v;
                }
            }
        }
        for (g, b) in self.g0.iter_mut().zip(h_star.b.iter()).take(dim) {
            *g = -b;
        }
        self.c0 = self.r0.iter().take(dim).map(|r| r * r).sum();
        self.dim = dim;
        Ok(())
    }

    /// What the prior knows about the window's gauge, the four directions no measurement of a
    /// visual-inertial window can see: a translation of every keyframe, and a rotation of every
    /// keyframe about gravity (world `z`), which moves `p` by `z x p`, `v` by `z x v` and the
    /// attitude by `R^T z` in its right-perturbation error. Returns the standard deviations
    /// `([x, y, z] m, yaw rad)` of the prior's Gaussian restricted to those directions, each
    /// with the other three free, evaluated at the prior's linearization points; `None`
    /// without a prior. [`f64::INFINITY`] where the prior holds no information.
    ///
    /// It starts from the first state's prior ([`crate::estimator::FirstStatePrior`]: `p_m`,
    /// `theta_rad` for the yaw). No measurement adds gauge information, and marginalizing a
    /// keyframe can only dilute it (the window's absolute pose drifts away from the first
    /// one), so in a consistent window these deviations never shrink. A shrinking one is the
    /// spurious information that linearizing the prior's factors and the window's factors at
    /// different points creates (what first-estimate Jacobians prevent). A diagnostic: `O(p^2)`
    /// per call; nothing in the solve depends on it.
    pub fn gauge_std(&self) -> Option<([f64; 3], f64)> {
        if self.dim == 0 {
            return None;
        }
        let p = self.dim;
        // The gauge directions as four columns over the prior's error state.
        let mut n = [[0.0f64; 4]; D];
        let mut at = 0;
        for (b, lin) in self.blocks.iter() {
            if let LinPoint::Kf(x0) = lin {
                let z = Vec3::z();
                let parts = [
                    z.cross(&x0.p_wb),
                    x0.q_wb.inverse_transform_vector(&z),
                    z.cross(&x0.v_wb),
                ];
                for (k, part) in parts.iter().enumerate() {
                    for i in 0..3 {
                        if let Some(row) = n.get_mut(at + 3 * k + i) {
                            row[3] = part[i];
                            if k == 0 {
                                row[i] = 1.0;
                            }
                        }
                    }
                }
            }
            at += b.dim();
        }
        // H0 N over the rows the directions touch, then M = N^T H0 N.
        let touched = |r: &[f64; 4]| r.iter().any(|v| *v != 0.0);
        let mut m = nalgebra::Matrix4::<f64>::zeros();
        for (ni, hrow) in n.iter().zip(self.h0.iter()).take(p) {
            if !touched(ni) {
                continue;
            }
            let mut hn = [0.0f64; 4];
            for (nj, h) in n.iter().zip(hrow.iter()).take(p) {
                if touched(nj) {
                    for (o, v) in hn.iter_mut().zip(nj.iter()) {
                        *o += h * v;
                    }
                }
            }
            for a in 0..4 {
                for c in 0..4 {
                    m[(a, c)] += ni[a] * hn[c];
                }
            }
        }
        let std = |v: f64| {
            if v > 0.0 {
                libm::sqrt(v)
            } else {
                f64::INFINITY
            }
        };
        match m.try_inverse() {
            Some(cov) if cov.iter().all(|v| v.is_finite()) => Some((
                [std(cov[(0, 0)]), std(cov[(1, 1)]), std(cov[(2, 2)])],
                std(cov[(3, 3)]),
            )),
            _ => Some(([f64::INFINITY; 3], f64::INFINITY)),
        }
    }

    /// Renames every block after the oldest keyframe left the window (positions shift by one).
    /// Fails if the prior still refers to position 0.
    pub fn shift_positions(&mut self) -> Result<(), Error> {
        for (b, _) in self.blocks.iter_mut() {
            *b = match *b {
                Block::Kf(0) | Block::Td(0) => return Err(Error::Degenerate),
                Block::Kf(k) => Block::Kf(k - 1),
                Block::Td(k) => Block::Td(k - 1),
                Block::Ext => Block::Ext,
            };
        }
        Ok(())
    }

    /// Computes `dx = x [-] x0` block by block with the current state given by `current`,
    /// and the column of each prior entry in `layout`, then adds the residual `r0 + J0 dx` to
    /// `ne` (or only its cost when `ne` is `None`), through its quadratic model
    /// (`H0`, `g0`, `c0`): `O(p^2)`. Returns the prior's cost `|r|^2`.
    ///
    /// The rotation part of `dx` is `Log(R0^T R)`, whose derivative w.r.t. the right
    /// perturbation of `R` is `Jr^-1(Log(R0^T R))`: the system added is `M^T H0 M` with those
    /// blocks of `M` equal to it, so the gradient stays exact when the window rotates away from
    /// the linearization point (a yaw drift of the gauge, for instance).
    pub fn add_to(
        &mut self,
        layout: &Layout<N>,
        current: impl Fn(Block) -> Option<LinPoint>,
        ne: Option<&mut NormalEquations<D>>,
    ) -> Result<f64, Error> {
        if self.dim == 0 {
            return Ok(0.0);
        }
        let mut dx = [0.0; D];
        let mut cols = [0usize; D];
        self.delta(layout, current, &mut dx, &mut cols)?;
        let p = self.dim;
        let (dx, cols) = (
            dx.get(..p).ok_or(Error::DimensionMismatch)?,
            cols.get(..p).ok_or(Error::DimensionMismatch)?,
        );
        // |r0 + J0 dx|^2 = c0 + dx . (g0 + q) with q = g0 + H0 dx; the gradient w.r.t. dx is 2 q.
        let mut q = [0.0; D];
        for ((qi, row), gi) in q.iter_mut().zip(self.h0.iter()).zip(self.g0.iter()).take(p) {
            *qi = gi + row.iter().zip(dx).map(|(h, d)| h * d).sum::<f64>();
        }
        let cost = self.c0
            + dx.iter()
                .zip(q.iter().zip(self.g0.iter()))
                .map(|(d, (qi, gi))| d * (gi + qi))
                .sum::<f64>();
        if !cost.is_finite() {
            return Err(Error::NonFinite);
        }
        let Some(ne) = ne else { return Ok(cost) };
        if cols.iter().any(|&c| c >= ne.dim()) {
            return Err(Error::DimensionMismatch);
        }
        // Mapped system M^T H0 M, -M^T q, with M = I except Jr^-1 on the rotation blocks.
        for (row_eff, row) in self.h_eff.iter_mut().zip(self.h0.iter()).take(p) {
            if let (Some(dst), Some(src)) = (row_eff.get_mut(..p), row.get(..p)) {
                dst.copy_from_slice(src);
            }
        }
        let mut b_eff = [0.0; D];
        for (be, qi) in b_eff.iter_mut().zip(q.iter()).take(p) {
            *be = -qi;
        }
        self.map_rotations(dx, &mut b_eff);
        if !b_eff.iter().take(p).all(|v| v.is_finite()) {
            return Err(Error::NonFinite);
        }
        self.add_mapped(cols, &b_eff, ne)?;
        ne.cost += cost;
        Ok(cost)
    }

    /// The prior's residual `r = r0 + J0 (x [-] x0)` (the current state given by `current`, as in
    /// [`Self::add_to`]) into `out`: its number of rows ([`Self::dim`]); [`Error::NonFinite`]
    /// for a non-finite row, [`Error::CapacityExceeded`] when `out` is too short.
    pub fn residual(
        &self,
        layout: &Layout<N>,
        current: impl Fn(Block) -> Option<LinPoint>,
        out: &mut [f64],
    ) -> Result<usize, Error> {
        let p = self.dim;
        let mut dx = [0.0; D];
        let mut cols = [0usize; D];
        self.delta(layout, current, &mut dx, &mut cols)?;
        let out = out.get_mut(..p).ok_or(Error::CapacityExceeded)?;
        for (i, (o, row)) in out.iter_mut().zip(self.j0.iter()).enumerate() {
            let jdx: f64 = row
                .get(i..p)
                .unwrap_or(&[])
                .iter()
                .zip(dx.get(i..p).unwrap_or(&[]))
                .map(|(j, d)| j * d)
                .sum();
            *o = self.r0.get(i).copied().unwrap_or(0.0) + jdx;
        }
        if !out.iter().all(|r| r.is_finite()) {
            return Err(Error::NonFinite);
        }
        Ok(p)
    }

    /// `dx = x [-] x0` block by block with the current state given by `current`, and the column
    /// of each prior entry in `layout` (see [`Self::add_to`]), into the first `dim` entries of
    /// `dx` and `cols`.
    fn delta(
        &self,
        layout: &Layout<N>,
        current: impl Fn(Block) -> Option<LinPoint>,
        dx: &mut [f64; D],
        cols: &mut [usize; D],
    ) -> Result<(), Error> {
        let mut at = 0;
        for (b, lin) in self.blocks.iter() {
            let w = b.dim();
            let c0 = layout.col(*b).ok_or(Error::DimensionMismatch)?;
            let out = dx.get_mut(at..at + w).ok_or(Error::DimensionMismatch)?;
            match (current(*b), lin) {
                (Some(LinPoint::Kf(x)), LinPoint::Kf(x0)) => kf_minus(&x, x0, out),
                (Some(LinPoint::Ext(x)), LinPoint::Ext(x0)) => ext_minus(&x, x0, out),
                (Some(LinPoint::Td(x)), LinPoint::Td(x0)) => {
                    if let Some(o) = out.first_mut() {
                        *o = x - x0;
                    }
                }
                _ => return Err(Error::DimensionMismatch),
            }
            for (i, c) in cols
                .get_mut(at..at + w)
                .ok_or(Error::DimensionMismatch)?
                .iter_mut()
                .enumerate()
            {
                *c = c0 + i;
            }
            at += w;
        }
        Ok(())
    }

    /// The mapped system of [`Self::add_to`]: `h_eff` (holding `H0`) and `b_eff` (holding `-q`)
    /// multiplied by `M = I` except `Jr^-1` of the rotation part of `dx` on the rotation blocks,
    /// into `M^T H0 M` and `-M^T q`.
    fn map_rotations(&mut self, dx: &[f64], b_eff: &mut [f64; D]) {
        let p = self.dim;
        let mut at = 0;
        for (blk, _) in self.blocks.iter() {
            let c = at + 3;
            at += blk.dim();
            if matches!(blk, Block::Td(_)) {
                continue;
            }
            let th = Vec3::new(
                dx.get(c).copied().unwrap_or(0.0),
                dx.get(c + 1).copied().unwrap_or(0.0),
                dx.get(c + 2).copied().unwrap_or(0.0),
            );
            let m = jr_inv_so3(&th);
            for row in self.h_eff.iter_mut().take(p) {
                if let Some(v) = row.get_mut(c..c + 3) {
                    let x = [v[0], v[1], v[2]];
                    for (k, o) in v.iter_mut().enumerate() {
                        *o = x[0] * m[(0, k)] + x[1] * m[(1, k)] + x[2] * m[(2, k)];
                    }
                }
            }
            for j in 0..p {
                let x: [f64; 3] = core::array::from_fn(|i| {
                    self.h_eff
                        .get(c + i)
                        .and_then(|r| r.get(j))
                        .copied()
                        .unwrap_or(0.0)
                });
                for k in 0..3 {
                    if let Some(o) = self.h_eff.get_mut(c + k).and_then(|r| r.get_mut(j)) {
                        *o = x[0] * m[(0, k)] + x[1] * m[(1, k)] + x[2] * m[(2, k)];
                    }
                }
            }
            if let Some(v) = b_eff.get_mut(c..c + 3) {
                let x = [v[0], v[1], v[2]];
                for (k, o) in v.iter_mut().enumerate() {
                    *o = x[0] * m[(0, k)] + x[1] * m[(1, k)] + x[2] * m[(2, k)];
                }
            }
        }
    }

    /// Adds the mapped system (`h_eff`, `b_eff`, prior entry `i` at column `cols[i]`) to `ne`.
    fn add_mapped(
        &self,
        cols: &[usize],
        b_eff: &[f64; D],
        ne: &mut NormalEquations<D>,
    ) -> Result<(), Error> {
        let p = self.dim;
        // The prior's columns are runs of consecutive state columns (whole blocks, in layout
        // order), so each row is added run by run as contiguous slices.
        let mut runs: HVec<(usize, usize), MAX_PRIOR_BLOCKS> = HVec::new();
        let mut start = 0;
        for k in 1..=p {
            let breaks = k == p || cols.get(k).copied() != cols.get(k - 1).map(|c| c + 1);
            if breaks {
                runs.push((start, k)).map_err(|_| Error::CapacityExceeded)?;
                start = k;
            }
        }
        let ascending = cols.windows(2).all(|w| w[0] < w[1]);
        for (i, (&ci, row)) in cols.iter().zip(self.h_eff.iter()).enumerate() {
            if let Some(b) = ne.b.get_mut(ci) {
                *b += b_eff.get(i).copied().unwrap_or(0.0);
            }
            if !ascending {
                for (&cj, &v) in cols.iter().zip(row.iter()).skip(i) {
                    let (r, c) = if ci <= cj { (ci, cj) } else { (cj, ci) };
                    if let Some(h) = ne.h.get_mut(r).and_then(|h| h.get_mut(c)) {
                        *h += v;
                    }
                }
                continue;
            }
            let Some(hrow) = ne.h.get_mut(ci) else {
                continue;
            };
            for &(a, b) in runs.iter() {
                if b <= i {
                    continue;
                }
                let a = a.max(i);
                let Some(&c0) = cols.get(a) else { continue };
                if let (Some(dst), Some(src)) = (hrow.get_mut(c0..c0 + (b - a)), row.get(a..b)) {
                    for (h, v) in dst.iter_mut().zip(src) {
                        *h += v;
                    }
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod gauge_tests {
    use super::*;
    use crate::math::{exp_so3, Quat};

    const P: usize = 30;
    type Prior = MargPrior<32, 4>;

    /// `x [+] dx` for a keyframe error state `[p, theta (right), v, bg, ba]`.
    fn plus(x: &NavState, dx: &[f64]) -> NavState {
        let v = |i: usize| Vec3::new(dx[i], dx[i + 1], dx[i + 2]);
        let dq = Quat::from_matrix(&exp_so3(&v(3)));
        NavState {
            p_wb: x.p_wb + v(0),
            q_wb: x.q_wb * dq,
            v_wb: x.v_wb + v(6),
            ..*x
        }
    }

    /// Residuals of two keyframes that a global translation and yaw leave unchanged: kf 2's
    /// position, attitude and velocity seen from kf 1, and kf 1's velocity in its body frame.
    fn relative(a: &NavState, b: &NavState) -> [f64; 12] {
        let rt = a.q_wb.inverse();
        let parts = [
            rt * (b.p_wb - a.p_wb),
            log_so3(&(rt * b.q_wb)),
            rt * b.v_wb,
            rt * a.v_wb,
        ];
        core::array::from_fn(|i| parts[i / 3][i % 3])
    }

    /// A prior over kf 1 and kf 2 at `x1`, `x2`: the invariant residuals (Jacobian by central
    /// differences, so it knows nothing of the gauge directions `gauge_std` assumes), plus
    /// `extra` on the diagonal of the state.
    fn prior(x1: &NavState, x2: &NavState, extra: &[(usize, f64)]) -> Prior {
        let mut jac = [[0.0; P]; 12];
        let h = 1e-6;
        for c in 0..P {
            let mut d = [0.0; P];
            d[c] = h;
            let f = |s: f64| {
                let dd: [f64; P] = core::array::from_fn(|i| s * d[i]);
                relative(&plus(x1, &dd[..15]), &plus(x2, &dd[15..]))
            };
            let (fp, fm) = (f(1.0), f(-1.0));
            for r in 0..12 {
                jac[r][c] = (fp[r] - fm[r]) / (2.0 * h);
            }
        }
        let mut ne = NormalEquations::<32>::new();
        ne.reset(P).expect("30 of 32 columns");
        let flat: [f64; 12 * P] = core::array::from_fn(|i| jac[i / P][i % P] * 10.0);
        let cols: [usize; P] = core::array::from_fn(|i| i);
        ne.add_residual(&[0.0; 12], &flat, &cols, 12, P)
            .expect("finite");
        for &(i, info) in extra {
            ne.add_to_diagonal(i, info).expect("in range");
        }
        let mut pr = Prior::new();
        pr.blocks
            .push((Block::Kf(1), LinPoint::Kf(*x1)))
            .expect("room");
        pr.blocks
            .push((Block::Kf(2), LinPoint::Kf(*x2)))
            .expect("room");
        pr.set_dim(P, &ne).expect("consistent dimensions");
        pr
    }

    fn states() -> (NavState, NavState) {
        let x1 = NavState {
            p_wb: Vec3::new(3.0, -2.0, 1.0),
            q_wb: Quat::from_euler_angles(0.1, -0.2, 0.7),
            v_wb: Vec3::new(1.2, 0.4, -0.1),
            ..NavState::ZERO
        };
        let x2 = NavState {
            p_wb: Vec3::new(3.4, -1.7, 1.1),
            q_wb: Quat::from_euler_angles(0.15, -0.1, 0.9),
            v_wb: Vec3::new(1.0, 0.6, 0.0),
            ..NavState::ZERO
        };
        (x1, x2)
    }

    /// Absolute priors on kf 1's position (sigma 1e-3 m) and attitude (0.02 rad), the first
    /// state's prior: as the only information on the gauge, they are what `gauge_std` gives.
    fn first_prior() -> [(usize, f64); 6] {
        let (sp, st) = (1e-3f64, 0.02f64);
        core::array::from_fn(|i| {
            (
                i,
                if i < 3 {
                    1.0 / (sp * sp)
                } else {
                    1.0 / (st * st)
                },
            )
        })
    }

    #[test]
    fn invariant_factors_add_no_gauge_information() {
        let (x1, x2) = states();
        let (pos, yaw) = prior(&x1, &x2, &first_prior())
            .gauge_std()
            .expect("a prior");
        // The yaw also moves kf 1's position (by z x p), but with the translation free that
        // part is taken up: the yaw keeps the attitude prior's 0.02 rad.
        assert!((yaw - 0.02).abs() < 2e-6, "yaw std {yaw}");
        for s in pos {
            assert!(
                s.is_finite() && s >= 1e-3 * (1.0 - 1e-6),
                "position std {s}"
            );
        }
        // Without any absolute prior, the gauge is free.
        let (pos, yaw) = prior(&x1, &x2, &[]).gauge_std().expect("a prior");
        assert!(yaw > 1e3 && pos.iter().all(|s| *s > 1e3), "{pos:?} {yaw}");
    }

    #[test]
    fn an_absolute_yaw_measurement_shows_as_gauge_information() {
        let (x1, x2) = states();
        let base = prior(&x1, &x2, &first_prior())
            .gauge_std()
            .expect("a prior")
            .1;
        // Information on kf 2's attitude about its body axes, as a fixed linearization point
        // gives the window when the states moved: it includes the yaw.
        let mut extra = first_prior().to_vec();
        extra.extend((18..21).map(|i| (i, 1.0 / (1e-3f64 * 1e-3))));
        let yaw = prior(&x1, &x2, &extra).gauge_std().expect("a prior").1;
        assert!(
            yaw < 0.1 * base && yaw > 5e-4,
            "yaw std {yaw} (without: {base})"
        );
    }
}
