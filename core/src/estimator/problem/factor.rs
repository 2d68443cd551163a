//! The one interface of the window's factors ([`WindowFactor`]), the variables they read
//! ([`WindowVars`]) and the one choice of a landmark's measurement model ([`LandmarkModel`]).
//!
//! A factor of the window's least-squares problem is a whitened residual `r(x)` of some of the
//! window's variables `x` (keyframe states, delays, the extrinsic), with a robust kernel where it
//! has one. [`WindowFactor::add`] either returns its robust cost alone, or also adds its
//! Gauss–Newton system `H += J^T W J`, `b -= J^T W r` (IRLS weights `W`, see
//! [`crate::factors::robust`]) at the columns of the variables in the [`Layout`] into the
//! caller's [`NormalEquations`]; a variable without a column is held fixed. A measurement with a
//! nuisance parameter of its own (a landmark's inverse depth) adds the system with that
//! parameter eliminated by its Schur complement. [`WindowFactor::residuals`] gives the whitened
//! rows themselves, a landmark's at its inverse depth (for checks: the conformance suite
//! differentiates them numerically, the depth as one more variable that it eliminates).
//!
//! Every landmark has one [`LandmarkModel`], chosen by [`LandmarkModel::of`] alone: the assembly
//! (`estimator::problem::landmarks`) adds the landmark's factor of that model, and the culling
//! (`estimator::cull`) evaluates the landmark's residuals under the same model.
#![deny(clippy::too_many_lines)]

use crate::camera::{CameraExtrinsic, Vec2};
use crate::estimator::config::{EstimatorConfig, VisualMode};
use crate::estimator::window::{Block, Layout, Window};
use crate::factors::inverse_depth_visual::WindowRotations;
use crate::factors::pose_only_visual::PoseOnlyAnchors;
use crate::factors::robust::Huber;
use crate::factors::{CamFrame, KeyframePose, TimedObs};
use crate::landmarks::Landmark;
use crate::landmarks::{KfObs, LidarDepth};
use crate::lidar::LdmMode;
use crate::math::{Mat3, Vec3};
use crate::solver::{JacobianBlock, NormalEquations};
use crate::Error;
use core::cell::OnceCell;

/// The window's variables as its factors read them, with what a pass over the factors computes
/// once: the keyframes' body poses and camera frames, the window's rotations for a
/// linearization that needs them, and on first use the keyframe pairs' relative camera poses.
pub struct WindowVars<'a, const N: usize> {
    /// Keyframes: states, delays, preintegrations (positions `0..count`).
    pub window: &'a Window<N>,
    /// The camera-IMU extrinsic.
    pub ext: &'a CameraExtrinsic,
    /// Columns of the variables in the system (a block without a column is held fixed).
    pub layout: Layout<N>,
    /// Keyframes in the window.
    pub count: usize,
    /// The delays have columns.
    pub est_td: bool,
    /// The extrinsic has columns.
    pub est_ext: bool,
    /// Body poses and delays of the keyframes ([`Window::poses`]).
    pub poses: [KeyframePose; N],
    /// Camera frames of the keyframes.
    pub frames: [CamFrame; N],
    rel: OnceCell<[[(Mat3, Vec3); N]; N]>,
    rot: Option<&'a WindowRotations<N>>,
}

impl<'a, const N: usize> WindowVars<'a, N> {
    /// The variables of `window` and `ext` at the columns of `layout`, with the window's
    /// rotations `rot` ([`WindowRotations::new`] of the same poses and extrinsic) where the
    /// caller formed them ([`Self::rotations`]).
    #[inline(always)]
    pub fn new(
        window: &'a Window<N>,
        ext: &'a CameraExtrinsic,
        layout: Layout<N>,
        rot: Option<&'a WindowRotations<N>>,
    ) -> Self {
        let poses = window.poses();
        // Camera frames once per keyframe rather than three times per residual.
        let frames = core::array::from_fn(|k| CamFrame::new(&poses[k], ext));
        let count = window.len();
        WindowVars {
            rot,
            window,
            ext,
            layout,
            count,
            est_td: layout.col(Block::Td(0)).is_some(),
            est_ext: layout.col(Block::Ext).is_some(),
            poses,
            frames,
            rel: OnceCell::new(),
        }
    }

