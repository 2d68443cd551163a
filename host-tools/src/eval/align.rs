//! Trajectory alignment: the similarity transform that maps the estimate's world `v` into the
//! ground truth's world `w`, fitted to matched positions only (as evo and OpenVINS ov_eval do):
//!
//! `p_w ~= s * R_wv * p_v + t_wv`, `q_wb_aligned = q_wv * q_vb`.
//!
//! With centered points `x_i = p_v,i - mean(p_v)`, `y_i = p_w,i - mean(p_w)`:
//!
//! - **SE3 / Sim3** (Umeyama 1991, evo's `geometry.umeyama_alignment`): `C = 1/n sum y_i x_i^T =
//!   U D V^T`, `S = diag(1, 1, det(U) det(V) < 0 ? -1 : 1)`, `R = U S V^T`,
//!   `s = tr(D S) / (1/n sum |x_i|^2)` (Sim3) or 1 (SE3), `t = mean(p_w) - s R mean(p_v)`.
//!   Fewer than two singular values above machine epsilon (collinear or coincident points)
//!   makes the rotation unobservable and is an error, as in evo.
//! - **PosYaw** (4-DoF, the gauge freedom of a VIO; OpenVINS `align_umeyama(.., known_scale,
//!   yaw_only)`): `R = Rz(theta)` maximizing `sum y_i . R x_i = tr(R H)`, `H = sum x_i y_i^T`;
//!   `tr(Rz(theta) H) = cos(theta) (H00 + H11) + sin(theta) (H01 - H10) + H22`, so
//!   `theta = atan2(H01 - H10, H00 + H11)`; `s = 1`, `t` as above. Roll and pitch are not
//!   corrected, so an estimate that tilted gravity is charged for it.

use anyhow::{bail, Result};
use nalgebra::Rotation3;
use povins_core::math::{Mat3, Quat, Vec3};
use serde::Serialize;

/// Which transform to fit between the estimate and the ground truth.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Alignment {
    /// Position and yaw (4-DoF), the unobservable directions of a visual-inertial estimator.
    #[value(name = "posyaw")]
    PosYaw,
    /// Rotation and translation (6-DoF).
    Se3,
    /// Rotation, translation and scale (7-DoF).
    Sim3,
    /// Compare as-is.
    None,
}

impl Alignment {
    /// The name used on the command line and in JSON.
    pub fn name(self) -> &'static str {
        match self {
            Alignment::PosYaw => "posyaw",
            Alignment::Se3 => "se3",
            Alignment::Sim3 => "sim3",
            Alignment::None => "none",
        }
    }
}

/// A similarity transform from the estimate's world `v` into the ground truth's world `w`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sim3 {
    /// Rotation `v -> w`.
    pub q_wv: Quat,
    /// Origin of `v` in `w`, m.
    pub t_wv: Vec3,
    /// Scale applied to `v` positions before rotating.
    pub scale: f64,
}

impl Sim3 {
    /// The identity.
    pub fn identity() -> Self {
        Sim3 {
            q_wv: Quat::identity(),
            t_wv: Vec3::zeros(),
            scale: 1.0,
        }
    }

    /// Maps a position of `v` into `w`.
    pub fn apply_position(&self, p_v: &Vec3) -> Vec3 {
        self.q_wv * (p_v * self.scale) + self.t_wv
    }

    /// Maps a body orientation in `v` into `w`.
    pub fn apply_rotation(&self, q_vb: &Quat) -> Quat {
        self.q_wv * q_vb
    }
}

/// The means of matched positions, summed one pair at a time (the first pass of an alignment;
/// [`Moments`] is the second).
#[derive(Debug, Clone, Copy, Default)]
pub struct Centering {
    n: usize,
    sum_v: Vec3,
    sum_w: Vec3,
}

impl Centering {
    /// Adds a matched pair: the estimate's position in `v`, the ground truth's in `w`.
    pub fn push(&mut self, p_v: &Vec3, p_w: &Vec3) {
        self.n += 1;
        self.sum_v += p_v;
        self.sum_w += p_w;
    }

    /// The second pass, about these means.
    pub fn moments(&self) -> Moments {
        let n = self.n.max(1) as f64;
        Moments {
            n: self.n,
            mu_v: self.sum_v / n,
            mu_w: self.sum_w / n,
            h: Mat3::zeros(),
            sigma_v: 0.0,
            spread: 0.0,
        }
    }
}

/// The second moments of matched positions about their means (see the module docs), summed one
/// pair at a time: what every alignment is fitted to.
#[derive(Debug, Clone, Copy)]
pub struct Moments {
    n: usize,
    mu_v: Vec3,
    mu_w: Vec3,
    /// `sum x_i y_i^T`.
    h: Mat3,
    /// `sum |x_i|^2`.
    sigma_v: f64,
    /// `sum |x_i,xy| |y_i,xy|`, the horizontal scale the yaw's observability is judged by.
    spread: f64,
}

