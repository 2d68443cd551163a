//! The factor conformance suite: one set of checks that every factor of the window's problem
//! ([`WindowFactor`]) passes alike, instantiated per factor by [`factor_conformance!`].
//!
//! A case ([`Case`]) builds its factor on a [`Scene`] (a window of four keyframes from INS
//! propagations with their preintegrations, the extrinsic, one landmark seen by every keyframe,
//! a marginalization prior), exact or noisy, and says how to break it. A landmark's scene keeps
//! the inverse depth its factor solves for (as the assembly does), and a landmark's depth is
//! one more variable of the checks, which its factor eliminates. The checks:
//! - **exact data**: every residual row vanishes, and so does the cost;
//! - **Jacobian**: the factor's system in the normal equations against the Gauss–Newton system
//!   of its residual rows differentiated by central differences ([`crate::numdiff`], the one
//!   numerical differentiation of the tests) over every column of the layout and the
//!   landmark's depth, the depth eliminated by its Schur complement: `H` on exact and on noisy
//!   data, `b = -J^T r` on noisy data, each to 1e-7 of its largest entry;
//! - **cost**: the cost-only evaluation equals the linearization's cost and the squared norm of
//!   the residual rows (the noise stays inside the robust kernel's threshold);
//! - **NaN** and **degenerate** input give an error from every path;
//! - **no allocation** on any path (a counting global allocator, `factor_conformance.rs`).
#![allow(dead_code)]
#![allow(clippy::needless_range_loop)] // dense reference math reads best with indices

use crate::numdiff::central_differences;
use crate::vision_common::{euroc_extrinsic, Rng};
use povins_core::camera::{CameraExtrinsic, PinholeCamera};
use povins_core::estimator::prior::{LinPoint, MargPrior};
use povins_core::estimator::problem::{LandmarkFactor, WindowFactor, WindowVars, SCHUR_COLS};
use povins_core::estimator::window::{Block, Layout, Window};
use povins_core::estimator::EstimatorConfig;
use povins_core::factors::inverse_depth_visual::WindowRotations;
use povins_core::factors::KeyframePose;
use povins_core::inertial::ins::{Ins, InsConfig};
use povins_core::inertial::preintegration::{PreintConfig, Preintegration};
use povins_core::inertial::{ImuNoise, ImuSample, NavState};
use povins_core::landmarks::{KfObs, Landmark, LidarDepth, MargPlan};
use povins_core::math::{quat_exp, Vec3};
use povins_core::solver::{LandmarkSchur, NormalEquations};
use povins_core::Error;

/// Keyframes of the scenes' window.
pub const N: usize = 4;
/// Capacity of the normal equations (`16 N + 6`).
pub const D: usize = 16 * N + 6;
/// Keyframes at these IMU samples (200 Hz).
const KF_SAMPLES: [i64; N] = [0, 60, 120, 180];
/// Every keyframe's delay in the exact scenes, s (equal, so the delay random walk vanishes).
const TD_S: f64 = 0.004;
/// Central-difference step.
const H: f64 = 1e-6;

/// What the checks evaluate a factor on.
#[derive(Clone)]
pub struct Scene {
    /// Configuration (camera, noise, LiDAR on).
    pub cfg: EstimatorConfig,
    /// Keyframes with their preintegrations.
    pub window: Window<N>,
    /// Camera-IMU extrinsic.
    pub ext: CameraExtrinsic,
    /// Columns of the variables.
    pub layout: Layout<N>,
    /// A landmark seen by every keyframe, anchors `s = 0`, `e = 3`, with a LiDAR depth.
    pub lm: Landmark<N>,
    /// Its Schur accumulator.
    pub schur: LandmarkSchur<SCHUR_COLS>,
    /// A marginalization prior on keyframes 1..4, the extrinsic and delays 1..4 (with the
    /// extrinsic and the delays estimated).
    pub prior: MargPrior<D, N>,
    /// Samples the preintegrations were built from.
    pub samples: Vec<ImuSample>,
    /// Storage of the window's rotations, formed for every evaluation ([`Scene::split`]) as the
    /// assembly forms them for a linearization.
    pub rot: Option<WindowRotations<N>>,
    /// The exact scene's first state, delay (every keyframe's) and extrinsic: the priors'
    /// means.
    pub means: (NavState, f64, CameraExtrinsic),
}

