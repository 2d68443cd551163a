//! One landmark's inverse-depth reprojections as functions of its inverse depth `tau` (and of a
//! correction `delta` of its anchor's bearing) ([`TauLandmark`]: the factors of its observations
//! `j != s`, and the LiDAR depth row of an MSC-based LDM; [`Ray`]: one observation as
//! `P_j ~ a + R_js (delta, 0) + tau b`), and the 1-D Gauss-Newton solve for the `tau*` that
//! minimizes their stacked cost with the anchor's bearing exact. Shared by the paper's MSC-based
//! LiDAR-depth measurement (`estimator::problem::lidar`) and the depth-only optimization
//! (`estimator::lidar`), which take the bearing as exact, the eliminated measurement of visual
//! and LiDAR landmarks (`estimator::problem::visual`, which solves for it too) and the culling
//! residuals (`estimator::cull`).

use super::problem::factor::timed;
#[cfg(test)]
use crate::camera::CameraExtrinsic;
use crate::camera::Vec2;
use crate::factors::inverse_depth_visual::InverseDepthVisualFactor;
use crate::factors::{CamFrame, KeyframePose, MIN_Z_REL};
use crate::landmarks::{KfObs, LidarDepth};
use crate::math::Vec3;
use crate::Error;
use heapless::Vec as HVec;

/// Most iterations of the 1-D inverse-depth solve. It starts from the last solution, so two or
/// three are normally enough; a landmark whose Huber weights change (an outlier among its rays)
/// converges linearly and needs more. Stopping early leaves `dcost/dtau != 0`, and then the
/// projected gradient is no longer the gradient of the minimized cost (measured: 1.4e-2
/// relative error at 10 iterations, 7e-6 at convergence).
const TAU_ITERS: usize = 60;
/// Relative step at which the 1-D solve stops. The IRLS converges linearly (about six steps to
/// 1e-10 on the corridor); an error of 1e-7 of `tau` is far below its noise and changes the
/// projected system only to second order (`beta` carries the first-order correction).
const TAU_TOL: f64 = 1e-7;

/// Inverse-depth reprojections `j != s` of one landmark, ready to evaluate, with the LiDAR
/// depth of an MSC-based LDM (or without one: a visual landmark whose inverse depth is
/// eliminated the same way, `estimator::problem::visual`).
pub(super) struct TauLandmark<const N: usize> {
    /// Anchor position.
    pub s: usize,
    /// `(position j, factor)` per observation, all with the same anchor `s` and `obs_s`.
    pub obs: HVec<(usize, InverseDepthVisualFactor), N>,
    /// The LiDAR depth, if any.
    pub depth: Option<LidarDepth>,
}

impl<const N: usize> TauLandmark<N> {
    /// The landmark's measurements, or `None` without an anchor observation or any `j != s`.
    /// (Inlined: built in place instead of copied out.)
    #[inline(always)]
    pub fn new(
        obs: &[Option<KfObs>; N],
        s: usize,
        depth: Option<LidarDepth>,
        sqrt_info: Vec2,
        count: usize,
    ) -> Option<Self> {
        Self::without(obs, s, None, depth, sqrt_info, count)
    }

    /// [`Self::new`] as if the observation at position `skip` (if any) were not there.
    #[inline(always)]
    pub fn without(
        obs: &[Option<KfObs>; N],
        s: usize,
        skip: Option<usize>,
        depth: Option<LidarDepth>,
        sqrt_info: Vec2,
        count: usize,
    ) -> Option<Self> {
        if skip == Some(s) {
            return None;
        }
        let obs_s = timed(obs.get(s)?.as_ref()?);
        let mut m = TauLandmark {
            s,
            obs: HVec::new(),
            depth,
        };
        for (j, o) in obs.iter().enumerate().take(count) {
            if let (Some(o), true) = (o, j != s && Some(j) != skip) {
                let f = InverseDepthVisualFactor {
                    kf_s: s,
                    kf_j: j,
                    obs_s,
                    obs_j: timed(o),
                    sqrt_info,
                };
                let _ = m.obs.push((j, f));
            }
        }
        if m.obs.is_empty() {
            return None;
        }
        Some(m)
    }

    /// The whitened depth row and its derivative in `tau` (zero without a LiDAR depth).
    pub(super) fn depth_row(&self, tau: f64) -> (f64, f64) {
        let Some(d) = self.depth else {
            return (0.0, 0.0);
        };
        let [r, d1, _] = d.row(tau);
        (r, d1)
    }

    /// The observations as rays in `tau`: camera `j` sees the landmark at `P_j ~ a + tau b`
    /// with `a = R_jw R_ws x_s`, `b = R_jw (p_ws - p_wj)` (`P_j = (a + tau b) / tau`, and the
    /// projection is scale-free), so once `(a, b)` are known every 1-D step costs a few flops.
    pub(super) fn rays(
        &self,
        poses: &[KeyframePose; N],
        frames: &[CamFrame; N],
    ) -> Result<HVec<Ray, N>, Error> {
        let mut out = HVec::new();
        self.rays_into(poses, frames, &mut out)?;
        Ok(out)
    }

