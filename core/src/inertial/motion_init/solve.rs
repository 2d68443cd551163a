//! The solve of the in-motion initializer (the model is in the module docs of [`super`]):
//! gather the tracks of the init frames, reweighted linear least squares for `(v0, g)`, the
//! refinement of `g` on the sphere, and the checks that refuse a degenerate start.

use super::{InitFrame, MotionInitializer, Pre, Refusal};
use crate::camera::CameraExtrinsic;
use crate::math::{skew, Mat3, Vec3};
use heapless::Vec as HVec;
use nalgebra::{SMatrix, SVector};

type Mat6 = SMatrix<f64, 6, 6>;
type Vec6 = SVector<f64, 6>;
type Mat36 = SMatrix<f64, 3, 6>;
type Mat5 = SMatrix<f64, 5, 5>;
type Vec5 = SVector<f64, 5>;
type Mat65 = SMatrix<f64, 6, 5>;

/// Huber threshold on the whitened residual norm.
const HUBER: f64 = 2.0;
/// A view whose whitened residual is above this is an outlier (residual statistics).
const INLIER_SIGMAS: f64 = 3.0;
/// Reweighted linear solves.
const IRLS_ITERATIONS: usize = 5;
/// Gauss-Newton steps on `(v0, g, bg)`.
const BIAS_ITERATIONS: usize = 5;
/// Step halvings of one of them.
const STEP_HALVINGS: usize = 5;
/// Largest change of the gyro bias from the given one, rad/s (larger: kept as given).
const MAX_BIAS_STEP_RPS: f64 = 0.2;
/// Gauss-Newton steps on the gravity sphere.
const SPHERE_ITERATIONS: usize = 4;

/// What a successful solve found (everything in the oldest init frame's body frame `b0`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Solution {
    /// Velocity of the body at the oldest init frame, in `b0`, m/s.
    pub v0_b0: Vec3,
    /// Gravity in `b0` (norm: the configured gravity), m/s^2.
    pub g_b0: Vec3,
    /// Norm of the unconstrained gravity estimate, m/s^2.
    pub g_norm_free_mps2: f64,
    /// Largest posterior standard deviation of a velocity axis, m/s.
    pub std_v_mps: f64,
    /// Largest posterior standard deviation of the gravity direction, rad.
    pub std_g_rad: f64,
    /// RMS of the inliers' whitened residuals, sigmas.
    pub rms_sigmas: f64,
    /// Share of inlier views.
    pub inlier_ratio: f64,
    /// Tracks used.
    pub tracks: u32,
    /// Gyro bias estimated with `(v0, g)`, rad/s.
    pub bg: Vec3,
    /// The IMU integrated from `b0` to the newest sample.
    pub(crate) end: Pre,
}

/// One track's views: the init frame and its unit bearing in the camera; `r` the view of largest
/// parallax.
#[derive(Debug, Clone)]
pub(crate) struct Track<const K: usize> {
    views: HVec<(u8, Vec3), K>,
    r: u8,
}

/// The solve's storage (inside the initializer: nothing large on the stack).
#[derive(Debug, Clone)]
pub(crate) struct Scratch<const K: usize, const F: usize> {
    tracks: HVec<Track<K>, F>,
}

impl<const K: usize, const F: usize> Scratch<K, F> {
    pub(crate) const fn new() -> Self {
        Scratch {
            tracks: HVec::new(),
        }
    }
}

/// Residual statistics of one accumulation.
#[derive(Default)]
struct Stats {
    views: u32,
    inliers: u32,
    sq_inliers: f64,
}

/// Body position coefficients: `p(t) = A(t) x + ...` with `x = (v0, g)`.
fn a_of(t: f64) -> Mat36 {
    let mut a = Mat36::zeros();
    let h = 0.5 * t * t;
    for k in 0..3 {
        a[(k, k)] = t;
        a[(k, k + 3)] = h;
    }
    a
}