impl Moments {
    /// Adds the pair again, in the order of [`Centering::push`].
    pub fn push(&mut self, p_v: &Vec3, p_w: &Vec3) {
        let (x, y) = (p_v - self.mu_v, p_w - self.mu_w);
        self.h += x * y.transpose();
        self.sigma_v += x.norm_squared();
        self.spread += x.xy().norm() * y.xy().norm();
    }

    /// Fits the transform `method` asks for.
    pub fn fit(&self, method: Alignment) -> Result<Sim3> {
        if self.n < 3 {
            bail!("alignment needs at least 3 matched points, got {}", self.n);
        }
        match method {
            Alignment::PosYaw => self.posyaw(),
            Alignment::Se3 => self.umeyama(false),
            Alignment::Sim3 => self.umeyama(true),
            Alignment::None => Ok(Sim3::identity()),
        }
    }

    fn umeyama(&self, with_scale: bool) -> Result<Sim3> {
        let n = self.n as f64;
        let cov = self.h.transpose() / n;
        let sigma_v = self.sigma_v / n;
        let Some(svd) = cov.try_svd_unordered(true, true, f64::EPSILON, 1000) else {
            bail!("Umeyama alignment: SVD of the cross-covariance did not converge");
        };
        let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
            bail!("Umeyama alignment: SVD returned no singular vectors");
        };
        let d = svd.singular_values;
        if d.iter().filter(|&&x| x > f64::EPSILON).count() < 2 {
            bail!("degenerate cross-covariance (positions collinear or static): Umeyama alignment is not possible");
        }
        // The reflection fix flips the direction of the smallest singular value; nalgebra's
        // unordered SVD does not promise which slot that is.
        let mut s_diag = Vec3::repeat(1.0);
        if u.determinant() * v_t.determinant() < 0.0 {
            let i_min = d.imin();
            s_diag[i_min] = -1.0;
        }
        let r = u * Mat3::from_diagonal(&s_diag) * v_t;
        let scale = if with_scale {
            if sigma_v <= 0.0 {
                bail!("estimate positions have zero spread: scale is not observable");
            }
            d.component_mul(&s_diag).sum() / sigma_v
        } else {
            1.0
        };
        let q_wv = Quat::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
        let t_wv = self.mu_w - q_wv * (self.mu_v * scale);
        Ok(Sim3 { q_wv, t_wv, scale })
    }

    fn posyaw(&self) -> Result<Sim3> {
        let h = &self.h;
        let a = h[(0, 1)] - h[(1, 0)];
        let b = h[(0, 0)] + h[(1, 1)];
        // Without horizontal motion every yaw fits equally well.
        if a.hypot(b) <= 1e-12 * self.spread || self.spread == 0.0 {
            bail!("no horizontal motion in the matched positions: yaw alignment is not observable");
        }
        let theta = a.atan2(b);
        let q_wv = Quat::from_axis_angle(&Vec3::z_axis(), theta);
        Ok(Sim3 {
            q_wv,
            t_wv: self.mu_w - q_wv * self.mu_v,
            scale: 1.0,
        })
    }
}

fn check_inputs(est_p_v: &[Vec3], gt_p_w: &[Vec3]) -> Result<()> {
    if est_p_v.len() != gt_p_w.len() {
        bail!(
            "alignment needs matched points: {} estimate vs {} ground truth",
            est_p_v.len(),
            gt_p_w.len()
        );
    }
    if est_p_v.len() < 3 {
        bail!(
            "alignment needs at least 3 matched points, got {}",
            est_p_v.len()
        );
    }
    Ok(())
}

/// The moments of matched positions held in memory (both passes).
fn moments(est_p_v: &[Vec3], gt_p_w: &[Vec3]) -> Result<Moments> {
    check_inputs(est_p_v, gt_p_w)?;
    let mut c = Centering::default();
    for (v, w) in est_p_v.iter().zip(gt_p_w) {
        c.push(v, w);
    }
    let mut m = c.moments();
    for (v, w) in est_p_v.iter().zip(gt_p_w) {
        m.push(v, w);
    }
    Ok(m)
}

/// Umeyama's least-squares similarity (`with_scale`) or rigid transform taking `est_p_v[i]` to
/// `gt_p_w[i]`.
pub fn umeyama(est_p_v: &[Vec3], gt_p_w: &[Vec3], with_scale: bool) -> Result<Sim3> {
    moments(est_p_v, gt_p_w)?.umeyama(with_scale)
}

/// The 4-DoF (position + yaw about the world z axis) transform taking `est_p_v[i]` to
/// `gt_p_w[i]`, both worlds z up.
pub fn posyaw(est_p_v: &[Vec3], gt_p_w: &[Vec3]) -> Result<Sim3> {
    moments(est_p_v, gt_p_w)?.posyaw()
}