    /// [`Self::rays`] into `out` (cleared first; inlined: the rays are built in place instead
    /// of copied out).
    #[inline(always)]
    pub(super) fn rays_into(
        &self,
        poses: &[KeyframePose; N],
        frames: &[CamFrame; N],
        out: &mut HVec<Ray, N>,
    ) -> Result<(), Error> {
        out.clear();
        let ps = poses.get(self.s).ok_or(Error::DimensionMismatch)?;
        let fs = frames.get(self.s).ok_or(Error::DimensionMismatch)?;
        // Every factor of the landmark has the same anchor observation: its ray in the world
        // is formed once.
        let Some((_, f0)) = self.obs.first() else {
            return Ok(());
        };
        let ray_s = fs.r_wc * f0.obs_s.corrected(ps.td);
        for (j, f) in self.obs.iter() {
            let (pj, fj) = (
                poses.get(*j).ok_or(Error::DimensionMismatch)?,
                frames.get(*j).ok_or(Error::DimensionMismatch)?,
            );
            let x_j = f.obs_j.corrected(pj.td);
            let r_jw = fj.r_wc.transpose();
            let a = r_jw * ray_s;
            let b = r_jw * (fs.p_wc - fj.p_wc);
            // `R_js`'s first two columns: how the anchor bearing's correction moves the ray.
            let r_js = r_jw * fs.r_wc;
            let a_d = [r_js.column(0).into_owned(), r_js.column(1).into_owned()];
            let ok = a
                .iter()
                .chain(b.iter())
                .chain(x_j.iter())
                .all(|v| v.is_finite());
            if !ok {
                return Err(Error::NonFinite);
            }
            let _ = out.push(Ray {
                a,
                a_d,
                b,
                x_j: Vec2::new(x_j.x, x_j.y),
                w: f.sqrt_info,
            });
        }
        Ok(())
    }

    /// 1-D Gauss–Newton on the inverse depth from `tau0` (or `1/d_r`): `visual(tau, g, h)`
    /// adds the visual rows' `J^T r` and `J^T J` to the LiDAR depth row's `(g, h)`.
    pub(super) fn gauss_newton_tau(
        &self,
        tau0: f64,
        mut visual: impl FnMut(f64, f64, f64) -> Result<(f64, f64), Error>,
    ) -> Result<f64, Error> {
        let mut tau = if tau0 > 0.0 && tau0.is_finite() {
            tau0
        } else {
            1.0 / self.depth.ok_or(Error::NotEnoughData)?.depth_m
        };
        for _ in 0..TAU_ITERS {
            let (rd, jd) = self.depth_row(tau);
            let (g, h) = visual(tau, jd * rd, jd * jd)?;
            if !(h > 0.0 && g.is_finite() && h.is_finite()) {
                return Err(Error::NonFinite);
            }
            let step = -g / h;
            let next = tau + step;
            // The inverse depth stays positive: halve toward zero instead of crossing it.
            tau = if next > 0.0 { next } else { 0.5 * tau };
            if libm::fabs(step) <= TAU_TOL * tau {
                break;
            }
        }
        Ok(tau)
    }

    /// `tau*` on precomputed rays (same minimizer as `Self::best_tau`, a test-only reference).
    pub fn best_tau_rays(&self, rays: &[Ray], tau0: f64) -> Result<f64, Error> {
        self.gauss_newton_tau(tau0, |tau, mut g, mut h| {
            for ray in rays {
                let (r, jt) = ray.residual_and_d_tau(tau)?;
                g += jt.dot(&r);
                h += jt.norm_squared();
            }
            Ok((g, h))
        })
    }

    /// `|e(tau)|^2` on precomputed rays.
    pub fn stacked_sq_rays(&self, rays: &[Ray], tau: f64) -> Result<f64, Error> {
        let rd = self.depth_row(tau).0;
        let mut sq = rd * rd;
        for ray in rays {
            sq += ray.residual_and_d_tau(tau)?.0.norm_squared();
        }
        Ok(sq)
    }

    /// `tau*` and the rays for the given poses and camera frames.
    pub fn solve(
        &self,
        poses: &[KeyframePose; N],
        frames: &[CamFrame; N],
        tau0: f64,
    ) -> Result<(f64, HVec<Ray, N>), Error> {
        let rays = self.rays(poses, frames)?;
        let tau = self.best_tau_rays(&rays, tau0)?;
        Ok((tau, rays))
    }