impl<const K: usize, const F: usize, const M: usize> MotionInitializer<K, F, M> {
    /// The solve (see the module docs of [`super`]); `Err` with the reason of a refusal.
    pub(super) fn solve(
        &mut self,
        ext: &CameraExtrinsic,
        gravity: f64,
        bg: &Vec3,
    ) -> Result<Solution, Refusal> {
        let mut pre = [Pre::ZERO; K];
        let mut end = self.integrate(bg, &mut pre).ok_or(Refusal::TooFewTracks)?;
        if !(gravity.is_finite() && gravity > 0.0) {
            return Err(Refusal::NonFinite);
        }
        let cfg = self.cfg;
        let r_bc = ext.q_bc.to_rotation_matrix().into_inner();
        let (seen, used) = gather(
            &self.frames,
            self.head,
            self.len,
            &pre,
            &r_bc,
            cfg.min_parallax_rad,
            &mut self.scratch,
        );
        if seen < cfg.min_tracks {
            return Err(Refusal::TooFewTracks);
        }
        if used < cfg.min_tracks {
            return Err(Refusal::LowParallax);
        }
        // Excitation (OpenVINS' "no accel jerk"): the spread of the frame-to-frame mean
        // specific force in b0. Without it an acceleration is a tilt of the gravity and the
        // scale of v0 is free (a vehicle cruising or in a steady turn).
        if excitation(&pre[..self.len.min(K)]) < cfg.min_accel_excitation_mps2 {
            return Err(Refusal::IllConditioned);
        }
        let tracks = &self.scratch.tracks;
        let p_bc = ext.p_bc;
        let sigma = cfg.sigma_rad;
        // Reweighted linear solves (the first in metres: no distances yet), then the gyro bias
        // with them, then the linear solves again at that bias.
        let (x, _) = irls(tracks, &pre, &r_bc, &p_bc, None, sigma, IRLS_ITERATIONS)?;
        let mut bg_used = *bg;
        let refined = (!self.hold_gyro_bias)
            .then(|| refine_bias(self, tracks, &r_bc, &p_bc, x, *bg, sigma))
            .flatten();
        if let Some((xb, bgb)) = refined {
            if (bgb - bg).norm() <= MAX_BIAS_STEP_RPS {
                if let Some(e) = self.integrate(&bgb, &mut pre) {
                    end = e;
                    bg_used = bgb;
                    let _ = xb;
                }
            }
        }
        let (x, h) = irls(tracks, &pre, &r_bc, &p_bc, Some(x), sigma, 2)?;
        let cov = h.cholesky().ok_or(Refusal::IllConditioned)?.inverse();
        let std_v_lin = (0..3).map(|k| cov[(k, k)]).fold(0.0, f64::max);
        if libm::sqrt(std_v_lin).is_nan() || libm::sqrt(std_v_lin) > cfg.max_velocity_std_mps {
            return Err(Refusal::IllConditioned);
        }
        let g_free = Vec3::new(x[3], x[4], x[5]);
        let g_norm = g_free.norm();
        let g_err = libm::fabs(g_norm - gravity);
        if g_err.is_nan() || g_err > cfg.max_gravity_norm_error * gravity {
            return Err(Refusal::GravityNorm);
        }
        // The gravity on the sphere |g| = gravity: two tangent unknowns (and v0).
        let mut g = g_free * (gravity / g_norm);
        let mut v0 = Vec3::new(x[0], x[1], x[2]);
        for _ in 0..SPHERE_ITERATIONS {
            let xg = Vec6::new(v0.x, v0.y, v0.z, g.x, g.y, g.z);
            let (hh, b, _) = accumulate(tracks, &pre, &r_bc, &p_bc, Some(&xg), sigma);
            let t = tangent(&g);
            let x0 = Vec6::new(0.0, 0.0, 0.0, g.x, g.y, g.z);
            let h5: Mat5 = t.transpose() * hh * t;
            let b5: Vec5 = t.transpose() * (hh * x0 + b);
            let y = -h5.cholesky().ok_or(Refusal::IllConditioned)?.solve(&b5);
            v0 = Vec3::new(y[0], y[1], y[2]);
            let dg = t.fixed_view::<3, 2>(3, 3) * y.fixed_rows::<2>(3);
            g = (g + dg).normalize() * gravity;
            if !(v0.iter().chain(g.iter()).all(|v| v.is_finite())) {
                return Err(Refusal::NonFinite);
            }
        }
        let xg = Vec6::new(v0.x, v0.y, v0.z, g.x, g.y, g.z);
        let (hh, _, st) = accumulate(tracks, &pre, &r_bc, &p_bc, Some(&xg), sigma);
        let t = tangent(&g);
        let h5: Mat5 = t.transpose() * hh * t;
        let cov5 = h5.cholesky().ok_or(Refusal::IllConditioned)?.inverse();
        let std_v = libm::sqrt((0..3).map(|k| cov5[(k, k)]).fold(0.0, f64::max));
        let std_g = libm::sqrt((3..5).map(|k| cov5[(k, k)]).fold(0.0, f64::max)) / gravity;
        // The scale: the velocity's standard deviation along itself, relative to its norm (a
        // constant velocity leaves it unobservable, and a scale shrunk towards zero shrinks
        // the absolute standard deviations with it).
        let speed = v0.norm();
        let cov_v = cov5.fixed_view::<3, 3>(0, 0);
        let rel_v = if speed > 0.0 {
            libm::sqrt((v0.transpose() * cov_v * v0)[0].max(0.0)) / (speed * speed)
        } else {
            0.0
        };
        if !(std_v <= cfg.max_velocity_std_mps
            && std_g <= cfg.max_gravity_std_rad
            && rel_v <= cfg.max_velocity_rel_std)
        {
            return Err(Refusal::IllConditioned);
        }
        let inlier_ratio = st.inliers as f64 / (st.views.max(1)) as f64;
        let rms = libm::sqrt(st.sq_inliers / st.inliers.max(1) as f64);
        if !(inlier_ratio >= cfg.min_inlier_ratio && rms <= cfg.max_residual_sigmas) {
            return Err(Refusal::Residual);
        }
        Ok(Solution {
            v0_b0: v0,
            g_b0: g,
            g_norm_free_mps2: g_norm,
            std_v_mps: std_v,
            std_g_rad: std_g,
            rms_sigmas: rms,
            inlier_ratio,
            tracks: used,
            bg: bg_used,
            end,
        })
    }
}

