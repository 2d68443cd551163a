//! LiDAR-depth measurements of the window's problem (paper V.C).
//!
//! **MSC-based LDM** (the paper's, under the two-view visual depth; with the depth eliminated,
//! the default, a LiDAR landmark's depth row joins its eliminated measurement instead, the
//! anchor's bearing free: `estimator::problem::visual`). A landmark with an accepted LiDAR depth `d_r` (z in its anchor camera `s`)
//! contributes one measurement made of its whitened inverse-depth reprojections `j != s`
//! (LE-VINS form, [`InverseDepthVisualFactor`]) and the depth row `(1/tau - d_r) / sigma_dr`, with
//! the inverse depth `tau` projected out (math notes sec. 5). At each linearization `tau*` is
//! re-solved for the current poses (1-D Gauss–Newton from the last value: variable projection),
//! and the block is added through the landmark's Schur accumulator:
//!
//! ```text
//! H += J_Y^T J_Y - J_Y^T J_tau J_tau^T J_Y / |J_tau|^2 ,   b += -J_Y^T e + J_Y^T J_tau (J_tau^T e) / |J_tau|^2
//! ```
//!
//! which is exactly `A^T`-projected system of eq. (29)-(30) for any orthonormal basis `A` of
//! the left nullspace of `J_tau` (`A A^T = I - J_tau J_tau^T / |J_tau|^2`): the Givens form in
//! [`crate::factors::lidar_depth::MscLidarDepth`] builds the same normal equations row by row (a
//! test checks they agree), at a cost of `O(n^2)` dense rows instead of `n` sparse ones. The
//! cost is `min_tau |e(tau)|^2` at the current poses, so the LM gain ratio compares the
//! projected cost the linear model predicts. No separate visual measurement is added for such a
//! landmark. Huber acts on the block: `n rho(|e|^2 / n)` for `n` observations, i.e. per
//! observation on average, so an inlier block is weighted like its `n` visual measurements.
//!
//! **Direct LDM** (eq. 24, the ablation): `(d_s(poses) - d_r) / sigma_dr` beside the landmark's
//! pose-only visual measurements, Huber on its square.
//!
//! [`InverseDepthVisualFactor`]: crate::factors::inverse_depth_visual::InverseDepthVisualFactor
#![deny(clippy::too_many_lines)]

use super::factor::{
    put_rows, row_major, timed, LandmarkFactor, VisualSettings, WindowFactor, WindowVars,
};
use super::pose_only::TwoViewLandmark;
use super::SCHUR_COLS;
use crate::camera::CameraExtrinsic;
use crate::estimator::tau_landmark::TauLandmark;
use crate::estimator::window::{Block, Layout};
use crate::factors::inverse_depth_visual::InverseDepthJacobians;
use crate::factors::lidar_depth::{DirectDepthJacobians, DirectLidarDepthFactor};
use crate::factors::robust::Huber;
use crate::factors::KeyframePose;
use crate::landmarks::Landmark;
use crate::solver::LandmarkSchur;
use crate::solver::{JacobianBlock, NormalEquations};
use crate::Error;
use heapless::Vec as HVec;

/// Robust cost of an MSC block of `n` observations with stacked squared norm `sq`, and the
/// square root of its IRLS weight.
pub(super) fn msc_robust(huber: &Huber, sq: f64, n: usize) -> (f64, f64) {
    let n = n.max(1) as f64;
    let per = sq / n;
    (n * huber.rho(per)[0], huber.sqrt_weight(per))
}