    /// `(R_js, t_js)` of camera `s` into camera `j` (`frames[j].relative_from(&frames[s])`),
    /// formed for every keyframe pair on the first call rather than per observation.
    pub fn relative(&self, j: usize, s: usize) -> Option<(Mat3, Vec3)> {
        let rel = self.rel.get_or_init(|| {
            let (frames, count) = (&self.frames, self.count);
            core::array::from_fn(|j| {
                core::array::from_fn(|s| match (frames.get(j), frames.get(s)) {
                    (Some(fj), Some(fs)) if j < count && s < count => fj.relative_from(fs),
                    _ => (Mat3::identity(), Vec3::zeros()),
                })
            })
        });
        rel.get(j).and_then(|row| row.get(s)).copied()
    }

    /// The window's rotations for the inverse-depth factors' pose Jacobians, if formed
    /// ([`Self::new`]).
    pub fn rotations(&self) -> Option<&WindowRotations<N>> {
        self.rot
    }

    /// First column of a block ([`Error::DimensionMismatch`] without one).
    pub fn col(&self, b: Block) -> Result<usize, Error> {
        self.layout.col(b).ok_or(Error::DimensionMismatch)
    }
}

/// A factor of the window's least-squares problem (module docs).
pub trait WindowFactor<const N: usize, const D: usize> {
    /// The factor's robust cost at `v`; with `ne`, its (IRLS-weighted) Gauss–Newton system is
    /// added too. On `Err` (non-finite or degenerate input, [`Error::NonFinite`],
    /// [`Error::Degenerate`], ...) the caller drops the factor or fails the evaluation.
    fn add(
        &mut self,
        v: &WindowVars<'_, N>,
        ne: Option<&mut NormalEquations<D>>,
    ) -> Result<f64, Error>;

    /// The whitened residual rows at `v` into `out` (before the robust kernel; a landmark's
    /// measurement at the landmark's inverse depth: the state of the inverse-depth mode, the
    /// depth a measurement that eliminates it solved for at its last linearization); returns
    /// their number. [`Error::NonFinite`] for a non-finite row, [`Error::CapacityExceeded`]
    /// when `out` is too short.
    fn residuals(&mut self, v: &WindowVars<'_, N>, out: &mut [f64]) -> Result<usize, Error>;
}

/// A landmark's measurement: a [`WindowFactor`] that also says what its last
/// [`WindowFactor::add`] used.
pub trait LandmarkFactor<const N: usize, const D: usize>: WindowFactor<N, D> {
    /// Visual observations (2-row reprojections) of the last `add`.
    fn observations(&self) -> u32;
    /// The work of the last `add` in units of one observation's residual evaluated
    /// ([`linearization_work`] where it linearized): what a solve's work budget counts
    /// ([`crate::solver::LmProblem::work`]). A factor that iterates over its observations (an
    /// eliminated depth's inner solve) counts each pass.
    fn work(&self, linearized: bool) -> u32 {
        let k = self.observations();
        if linearized {
            linearization_work(k)
        } else {
            k
        }
    }
    /// LiDAR-depth measurements of the last `add`.
    fn depth_measurements(&self) -> u32 {
        0
    }
    /// The inverse depth the landmark keeps after the last `add` (the one a measurement that
    /// eliminates its depth solved for), if any.
    fn inverse_depth(&self) -> Option<f64> {
        None
    }
    /// The correction of the anchor's bearing the landmark keeps after the last `add` (where the
    /// measurement solves for it with the depth), if any.
    fn bearing_delta(&self) -> Option<[f64; 2]> {
        None
    }
}

/// How a landmark's observations enter the window's problem: the one choice of a landmark's
/// measurement model (module docs). The assembly linearizes the landmark under it and the
/// culling evaluates its residuals under it, so a landmark is never culled under a model it was
/// not solved with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LandmarkModel {
    /// The paper's pose-only reprojections with the depth from the anchors `(s, e)`, exact in
    /// every residual ([`VisualDepth::TwoView`](super::VisualDepth::TwoView),
    /// `estimator::problem::pose_only`).
    TwoView,
    /// [`LandmarkModel::TwoView`] with the direct LiDAR-depth measurement beside it (a LiDAR
    /// landmark with [`LdmMode::Direct`], `estimator::problem::lidar`).
    DirectLidar,
    /// Pose-only reprojections with the inverse depth and anchor bearing that fit all
    /// observations eliminated
    /// ([`VisualDepth::Eliminated`](super::VisualDepth::Eliminated),
    /// `estimator::problem::visual`); a LiDAR landmark with [`LdmMode::Msc`] adds its depth
    /// row to them (the MSC-based LDM with the anchor's bearing free).
    Eliminated,
    /// The paper's MSC-based LiDAR-depth measurement, the anchor's bearing exact (a LiDAR
    /// landmark with [`LdmMode::Msc`] under the two-view visual depth,
    /// `estimator::problem::lidar`).
    MscLidar,
    /// The inverse depth as a state, eliminated by its Schur accumulator
    /// ([`VisualMode::InverseDepth`], `estimator::problem::inverse_depth`).
    InverseDepth,
}