/// RMS deviation from their mean of the mean specific forces (in `b0`) of the intervals
/// between consecutive init frames, m/s^2 (0 below two intervals).
fn excitation(pre: &[Pre]) -> f64 {
    let mut acc: HVec<Vec3, 64> = HVec::new();
    for w in pre.windows(2) {
        if let [a, b] = w {
            let dt = b.t_s - a.t_s;
            if dt > 0.0 {
                let _ = acc.push((b.dv - a.dv) / dt);
            }
        }
    }
    if acc.len() < 2 {
        return 0.0;
    }
    let n = acc.len() as f64;
    let mean = acc.iter().fold(Vec3::zeros(), |s, a| s + a) / n;
    let var = acc.iter().map(|a| (a - mean).norm_squared()).sum::<f64>() / n;
    libm::sqrt(var)
}

/// `iterations` reweighted linear solves from `x` (none: the first unweighted); the solution
/// and the normal matrix of the last.
fn irls<const K: usize>(
    tracks: &[Track<K>],
    pre: &[Pre; K],
    r_bc: &Mat3,
    p_bc: &Vec3,
    mut x: Option<Vec6>,
    sigma: f64,
    iterations: usize,
) -> Result<(Vec6, Mat6), Refusal> {
    let mut h = Mat6::zeros();
    for _ in 0..iterations {
        let (hh, b, _) = accumulate(tracks, pre, r_bc, p_bc, x.as_ref(), sigma);
        let sol = -hh.cholesky().ok_or(Refusal::IllConditioned)?.solve(&b);
        if !sol.iter().all(|v| v.is_finite()) {
            return Err(Refusal::NonFinite);
        }
        x = Some(sol);
        h = hh;
    }
    Ok((x.ok_or(Refusal::IllConditioned)?, h))
}