/// Adds one inverse-depth reprojection `s -> j` (weighted by `w`) to `ne`, its inverse-depth
/// column to the landmark's Schur accumulator `sc`.
#[allow(clippy::too_many_arguments)]
pub(super) fn add_inverse_depth_obs<const N: usize, const D: usize>(
    sc: &mut LandmarkSchur<SCHUR_COLS>,
    ne: &mut NormalEquations<D>,
    jac: &InverseDepthJacobians,
    w: f64,
    s: usize,
    j: usize,
    l: &Layout<N>,
    est_td: bool,
    est_ext: bool,
) -> Result<(), Error> {
    if !est_td && !est_ext {
        let col = |k: usize| l.col(Block::Kf(k as u8)).ok_or(Error::DimensionMismatch);
        return sc.add_residual_2x6(
            ne,
            &(jac.r * w),
            &[jac.d_pose_s * w, jac.d_pose_j * w],
            [col(s)?, col(j)?],
            &(jac.d_tau * w),
        );
    }
    let r = [jac.r.x * w, jac.r.y * w];
    let (mut a, mut c, mut x) = ([0.0; 12], [0.0; 12], [0.0; 12]);
    row_major(&(jac.d_pose_s * w), &mut a);
    row_major(&(jac.d_pose_j * w), &mut c);
    row_major(&(jac.d_ext * w), &mut x);
    let tds = [
        [jac.d_td[0].x * w, jac.d_td[0].y * w],
        [jac.d_td[1].x * w, jac.d_td[1].y * w],
    ];
    let jl = [jac.d_tau.x * w, jac.d_tau.y * w];
    let mut blocks: HVec<JacobianBlock<'_>, 6> = HVec::new();
    let col = |b: Block| l.col(b).ok_or(Error::DimensionMismatch);
    let _ = blocks.push(JacobianBlock::new(col(Block::Kf(s as u8))?, 6, &a));
    let _ = blocks.push(JacobianBlock::new(col(Block::Kf(j as u8))?, 6, &c));
    if est_ext {
        let _ = blocks.push(JacobianBlock::new(col(Block::Ext)?, 6, &x));
    }
    if est_td {
        let _ = blocks.push(JacobianBlock::new(col(Block::Td(s as u8))?, 1, &tds[0]));
        let _ = blocks.push(JacobianBlock::new(col(Block::Td(j as u8))?, 1, &tds[1]));
    }
    sc.add_residual(ne, &r, &blocks, &jl)
}

/// Linearizes the MSC block of `m` at `tau` and adds it to `ne` through the Schur
/// accumulator `sc` (projection of `tau`). Returns the block's robust cost.
#[allow(clippy::too_many_arguments)]
#[inline(never)]
pub(super) fn accumulate_msc<const N: usize, const D: usize>(
    m: &TauLandmark<N>,
    poses: &[KeyframePose; N],
    ext: &CameraExtrinsic,
    tau: f64,
    huber: &Huber,
    l: &Layout<N>,
    est_td: bool,
    est_ext: bool,
    sc: &mut LandmarkSchur<SCHUR_COLS>,
    ne: &mut NormalEquations<D>,
) -> Result<f64, Error> {
    let ps = poses.get(m.s).ok_or(Error::DimensionMismatch)?;
    let mut jacs: HVec<(usize, InverseDepthJacobians), N> = HVec::new();
    let (rd, jd) = m.depth_row(tau);
    let mut sq = rd * rd;
    for (j, f) in m.obs.iter() {
        let pj = poses.get(*j).ok_or(Error::DimensionMismatch)?;
        let jac = f.evaluate(ps, pj, ext, tau)?;
        sq += jac.r.norm_squared();
        let _ = jacs.push((*j, jac));
    }
    let (cost, w) = msc_robust(huber, sq, m.obs.len());
    let s = m.s;
    sc.clear();
    for (j, jac) in jacs.iter() {
        add_inverse_depth_obs(sc, ne, jac, w, s, *j, l, est_td, est_ext)?;
    }
    sc.add_residual(ne, &[rd * w], &[], &[jd * w])?;
    sc.fold_into(ne, 0.0)?;
    Ok(cost)
}

/// The MSC-based LiDAR-depth measurement of a landmark (module docs).
pub struct MscLandmark<'a, const N: usize> {
    vs: VisualSettings<'a>,
    lm: &'a Landmark<N>,
    schur: &'a mut LandmarkSchur<SCHUR_COLS>,
    tau: Option<f64>,
    n_obs: u32,
}

impl<'a, const N: usize> MscLandmark<'a, N> {
    /// The measurement of LiDAR landmark `lm`, with `schur` as its accumulator.
    pub fn new(
        vs: VisualSettings<'a>,
        lm: &'a Landmark<N>,
        schur: &'a mut LandmarkSchur<SCHUR_COLS>,
    ) -> Self {
        MscLandmark {
            vs,
            lm,
            schur,
            tau: None,
            n_obs: 0,
        }
    }

    /// The landmark's reprojections and depth row in `tau` over the first `count` positions.
    fn tau_landmark(&self, count: usize) -> Result<TauLandmark<N>, Error> {
        let lm = self.lm;
        let depth = lm.lidar.ok_or(Error::NotEnoughData)?;
        TauLandmark::new(
            &lm.obs,
            lm.anchor_s as usize,
            Some(depth),
            self.vs.sqrt_info,
            count,
        )
        .ok_or(Error::NotEnoughData)
    }
}