/// Fits the transform `method` asks for.
pub fn align(method: Alignment, est_p_v: &[Vec3], gt_p_w: &[Vec3]) -> Result<Sim3> {
    moments(est_p_v, gt_p_w)?.fit(method)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::testutil::Rng;
    use povins_core::math::quat_exp;

    fn cloud(rng: &mut Rng, n: usize) -> Vec<Vec3> {
        (0..n).map(|_| rng.vec3() * 10.0).collect()
    }

    fn apply(t: &Sim3, pts: &[Vec3]) -> Vec<Vec3> {
        pts.iter().map(|p| t.apply_position(p)).collect()
    }

    fn assert_same(a: &Sim3, b: &Sim3) {
        assert!(a.q_wv.angle_to(&b.q_wv) < 1e-12, "{a:?} vs {b:?}");
        assert!((a.t_wv - b.t_wv).norm() < 1e-10, "{a:?} vs {b:?}");
        assert!((a.scale - b.scale).abs() < 1e-12, "{a:?} vs {b:?}");
    }

    #[test]
    fn umeyama_recovers_random_sim3_and_se3_exactly() {
        let mut rng = Rng::new(7);
        for trial in 0..20 {
            let pts = cloud(&mut rng, 50);
            let truth = Sim3 {
                q_wv: quat_exp(&(rng.vec3() * 3.0)),
                t_wv: rng.vec3() * 100.0,
                scale: 0.2 + 2.0 * (rng.next() + 1.0),
            };
            let got = umeyama(&pts, &apply(&truth, &pts), true).unwrap();
            assert_same(&got, &truth);
            let rigid = Sim3 {
                scale: 1.0,
                ..truth
            };
            let got = umeyama(&pts, &apply(&rigid, &pts), false).unwrap();
            assert_same(&got, &rigid);
            // SE3 must not absorb a scale error: points scaled by 2 keep a residual.
            if trial == 0 {
                let got = umeyama(&pts, &apply(&truth, &pts), false).unwrap();
                assert_eq!(got.scale, 1.0);
                let res: f64 = apply(&got, &pts)
                    .iter()
                    .zip(apply(&truth, &pts))
                    .map(|(a, b)| (a - b).norm())
                    .sum();
                assert!(res > 1.0, "{res}");
            }
        }
    }

    #[test]
    fn umeyama_handles_planar_points_with_a_reflection_free_rotation() {
        // Planar (rank-2) clouds are where the det(U) det(V) fix matters.
        let mut rng = Rng::new(11);
        let pts: Vec<Vec3> = (0..30)
            .map(|_| Vec3::new(rng.next() * 5.0, rng.next() * 5.0, 0.0))
            .collect();
        let truth = Sim3 {
            q_wv: quat_exp(&Vec3::new(0.3, -0.2, 2.5)),
            t_wv: Vec3::new(1.0, 2.0, 3.0),
            scale: 1.0,
        };
        let got = umeyama(&pts, &apply(&truth, &pts), false).unwrap();
        assert_same(&got, &truth);
    }

    #[test]
    fn posyaw_recovers_yaw_and_translation_but_not_roll() {
        let mut rng = Rng::new(3);
        let pts = cloud(&mut rng, 40);
        let truth = Sim3 {
            q_wv: Quat::from_axis_angle(&Vec3::z_axis(), -2.9),
            t_wv: Vec3::new(-4.0, 7.5, 1.25),
            scale: 1.0,
        };
        assert_same(&posyaw(&pts, &apply(&truth, &pts)).unwrap(), &truth);
        // A roll of the estimate's world is not a yaw: the fit stays yaw-only.
        let tilted = Sim3 {
            q_wv: quat_exp(&Vec3::new(0.1, 0.0, 0.4)),
            ..truth
        };
        let got = posyaw(&pts, &apply(&tilted, &pts)).unwrap();
        let axis_angle = got.q_wv.scaled_axis();
        assert!(axis_angle.x == 0.0 && axis_angle.y == 0.0, "{axis_angle:?}");
    }

    #[test]
    fn degenerate_inputs_are_errors() {
        let line: Vec<Vec3> = (0..10).map(|i| Vec3::new(i as f64, 0.0, 0.0)).collect();
        assert!(umeyama(&line, &line, false).is_err());
        let vertical: Vec<Vec3> = (0..10).map(|i| Vec3::new(0.0, 0.0, i as f64)).collect();
        assert!(posyaw(&vertical, &vertical).is_err());
        assert!(align(Alignment::Se3, &line[..2], &line[..2]).is_err());
        assert!(align(Alignment::None, &line[..3], &line[..2]).is_err());
    }
}