/// `x = x0 + T y` with `y = (v0, w)`: the velocity kept, the gravity moved in the tangent plane
/// of `g` (basis in the lower right 3x2 block).
fn tangent(g: &Vec3) -> Mat65 {
    let n = g.normalize();
    let a = if libm::fabs(n.x) < 0.9 {
        Vec3::x()
    } else {
        Vec3::z()
    };
    let b1 = n.cross(&a).normalize();
    let b2 = n.cross(&b1);
    let mut t = Mat65::zeros();
    for k in 0..3 {
        t[(k, k)] = 1.0;
        t[(3 + k, 3)] = b1[k];
        t[(3 + k, 4)] = b2[k];
    }
    t
}

/// Whether `frame` sees track `id`, and its bearing.
fn find<const F: usize>(frame: &InitFrame<F>, id: u64) -> Option<Vec3> {
    let k = frame.obs.binary_search_by_key(&id, |o| o.0).ok()?;
    frame.obs.get(k).map(|o| o.1)
}

/// Collects into `scratch` the tracks seen in at least 3 init frames (bearings rotated into
/// `b0`) whose largest rotation-compensated parallax reaches `min_parallax`. Returns how many
/// were seen in 3 frames and how many were kept.
fn gather<const K: usize, const F: usize>(
    frames: &[InitFrame<F>; K],
    head: usize,
    len: usize,
    pre: &[Pre; K],
    r_bc: &Mat3,
    min_parallax: f64,
    scratch: &mut Scratch<K, F>,
) -> (u32, u32) {
    scratch.tracks.clear();
    let frame = |i: usize| frames.get((head + i) % K);
    let (mut seen, mut used) = (0u32, 0u32);
    for k in 0..len {
        let Some(fk) = frame(k) else { continue };
        for (id, _) in fk.obs.iter() {
            if (0..k).any(|j| frame(j).and_then(|f| find(f, *id)).is_some()) {
                continue;
            }
            let mut t = Track::<K> {
                views: HVec::new(),
                r: 0,
            };
            for j in k..len {
                let (Some(f), Some(p)) = (frame(j), pre.get(j)) else {
                    continue;
                };
                if let Some(u) = find(f, *id) {
                    let _ = p;
                    let _ = t.views.push((j as u8, u));
                }
            }
            if t.views.len() < 3 {
                continue;
            }
            seen += 1;
            let bearing = |&(j, u): &(u8, Vec3)| pre.get(j as usize).map(|p| p.r * (r_bc * u));
            let Some(m_l) = t.views.first().and_then(bearing) else {
                continue;
            };
            let (mut best, mut par) = (0usize, 0.0);
            for (i, v) in t.views.iter().enumerate().skip(1) {
                let Some(m) = bearing(v) else { continue };
                let p = m_l.cross(&m).norm();
                if p > par {
                    (best, par) = (i, p);
                }
            }
            if par.is_nan() || par < min_parallax || best == 0 {
                continue;
            }
            t.r = best as u8;
            if scratch.tracks.push(t).is_ok() {
                used += 1;
            }
        }
    }
    (seen, used)
}

/// A view's pieces under the integration `pre`: `A(t_i)`, the camera centre's known part
/// `Dp_i + R_i p_bc`, and the bearing `m_i = R_i R_bc u_i` (all in `b0`).
fn view_at<const K: usize>(
    v: &(u8, Vec3),
    pre: &[Pre; K],
    r_bc: &Mat3,
    p_bc: &Vec3,
) -> Option<(Mat36, Vec3, Vec3)> {
    let p = pre.get(v.0 as usize)?;
    Some((a_of(p.t_s), p.dp + p.r * p_bc, p.r * (r_bc * v.1)))
}

/// A track's anchor pieces under the integration `pre`, shared by its views: the first view
/// `l` (`A_l`, `b_l`, `m_l`) and the depth `d_l = d_a x + d_b` from the anchors `l`, `r`.
/// `None` when the anchors' bearings are parallel (or not finite).
struct Anchor {
    al: Mat36,
    bl: Vec3,
    m_l: Vec3,
    d_a: SMatrix<f64, 1, 6>,
    d_b: f64,
}