/// The borrowed parts of a [`Scene`] a case builds its factor from.
pub struct Parts<'a> {
    pub cfg: &'a EstimatorConfig,
    pub lm: &'a Landmark<N>,
    pub schur: &'a mut LandmarkSchur<SCHUR_COLS>,
    pub prior: &'a mut MargPrior<D, N>,
}

/// Smooth motion, every gyro and accelerometer axis varying.
fn sample(k: i64) -> ImuSample {
    let t = k as f64 * 0.005;
    ImuSample {
        t_ns: 1_000_000_000 + k * 5_000_000,
        gyro_rps: Vec3::new(
            0.5 * libm::sin(1.3 * t),
            0.3 * libm::cos(0.7 * t),
            0.8 * libm::sin(0.5 * t + 1.0),
        ),
        accel_mps2: Vec3::new(
            1.0 + libm::sin(t),
            0.5 * libm::cos(2.0 * t),
            9.81 + 0.3 * libm::sin(3.0 * t),
        ),
    }
}

fn pose(st: &NavState, td: f64) -> KeyframePose {
    KeyframePose {
        p_wb: st.p_wb,
        q_wb: st.q_wb,
        td,
    }
}

impl Scene {
    /// The moving scene: the keyframes along one INS propagation (their preintegrations vanish
    /// on it), the landmark 5 m ahead of the first camera, exact observations with feature
    /// velocities and extraction delays; the layout estimates the extrinsic with `est_ext` and
    /// the delays with `est_td`.
    pub fn moving(est_ext: bool, est_td: bool, noise: ImuNoise) -> Box<Scene> {
        let x0 = NavState {
            t_ns: sample(0).t_ns,
            p_wb: Vec3::new(1.0, -2.0, 0.5),
            q_wb: quat_exp(&Vec3::new(0.3, -0.2, 1.0)),
            v_wb: Vec3::new(0.5, 0.2, -0.1),
            bg: Vec3::new(0.004, -0.003, 0.002),
            ba: Vec3::new(0.05, -0.04, 0.03),
        };
        let ins_cfg = InsConfig {
            gravity_mps2: 9.81,
            max_dt_s: 0.05,
        };
        let samples: Vec<ImuSample> = (0..=KF_SAMPLES[N - 1]).map(sample).collect();
        let mut states = [x0; N];
        let mut window = Window::<N>::new();
        window.push(x0.t_ns, x0, TD_S, false, None).unwrap();
        for k in 1..N {
            // Each interval integrated afresh from the previous keyframe, as its preintegration
            // is (the INS's two-sample correction would carry the samples before it).
            let (a, b) = (KF_SAMPLES[k - 1] as usize, KF_SAMPLES[k] as usize);
            let prev = states[k - 1];
            let mut ins = Ins::new(ins_cfg, prev).unwrap();
            let mut pre = Box::new(
                Preintegration::new(noise, PreintConfig::DEFAULT, &samples[a], prev.bg, prev.ba)
                    .unwrap(),
            );
            ins.propagate(&samples[a]).unwrap();
            for s in &samples[a + 1..=b] {
                ins.propagate(s).unwrap();
                pre.push(s).unwrap();
            }
            let mut st = *ins.state();
            // Gauss–Markov biases decay over the interval.
            if let Some(tau) = noise.bias_corr_time_s {
                let rho = libm::exp(-pre.dt_s() / tau);
                (st.bg, st.ba) = (prev.bg * rho, prev.ba * rho);
            }
            states[k] = st;
            window
                .push(st.t_ns, st, TD_S, false, Some(&mut pre))
                .unwrap();
        }
        let ext = euroc_extrinsic();
        let cfg = {
            let mut c = EstimatorConfig::new(PinholeCamera::EUROC_CAM0, ext, noise);
            c.lidar.enabled = true;
            c
        };
        let lm = Self::landmark(&states, &ext);
        let prior = MargPrior::new();
        let mut s = Box::new(Scene {
            cfg,
            window,
            ext,
            layout: Layout::solve(N, est_ext, est_td),
            lm,
            schur: LandmarkSchur::new(),
            prior,
            samples,
            rot: None,
            means: (states[0], TD_S, ext),
        });
        if est_ext && est_td {
            s.build_prior();
        }
        s
    }

