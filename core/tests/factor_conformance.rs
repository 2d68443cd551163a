//! Every factor of the window's problem through the same conformance checks (`conformance`):
//! residual zero on exact data, analytic Jacobian against central differences, cost-only path
//! equal to the linearized cost, NaN and degenerate input rejected with an error, no
//! allocation. The factors: IMU preintegration (white and Gauss–Markov bias noise), the delay
//! random walk, the landmark models (two-view pose-only, direct LiDAR beside it, pose-only with
//! the depth eliminated, MSC LiDAR, inverse depth with its LiDAR prior) and the direct LiDAR
//! depth alone, each under the layouts that take different assembly paths, the priors (first
//! keyframe, first delay, extrinsic, marginalization) and the delay hold, the zero-velocity
//! updates.

mod conformance;
mod counting_alloc;
mod numdiff;
mod vision_common;

use conformance::{Case, Eval, Keeps, Scene, D, N};
use counting_alloc::count_allocs;
use povins_core::estimator::problem::{
    DirectDepth, DirectLidarLandmark, EliminatedLandmark, ExtPrior, FirstStatePrior, ImuFactor,
    InverseDepthLandmark, LandmarkFactor, MargPriorFactor, MscLandmark, TdHold, TdPrior,
    TdRandomWalkFactor, TwoViewLandmark, VisualSettings, WindowVars, ZuptPosition, ZuptRotation,
    ZuptVelocity,
};
use povins_core::factors::robust::Huber;
use povins_core::inertial::ImuNoise;
use povins_core::math::{quat_exp, Vec3};