/// The LiDAR depth landmark `lm`'s measurement takes under `cfg`: its associated depth while the
/// LiDAR is enabled (what makes it a LiDAR landmark for [`LandmarkModel::of`]).
pub fn lidar_depth<const N: usize>(cfg: &EstimatorConfig, lm: &Landmark<N>) -> Option<LidarDepth> {
    lm.lidar.filter(|_| cfg.lidar.enabled)
}

impl LandmarkModel {
    /// The model of landmark `lm` under `cfg`: the inverse-depth mode takes every landmark's
    /// depth as a state; otherwise a LiDAR landmark (with the LiDAR enabled) takes the configured
    /// LiDAR-depth measurement (the MSC-based one as the eliminated measurement with a depth row
    /// where the visual depth is eliminated, the paper's block under the two-view depth), and a
    /// visual one the configured pose-only depth (with the direct LDM every landmark keeps the
    /// two-view form, see [`EstimatorConfig::depth_eliminated`]).
    pub fn of<const N: usize>(cfg: &EstimatorConfig, lm: &Landmark<N>) -> Self {
        if cfg.mode == VisualMode::InverseDepth {
            return LandmarkModel::InverseDepth;
        }
        let lidar = lidar_depth(cfg, lm).is_some();
        match (lidar, cfg.lidar.ldm) {
            (true, LdmMode::Msc) if cfg.depth_eliminated() => LandmarkModel::Eliminated,
            (true, LdmMode::Msc) => LandmarkModel::MscLidar,
            (true, LdmMode::Direct) => LandmarkModel::DirectLidar,
            (false, _) if cfg.depth_eliminated() => LandmarkModel::Eliminated,
            (false, _) => LandmarkModel::TwoView,
        }
    }

    /// Whether the landmark's reprojections are the inverse-depth rays of its anchor `s` at the
    /// landmark's inverse depth (else the two-view form on its anchors `(s, e)`).
    pub fn uses_inverse_depth(self) -> bool {
        matches!(
            self,
            LandmarkModel::Eliminated | LandmarkModel::MscLidar | LandmarkModel::InverseDepth
        )
    }
}

/// What every landmark measurement takes from the configuration, formed once per pass over the
/// landmarks.
#[derive(Debug, Clone, Copy)]
pub struct VisualSettings<'a> {
    /// The configuration (camera, pixel noise, depth-uncertainty weighting, LiDAR).
    pub cfg: &'a EstimatorConfig,
    /// The visual residuals' robust kernel.
    pub huber: Huber,
    /// Whitening of a normalized-plane residual, `f / sigma_p` per axis.
    pub sqrt_info: Vec2,
}