    /// The static scene: every keyframe at the same pose at rest (zero-velocity updates
    /// vanish on it); no preintegrations.
    pub fn at_rest(est_ext: bool, est_td: bool) -> Box<Scene> {
        let mut s = Scene::moving(est_ext, est_td, ImuNoise::EUROC_ADIS16448);
        let st0 = s.window.get(0).unwrap().state;
        let mut window = Window::<N>::new();
        for k in 0..N {
            let st = NavState {
                v_wb: Vec3::zeros(),
                t_ns: st0.t_ns + k as i64 * 300_000_000,
                ..st0
            };
            window.push(st.t_ns, st, TD_S, true, None).unwrap();
        }
        s.window = window;
        s.means.0 = s.window.get(0).unwrap().state;
        s
    }

    /// The landmark seen by every keyframe (module docs).
    fn landmark(states: &[NavState; N], ext: &CameraExtrinsic) -> Landmark<N> {
        let mut rng = Rng::new(7);
        let c0 = ext.camera_pose(&states[0].p_wb, &states[0].q_wb);
        let depth0 = 5.0;
        let p_w = c0.p_wc + c0.q_wc * (Vec3::new(0.1, -0.05, 1.0) * depth0);
        let obs = core::array::from_fn(|k| {
            let c = ext.camera_pose(&states[k].p_wb, &states[k].q_wb);
            let p_c = c.q_wc.inverse() * (p_w - c.p_wc);
            assert!(p_c.z > 1.0, "the landmark is in front of every camera");
            let vel = [rng.range(-0.5, 0.5), rng.range(-0.5, 0.5)];
            let td0_s = rng.range(-0.01, 0.01);
            Some(KfObs {
                x_n: [
                    p_c.x / p_c.z + vel[0] * (TD_S - td0_s),
                    p_c.y / p_c.z + vel[1] * (TD_S - td0_s),
                ],
                vel,
                td0_s,
            })
        });
        Landmark {
            id: 1,
            obs,
            anchor_s: 0,
            anchor_e: Some(3),
            inv_depth: 1.0 / depth0,
            bearing_delta: [0.0; 2],
            usable: true,
            lidar: Some(LidarDepth {
                depth_m: depth0,
                sigma_m: 0.1,
            }),
            marg: MargPlan::None,
        }
    }

    /// A prior on keyframes 1..4, the extrinsic and delays 1..4 at their current values: a
    /// well-conditioned upper-triangular `J0`, `r0 = 0`.
    fn build_prior(&mut self) {
        let mut rng = Rng::new(11);
        let mut prior = MargPrior::<D, N>::new();
        for k in 1..N {
            let st = self.window.get(k).unwrap().state;
            prior
                .blocks
                .push((Block::Kf(k as u8), LinPoint::Kf(st)))
                .unwrap();
        }
        prior
            .blocks
            .push((Block::Ext, LinPoint::Ext(self.ext)))
            .unwrap();
        for k in 1..N {
            let td = self.window.get(k).unwrap().td_s;
            prior
                .blocks
                .push((Block::Td(k as u8), LinPoint::Td(td)))
                .unwrap();
        }
        let p: usize = prior.blocks.iter().map(|(b, _)| b.dim()).sum();
        for i in 0..p {
            for j in i..p {
                prior.j0[i][j] = if i == j {
                    1.0 + rng.uniform()
                } else {
                    0.2 * (rng.uniform() - 0.5)
                };
            }
        }
        let mut h_star = Box::new(NormalEquations::<D>::new());
        h_star.reset(p).unwrap();
        for i in 0..p {
            for j in i..p {
                h_star.h[i][j] = (0..=i).map(|k| prior.j0[k][i] * prior.j0[k][j]).sum();
            }
        }
        prior.set_dim(p, &h_star).unwrap();
        self.prior = prior;
    }