fn anchor<const K: usize>(
    t: &Track<K>,
    pre: &[Pre; K],
    r_bc: &Mat3,
    p_bc: &Vec3,
) -> Option<Anchor> {
    let (al, bl, m_l) = view_at(t.views.first()?, pre, r_bc, p_bc)?;
    let (ar, br, m_r) = view_at(t.views.get(t.r as usize)?, pre, r_bc, p_bc)?;
    let cr = m_r.cross(&m_l);
    let s2 = cr.norm_squared();
    if s2.is_nan() || s2 <= 0.0 {
        return None;
    }
    // d_l = a^T (c_r - c_l) = a^T (A_r - A_l) x + a^T (b_r - b_l)
    let a = cr.cross(&m_r) / s2;
    Some(Anchor {
        al,
        bl,
        m_l,
        d_a: a.transpose() * (ar - al),
        d_b: a.dot(&(br - bl)),
    })
}

/// One view's linear pieces under the integration `pre` (with its track's [`anchor`] under
/// the same `pre`): `X - c_i = D x + f` (the landmark from the anchors `l`, `r` minus the
/// view's camera centre, in `b0`) and the view's bearing `m_i`; the residual is
/// `[m_i]x (D x + f)`.
fn terms<const K: usize>(
    anc: &Anchor,
    t: &Track<K>,
    view: usize,
    pre: &[Pre; K],
    r_bc: &Mat3,
    p_bc: &Vec3,
) -> Option<(Mat36, Vec3, Vec3)> {
    let (ai, bi, m_i) = view_at(t.views.get(view)?, pre, r_bc, p_bc)?;
    Some((
        anc.al - ai + anc.m_l * anc.d_a,
        anc.bl - bi + anc.m_l * anc.d_b,
        m_i,
    ))
}

/// The weight of a view with `X - c_i = dvec` and residual `res` at the current `x`: the
/// whitening by the bearing noise times the distance, Huber; with the statistics.
fn weight(dvec: &Vec3, res: &Vec3, sigma: f64, st: &mut Stats) -> Option<f64> {
    let s = sigma * dvec.norm().max(1e-3);
    let z = res.norm() / s;
    if !z.is_finite() {
        return None;
    }
    st.views += 1;
    if z <= INLIER_SIGMAS {
        st.inliers += 1;
        st.sq_inliers += z * z;
    }
    let hub = if z <= HUBER { 1.0 } else { HUBER / z };
    Some(hub / (s * s))
}

/// The normal equations `H x = -b` of every view's `[m_i]x ((c_l - c_i) + m_l d_l)`; with a
/// current `x`, whitened by the bearing noise times the distance and Huber-reweighted (with
/// the residual statistics), else unweighted (metres).
fn accumulate<const K: usize>(
    tracks: &[Track<K>],
    pre: &[Pre; K],
    r_bc: &Mat3,
    p_bc: &Vec3,
    x: Option<&Vec6>,
    sigma: f64,
) -> (Mat6, Vec6, Stats) {
    let mut h = Mat6::zeros();
    let mut b = Vec6::zeros();
    let mut st = Stats::default();
    for t in tracks {
        let Some(anc) = anchor(t, pre, r_bc, p_bc) else {
            continue;
        };
        for view in 1..t.views.len() {
            let Some((d, f, m_i)) = terms(&anc, t, view, pre, r_bc, p_bc) else {
                continue;
            };
            let sk = skew(&m_i);
            let jac: Mat36 = sk * d;
            let e: Vec3 = sk * f;
            let w = match x {
                None => 1.0,
                Some(x) => match weight(&(d * x + f), &(jac * x + e), sigma, &mut st) {
                    Some(w) => w,
                    None => continue,
                },
            };
            h += jac.transpose() * jac * w;
            b += jac.transpose() * e * w;
        }
    }
    (h, b, st)
}