impl<'a> VisualSettings<'a> {
    /// Errors: [`Error::InvalidConfig`] for a non-positive Huber threshold.
    pub fn new(cfg: &'a EstimatorConfig) -> Result<Self, Error> {
        Ok(VisualSettings {
            cfg,
            huber: Huber::new(cfg.huber_delta)?,
            sqrt_info: Vec2::new(cfg.camera.fx, cfg.camera.fy) / cfg.sigma_px,
        })
    }
}

/// The anchors' depth uncertainty for [`PoseOnlyAnchors::with_depth_std`] (0 when the weighting
/// is off or the uncertainty is undefined).
pub(in crate::estimator) fn anchor_depth_std(
    cfg: &EstimatorConfig,
    anchors: &PoseOnlyAnchors<'_>,
) -> f64 {
    if !cfg.depth_uncertainty_weighting {
        return 0.0;
    }
    let focal = Vec2::new(cfg.camera.fx, cfg.camera.fy);
    crate::landmarks::depth_std(anchors.two_view(), cfg.sigma_px, &focal).unwrap_or(0.0)
}

/// A landmark observation with its delay-correction data.
pub(in crate::estimator) fn timed(o: &KfObs) -> TimedObs {
    TimedObs {
        x_n: Vec2::new(o.x_n[0], o.x_n[1]),
        vel: Vec2::new(o.vel[0], o.vel[1]),
        td0: o.td0_s,
    }
}

/// Copies a column-major nalgebra matrix into a row-major slice.
pub(in crate::estimator) fn row_major<const R: usize, const C: usize>(
    m: &nalgebra::SMatrix<f64, R, C>,
    out: &mut [f64],
) {
    for (r, row) in out.chunks_mut(C).take(R).enumerate() {
        for (c, o) in row.iter_mut().enumerate() {
            *o = m[(r, c)];
        }
    }
}

/// Accumulates a residual or only its cost.
pub(in crate::estimator) fn sink<const D: usize>(
    ne: &mut Option<&mut NormalEquations<D>>,
    r: &[f64],
    blocks: &[JacobianBlock<'_>],
) -> Result<f64, Error> {
    let c: f64 = r.iter().map(|x| x * x).sum();
    if !c.is_finite() {
        return Err(Error::NonFinite);
    }
    if let Some(ne) = ne.as_deref_mut() {
        ne.add_blocks(r, blocks)?;
    }
    Ok(c)
}

/// Copies `rows` into the front of `out`: the number of rows; [`Error::NonFinite`] for a
/// non-finite row, [`Error::CapacityExceeded`] when `out` is too short.
pub(in crate::estimator) fn put_rows(rows: &[f64], out: &mut [f64]) -> Result<usize, Error> {
    if !rows.iter().all(|r| r.is_finite()) {
        return Err(Error::NonFinite);
    }
    out.get_mut(..rows.len())
        .ok_or(Error::CapacityExceeded)?
        .copy_from_slice(rows);
    Ok(rows.len())
}

/// The work of linearizing a landmark of `k` observations, in units of one observation's
/// residual evaluated ([`LandmarkFactor::work`]): each observation's Jacobians in the poses,
/// delays and extrinsic, its whitening and its share of the fold into the window's Hessian
/// ([`LINEARIZE_WORK_PER_OBS`]).
pub fn linearization_work(k: u32) -> u32 {
    k.saturating_mul(LINEARIZE_WORK_PER_OBS)
}

/// Work units per observation linearized ([`linearization_work`]): fitted to the solve's time
/// per keyframe on the simulator's five scenarios (2026-12-05: 0.30 us per observation and
/// pass of an eliminated depth's inner solve, 3.6 us per observation linearized, a term in the
/// pairs of a landmark's observations not significant). The budget needs a count that grows
/// as the time does, not the time.
pub const LINEARIZE_WORK_PER_OBS: u32 = 12;