    /// The variables (as the assembly sees them) and the parts a factor is built from.
    pub fn split(&mut self) -> (WindowVars<'_, N>, Parts<'_>) {
        let poses = self.window.poses();
        self.rot = Some(WindowRotations::new(&poses, self.window.len(), &self.ext));
        let v = WindowVars::new(&self.window, &self.ext, self.layout, self.rot.as_ref());
        let parts = Parts {
            cfg: &self.cfg,
            lm: &self.lm,
            schur: &mut self.schur,
            prior: &mut self.prior,
        };
        (v, parts)
    }

    /// Moves the variables by `dx` on the layout's columns as the LM applies a step
    /// (`p += dp`, `R <- R Exp(dtheta)`, ...); `locals` entries after them move the landmark's
    /// own parameters: 1, its inverse depth; 3, its anchor bearing correction and inverse depth.
    pub fn apply(&mut self, dx: &[f64], locals: usize) {
        let l = self.layout;
        let get3 = |c: usize| Vec3::new(dx[c], dx[c + 1], dx[c + 2]);
        for k in 0..self.window.len() {
            let tdc = l.col(Block::Td(k as u8));
            let kf = self.window.get_mut(k).unwrap();
            if let Some(c) = l.col(Block::Kf(k as u8)) {
                let s = &mut kf.state;
                s.p_wb += get3(c);
                s.q_wb *= quat_exp(&get3(c + 3));
                s.v_wb += get3(c + 6);
                s.bg += get3(c + 9);
                s.ba += get3(c + 12);
            }
            if let Some(t) = tdc {
                kf.td_s += dx[t];
            }
        }
        if let Some(c) = l.col(Block::Ext) {
            self.ext.p_bc += get3(c);
            self.ext.q_bc *= quat_exp(&get3(c + 3));
        }
        let n = l.dim();
        match locals {
            0 => {}
            1 => self.lm.inv_depth += dx[n],
            3 => {
                self.lm.bearing_delta[0] += dx[n];
                self.lm.bearing_delta[1] += dx[n + 1];
                self.lm.inv_depth += dx[n + 2];
            }
            _ => panic!("{locals} local parameters"),
        }
    }

    /// The same scene with noise: observations 1e-4 (0.05 px) off, the LiDAR depth 3 cm off,
    /// every variable moved by up to 3e-4, the inverse depth 1 % off.
    pub fn noisy(&self) -> Box<Scene> {
        let mut s = Box::new(self.clone());
        let mut rng = Rng::new(3);
        for o in s.lm.obs.iter_mut().flatten() {
            o.x_n[0] += 1e-4 * rng.normal();
            o.x_n[1] += 1e-4 * rng.normal();
        }
        if let Some(d) = s.lm.lidar.as_mut() {
            d.depth_m += 0.03;
        }
        s.lm.inv_depth *= 1.01;
        let dx: Vec<f64> = (0..s.layout.dim())
            .map(|_| rng.range(-3e-4, 3e-4))
            .collect();
        s.apply(&dx, 0);
        s
    }
}

