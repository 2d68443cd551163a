//! LiDAR configuration: extrinsic, association parameters and the run-time switches of the
//! paper's ablations (Table VI).

use crate::math::{Quat, Vec3};
use crate::Error;

/// LiDAR in the body frame: `P_b = R_bl P_l + p_bl`.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct LidarExtrinsic {
    /// Rotation LiDAR -> body (serialized as `[x, y, z, w]`: `math::serde_quat_xyzw`).
    #[cfg_attr(feature = "serde", serde(with = "crate::math::serde_quat_xyzw"))]
    pub q_bl: Quat,
    /// LiDAR origin in the body frame, m.
    pub p_bl: Vec3,
}

impl LidarExtrinsic {
    /// The identity (LiDAR frame = body frame).
    pub fn identity() -> Self {
        Self::IDENTITY
    }

    /// The identity, as a constant.
    pub const IDENTITY: LidarExtrinsic = LidarExtrinsic {
        q_bl: crate::math::QUAT_IDENTITY,
        p_bl: crate::math::VEC3_ZERO,
    };
}

/// Which LiDAR-depth measurement the solver uses (paper V.C).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields, rename_all = "kebab-case")
)]
pub enum LdmMode {
    /// MSC-based LDM (eq. 25-30): the landmark's observations and depth in one measurement with
    /// the inverse depth projected out; no separate visual measurement (PO-VINS). With the
    /// visual depth eliminated (the default) the anchor's bearing is projected out with it.
    Msc,
    /// Direct LDM (eq. 24): `d_s(poses) - d_r` beside the landmark's visual measurements.
    Direct,
}

/// Depth association on the camera's unit sphere (LE-VINS).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct AssociationConfig {
    /// Angular size of a grid cell, rad.
    pub cell_rad: f64,
    /// Neighbours used for the plane fit (3 ..= [`AssociationConfig::MAX_NEIGHBOURS`]).
    pub neighbours: usize,
    /// Largest angle between the feature bearing and a neighbour's bearing, rad.
    pub max_neighbour_rad: f64,
    /// Largest distance of a neighbour from the fitted plane, m.
    pub max_plane_dist_m: f64,
    /// Largest spread of the neighbours' ranges relative to their mean range (foreground and
    /// background mixed in one fit fail this).
    pub max_range_spread: f64,
    /// Smallest cosine between the ray and the plane normal (grazing planes are unreliable).
    pub min_incidence_cos: f64,
    /// Accepted depth range (z in the camera), m.
    pub depth_range_m: (f64, f64),
    /// Points older than this before the keyframe are not used, s.
    pub span_s: f64,
}

impl AssociationConfig {
    /// Capacity of the neighbour search.
    pub const MAX_NEIGHBOURS: usize = 8;

    /// The defaults (what [`Default`] gives); `const` for static configurations.
    pub const DEFAULT: AssociationConfig = AssociationConfig {
        cell_rad: 0.5f64.to_radians(),
        // 8, not 5: on a Livox-like rosette (0.5 s, 50k points; `association` tests) the
        // five nearest cells are often one scan line (collinear: no plane), and with 2 cm
        // range noise five points 5 cm apart give normals too noisy for the incidence gate.
        // Bearings given a depth, noise-free / 2 cm noise (RMS, worst error with noise):
        // 5 -> 95% / 87% (2.4 cm, 11 cm); 8 -> 100% / 98% (1.8 cm, 9.9 cm).
        neighbours: 8,
        max_neighbour_rad: 2.0f64.to_radians(),
        max_plane_dist_m: 0.10,
        // 0.20, not 0.10: eight neighbours span about +-0.75 deg, over which one plane met
        // at incidence theta spreads its ranges by ~2 * 0.013 * tan(theta): 0.10 already
        // rejected planes at 76 deg that the incidence gate (78.5 deg) accepts, so grazing
        // surfaces were reported as "mixing". Real foreground/background mixing is far
        // above 0.2 (pole at 3 m before a wall at 7 m: 0.8), and mixed sets under it (a
        // board 0.5 m before a wall at 6 m) fail the plane or incidence checks (tests).
        max_range_spread: 0.20,
        min_incidence_cos: 0.2,
        depth_range_m: (0.5, 80.0),
        span_s: 0.5,
    };
}