impl<const N: usize, const D: usize> WindowFactor<N, D> for MscLandmark<'_, N> {
    fn add(
        &mut self,
        v: &WindowVars<'_, N>,
        ne: Option<&mut NormalEquations<D>>,
    ) -> Result<f64, Error> {
        self.tau = None;
        let m = self.tau_landmark(v.count)?;
        let (tau, rays) = m.solve(&v.poses, &v.frames, self.lm.inv_depth)?;
        let n_obs = m.obs.len();
        self.n_obs = n_obs as u32;
        let huber = &self.vs.huber;
        let Some(ne) = ne else {
            let sq = m.stacked_sq_rays(&rays, tau)?;
            return Ok(msc_robust(huber, sq, n_obs).0);
        };
        let (l, sc) = (&v.layout, &mut *self.schur);
        let (est_td, est_ext) = (v.est_td, v.est_ext);
        let cost = accumulate_msc(&m, &v.poses, v.ext, tau, huber, l, est_td, est_ext, sc, ne)?;
        self.tau = Some(tau);
        Ok(cost)
    }

    fn residuals(&mut self, v: &WindowVars<'_, N>, out: &mut [f64]) -> Result<usize, Error> {
        let m = self.tau_landmark(v.count)?;
        let rays = m.rays(&v.poses, &v.frames)?;
        let tau = self.lm.inv_depth;
        let mut rows = 0;
        for ray in rays.iter() {
            let (r, _) = ray.residual_and_d_tau(tau)?;
            rows += put_rows(&[r.x, r.y], out.get_mut(rows..).unwrap_or(&mut []))?;
        }
        let rd = m.depth_row(tau).0;
        rows += put_rows(&[rd], out.get_mut(rows..).unwrap_or(&mut []))?;
        Ok(rows)
    }
}

impl<const N: usize, const D: usize> LandmarkFactor<N, D> for MscLandmark<'_, N> {
    fn observations(&self) -> u32 {
        self.n_obs
    }

    fn depth_measurements(&self) -> u32 {
        1
    }

    fn inverse_depth(&self) -> Option<f64> {
        self.tau
    }
}

/// The direct LiDAR-depth measurement of a landmark with anchors `s`, `e` (module docs), Huber
/// on its square.
pub struct DirectDepth<'a, const N: usize> {
    huber: Huber,
    lm: &'a Landmark<N>,
}

impl<'a, const N: usize> DirectDepth<'a, N> {
    /// The measurement of LiDAR landmark `lm`.
    pub fn new(huber: Huber, lm: &'a Landmark<N>) -> Self {
        DirectDepth { huber, lm }
    }

    /// Residual and Jacobians at `v`, with the anchors.
    fn evaluate(
        &self,
        v: &WindowVars<'_, N>,
    ) -> Result<(DirectDepthJacobians, usize, usize), Error> {
        let lm = self.lm;
        let depth = lm.lidar.ok_or(Error::NotEnoughData)?;
        let (s, e) = (
            lm.anchor_s as usize,
            lm.anchor_e.ok_or(Error::NotEnoughData)? as usize,
        );
        let (Some(Some(os)), Some(Some(oe))) = (lm.obs.get(s), lm.obs.get(e)) else {
            return Err(Error::NotEnoughData);
        };
        let f = DirectLidarDepthFactor {
            kf_s: s,
            kf_e: e,
            obs_s: timed(os),
            obs_e: timed(oe),
            d_r: depth.depth_m,
            sigma_dr: depth.sigma_m,
        };
        let (ps, pe) = (
            v.poses.get(s).ok_or(Error::DimensionMismatch)?,
            v.poses.get(e).ok_or(Error::DimensionMismatch)?,
        );
        Ok((f.evaluate(ps, pe, v.ext)?, s, e))
    }
}