/// One factor under the suite: how to build it on a scene and how to break it.
pub trait Case {
    /// The landmark's own parameters the factor eliminates in its linearization (moved by
    /// [`Scene::apply`]): 0; 1, the inverse depth; 3, the anchor bearing correction and the
    /// inverse depth.
    const LOCALS: usize = 0;
    /// The exact scene.
    fn scene() -> Box<Scene>;
    /// Builds the factor on `s` and runs `f` on it.
    fn with<R>(s: &mut Scene, f: impl FnOnce(&mut dyn Eval, &WindowVars<'_, N>) -> R) -> R;
    /// Makes an input the factor reads non-finite.
    fn nan(s: &mut Scene);
    /// Makes the factor's input degenerate (geometry it cannot be evaluated at).
    fn degenerate(s: &mut Scene);
}

/// A factor's paths, object-safe.
pub trait Eval {
    fn cost(&mut self, v: &WindowVars<'_, N>) -> Result<f64, Error>;
    fn linearize(
        &mut self,
        v: &WindowVars<'_, N>,
        ne: &mut NormalEquations<D>,
    ) -> Result<f64, Error>;
    fn residuals(&mut self, v: &WindowVars<'_, N>, out: &mut [f64]) -> Result<usize, Error>;
    /// The inverse depth the landmark keeps after the last evaluation, if any.
    fn inverse_depth(&self) -> Option<f64> {
        None
    }
    /// The anchor bearing correction the landmark keeps after the last evaluation, if any.
    fn bearing_delta(&self) -> Option<[f64; 2]> {
        None
    }
}

/// A landmark's measurement as an [`Eval`] that reports the inverse depth it keeps.
pub struct Keeps<F>(pub F);

impl<F: LandmarkFactor<N, D>> Eval for Keeps<F> {
    fn cost(&mut self, v: &WindowVars<'_, N>) -> Result<f64, Error> {
        self.0.add(v, None)
    }
    fn linearize(
        &mut self,
        v: &WindowVars<'_, N>,
        ne: &mut NormalEquations<D>,
    ) -> Result<f64, Error> {
        self.0.add(v, Some(ne))
    }
    fn residuals(&mut self, v: &WindowVars<'_, N>, out: &mut [f64]) -> Result<usize, Error> {
        WindowFactor::residuals(&mut self.0, v, out)
    }
    fn inverse_depth(&self) -> Option<f64> {
        LandmarkFactor::<N, D>::inverse_depth(&self.0)
    }
    fn bearing_delta(&self) -> Option<[f64; 2]> {
        LandmarkFactor::<N, D>::bearing_delta(&self.0)
    }
}

impl<F: WindowFactor<N, D>> Eval for F {
    fn cost(&mut self, v: &WindowVars<'_, N>) -> Result<f64, Error> {
        self.add(v, None)
    }
    fn linearize(
        &mut self,
        v: &WindowVars<'_, N>,
        ne: &mut NormalEquations<D>,
    ) -> Result<f64, Error> {
        self.add(v, Some(ne))
    }
    fn residuals(&mut self, v: &WindowVars<'_, N>, out: &mut [f64]) -> Result<usize, Error> {
        WindowFactor::residuals(self, v, out)
    }
}

/// Most residual rows of a factor.
const ROWS: usize = 2 * D;

fn residuals<C: Case>(s: &mut Scene) -> Result<Vec<f64>, Error> {
    let mut out = [0.0; ROWS];
    let n = C::with(s, |f, v| f.residuals(v, &mut out))?;
    Ok(out[..n].to_vec())
}

fn cost<C: Case>(s: &mut Scene) -> Result<f64, Error> {
    C::with(s, |f, v| f.cost(v))
}

/// The factor's system at `s` (upper triangle) and its cost.
fn linearize<C: Case>(s: &mut Scene) -> Result<(Box<NormalEquations<D>>, f64), Error> {
    let mut ne = Box::new(NormalEquations::<D>::new());
    ne.reset(s.layout.dim()).unwrap();
    let c = C::with(s, |f, v| f.linearize(v, &mut ne))?;
    Ok((ne, c))
}

/// The landmark keeps the inverse depth its factor solves for at `s` (as the assembly keeps it).
fn settle<C: Case>(s: &mut Scene) {
    let mut ne = Box::new(NormalEquations::<D>::new());
    ne.reset(s.layout.dim()).unwrap();
    let (tau, delta) = C::with(s, |f, v| {
        f.linearize(v, &mut ne).unwrap();
        (f.inverse_depth(), f.bearing_delta())
    });
    if let Some(tau) = tau {
        s.lm.inv_depth = tau;
    }
    if let Some(delta) = delta {
        s.lm.bearing_delta = delta;
    }
}

/// The case's exact scene, settled.
fn exact<C: Case>() -> Box<Scene> {
    let mut s = C::scene();
    settle::<C>(&mut s);
    s
}

/// The case's noisy scene, settled.
fn noisy<C: Case>() -> Box<Scene> {
    let mut s = C::scene().noisy();
    settle::<C>(&mut s);
    s
}

/// The Gauss–Newton system `(H, b)` of the residual rows at `s` by central differences over the
/// layout's columns (and the local variables), the local variables eliminated.
fn reference<C: Case>(s: &Scene) -> (Vec<Vec<f64>>, Vec<f64>) {
    let nx = s.layout.dim();
    let n = nx + C::LOCALS;
    let r0 = residuals::<C>(&mut s.clone()).expect("residuals at the scene");
    let (m, jac) = central_differences(n, H, |dx| {
        let mut t = Box::new(s.clone());
        t.apply(dx, C::LOCALS);
        residuals::<C>(&mut t).expect("residuals near the scene")
    });
    assert_eq!(m, r0.len());
    let j = |r: usize, c: usize| jac[r * n + c];
    let mut h = vec![vec![0.0; n]; n];
    let mut b = vec![0.0; n];
    for a in 0..n {
        b[a] = -(0..m).map(|r| j(r, a) * r0[r]).sum::<f64>();
        for c in 0..n {
            h[a][c] = (0..m).map(|r| j(r, a) * j(r, c)).sum();
        }
    }
    // The local variables eliminated one after the other (a block Schur complement).
    for l in nx..n {
        assert!(h[l][l] > 0.0, "the local variable {} is observed", l - nx);
        let rest = || (0..nx).chain(l + 1..n);
        for a in rest() {
            b[a] -= h[a][l] * b[l] / h[l][l];
            for c in rest() {
                h[a][c] -= h[a][l] * h[l][c] / h[l][l];
            }
        }
    }
    h.truncate(nx);
    for row in h.iter_mut() {
        row.truncate(nx);
    }
    b.truncate(nx);
    (h, b)
}

/// Largest absolute value.
fn amax<'a>(v: impl IntoIterator<Item = &'a f64>) -> f64 {
    v.into_iter().fold(0.0, |a, x| a.max(x.abs()))
}

/// Every residual row and the cost vanish on exact data.
pub fn residual_is_zero_on_exact_data<C: Case>() {
    let mut s = exact::<C>();
    let r = residuals::<C>(&mut s).unwrap();
    assert!(!r.is_empty(), "the factor has residual rows");
    assert!(amax(&r) < 1e-7, "residual on exact data: {r:?}");
    let c = cost::<C>(&mut s).unwrap();
    assert!(c < 1e-12, "cost on exact data: {c}");
    // ... and not on the noisy data the other checks use.
    let r = residuals::<C>(&mut noisy::<C>()).unwrap();
    assert!(amax(&r) > 1e-5, "the noise shows in the residual: {r:?}");
}

/// `H` on exact and noisy data and `b` on noisy data against central differences (module
/// docs).
pub fn jacobian_matches_central_differences<C: Case>() {
    let (exact, noisy) = (exact::<C>(), noisy::<C>());
    for (name, scene, check_b) in [("exact", &exact, false), ("noisy", &noisy, true)] {
        let (ne, _) = linearize::<C>(&mut scene.clone()).unwrap();
        let (h, b) = reference::<C>(scene);
        let nx = h.len();
        {
            let scale = amax(h.iter().flatten());
            assert!(scale > 1e-6, "{name}: the factor has information");
            let mut worst = (0.0, 0, 0);
            for i in 0..nx {
                for j in i..nx {
                    let e = (ne.h[i][j] - h[i][j]).abs() / scale;
                    if e > worst.0 {
                        worst = (e, i, j);
                    }
                }
            }
            let (e, i, j) = worst;
            assert!(
                e < 1e-7,
                "{name}: H[{i}][{j}] analytic {} vs central differences {} (relative to max |H| \
                 {scale:.3e}: {e:.2e})",
                ne.h[i][j],
                h[i][j]
            );
        }
        if check_b {
            let scale = amax(&b);
            assert!(scale > 1e-9, "{name}: the factor has a gradient");
            let (e, i) = (0..nx)
                .map(|i| ((ne.b[i] - b[i]).abs() / scale, i))
                .fold((0.0, 0), |a, x| if x.0 > a.0 { x } else { a });
            assert!(
                e < 1e-7,
                "{name}: b[{i}] analytic {} vs central differences {} (relative to max |b| \
                 {scale:.3e}: {e:.2e})",
                ne.b[i],
                b[i]
            );
        }
    }
}

/// The cost-only evaluation equals the linearization's cost and the squared residual rows.
pub fn cost_only_equals_linearized_cost<C: Case>() {
    let noisy = noisy::<C>();
    let c = cost::<C>(&mut noisy.clone()).unwrap();
    let (_, cl) = linearize::<C>(&mut noisy.clone()).unwrap();
    let r = residuals::<C>(&mut noisy.clone()).unwrap();
    let sq: f64 = r.iter().map(|x| x * x).sum();
    assert!(c > 0.0);
    assert!(
        (c - cl).abs() <= 1e-9 * c,
        "cost only {c} vs linearized {cl}"
    );
    assert!(
        (c - sq).abs() <= 1e-8 * c,
        "cost {c} vs squared residual rows {sq}"
    );
}

fn rejected<C: Case>(s: &Scene, what: &str) {
    let c = cost::<C>(&mut s.clone());
    assert!(c.is_err(), "{what}: the cost is {c:?}");
    let l = linearize::<C>(&mut s.clone()).map(|x| x.1);
    assert!(l.is_err(), "{what}: the linearization's cost is {l:?}");
    let r = residuals::<C>(&mut s.clone());
    assert!(r.is_err(), "{what}: the residual rows are {r:?}");
}

/// Non-finite input is an error on every path.
pub fn nan_is_rejected<C: Case>() {
    let mut s = exact::<C>();
    C::nan(&mut s);
    rejected::<C>(&s, "NaN");
}

/// Degenerate input is an error on every path.
pub fn degenerate_input_is_rejected<C: Case>() {
    let mut s = exact::<C>();
    C::degenerate(&mut s);
    rejected::<C>(&s, "degenerate");
}

/// No path allocates.
pub fn does_not_allocate<C: Case>(count: impl Fn(&mut dyn FnMut()) -> usize) {
    let mut s = noisy::<C>();
    let mut ne = Box::new(NormalEquations::<D>::new());
    ne.reset(s.layout.dim()).unwrap();
    let mut out = [0.0; ROWS];
    let n = count(&mut || {
        C::with(&mut s, |f, v| {
            f.cost(v).unwrap();
            f.linearize(v, &mut ne).unwrap();
            f.residuals(v, &mut out).unwrap();
        })
    });
    assert_eq!(n, 0, "allocations");
}

/// The suite's tests for one case (module docs).
#[macro_export]
macro_rules! factor_conformance {
    ($($name:ident: $case:ty;)+) => {
        $(
            mod $name {
                use super::*;

                #[test]
                fn residual_is_zero_on_exact_data() {
                    conformance::residual_is_zero_on_exact_data::<$case>();
                }

                #[test]
                fn jacobian_matches_central_differences() {
                    conformance::jacobian_matches_central_differences::<$case>();
                }

                #[test]
                fn cost_only_equals_linearized_cost() {
                    conformance::cost_only_equals_linearized_cost::<$case>();
                }

                #[test]
                fn nan_is_rejected() {
                    conformance::nan_is_rejected::<$case>();
                }

                #[test]
                fn degenerate_input_is_rejected() {
                    conformance::degenerate_input_is_rejected::<$case>();
                }

                #[test]
                fn does_not_allocate() {
                    conformance::does_not_allocate::<$case>(|f| count_allocs(f));
                }
            }
        )+
    };
}