    /// `tau*` = argmin of the stacked cost for the given poses, from `tau0` (or `1/d_r`).
    /// Reference form through the full factor chain (tests).
    #[cfg(test)]
    pub fn best_tau(
        &self,
        poses: &[KeyframePose; N],
        ext: &CameraExtrinsic,
        tau0: f64,
    ) -> Result<f64, Error> {
        let ps = poses.get(self.s).ok_or(Error::DimensionMismatch)?;
        self.gauss_newton_tau(tau0, |tau, mut g, mut h| {
            for (j, f) in self.obs.iter() {
                let pj = poses.get(*j).ok_or(Error::DimensionMismatch)?;
                let (r, jt) = f.residual_and_d_tau(ps, pj, ext, tau)?;
                g += jt.dot(&r);
                h += jt.norm_squared();
            }
            Ok((g, h))
        })
    }

    /// Stacked squared norm `|e(tau)|^2`.
    #[cfg(test)]
    pub fn stacked_sq(
        &self,
        poses: &[KeyframePose; N],
        ext: &CameraExtrinsic,
        tau: f64,
    ) -> Result<f64, Error> {
        let ps = poses.get(self.s).ok_or(Error::DimensionMismatch)?;
        let rd = self.depth_row(tau).0;
        let mut sq = rd * rd;
        for (j, f) in self.obs.iter() {
            let pj = poses.get(*j).ok_or(Error::DimensionMismatch)?;
            sq += f.residual(ps, pj, ext, tau)?.norm_squared();
        }
        Ok(sq)
    }
}

/// One observation as a function of the inverse depth (see [`TauLandmark::solve`]).
#[derive(Debug, Clone, Copy)]
pub(super) struct Ray {
    /// `R_jw R_ws x_s`.
    pub(super) a: Vec3,
    /// `R_js e_x`, `R_js e_y`: the derivatives of `a` in a correction `delta` of the anchor's
    /// bearing `x_s + (delta, 0)` (`estimator::problem::visual`).
    pub(super) a_d: [Vec3; 2],
    /// `R_jw (p_ws - p_wj)`.
    pub(super) b: Vec3,
    /// The delay-corrected observation in camera `j` (z = 1).
    pub(super) x_j: Vec2,
    /// Whitening (square root of the information) per axis.
    pub(super) w: Vec2,
}

impl Ray {
    /// Whitened residual `w (pi(a + tau b) - x_j)` and its derivative in `tau`.
    #[inline]
    pub(super) fn residual_and_d_tau(&self, tau: f64) -> Result<(Vec2, Vec2), Error> {
        let q = self.a + self.b * tau;
        // `q` points like P_j (tau > 0): the landmark must be in front of camera j.
        if q.z <= MIN_Z_REL * q.norm() || tau <= 0.0 {
            return Err(Error::Degenerate);
        }
        let iz = 1.0 / q.z;
        let (u, v) = (q.x * iz, q.y * iz);
        let r = Vec2::new((u - self.x_j.x) * self.w.x, (v - self.x_j.y) * self.w.y);
        let d = Vec2::new(
            (self.b.x - u * self.b.z) * iz * self.w.x,
            (self.b.y - v * self.b.z) * iz * self.w.y,
        );
        Ok((r, d))
    }

    /// Whitened residual `w (pi(a + R_js (delta, 0) + tau b) - x_j)` with the anchor's bearing
    /// corrected by `delta`, and its derivatives in `delta.x`, `delta.y` and `tau`.
    #[inline]
    pub(super) fn residual_and_d_bearing_tau(
        &self,
        delta: [f64; 2],
        tau: f64,
    ) -> Result<(Vec2, [Vec2; 3]), Error> {
        let [dx, dy] = self.a_d;
        let q = self.a + dx * delta[0] + dy * delta[1] + self.b * tau;
        if q.z <= MIN_Z_REL * q.norm() || tau <= 0.0 {
            return Err(Error::Degenerate);
        }
        let iz = 1.0 / q.z;
        let (u, v) = (q.x * iz, q.y * iz);
        let r = Vec2::new((u - self.x_j.x) * self.w.x, (v - self.x_j.y) * self.w.y);
        // d pi / d q applied to a direction `e` of `q`.
        let d = |e: &Vec3| {
            Vec2::new(
                (e.x - u * e.z) * iz * self.w.x,
                (e.y - v * e.z) * iz * self.w.y,
            )
        };
        Ok((r, [d(&dx), d(&dy), d(&self.b)]))
    }

    /// The ray's curvatures `kappa_k = e_k.z / q_z` in `(delta.x, delta.y, tau)` (`e_k` the
    /// direction each moves `q` in): the residual's second derivatives are
    /// `d2r/du_k du_l = -(kappa_l dr/du_k + kappa_k dr/du_l)` (for `u = q_x / q_z`,
    /// `u_kl = -(u_k e_l.z + u_l e_k.z) / q_z`).
    #[inline]
    pub(super) fn curvatures(&self, delta: [f64; 2], tau: f64) -> [f64; 3] {
        let [dx, dy] = self.a_d;
        let q_z = self.a.z + dx.z * delta[0] + dy.z * delta[1] + self.b.z * tau;
        [dx.z / q_z, dy.z / q_z, self.b.z / q_z]
    }
}