impl<const N: usize, const D: usize> WindowFactor<N, D> for DirectDepth<'_, N> {
    #[inline(never)]
    fn add(
        &mut self,
        v: &WindowVars<'_, N>,
        ne: Option<&mut NormalEquations<D>>,
    ) -> Result<f64, Error> {
        let (jac, s, e) = self.evaluate(v)?;
        let huber = &self.huber;
        let sq = jac.r * jac.r;
        let cost = huber.rho(sq)[0];
        let Some(ne) = ne else {
            return Ok(cost);
        };
        let w = huber.sqrt_weight(sq);
        let col = |b: Block| v.col(b);
        let (a, b, x) = (jac.d_pose_s * w, jac.d_pose_e * w, jac.d_ext * w);
        let td = [jac.d_td[0] * w, jac.d_td[1] * w];
        let mut blocks: HVec<JacobianBlock<'_>, 5> = HVec::new();
        let _ = blocks.push(JacobianBlock::new(
            col(Block::Kf(s as u8))?,
            6,
            a.as_slice(),
        ));
        let _ = blocks.push(JacobianBlock::new(
            col(Block::Kf(e as u8))?,
            6,
            b.as_slice(),
        ));
        if v.est_ext {
            let _ = blocks.push(JacobianBlock::new(col(Block::Ext)?, 6, x.as_slice()));
        }
        if v.est_td {
            let _ = blocks.push(JacobianBlock::new(col(Block::Td(s as u8))?, 1, &td[..1]));
            let _ = blocks.push(JacobianBlock::new(col(Block::Td(e as u8))?, 1, &td[1..]));
        }
        ne.add_blocks(&[jac.r * w], &blocks)?;
        Ok(cost)
    }

    fn residuals(&mut self, v: &WindowVars<'_, N>, out: &mut [f64]) -> Result<usize, Error> {
        put_rows(&[self.evaluate(v)?.0.r], out)
    }
}

/// A LiDAR landmark under the direct LDM: its two-view visual measurement and the direct
/// LiDAR-depth measurement beside it. A degenerate depth geometry only drops the depth
/// measurement from a linearization (the visual ones were fine); a cost evaluation fails.
pub struct DirectLidarLandmark<'a, const N: usize> {
    visual: TwoViewLandmark<'a, N>,
    depth: DirectDepth<'a, N>,
    ldm: u32,
}

impl<'a, const N: usize> DirectLidarLandmark<'a, N> {
    /// The measurements of LiDAR landmark `lm`, or `None` as [`TwoViewLandmark::new`].
    pub fn new(vs: VisualSettings<'a>, lm: &'a Landmark<N>) -> Option<Self> {
        Some(DirectLidarLandmark {
            visual: TwoViewLandmark::new(vs, lm, None)?,
            depth: DirectDepth::new(vs.huber, lm),
            ldm: 0,
        })
    }
}

impl<const N: usize, const D: usize> WindowFactor<N, D> for DirectLidarLandmark<'_, N> {
    fn add(
        &mut self,
        v: &WindowVars<'_, N>,
        mut ne: Option<&mut NormalEquations<D>>,
    ) -> Result<f64, Error> {
        self.ldm = 0;
        let mut cost = self.visual.add(v, ne.as_deref_mut())?;
        let linearize = ne.is_some();
        match self.depth.add(v, ne) {
            Ok(c) => {
                cost += c;
                self.ldm = 1;
            }
            Err(_) if linearize => {}
            Err(e) => return Err(e),
        }
        Ok(cost)
    }

    fn residuals(&mut self, v: &WindowVars<'_, N>, out: &mut [f64]) -> Result<usize, Error> {
        let rows = WindowFactor::<N, D>::residuals(&mut self.visual, v, out)?;
        let depth = WindowFactor::<N, D>::residuals(
            &mut self.depth,
            v,
            out.get_mut(rows..).unwrap_or(&mut []),
        )?;
        Ok(rows + depth)
    }
}