impl Default for AssociationConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Largest LiDAR-IMU time offset accepted, s (`lidar.td_l_s`; the camera's delay has the same
/// bound): a larger one is a clock in another unit or epoch, not an offset.
pub const MAX_TD_L_S: f64 = 1.0;

/// LiDAR enhancement settings. `enabled = false` is PO-VINS-WO (LiDAR ignored).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct LidarConfig {
    /// Use LiDAR depths at all.
    pub enabled: bool,
    /// LiDAR-depth measurement model.
    pub ldm: LdmMode,
    /// Uncertainty-based rejection of LiDAR depths (paper IV.C).
    pub depth_outlier_rejection: bool,
    /// Depth-only optimization of LiDAR landmarks after each solve (paper V.D).
    pub depth_only_opt: bool,
    /// Standard deviation of an associated LiDAR depth at short range, m (paper: 0.1).
    pub sigma_dr_m: f64,
    /// Angular part of the LiDAR-depth standard deviation, rad (a relative depth error at
    /// normal incidence): the depth's sigma is `sqrt(sigma_dr_m^2 + (sigma_dr_rel d / c)^2)`
    /// ([`LidarConfig::sigma_dr`]) with `c = |n . b|` the cosine of the ray's incidence on the
    /// fitted plane. An angular error `a` between the feature's ray and the LiDAR points (the
    /// LiDAR-camera rotation's calibration, the feature's pixel noise, the de-skew) moves the
    /// ray's intersection with a plane at depth `d` by `a d / c` along the ray (to first order:
    /// `a d` head-on, `a d tan(theta)` of it from the plane's slope), so far depths and depths on
    /// surfaces seen obliquely (a road, a wall beside a car) are less certain than the paper's
    /// fixed 0.1 m says; 0 gives the paper's model. Default 0.01 (measured on the simulator,
    /// 0.5 deg calibration error, 40 s x 3 scenarios x 3 seeds: mean ATE 0.209 m against 0.243 m
    /// with 0, before the incidence term; BENCHMARKS "The LiDAR depth's sigma on oblique
    /// surfaces").
    pub sigma_dr_rel: f64,
    /// Feature noise used in the rejection's depth uncertainty, px (paper: 1.5).
    pub rejection_sigma_px: f64,
    /// Rejection gate in standard deviations of `1/d_v - 1/d_r` (paper: 3, in depth; see
    /// [`crate::lidar::rejection`]).
    pub rejection_sigmas: f64,
    /// LiDAR-IMU extrinsic.
    pub extrinsic: LidarExtrinsic,
    /// LiDAR-IMU time offset, `t_imu = t_lidar + td_l_s`, s, within [`MAX_TD_L_S`].
    pub td_l_s: f64,
    /// Association parameters.
    pub association: AssociationConfig,
    /// Drop, when a sweep is pushed, the points that cannot reach the camera's image within
    /// [`LidarConfig::view_margin_rad`] ([`crate::lidar::crop`]), so that a LiDAR that sees all
    /// around fills the buffers with points the association can use. Counted in
    /// `Counters::lidar_points_outside_view`.
    pub crop_to_view: bool,
    /// Angle added on every side of the camera's field of view by the crop, rad. Default 0.6:
    /// a camera turning at 1.2 rad/s over the association's 0.5 s span.
    pub view_margin_rad: f64,
}

impl LidarConfig {
    /// The paper's settings, LiDAR off (what [`Default`] gives); `const` for static
    /// configurations.
    pub const DEFAULT: LidarConfig = LidarConfig {
        enabled: false,
        ldm: LdmMode::Msc,
        depth_outlier_rejection: true,
        depth_only_opt: true,
        sigma_dr_m: 0.1,
        sigma_dr_rel: 0.01,
        rejection_sigma_px: 1.5,
        rejection_sigmas: 3.0,
        extrinsic: LidarExtrinsic::IDENTITY,
        td_l_s: 0.0,
        association: AssociationConfig::DEFAULT,
        crop_to_view: true,
        view_margin_rad: 0.6,
    };
}

impl Default for LidarConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl LidarConfig {
    /// Standard deviation of a LiDAR depth `depth_m` whose ray meets the fitted plane at
    /// incidence cosine `incidence_cos` (`DepthMeasurement::incidence_cos`; 1 head-on), m.
    /// The cosine is taken at least [`MIN_SIGMA_INCIDENCE_COS`] (a configuration with no
    /// incidence gate must not give an infinite sigma).
    ///
    /// [`MIN_SIGMA_INCIDENCE_COS`]: LidarConfig::MIN_SIGMA_INCIDENCE_COS
    pub fn sigma_dr(&self, depth_m: f64, incidence_cos: f64) -> f64 {
        let c = libm::fabs(incidence_cos).max(Self::MIN_SIGMA_INCIDENCE_COS);
        let rel = self.sigma_dr_rel * depth_m / c;
        libm::sqrt(self.sigma_dr_m * self.sigma_dr_m + rel * rel)
    }