/// Runs `f` on `factor` with the scene's variables.
fn run<R>(
    mut factor: impl Eval,
    v: &WindowVars<'_, N>,
    f: impl FnOnce(&mut dyn Eval, &WindowVars<'_, N>) -> R,
) -> R {
    f(&mut factor, v)
}

/// Keyframe `k`'s position made NaN.
fn nan_position(s: &mut Scene, k: usize) {
    s.window.get_mut(k).unwrap().state.p_wb.x = f64::NAN;
}

/// Keyframe `k` turned half around its camera's axes: the landmark is behind that camera.
fn turn_around(s: &mut Scene, k: usize) {
    let q_bc = s.ext.q_bc;
    let kf = s.window.get_mut(k).unwrap();
    // R_wb' R_bc = R_wb R_bc Ry(pi): the camera turned about its own y axis.
    kf.state.q_wb = kf.state.q_wb
        * q_bc
        * quat_exp(&Vec3::new(0.0, core::f64::consts::PI, 0.0))
        * q_bc.inverse();
}

/// Keyframe `k` at the position of keyframe 0 (no baseline between them).
fn no_baseline(s: &mut Scene, k: usize) {
    let p0 = s.window.get(0).unwrap().state.p_wb;
    let q0 = s.window.get(0).unwrap().state.q_wb;
    let kf = s.window.get_mut(k).unwrap();
    kf.state.p_wb = p0;
    kf.state.q_wb = q0;
}

// ------------------------------------------------------------------ IMU and delay

/// IMU preintegration from keyframe 1 to 2; `GM`: Gauss–Markov bias noise.
struct Imu<const GM: bool>;

impl<const GM: bool> Case for Imu<GM> {
    fn scene() -> Box<Scene> {
        let noise = ImuNoise {
            bias_corr_time_s: GM.then_some(3.0),
            ..ImuNoise::EUROC_ADIS16448
        };
        Scene::moving(false, false, noise)
    }
    fn with<R>(s: &mut Scene, f: impl FnOnce(&mut dyn Eval, &WindowVars<'_, N>) -> R) -> R {
        let gravity_mps2 = s.cfg.gravity_mps2;
        let (v, _) = s.split();
        run(ImuFactor { k: 2, gravity_mps2 }, &v, f)
    }
    fn nan(s: &mut Scene) {
        nan_position(s, 1);
    }
    fn degenerate(s: &mut Scene) {
        // No sample integrated: no measurement.
        let first = s.samples[60];
        let (bg, ba) = (Vec3::zeros(), Vec3::zeros());
        let kf = s.window.get_mut(2).unwrap();
        kf.preint_mut().unwrap().reset(&first, bg, ba).unwrap();
    }
}

/// The delay's random walk from keyframe 1 to 2.
struct TdWalk;

impl Case for TdWalk {
    fn scene() -> Box<Scene> {
        Scene::moving(false, true, ImuNoise::EUROC_ADIS16448)
    }
    fn with<R>(s: &mut Scene, f: impl FnOnce(&mut dyn Eval, &WindowVars<'_, N>) -> R) -> R {
        let rw_s_per_sqrt_s = s.cfg.td.rw_s_per_sqrt_s;
        let (v, _) = s.split();
        run(
            TdRandomWalkFactor {
                k: 2,
                rw_s_per_sqrt_s,
            },
            &v,
            f,
        )
    }
    fn nan(s: &mut Scene) {
        s.window.get_mut(1).unwrap().td_s = f64::NAN;
    }
    fn degenerate(s: &mut Scene) {
        // No random walk: no variance.
        s.cfg.td.rw_s_per_sqrt_s = 0.0;
    }
}

// ------------------------------------------------------------------ landmark models

/// The scene of a landmark model with the extrinsic (`EXT`) and the delays (`TD`) estimated.
fn landmark_scene(ext: bool, td: bool) -> Box<Scene> {
    Scene::moving(ext, td, ImuNoise::EUROC_ADIS16448)
}

/// The two-view pose-only measurement (PO-VINS).
struct TwoView<const EXT: bool, const TD: bool>;

impl<const EXT: bool, const TD: bool> Case for TwoView<EXT, TD> {
    fn scene() -> Box<Scene> {
        let mut s = landmark_scene(EXT, TD);
        s.lm.lidar = None;
        s
    }
    fn with<R>(s: &mut Scene, f: impl FnOnce(&mut dyn Eval, &WindowVars<'_, N>) -> R) -> R {
        let (v, p) = s.split();
        let vs = VisualSettings::new(p.cfg).unwrap();
        run(TwoViewLandmark::new(vs, p.lm, None).unwrap(), &v, f)
    }
    fn nan(s: &mut Scene) {
        nan_position(s, 1);
    }
    fn degenerate(s: &mut Scene) {
        no_baseline(s, 3);
    }
}

/// The two-view measurement with the direct LiDAR depth beside it.
struct DirectLidar<const EXT: bool, const TD: bool>;

impl<const EXT: bool, const TD: bool> Case for DirectLidar<EXT, TD> {
    fn scene() -> Box<Scene> {
        landmark_scene(EXT, TD)
    }
    fn with<R>(s: &mut Scene, f: impl FnOnce(&mut dyn Eval, &WindowVars<'_, N>) -> R) -> R {
        let (v, p) = s.split();
        let vs = VisualSettings::new(p.cfg).unwrap();
        run(DirectLidarLandmark::new(vs, p.lm).unwrap(), &v, f)
    }
    fn nan(s: &mut Scene) {
        nan_position(s, 1);
    }
    fn degenerate(s: &mut Scene) {
        turn_around(s, 2);
    }
}

/// The direct LiDAR depth alone.
struct DirectLidarDepth<const EXT: bool, const TD: bool>;

impl<const EXT: bool, const TD: bool> Case for DirectLidarDepth<EXT, TD> {
    fn scene() -> Box<Scene> {
        landmark_scene(EXT, TD)
    }
    fn with<R>(s: &mut Scene, f: impl FnOnce(&mut dyn Eval, &WindowVars<'_, N>) -> R) -> R {
        let (v, p) = s.split();
        let huber = Huber::new(p.cfg.huber_delta).unwrap();
        run(DirectDepth::new(huber, p.lm), &v, f)
    }
    fn nan(s: &mut Scene) {
        nan_position(s, 0);
    }
    fn degenerate(s: &mut Scene) {
        no_baseline(s, 3);
    }
}

/// The pose-only measurement with the depth eliminated (the default).
struct Eliminated<const EXT: bool, const TD: bool>;

impl<const EXT: bool, const TD: bool> Case for Eliminated<EXT, TD> {
    const LOCALS: usize = 3;
    fn scene() -> Box<Scene> {
        let mut s = landmark_scene(EXT, TD);
        s.lm.lidar = None;
        s
    }
    fn with<R>(s: &mut Scene, f: impl FnOnce(&mut dyn Eval, &WindowVars<'_, N>) -> R) -> R {
        let (v, p) = s.split();
        let vs = VisualSettings::new(p.cfg).unwrap();
        let elim = EliminatedLandmark::new(vs, p.lm, false, None);
        run(Keeps(elim), &v, f)
    }
    fn nan(s: &mut Scene) {
        nan_position(s, 1);
    }
    fn degenerate(s: &mut Scene) {
        turn_around(s, 2);
    }
}

/// The eliminated measurement of a LiDAR landmark: its depth row beside the reprojections (the
/// MSC-based LDM with the anchor's bearing free).
struct EliminatedLidar<const EXT: bool, const TD: bool>;

impl<const EXT: bool, const TD: bool> Case for EliminatedLidar<EXT, TD> {
    const LOCALS: usize = 3;
    fn scene() -> Box<Scene> {
        let mut s = landmark_scene(EXT, TD);
        s.cfg.lidar.enabled = true;
        assert!(
            s.lm.lidar.is_some(),
            "the scene's landmark has a LiDAR depth"
        );
        s
    }
    fn with<R>(s: &mut Scene, f: impl FnOnce(&mut dyn Eval, &WindowVars<'_, N>) -> R) -> R {
        let (v, p) = s.split();
        let vs = VisualSettings::new(p.cfg).unwrap();
        let elim = EliminatedLandmark::new(vs, p.lm, false, None);
        assert_eq!(LandmarkFactor::<N, D>::depth_measurements(&elim), 1);
        run(Keeps(elim), &v, f)
    }
    fn nan(s: &mut Scene) {
        nan_position(s, 1);
    }
    fn degenerate(s: &mut Scene) {
        turn_around(s, 2);
    }
}

/// The paper's MSC-based LiDAR-depth measurement (the anchor's bearing exact).
struct Msc<const EXT: bool, const TD: bool>;

impl<const EXT: bool, const TD: bool> Case for Msc<EXT, TD> {
    const LOCALS: usize = 1;
    fn scene() -> Box<Scene> {
        landmark_scene(EXT, TD)
    }
    fn with<R>(s: &mut Scene, f: impl FnOnce(&mut dyn Eval, &WindowVars<'_, N>) -> R) -> R {
        let (v, p) = s.split();
        let vs = VisualSettings::new(p.cfg).unwrap();
        run(Keeps(MscLandmark::new(vs, p.lm, p.schur)), &v, f)
    }
    fn nan(s: &mut Scene) {
        nan_position(s, 1);
    }
    fn degenerate(s: &mut Scene) {
        turn_around(s, 2);
    }
}

/// The inverse depth as a state, with the LiDAR depth as its prior.
struct InverseDepth<const EXT: bool, const TD: bool>;

impl<const EXT: bool, const TD: bool> Case for InverseDepth<EXT, TD> {
    const LOCALS: usize = 1;
    fn scene() -> Box<Scene> {
        landmark_scene(EXT, TD)
    }
    fn with<R>(s: &mut Scene, f: impl FnOnce(&mut dyn Eval, &WindowVars<'_, N>) -> R) -> R {
        let (v, p) = s.split();
        let vs = VisualSettings::new(p.cfg).unwrap();
        run(
            Keeps(InverseDepthLandmark::new(vs, p.lm, p.schur).unwrap()),
            &v,
            f,
        )
    }
    fn nan(s: &mut Scene) {
        nan_position(s, 1);
    }
    fn degenerate(s: &mut Scene) {
        turn_around(s, 2);
    }
}

// ------------------------------------------------------------------ priors and holds

/// The prior on the first keyframe's state.
struct FirstState;

impl Case for FirstState {
    fn scene() -> Box<Scene> {
        Scene::moving(false, false, ImuNoise::EUROC_ADIS16448)
    }
    fn with<R>(s: &mut Scene, f: impl FnOnce(&mut dyn Eval, &WindowVars<'_, N>) -> R) -> R {
        let kf0 = s.means.0;
        let p = s.cfg.first_prior;
        let sigma = [p.p_m, p.theta_rad, p.v_mps, p.bg_rps, p.ba_mps2];
        let (v, _) = s.split();
        run(FirstStatePrior { kf0, sigma }, &v, f)
    }
    fn nan(s: &mut Scene) {
        nan_position(s, 0);
    }
    fn degenerate(s: &mut Scene) {
        s.cfg.first_prior.theta_rad = 0.0;
    }
}

/// The prior on the first keyframe's delay.
struct FirstDelay;

impl Case for FirstDelay {
    fn scene() -> Box<Scene> {
        Scene::moving(false, true, ImuNoise::EUROC_ADIS16448)
    }
    fn with<R>(s: &mut Scene, f: impl FnOnce(&mut dyn Eval, &WindowVars<'_, N>) -> R) -> R {
        let td0_s = s.means.1;
        let sigma_s = s.cfg.td.prior_s;
        let (v, _) = s.split();
        run(TdPrior { td0_s, sigma_s }, &v, f)
    }
    fn nan(s: &mut Scene) {
        s.window.get_mut(0).unwrap().td_s = f64::NAN;
    }
    fn degenerate(s: &mut Scene) {
        s.cfg.td.prior_s = 0.0;
    }
}

/// The prior on the extrinsic.
struct Extrinsic;

impl Case for Extrinsic {
    fn scene() -> Box<Scene> {
        Scene::moving(true, false, ImuNoise::EUROC_ADIS16448)
    }
    fn with<R>(s: &mut Scene, f: impl FnOnce(&mut dyn Eval, &WindowVars<'_, N>) -> R) -> R {
        let ext0 = s.means.2;
        let (sigma_p_m, sigma_theta_rad) = s.cfg.extrinsic_prior;
        let (v, _) = s.split();
        let prior = ExtPrior {
            ext0,
            sigma_p_m,
            sigma_theta_rad,
        };
        run(prior, &v, f)
    }
    fn nan(s: &mut Scene) {
        s.ext.p_bc.y = f64::NAN;
    }
    fn degenerate(s: &mut Scene) {
        s.cfg.extrinsic_prior.1 = 0.0;
    }
}

/// The marginalization prior.
struct Marginalization;

impl Case for Marginalization {
    fn scene() -> Box<Scene> {
        Scene::moving(true, true, ImuNoise::EUROC_ADIS16448)
    }
    fn with<R>(s: &mut Scene, f: impl FnOnce(&mut dyn Eval, &WindowVars<'_, N>) -> R) -> R {
        let (v, p) = s.split();
        run(MargPriorFactor { prior: p.prior }, &v, f)
    }
    fn nan(s: &mut Scene) {
        nan_position(s, 2);
    }
    fn degenerate(s: &mut Scene) {
        // A block the window does not hold.
        s.window.drop_oldest();
    }
}

/// The delay hold of keyframe 2.
struct Hold;

impl Case for Hold {
    fn scene() -> Box<Scene> {
        Scene::moving(false, true, ImuNoise::EUROC_ADIS16448)
    }
    fn with<R>(s: &mut Scene, f: impl FnOnce(&mut dyn Eval, &WindowVars<'_, N>) -> R) -> R {
        let td0_s = s.means.1;
        let (v, _) = s.split();
        run(TdHold { k: 2, td0_s }, &v, f)
    }
    fn nan(s: &mut Scene) {
        s.window.get_mut(2).unwrap().td_s = f64::NAN;
    }
    fn degenerate(s: &mut Scene) {
        // Keyframe 2 is not in the window any more.
        s.window.drop_oldest();
        s.window.drop_oldest();
    }
}

/// Zero velocity of keyframe 2.
struct RestVelocity;

impl Case for RestVelocity {
    fn scene() -> Box<Scene> {
        Scene::at_rest(false, false)
    }
    fn with<R>(s: &mut Scene, f: impl FnOnce(&mut dyn Eval, &WindowVars<'_, N>) -> R) -> R {
        let sigma_mps = s.cfg.zupt.sigma_mps;
        let (v, _) = s.split();
        run(ZuptVelocity { k: 2, sigma_mps }, &v, f)
    }
    fn nan(s: &mut Scene) {
        s.window.get_mut(2).unwrap().state.v_wb.z = f64::NAN;
    }
    fn degenerate(s: &mut Scene) {
        s.cfg.zupt.sigma_mps = 0.0;
    }
}

/// No translation from keyframe 1 to 2.
struct RestPosition;

impl Case for RestPosition {
    fn scene() -> Box<Scene> {
        Scene::at_rest(false, false)
    }
    fn with<R>(s: &mut Scene, f: impl FnOnce(&mut dyn Eval, &WindowVars<'_, N>) -> R) -> R {
        let sigma_m = s.cfg.zupt.motion_sigma_m;
        let (v, _) = s.split();
        run(ZuptPosition { k: 2, sigma_m }, &v, f)
    }
    fn nan(s: &mut Scene) {
        nan_position(s, 1);
    }
    fn degenerate(s: &mut Scene) {
        s.cfg.zupt.motion_sigma_m = 0.0;
    }
}

/// No rotation from keyframe 1 to 2.
struct RestRotation;

impl Case for RestRotation {
    fn scene() -> Box<Scene> {
        Scene::at_rest(false, false)
    }
    fn with<R>(s: &mut Scene, f: impl FnOnce(&mut dyn Eval, &WindowVars<'_, N>) -> R) -> R {
        let sigma_rad = s.cfg.zupt.motion_sigma_rad;
        let (v, _) = s.split();
        run(ZuptRotation { k: 2, sigma_rad }, &v, f)
    }
    fn nan(s: &mut Scene) {
        let q = &mut s.window.get_mut(2).unwrap().state.q_wb;
        *q = povins_core::math::Quat::new_unchecked(nalgebra::Quaternion::new(
            f64::NAN,
            0.0,
            0.0,
            1.0,
        ));
    }
    fn degenerate(s: &mut Scene) {
        s.cfg.zupt.motion_sigma_rad = 0.0;
    }
}

factor_conformance! {
    imu_preintegration: Imu<false>;
    imu_preintegration_gauss_markov: Imu<true>;
    delay_random_walk: TdWalk;
    two_view: TwoView<false, false>;
    two_view_delays: TwoView<false, true>;
    two_view_extrinsic_delays: TwoView<true, true>;
    direct_lidar: DirectLidar<false, false>;
    direct_lidar_extrinsic_delays: DirectLidar<true, true>;
    direct_lidar_depth: DirectLidarDepth<false, false>;
    direct_lidar_depth_extrinsic_delays: DirectLidarDepth<true, true>;
    eliminated: Eliminated<false, false>;
    eliminated_delays: Eliminated<false, true>;
    eliminated_extrinsic: Eliminated<true, false>;
    eliminated_extrinsic_delays: Eliminated<true, true>;
    eliminated_lidar: EliminatedLidar<false, false>;
    eliminated_lidar_delays: EliminatedLidar<false, true>;
    eliminated_lidar_extrinsic_delays: EliminatedLidar<true, true>;
    msc_lidar: Msc<false, false>;
    msc_lidar_delays: Msc<false, true>;
    msc_lidar_extrinsic_delays: Msc<true, true>;
    inverse_depth: InverseDepth<false, false>;
    inverse_depth_extrinsic_delays: InverseDepth<true, true>;
    first_state_prior: FirstState;
    first_delay_prior: FirstDelay;
    extrinsic_prior: Extrinsic;
    marginalization_prior: Marginalization;
    delay_hold: Hold;
    zero_velocity: RestVelocity;
    zero_translation: RestPosition;
    zero_rotation: RestRotation;
}

// Keeps `D` in use for the reader: every case's normal equations have this capacity.
const _: usize = D;