impl<const N: usize, const D: usize> LandmarkFactor<N, D> for DirectLidarLandmark<'_, N> {
    fn observations(&self) -> u32 {
        LandmarkFactor::<N, D>::observations(&self.visual)
    }

    fn depth_measurements(&self) -> u32 {
        self.ldm
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Vec2;
    use crate::estimator::tau_landmark::Ray;
    use crate::factors::inverse_depth_visual::InverseDepthVisualFactor;
    use crate::factors::lidar_depth::MscLidarDepth;
    use crate::factors::{CamFrame, TimedObs};
    use crate::landmarks::LidarDepth;
    use crate::math::{quat_exp, Quat, Vec3};

    const N: usize = 4;
    const D: usize = 16 * N + 6;

    fn pose(p: [f64; 3], r: [f64; 3]) -> KeyframePose {
        KeyframePose {
            p_wb: Vec3::new(p[0], p[1], p[2]),
            q_wb: quat_exp(&Vec3::new(r[0], r[1], r[2])),
            td: 0.0,
        }
    }

    /// A landmark seen from three keyframes, a LiDAR depth 5 cm off the truth, pixel noise.
    fn scene() -> (
        [KeyframePose; N],
        CameraExtrinsic,
        TauLandmark<N>,
        MscLidarDepth<N>,
    ) {
        let ext = CameraExtrinsic {
            p_bc: Vec3::new(0.05, -0.02, 0.01),
            q_bc: quat_exp(&Vec3::new(-1.5, 0.02, -1.55)),
        };
        let poses = [
            pose([0.0, 0.0, 0.0], [0.0, 0.0, 0.0]),
            pose([0.3, 0.1, 0.02], [0.01, -0.02, 0.05]),
            pose([0.7, 0.15, -0.03], [0.02, 0.01, 0.12]),
            pose([0.0; 3], [0.0; 3]),
        ];
        let p_w = Vec3::new(4.0, 1.0, 0.5);
        let noise = [[0.0, 0.0], [0.002, -0.001], [-0.0015, 0.0025]];
        let obs: [Vec2; 3] = core::array::from_fn(|k| {
            let c = ext.camera_pose(&poses[k].p_wb, &poses[k].q_wb);
            let p_c = c.q_wc.inverse() * (p_w - c.p_wc);
            Vec2::new(p_c.x / p_c.z + noise[k][0], p_c.y / p_c.z + noise[k][1])
        });
        let c0 = ext.camera_pose(&poses[0].p_wb, &poses[0].q_wb);
        let d_true = (c0.q_wc.inverse() * (p_w - c0.p_wc)).z;
        let depth = LidarDepth {
            depth_m: d_true + 0.05,
            sigma_m: 0.1,
        };
        let sqrt_info = Vec2::new(460.0, 460.0) / 1.5;
        let obs_s = TimedObs::still(obs[0]);
        let mut m = TauLandmark {
            s: 0,
            obs: HVec::new(),
            depth: Some(depth),
        };
        let mut g = MscLidarDepth::<N>::new(0, obs_s, depth.depth_m, 0.1, sqrt_info).unwrap();
        for (j, o) in obs.iter().enumerate().skip(1) {
            let f = InverseDepthVisualFactor {
                kf_s: 0,
                kf_j: j,
                obs_s,
                obs_j: TimedObs::still(*o),
                sqrt_info,
            };
            m.obs.push((j, f)).unwrap();
            g.push(j, TimedObs::still(*o)).unwrap();
        }
        (poses, ext, m, g)
    }

    #[test]
    fn schur_projection_equals_givens_nullspace_projection() {
        let (poses, ext, m, mut g) = scene();
        let huber = Huber::new(1e6).unwrap();
        let l = Layout::<N>::solve(3, true, false);
        let n = l.dim();
        let tau = m.best_tau(&poses, &ext, 0.0).unwrap();

        let mut ne_schur = NormalEquations::<D>::new();
        ne_schur.reset(n).unwrap();
        let mut sc = LandmarkSchur::<SCHUR_COLS>::new();
        let cost = accumulate_msc(
            &m,
            &poses,
            &ext,
            tau,
            &huber,
            &l,
            false,
            true,
            &mut sc,
            &mut ne_schur,
        )
        .unwrap();

        // Givens: the 2n projected rows, each over (pose s, poses j, extrinsic).
        g.linearize(&poses[0], &[poses[1], poses[2]], &ext).unwrap();
        assert!(
            (g.tau() - tau).abs() <= 1e-9 * tau,
            "same tau*: {} vs {tau}",
            g.tau()
        );
        let mut ne_givens = NormalEquations::<D>::new();
        ne_givens.reset(n).unwrap();
        for row in g.rows() {
            let mut blocks: HVec<JacobianBlock<'_>, 4> = HVec::new();
            blocks
                .push(JacobianBlock::new(
                    l.col(Block::Kf(0)).unwrap(),
                    6,
                    row.d_pose_s.as_slice(),
                ))
                .unwrap();
            for (k, j) in [1usize, 2].iter().enumerate() {
                blocks
                    .push(JacobianBlock::new(
                        l.col(Block::Kf(*j as u8)).unwrap(),
                        6,
                        row.d_pose_j[k].as_slice(),
                    ))
                    .unwrap();
            }
            blocks
                .push(JacobianBlock::new(
                    l.col(Block::Ext).unwrap(),
                    6,
                    row.d_ext.as_slice(),
                ))
                .unwrap();
            ne_givens.add_blocks(&[row.r], &blocks).unwrap();
        }
        // Same cost (min over tau of the stack) ...
        let rel = (cost - g.projected_cost()).abs() / g.projected_cost();
        assert!(rel < 1e-6, "cost {cost} vs {}", g.projected_cost());
        assert!(
            cost > 0.5,
            "the test scene must have a visible residual: {cost}"
        );
        // ... and the same normal equations.
        let (mut h_max, mut b_max) = (0.0f64, 0.0f64);
        for i in 0..n {
            b_max = b_max.max(ne_givens.b[i].abs());
            for j in i..n {
                h_max = h_max.max(ne_givens.get(i, j).unwrap().abs());
            }
        }
        assert!(h_max > 1.0 && b_max > 1e-3);
        for i in 0..n {
            let db = (ne_schur.b[i] - ne_givens.b[i]).abs();
            assert!(
                db <= 1e-7 * b_max.max(1.0),
                "b[{i}]: {} vs {}",
                ne_schur.b[i],
                ne_givens.b[i]
            );
            for j in i..n {
                let (a, b) = (ne_schur.get(i, j).unwrap(), ne_givens.get(i, j).unwrap());
                assert!((a - b).abs() <= 1e-8 * h_max, "H[{i},{j}]: {a} vs {b}");
            }
        }
    }

    #[test]
    fn rays_agree_with_the_factor_chain() {
        let (poses, ext, m, _) = scene();
        let frames: [CamFrame; N] = core::array::from_fn(|k| CamFrame::new(&poses[k], &ext));
        let (tau, rays) = m.solve(&poses, &frames, 0.0).unwrap();
        let tau_ref = m.best_tau(&poses, &ext, 0.0).unwrap();
        assert!((tau - tau_ref).abs() <= 1e-10 * tau, "{tau} vs {tau_ref}");
        for t in [0.5 * tau, tau, 2.0 * tau] {
            let (a, b) = (
                m.stacked_sq_rays(&rays, t).unwrap(),
                m.stacked_sq(&poses, &ext, t).unwrap(),
            );
            assert!((a - b).abs() <= 1e-9 * b.max(1.0), "{a} vs {b}");
            for (ray, (j, f)) in rays.iter().zip(m.obs.iter()) {
                let (r, d) = ray.residual_and_d_tau(t).unwrap();
                let (r2, d2) = f
                    .residual_and_d_tau(&poses[0], &poses[*j], &ext, t)
                    .unwrap();
                assert!((r - r2).norm() <= 1e-9 * (1.0 + r2.norm()));
                assert!((d - d2).norm() <= 1e-9 * (1.0 + d2.norm()));
                // And against a central difference.
                let h = 1e-6 * t;
                let num = (ray.residual_and_d_tau(t + h).unwrap().0
                    - ray.residual_and_d_tau(t - h).unwrap().0)
                    / (2.0 * h);
                assert!((num - d).norm() <= 1e-6 * (1.0 + d.norm()), "{num} vs {d}");
            }
        }
        // Behind camera j: an error, not a number.
        let behind = Ray {
            a: Vec3::new(0.0, 0.0, -1.0),
            a_d: [Vec3::x(), Vec3::y()],
            b: Vec3::zeros(),
            x_j: Vec2::zeros(),
            w: Vec2::new(1.0, 1.0),
        };
        assert_eq!(
            behind.residual_and_d_tau(1.0).err(),
            Some(Error::Degenerate)
        );
    }

    #[test]
    fn best_tau_minimizes_the_stack() {
        let (poses, ext, m, _) = scene();
        let tau = m.best_tau(&poses, &ext, 0.0).unwrap();
        let c = m.stacked_sq(&poses, &ext, tau).unwrap();
        for d in [1e-4, -1e-4, 1e-3, -1e-3] {
            assert!(m.stacked_sq(&poses, &ext, tau * (1.0 + d)).unwrap() > c);
        }
        // The LiDAR depth pulls tau*: with a depth 1 m further the solution moves.
        let mut far = TauLandmark {
            s: m.s,
            obs: m.obs.clone(),
            depth: m.depth,
        };
        if let Some(d) = far.depth.as_mut() {
            d.depth_m += 1.0;
        }
        let tau_far = far.best_tau(&poses, &ext, 0.0).unwrap();
        assert!(tau_far < tau);
    }

    #[test]
    fn robust_block_cost_is_per_observation_huber() {
        let h = Huber::new(1.0).unwrap();
        // Inlier block: quadratic.
        let (c, w) = msc_robust(&h, 1.5, 3);
        assert!((c - 1.5).abs() < 1e-12 && (w - 1.0).abs() < 1e-12);
        // Outlier block: linear growth, down-weighted.
        let (c, w) = msc_robust(&h, 300.0, 3);
        assert!(c < 300.0 && w < 1.0);
        let _ = Quat::identity();
    }
}