    /// Smallest incidence cosine [`LidarConfig::sigma_dr`] uses (87 degrees from the normal).
    pub const MIN_SIGMA_INCIDENCE_COS: f64 = 0.05;

    /// [`Error::InvalidConfig`] for non-positive or non-finite parameters
    /// ([`Self::check_ranges`]).
    pub fn validate(&self) -> Result<(), Error> {
        crate::ranges::validate(|r| self.check_ranges(r))
    }

    /// The range checks (`[lidar]`): positive noise, thresholds and spans, a valid depth range,
    /// a finite extrinsic and delay.
    pub fn check_ranges(&self, r: &mut crate::ranges::Ranges<'_>) {
        let a = &self.association;
        r.positive("lidar.sigma_dr_m", self.sigma_dr_m);
        r.non_negative("lidar.sigma_dr_rel", self.sigma_dr_rel);
        r.positive("lidar.rejection_sigma_px", self.rejection_sigma_px);
        r.positive("lidar.rejection_sigmas", self.rejection_sigmas);
        r.within(
            "lidar.td_l_s",
            self.td_l_s,
            -MAX_TD_L_S,
            MAX_TD_L_S,
            "-1..=1 (s)",
        );
        let p = &self.extrinsic.p_bl;
        r.all_finite("lidar.extrinsic.p_bl", &[p.x, p.y, p.z]);
        let q = &self.extrinsic.q_bl.coords;
        r.all_finite("lidar.extrinsic.q_bl", &[q.x, q.y, q.z, q.w]);
        r.positive("lidar.association.cell_rad", a.cell_rad);
        r.check(
            "lidar.association.neighbours",
            a.neighbours as f64,
            "3..=8",
            (3..=AssociationConfig::MAX_NEIGHBOURS).contains(&a.neighbours),
        );
        r.positive("lidar.association.max_neighbour_rad", a.max_neighbour_rad);
        r.positive("lidar.association.max_plane_dist_m", a.max_plane_dist_m);
        r.positive("lidar.association.max_range_spread", a.max_range_spread);
        r.finite("lidar.association.min_incidence_cos", a.min_incidence_cos);
        let (near, far) = a.depth_range_m;
        r.positive("lidar.association.depth_range_m[0]", near);
        r.check(
            "lidar.association.depth_range_m[1]",
            far,
            "> depth_range_m[0], finite",
            far > near && far.is_finite(),
        );
        r.positive("lidar.association.span_s", a.span_s);
        r.check(
            "lidar.view_margin_rad",
            self.view_margin_rad,
            "0..=3.1416",
            (0.0..=core::f64::consts::PI).contains(&self.view_margin_rad),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_depths_sigma_grows_with_range_and_obliquity() {
        let cfg = LidarConfig::DEFAULT;
        let near_head_on = cfg.sigma_dr(1.0, 1.0);
        let head_on = cfg.sigma_dr(40.0, 1.0);
        // Head-on: the paper's 0.1 m beside the angular part at range.
        assert!((near_head_on - libm::hypot(0.1, 0.01)).abs() < 1e-12);
        assert!((head_on - libm::hypot(0.1, 0.4)).abs() < 1e-12);
        // At 60 degrees from the normal the angular part doubles; the sign of n.b is immaterial.
        assert!((cfg.sigma_dr(40.0, 0.5) - libm::hypot(0.1, 0.8)).abs() < 1e-12);
        assert_eq!(cfg.sigma_dr(40.0, -0.5), cfg.sigma_dr(40.0, 0.5));
        // A grazing ray (no incidence gate configured) stays finite, at the floor's cosine.
        let floor = cfg.sigma_dr(40.0, LidarConfig::MIN_SIGMA_INCIDENCE_COS);
        assert_eq!(cfg.sigma_dr(40.0, 0.0), floor);
        assert!(floor.is_finite() && floor > 7.9);
        // Without the angular part: the paper's fixed sigma at any range and incidence.
        let paper = LidarConfig {
            sigma_dr_rel: 0.0,
            ..LidarConfig::DEFAULT
        };
        assert_eq!(paper.sigma_dr(60.0, 0.2), 0.1);
    }
}