/// The Huber cost of the whitened residuals at `x` under `pre`.
fn robust_cost<const K: usize>(
    tracks: &[Track<K>],
    pre: &[Pre; K],
    r_bc: &Mat3,
    p_bc: &Vec3,
    x: &Vec6,
    sigma: f64,
) -> f64 {
    let mut c = 0.0;
    for t in tracks {
        let Some(anc) = anchor(t, pre, r_bc, p_bc) else {
            continue;
        };
        for view in 1..t.views.len() {
            let Some((d, f, m_i)) = terms(&anc, t, view, pre, r_bc, p_bc) else {
                continue;
            };
            let dvec = d * x + f;
            let z = m_i.cross(&dvec).norm() / (sigma * dvec.norm().max(1e-3));
            if z.is_finite() {
                c += if z <= HUBER {
                    z * z
                } else {
                    2.0 * HUBER * z - HUBER * HUBER
                };
            }
        }
    }
    c
}

/// Gauss-Newton steps on `(x, bg)` (the gyro bias's derivatives numeric, by re-integrating),
/// with the weights at the current values. Returns the refined `(x, bg)`; `None` when a step
/// fails (then the caller keeps its values).
#[allow(clippy::too_many_arguments)]
fn refine_bias<const K: usize, const F: usize, const M: usize>(
    init: &MotionInitializer<K, F, M>,
    tracks: &[Track<K>],
    r_bc: &Mat3,
    p_bc: &Vec3,
    mut x: Vec6,
    mut bg: Vec3,
    sigma: f64,
) -> Option<(Vec6, Vec3)> {
    const H: f64 = 1e-4;
    for _ in 0..BIAS_ITERATIONS {
        let mut pres = [[Pre::ZERO; K]; 4];
        for (k, p) in pres.iter_mut().enumerate() {
            let mut b = bg;
            if k > 0 {
                b[k - 1] += H;
            }
            init.integrate(&b, p)?;
        }
        let [p0, p1, p2, p3] = &pres;
        let mut h9 = SMatrix::<f64, 9, 9>::zeros();
        let mut b9 = SVector::<f64, 9>::zeros();
        let mut st = Stats::default();
        for t in tracks {
            let Some(anc0) = anchor(t, p0, r_bc, p_bc) else {
                continue;
            };
            let ancs = [p1, p2, p3].map(|p| anchor(t, p, r_bc, p_bc));
            for view in 1..t.views.len() {
                let Some((d, f, m_i)) = terms(&anc0, t, view, p0, r_bc, p_bc) else {
                    continue;
                };
                let dvec = d * x + f;
                let r0 = m_i.cross(&dvec);
                let Some(w) = weight(&dvec, &r0, sigma, &mut st) else {
                    continue;
                };
                let mut jac = SMatrix::<f64, 3, 9>::zeros();
                jac.fixed_view_mut::<3, 6>(0, 0)
                    .copy_from(&(skew(&m_i) * d));
                for (k, (p, anc)) in [p1, p2, p3].into_iter().zip(&ancs).enumerate() {
                    let Some((dk, fk, mk)) = anc
                        .as_ref()
                        .and_then(|anc| terms(anc, t, view, p, r_bc, p_bc))
                    else {
                        continue;
                    };
                    let rk = mk.cross(&(dk * x + fk));
                    jac.set_column(6 + k, &((rk - r0) / H));
                }
                h9 += jac.transpose() * jac * w;
                b9 += jac.transpose() * r0 * w;
            }
        }
        let dz = -h9.cholesky()?.solve(&b9);
        if !dz.iter().all(|v| v.is_finite()) {
            return None;
        }
        // Step halving on the robust cost (the residuals at a wrong bias are large: a full
        // Gauss-Newton step overshoots).
        let c0 = robust_cost(tracks, p0, r_bc, p_bc, &x, sigma);
        let mut accepted = false;
        let mut alpha = 1.0;
        for _ in 0..STEP_HALVINGS {
            let xa = x + dz.fixed_rows::<6>(0) * alpha;
            let ba = bg + dz.fixed_rows::<3>(6) * alpha;
            let mut pa = [Pre::ZERO; K];
            init.integrate(&ba, &mut pa)?;
            if robust_cost(tracks, &pa, r_bc, p_bc, &xa, sigma) < c0 {
                (x, bg, accepted) = (xa, ba, true);
                break;
            }
            alpha *= 0.5;
        }
        if !accepted {
            break;
        }
    }
    Some((x, bg))
}
