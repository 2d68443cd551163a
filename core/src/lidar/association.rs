//! Depth association on the unit sphere of the keyframe camera (LE-VINS, paper III).
//!
//! **Grid.** A buffered point `p_w` is expressed in the camera, `p_c = R_wc^T (p_w - p_wc)`, and
//! binned by its bearing on an equal-angle grid: column `floor(alpha / c + W/2)` with
//! `alpha = atan2(x, z)` (angle in the x-z plane), row `floor(beta / c + H/2)` with
//! `beta = atan2(y, z)` (angle in the y-z plane), `c` = [`AssociationConfig::cell_rad`]; the
//! default 256 x 192 cells of 0.5 deg span +-64 deg x +-48 deg around the optical axis. Both
//! angles come from the tangents `x/z`, `y/z`: no square root, so the binning loop vectorizes
//! (with `atan2(y, hypot(x, z))` it did not: 0.76 ms instead of 0.55 ms for 50k points). The
//! price is that cells shrink away from the axes: a cell spans `c cos(alpha)` of angle along
//! `beta` (and `c cos(beta)` along `alpha`), 0.77 c at 40 deg. Each cell keeps only its
//! nearest point (the foreground: a background point seen past an edge by the LiDAR is dropped
//! when a nearer one shares its cell). The angles are never computed per point:
//! `super::angle_index` maps the tangents to cells exactly with tabulated boundaries.
//!
//! **Association** of a feature at normalized coordinates `x_n`, bearing `b = (x, y, 1)/|.|`:
//! 1. the `k` points of largest `cos(b, p)` among the cells around `b`, no farther than
//!    `max_neighbour_rad` from `b` (else [`AssocReject::NoNeighbours`]); an angle `r` spans at
//!    most `r / cos(beta)` of `alpha` and `r / cos(alpha)` of `beta` (the grid metric), which
//!    sizes the searched window;
//! 2. range spread `(max |p| - min |p|) / mean |p| <= max_range_spread` (else
//!    [`AssocReject::RangeSpread`]): a foreground and a background surface in one set;
//! 3. total-least-squares plane `n . (p - c) = 0` (`super::plane`); every point within
//!    `max_plane_dist_m` of it, and the set not collinear (else [`AssocReject::PlaneFit`]);
//! 4. `|n . b| >= min_incidence_cos` (else [`AssocReject::Incidence`]);
//! 5. ray-plane intersection `P = t b`, `t = (n . c) / (n . b)`: range `t`, **depth = z = t b_z**
//!    (not the range: they differ by `|x_n, 1|`), inside `depth_range_m` (else
//!    [`AssocReject::DepthRange`]). On a plane `1/|p|` is linear in the bearing, so a bearing
//!    among its neighbours has a range between theirs: `t` outside
//!    `[min |p| - max_plane_dist_m, max |p| + max_plane_dist_m]` means a noise-tilted normal
//!    extrapolated far and is a [`AssocReject::PlaneFit`] (checked before the depth range).
//!
//! Times: the buffer stamps points on the LiDAR clock and `t_kf_ns` is on the IMU/camera clock;
//! the window `[t_kf - span_s, t_kf]` ignores their offset `td_l_s` (milliseconds against a
//! half-second span).

use super::angle_index::Axis;
use super::buffer::{seconds_to_ns, Packed, PointBuffer};
use super::config::AssociationConfig;
use super::plane::fit_plane;
use crate::camera::Vec2;
use crate::math::{Quat, Vec3};
use core::f64::consts::FRAC_PI_2;
use heapless::Vec as HVec;
use nalgebra::{Matrix3, Vector3};

/// Grid width (cells along the horizontal angle) of the estimator's sphere grid.
pub const GRID_W: usize = 256;
/// Grid height of the estimator's sphere grid.
pub const GRID_H: usize = 192;

/// Points nearer the camera plane than this (z, m) are not binned: behind the camera, or so
/// close that their bearing is meaningless for a feature.
const MIN_Z_M: f32 = 0.01;

/// Points binned per batch (3 kB of stack).
const CHUNK: usize = 128;

/// The neighbour search spans at most this many cells on each side of the bearing's cell
/// (bounds the cost for any configuration: at most 49 x 49 cells; the default searches 13 x 13
/// cells on the axis, 15 x 15 at 40 deg from it).
const MAX_SEARCH_HALF_CELLS: f64 = 24.0;

/// What [`SphereGrid::build`] saw.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GridStats {
    /// Buffered points considered (inside the time span).
    pub points: u32,
    /// Of those, in front of the camera and inside the grid.
    pub in_view: u32,
    /// Cells holding a point.
    pub cells_filled: u32,
}

/// A LiDAR depth for one feature bearing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthMeasurement {
    /// Depth: z of the ray-plane intersection in the camera, m.
    pub depth_m: f64,
    /// Range along the ray, m.
    pub range_m: f64,
    /// Neighbours in the plane fit.
    pub neighbours: u8,
    /// RMS distance of the neighbours from the plane, m.
    pub plane_rms_m: f64,
    /// `|n . b|`: cosine of the angle between the ray and the fitted plane's normal (1 head-on,
    /// at least [`AssociationConfig::min_incidence_cos`]).
    pub incidence_cos: f64,
}

/// Why a bearing got no depth.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AssocReject {
    /// Fewer than the configured neighbours within the angular radius.
    NoNeighbours,
    /// A neighbour is too far from the fitted plane (or the fit is degenerate).
    PlaneFit,
    /// Neighbour ranges spread too much (foreground mixed with background).
    RangeSpread,
    /// The ray grazes the plane.
    Incidence,
    /// The depth is outside the configured range.
    DepthRange,
    /// Non-finite input.
    NonFinite,
}

/// The nearest point of a cell in the camera frame `c` (x right, y down, z forward), m; `r2`
/// its squared range, `+inf` when the cell is empty.
#[derive(Debug, Clone, Copy)]
struct Cell {
    p_c: [f32; 3],
    r2: f32,
}

impl Cell {
    const EMPTY: Cell = Cell {
        p_c: [0.0; 3],
        r2: f32::INFINITY,
    };
    /// What a grid that was never built holds (all bits zero): every build starts by emptying
    /// the cells, and no cell is read before a build (`filled == 0`).
    const UNBUILT: Cell = Cell {
        p_c: [0.0; 3],
        r2: 0.0,
    };
}

/// Nearest point per angular cell of a `W x H` grid centred on the optical axis of one camera
/// pose (the frame `c` of the last [`SphereGrid::build`]); 16 bytes a cell (786 kB for
/// [`GRID_W`] x [`GRID_H`]: keep it in a `static` or a `Box`).
#[derive(Debug, Clone)]
pub struct SphereGrid<const W: usize, const H: usize> {
    cells: [[Cell; W]; H],
    /// Columns: tangent `x / z`; rows: tangent `y / z`.
    cols: Axis<W>,
    rows: Axis<H>,
    /// Cell size of the tables and the contents, rad; 0 until the first build.
    cell_rad: f64,
    filled: u32,
}

impl<const W: usize, const H: usize> Default for SphereGrid<W, H> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const W: usize, const H: usize> SphereGrid<W, H> {
    /// An empty grid; `const` so it can initialize a `static`. `W` or `H = 0` gives a grid that
    /// associates nothing (an estimator built without LiDAR storage).
    pub const fn new() -> Self {
        SphereGrid {
            cells: [[Cell::UNBUILT; W]; H],
            cols: Axis::new(),
            rows: Axis::new(),
            cell_rad: 0.0,
            filled: 0,
        }
    }

    /// Back to the state [`SphereGrid::new`] builds, in place.
    pub fn reset_to_new(&mut self) {
        for row in self.cells.iter_mut() {
            row.fill(Cell::UNBUILT);
        }
        self.cols.reset_to_new();
        self.rows.reset_to_new();
        self.cell_rad = 0.0;
        self.filled = 0;
    }

    /// Fills the grid with the buffered points of the last `cfg.span_s` before `t_kf_ns`,
    /// expressed in the camera with pose `(p_wc, q_wc)` in `w`. A non-finite pose or cell size
    /// leaves the grid empty.
    pub fn build<const P: usize>(
        &mut self,
        buf: &PointBuffer<P>,
        p_wc: &Vec3,
        q_wc: &Quat,
        t_kf_ns: i64,
        cfg: &AssociationConfig,
    ) -> GridStats {
        for row in self.cells.iter_mut() {
            row.fill(Cell::EMPTY);
        }
        self.filled = 0;
        let mut stats = GridStats::default();
        let pose_ok = p_wc.iter().chain(q_wc.coords.iter()).all(|v| v.is_finite());
        if !(pose_ok && cfg.cell_rad > 0.0 && cfg.cell_rad.is_finite()) {
            self.cell_rad = 0.0;
            return stats;
        }
        if cfg.cell_rad != self.cell_rad {
            self.cols.configure(cfg.cell_rad);
            self.rows.configure(cfg.cell_rad);
            self.cell_rad = cfg.cell_rad;
        }
        let r_cw = q_wc.inverse().to_rotation_matrix().into_inner();
        let r_f = r_cw.map(|v| v as f32);
        let t_min_ns = t_kf_ns.saturating_sub(seconds_to_ns(cfg.span_s).max(0));
        for seg in buf.segments() {
            // The span in the segment's time offsets.
            let lo = t_min_ns.saturating_sub(seg.t0_ns);
            let hi = t_kf_ns.saturating_sub(seg.t0_ns);
            let (dt_min, dt_max) = (i64::from(seg.dt_min), i64::from(seg.dt_max));
            if dt_max < lo || dt_min > hi {
                continue;
            }
            let span = (dt_min < lo || dt_max > hi).then_some((lo, hi));
            // Offsets are at most a few hundred metres: f32 keeps the camera-frame point to
            // 3e-5 m, and the grid stores f32 anyway.
            let o_c = (r_cw * (seg.origin_w - p_wc)).map(|v| v as f32);
            for chunk in seg.parts.iter().flat_map(|s| s.chunks(CHUNK)) {
                self.bin_chunk(chunk, &r_f, &o_c, span, &mut stats);
            }
        }
        stats.cells_filled = self.filled;
        stats
    }

    /// Bins up to [`CHUNK`] points: camera coordinates, tangents and squared ranges for the
    /// whole chunk first (straight-line loops the compiler vectorizes), then the cells. Points
    /// outside `span` (time offsets, when the segment straddles it) are skipped.
    fn bin_chunk(
        &mut self,
        pts: &[Packed],
        r: &Matrix3<f32>,
        o: &Vector3<f32>,
        span: Option<(i64, i64)>,
        stats: &mut GridStats,
    ) {
        let pts = pts.get(..CHUNK).unwrap_or(pts);
        // Structure of arrays, so the two loops below vectorize.
        let (mut xs, mut ys, mut zs) = ([0.0f32; CHUNK], [0.0f32; CHUNK], [0.0f32; CHUNK]);
        let xyz_mut = xs.iter_mut().zip(ys.iter_mut()).zip(zs.iter_mut());
        for (((x, y), z), q) in xyz_mut.zip(pts) {
            let [dx, dy, dz] = q.d_w;
            *x = o.x + r.m11 * dx + r.m12 * dy + r.m13 * dz;
            *y = o.y + r.m21 * dx + r.m22 * dy + r.m23 * dz;
            *z = o.z + r.m31 * dx + r.m32 * dy + r.m33 * dz;
        }
        // Tangents x/z and y/z, their table bins, squared range.
        let mut us = [0.0f32; CHUNK];
        let mut vs = [0.0f32; CHUNK];
        let mut bus = [0i32; CHUNK];
        let mut bvs = [0i32; CHUNK];
        let mut r2s = [0.0f32; CHUNK];
        let outs = us
            .iter_mut()
            .zip(vs.iter_mut())
            .zip(bus.iter_mut())
            .zip(bvs.iter_mut());
        let ins = xs.iter().zip(&ys).zip(&zs);
        for (((((u, v), bu), bv), r2), ((&x, &y), &z)) in outs.zip(r2s.iter_mut()).zip(ins) {
            *u = x / z;
            *v = y / z;
            *bu = self.cols.bin(*u);
            *bv = self.rows.bin(*v);
            *r2 = x * x + y * y + z * z;
        }
        // Offsets outside i32 cannot occur: the span is clamped to them.
        let (lo, hi) = span.map_or((i32::MIN, i32::MAX), |(lo, hi)| {
            (clamp_i32(lo), clamp_i32(hi))
        });
        let (mut points, mut in_view) = (0u32, 0u32);
        for (k, q) in pts.iter().enumerate() {
            let (Some(&x), Some(&y), Some(&z)) = (xs.get(k), ys.get(k), zs.get(k)) else {
                break;
            };
            let (Some(&u), Some(&v), Some(&bu), Some(&bv), Some(&r2)) =
                (us.get(k), vs.get(k), bus.get(k), bvs.get(k), r2s.get(k))
            else {
                break;
            };
            if q.dt_ns < lo || q.dt_ns > hi {
                continue;
            }
            points += 1;
            let in_front = z > MIN_Z_M; // false for NaN too
            if !in_front {
                continue;
            }
            let (Some(col), Some(row)) =
                (self.cols.cell_in_bin(u, bu), self.rows.cell_in_bin(v, bv))
            else {
                continue;
            };
            let Some(cell) = self.cells.get_mut(row).and_then(|r| r.get_mut(col)) else {
                continue;
            };
            in_view += 1;
            // Branch-free keep-the-nearest: which point is nearer is a coin toss.
            let nearer = r2 < cell.r2;
            self.filled += u32::from(nearer && cell.r2 == f32::INFINITY);
            let new = Cell { p_c: [x, y, z], r2 };
            *cell = if nearer { new } else { *cell };
        }
        stats.points = stats.points.saturating_add(points);
        stats.in_view = stats.in_view.saturating_add(in_view);
    }

    /// LiDAR depth of the feature at undistorted normalized coordinates `x_n` (the grid's own
    /// cell size, from its build, is used whatever `cfg.cell_rad` says now).
    pub fn associate(
        &self,
        x_n: &Vec2,
        cfg: &AssociationConfig,
    ) -> Result<DepthMeasurement, AssocReject> {
        if !(x_n.x.is_finite() && x_n.y.is_finite()) {
            return Err(AssocReject::NonFinite);
        }
        let k = cfg.neighbours.clamp(3, AssociationConfig::MAX_NEIGHBOURS);
        let radius = cfg.max_neighbour_rad;
        let searchable = self.filled > 0 && self.cell_rad > 0.0 && radius > 0.0;
        if !searchable {
            return Err(AssocReject::NoNeighbours);
        }
        let b = Vec3::new(x_n.x, x_n.y, 1.0).normalize();
        let nb = self.neighbours(&b, radius, k);
        if nb.len() < k {
            return Err(AssocReject::NoNeighbours);
        }
        let mut buf = [Vec3::zeros(); AssociationConfig::MAX_NEIGHBOURS];
        for (d, (_, p)) in buf.iter_mut().zip(nb.iter()) {
            *d = *p;
        }
        let pts = buf.get(..k).unwrap_or(&[]);

        let (mut r_min, mut r_max, mut r_sum) = (f64::INFINITY, 0.0f64, 0.0);
        for p in pts {
            let r = p.norm();
            r_min = r_min.min(r);
            r_max = r_max.max(r);
            r_sum += r;
        }
        let r_mean = r_sum / k as f64;
        // Every gate is written so that a NaN fails it.
        let one_surface = r_max - r_min <= cfg.max_range_spread * r_mean;
        if !one_surface {
            return Err(AssocReject::RangeSpread);
        }

        let plane = fit_plane(pts).ok_or(AssocReject::PlaneFit)?;
        let planar = plane.max_dist_m <= cfg.max_plane_dist_m;
        if !planar {
            return Err(AssocReject::PlaneFit);
        }
        let n_dot_b = plane.normal.dot(&b);
        let steep_enough = n_dot_b.abs() >= cfg.min_incidence_cos;
        if !steep_enough {
            return Err(AssocReject::Incidence);
        }
        let range_m = plane.normal.dot(&plane.centroid) / n_dot_b;
        if !(range_m >= r_min - cfg.max_plane_dist_m && range_m <= r_max + cfg.max_plane_dist_m) {
            return Err(AssocReject::PlaneFit);
        }
        let depth_m = range_m * b.z;
        if !(depth_m >= cfg.depth_range_m.0 && depth_m <= cfg.depth_range_m.1) {
            return Err(AssocReject::DepthRange);
        }
        Ok(DepthMeasurement {
            depth_m,
            range_m,
            neighbours: k as u8,
            plane_rms_m: plane.rms_m,
            incidence_cos: n_dot_b.abs(),
        })
    }

    /// The (at most) `k` cell points of largest `cos(b, p) >= cos(radius)`, largest first (ties:
    /// the first found, rows then columns, stays first).
    fn neighbours(&self, b: &Vec3, radius: f64, k: usize) -> Neighbours {
        let mut out = Neighbours::new();
        let c = self.cell_rad;
        let az = libm::atan2(b.x, b.z);
        let el = libm::atan2(b.y, b.z);
        let cos_r = if radius >= core::f64::consts::PI {
            -1.0
        } else {
            libm::cos(radius)
        };
        // A point within `radius` of `b` lies within `radius / cos(beta)` of its azimuth and
        // `radius / cos(alpha)` of its elevation, at the point's own angles; bound those by the
        // bearing's plus twice the radius (the window is capped anyway).
        let half = |other: f64| {
            let far = (other.abs() + 2.0 * radius).min(FRAC_PI_2);
            (libm::ceil(radius / (c * libm::cos(far))) + 1.0).min(MAX_SEARCH_HALF_CELLS)
        };
        let (half_rows, half_cols) = (half(az), half(el));
        let Some(rows) = window(el / c + H as f64 * 0.5, half_rows, H) else {
            return out;
        };
        let Some(cols) = window(az / c + W as f64 * 0.5, half_cols, W) else {
            return out;
        };
        for row in self.cells.get(rows).unwrap_or(&[]) {
            for cell in row.get(cols.clone()).unwrap_or(&[]) {
                if cell.r2 == f32::INFINITY {
                    continue;
                }
                let p = Vec3::new(
                    f64::from(cell.p_c[0]),
                    f64::from(cell.p_c[1]),
                    f64::from(cell.p_c[2]),
                );
                let cos_a = b.dot(&p) / p.norm();
                let within = cos_a >= cos_r;
                if !within {
                    continue;
                }
                if out.len() >= k {
                    if out.last().is_some_and(|l| l.0 >= cos_a) {
                        continue;
                    }
                    out.pop();
                }
                let at = out.iter().position(|e| e.0 < cos_a).unwrap_or(out.len());
                // Cannot fail (k <= capacity and one slot is free).
                let _ = out.insert(at, (cos_a, p));
            }
        }
        out
    }
}

type Neighbours = HVec<(f64, Vec3), { AssociationConfig::MAX_NEIGHBOURS }>;

fn clamp_i32(v: i64) -> i32 {
    i32::try_from(v).unwrap_or(if v < 0 { i32::MIN } else { i32::MAX })
}

/// Cells `floor(centre - half) ..= floor(centre + half)` clipped to `0..n`; `None` if empty.
fn window(centre: f64, half: f64, n: usize) -> Option<core::ops::RangeInclusive<usize>> {
    let lo = libm::floor(centre - half).max(0.0);
    let hi = libm::floor(centre + half).min(n as f64 - 1.0);
    (lo <= hi).then_some(lo as usize..=hi as usize)
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::lidar::buffer::MAX_LIDAR_POINTS;
    use crate::lidar::config::{LidarConfig, LidarExtrinsic};
    use crate::lidar::testutil::{
        big_stack, cast, rosette_dir, spiral_cap, sweep_noisy, Motion, Shape,
    };
    use crate::lidar::LidarPoint;
    use crate::math::{quat_exp, Mat3};
    use nalgebra::Rotation3;
    use std::vec::Vec;

    const MS: i64 = 1_000_000;
    type Buf = PointBuffer<MAX_LIDAR_POINTS>;
    type Grid = SphereGrid<GRID_W, GRID_H>;

    /// Body at rest, x forward / z up; LiDAR x forward, a little rotated and offset; camera
    /// looking along body x, 0.15 m ahead of the LiDAR and 0.05 m to its right.
    struct Rig {
        motion: Motion,
        cfg: LidarConfig,
        p_bc: Vec3,
        q_bc: Quat,
    }

    impl Rig {
        fn new(motion: Motion) -> Self {
            // Camera axes in the body: x_c = -y_b, y_c = -z_b, z_c = x_b.
            let r_bc = Mat3::new(0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0);
            Rig {
                motion,
                cfg: LidarConfig {
                    extrinsic: LidarExtrinsic {
                        q_bl: quat_exp(&Vec3::new(0.01, -0.02, 0.03)),
                        p_bl: Vec3::new(0.05, 0.05, 0.1),
                    },
                    td_l_s: 0.004,
                    ..LidarConfig::default()
                },
                p_bc: Vec3::new(0.2, 0.0, 0.1),
                q_bc: Quat::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r_bc)),
            }
        }

        fn still() -> Self {
            Self::new(Motion::still(Vec3::new(1.0, 2.0, 1.5), Quat::identity()))
        }

        fn camera(&self, t_ns: i64) -> (Vec3, Quat) {
            let (p_wb, q_wb) = self.motion.pose(t_ns);
            (p_wb + q_wb * self.p_bc, q_wb * self.q_bc)
        }

        /// A point `range` m in front of the camera at `t_ns`, along the optical axis, plus
        /// `lateral` in camera axes.
        fn ahead(&self, t_ns: i64, range: f64, lateral: Vec3) -> Vec3 {
            let (p, q) = self.camera(t_ns);
            p + q * (Vec3::z() * range + lateral)
        }

        /// Pushes `rays` (LiDAR clock) against `scene`, builds the grid at `t_kf_ns`.
        fn run(
            &self,
            scene: &[Shape],
            rays: impl IntoIterator<Item = (i64, Vec3)>,
            t_kf_ns: i64,
            buf: &mut Buf,
            grid: &mut Grid,
        ) -> GridStats {
            self.run_noisy(scene, rays, 0.0, t_kf_ns, buf, grid)
        }

        /// [`Rig::run`] with range noise.
        fn run_noisy(
            &self,
            scene: &[Shape],
            rays: impl IntoIterator<Item = (i64, Vec3)>,
            sigma_m: f64,
            t_kf_ns: i64,
            buf: &mut Buf,
            grid: &mut Grid,
        ) -> GridStats {
            let ins = self.motion.window::<256>(0, 1000 * MS, 5 * MS);
            let pts = sweep_noisy(&self.motion, &self.cfg, scene, rays, sigma_m);
            let st = buf.push_scan(&pts, &ins, &self.cfg);
            // Only returns beyond the 500 m gate (grazing planes) are refused.
            assert_eq!((st.rejected_nonfinite, st.rejected_time), (0, 0));
            assert_eq!((st.accepted + st.rejected_range) as usize, pts.len());
            let (p_wc, q_wc) = self.camera(t_kf_ns);
            grid.build(buf, &p_wc, &q_wc, t_kf_ns, &self.cfg.association)
        }

        /// Camera depth (z) of the scene along normalized coordinates `x_n`.
        fn true_depth(&self, scene: &[Shape], t_ns: i64, x_n: &Vec2) -> Option<f64> {
            let (p, q) = self.camera(t_ns);
            let b = Vec3::new(x_n.x, x_n.y, 1.0).normalize();
            cast(scene, &p, &(q * b)).map(|t| t * b.z)
        }
    }

    /// `n` rays over 0.1..0.5 s, filling the LiDAR's cone of `half_deg` around its x axis.
    fn dense_rays(n: usize, half_deg: f64) -> Vec<(i64, Vec3)> {
        spiral_cap(n, &Vec3::x(), half_deg.to_radians())
            .into_iter()
            .enumerate()
            .map(|(i, d)| (100 * MS + (i as i64 * 400 * MS) / n as i64, d))
            .collect()
    }

    fn grid_cells(n: usize) -> impl Iterator<Item = (f64, f64)> {
        let k = n as i32;
        (-k..=k).flat_map(move |i| (-k..=k).map(move |j| (i as f64, j as f64)))
    }

    #[test]
    fn oblique_wall_depth_is_the_ray_plane_z() {
        big_stack(|| {
            let rig = Rig::still();
            let t_kf = 500 * MS;
            // Wall 6 m ahead, turned 35 deg about the vertical.
            let n_w = quat_exp(&Vec3::new(0.0, 0.0, 35f64.to_radians())) * -Vec3::x();
            let on = rig.ahead(t_kf, 6.0, Vec3::zeros());
            let wall = [Shape::Plane {
                n: n_w,
                d: n_w.dot(&on),
            }];
            let (mut buf, mut grid) = (Buf::new(), Grid::new());
            let st = rig.run(&wall, dense_rays(50_000, 45.0), t_kf, &mut buf, &mut grid);
            assert_eq!((st.points, st.in_view), (50_000, 50_000));
            assert!(st.cells_filled > 20_000, "{st:?}");
            let cfg = AssociationConfig::default();
            let n_c = rig.camera(t_kf).1.inverse_transform_vector(&n_w);
            let mut worst = 0.0f64;
            for (i, j) in grid_cells(6) {
                let x_n = Vec2::new(0.1 * i, 0.07 * j);
                let d = grid.associate(&x_n, &cfg).unwrap();
                let truth = rig.true_depth(&wall, t_kf, &x_n).unwrap();
                worst = worst.max((d.depth_m - truth).abs());
                // The incidence is the ray's against the wall's normal.
                let b = Vec3::new(x_n.x, x_n.y, 1.0).normalize();
                assert!((d.incidence_cos - n_c.dot(&b).abs()).abs() < 1e-3, "{d:?}");
                // Range along the ray = depth |(x_n, 1)|.
                let k = Vec3::new(x_n.x, x_n.y, 1.0).norm();
                assert!((d.range_m - d.depth_m * k).abs() < 1e-9);
                assert!(d.plane_rms_m < 1e-3 && usize::from(d.neighbours) == cfg.neighbours);
            }
            assert!(worst < 0.01, "worst depth error {worst} m");
            // Off-axis the depth is not the range.
            let d = grid.associate(&Vec2::new(0.5, 0.3), &cfg).unwrap();
            assert!(d.range_m - d.depth_m > 0.5, "{d:?}");
        });
    }

    #[test]
    fn pole_in_front_of_a_wall_never_gets_the_wall_depth() {
        big_stack(|| {
            let rig = Rig::still();
            let t_kf = 500 * MS;
            let (p_wc, q_wc) = rig.camera(t_kf);
            let scene = [
                Shape::Plane {
                    n: -Vec3::x(),
                    d: -(p_wc.x + 7.0),
                },
                Shape::Cylinder {
                    c: rig.ahead(t_kf, 3.0, Vec3::zeros()),
                    axis: q_wc * Vec3::y(),
                    radius: 0.15,
                },
            ];
            let (mut buf, mut grid) = (Buf::new(), Grid::new());
            rig.run(&scene, dense_rays(50_000, 45.0), t_kf, &mut buf, &mut grid);
            let cfg = AssociationConfig::default();
            let edge = 0.15 / libm::sqrt(9.0 - 0.15 * 0.15); // silhouette from the camera
            let (mut wall_ok, mut pole_ok, mut edge_rejected) = (0, 0, 0);
            for k in -80..=80 {
                let x_n = Vec2::new(k as f64 * 0.0025, 0.1);
                let truth = rig.true_depth(&scene, t_kf, &x_n).unwrap();
                let on_pole = truth < 4.0;
                match grid.associate(&x_n, &cfg) {
                    Ok(d) => {
                        assert!(
                            (d.depth_m - truth).abs() < 0.03,
                            "x {}: depth {} truth {truth}",
                            x_n.x,
                            d.depth_m
                        );
                        if on_pole {
                            pole_ok += 1;
                        } else {
                            wall_ok += 1;
                        }
                    }
                    Err(e) => {
                        // Only near the silhouette may a bearing lose its depth.
                        let near_edge = (x_n.x.abs() - edge).abs() < 0.02;
                        assert!(near_edge, "x {} rejected: {e:?}", x_n.x);
                        if near_edge {
                            edge_rejected += 1;
                        }
                    }
                }
                // Interior of the pole and open wall: always a depth.
                if x_n.x.abs() < 0.03 || x_n.x.abs() > 0.08 {
                    assert!(grid.associate(&x_n, &cfg).is_ok(), "x {}", x_n.x);
                }
            }
            assert!(pole_ok >= 20 && wall_ok >= 100, "{pole_ok} {wall_ok}");
            assert!(edge_rejected >= 4, "{edge_rejected}");
            // Exactly on the silhouette foreground and background mix: the range spread says
            // so, and without that guard the plane fit (or the incidence) still does.
            let no_spread = AssociationConfig {
                max_range_spread: 1e9,
                ..cfg
            };
            for x in [-edge, edge] {
                let x_n = Vec2::new(x, 0.1);
                assert_eq!(grid.associate(&x_n, &cfg), Err(AssocReject::RangeSpread));
                let r = grid.associate(&x_n, &no_spread);
                assert!(
                    matches!(r, Err(AssocReject::PlaneFit | AssocReject::Incidence)),
                    "{r:?}"
                );
            }
        });
    }

    #[test]
    fn step_edge_depths_are_from_one_side_or_rejected() {
        // A board 0.5 m in front of a wall 6 m away (range ratio 9%: under the spread gate),
        // with its right edge on the optical axis; 2 cm range noise.
        big_stack(|| {
            let rig = Rig::still();
            let t_kf = 500 * MS;
            let (p_wc, q_wc) = rig.camera(t_kf);
            let scene = [
                Shape::Plane {
                    n: -Vec3::x(),
                    d: -(p_wc.x + 6.0),
                },
                Shape::Rect {
                    c: rig.ahead(t_kf, 5.5, Vec3::new(-1.0, 0.0, 0.0)),
                    u: q_wc * Vec3::x(),
                    v: q_wc * Vec3::y(),
                    half_u: 1.0,
                    half_v: 1.0,
                },
            ];
            let (mut buf, mut grid) = (Buf::new(), Grid::new());
            rig.run_noisy(
                &scene,
                dense_rays(50_000, 45.0),
                0.02,
                t_kf,
                &mut buf,
                &mut grid,
            );
            let cfg = AssociationConfig::default();
            let (mut ok, mut far_rejected, mut worst) = (0, 0, 0.0f64);
            for i in -40i32..=40 {
                for j in -3..=3 {
                    let x_n = Vec2::new(i as f64 * 0.002, j as f64 * 0.05);
                    let truth = rig.true_depth(&scene, t_kf, &x_n).unwrap();
                    match grid.associate(&x_n, &cfg) {
                        Ok(d) => {
                            ok += 1;
                            worst = worst.max((d.depth_m - truth).abs());
                            assert!(i != 0, "a depth on the edge itself: {d:?}");
                        }
                        Err(_) => far_rejected += usize::from(i.abs() > 10),
                    }
                }
            }
            assert!(worst < 0.1, "a depth {worst} m off across the step");
            // Away from the edge (> 1.1 deg) only noise costs a depth now and then.
            assert!(ok > 450 && far_rejected <= 5, "{ok} {far_rejected}");
        });
    }

    #[test]
    fn grazing_plane_is_rejected_for_incidence() {
        big_stack(|| {
            let rig = Rig::still();
            let t_kf = 500 * MS;
            let (p_wc, q_wc) = rig.camera(t_kf);
            // The optical axis meets the plane 5 m ahead at 81 deg from its normal.
            let n_w = q_wc
                * Vec3::new(
                    libm::sin(81f64.to_radians()),
                    0.0,
                    -libm::cos(81f64.to_radians()),
                );
            let on = p_wc + q_wc * Vec3::new(0.0, 0.0, 5.0);
            let plane = [Shape::Plane {
                n: n_w,
                d: n_w.dot(&on),
            }];
            let (mut buf, mut grid) = (Buf::new(), Grid::new());
            rig.run(&plane, dense_rays(50_000, 45.0), t_kf, &mut buf, &mut grid);
            let cfg = AssociationConfig::default();
            let r = grid.associate(&Vec2::new(0.0, 0.0), &cfg);
            assert_eq!(r, Err(AssocReject::Incidence));
            // Steeper than about 85 deg the neighbours' ranges (spread ~ 2 dtheta tan(theta))
            // already fail the range-spread guard; either way no depth.
            for deg in [79.0f64, 84.0, 87.0] {
                let x = libm::tan((deg - 81.0).to_radians());
                let r = grid.associate(&Vec2::new(x, 0.0), &cfg);
                assert!(
                    matches!(r, Err(AssocReject::Incidence | AssocReject::RangeSpread)),
                    "{deg}: {r:?}"
                );
            }
            // The same plane met at 60 deg (bearing turned 21 deg) is fine.
            let x = libm::tan(21f64.to_radians());
            let ok = grid.associate(&Vec2::new(-x, 0.0), &cfg);
            assert!(ok.is_ok(), "{ok:?}");
        });
    }

    #[test]
    fn no_points_or_outside_the_grid_gives_no_neighbours() {
        big_stack(|| {
            let rig = Rig::still();
            let t_kf = 500 * MS;
            let room = [Shape::RoomBox {
                min: Vec3::new(-10.0, -10.0, -3.0),
                max: Vec3::new(10.0, 10.0, 6.0),
            }];
            let cfg = AssociationConfig::default();
            let (mut buf, mut grid) = (Buf::new(), Grid::new());
            // Before any build.
            assert_eq!(
                grid.associate(&Vec2::new(0.0, 0.0), &cfg),
                Err(AssocReject::NoNeighbours)
            );
            // LiDAR rays only to the left (+y in l): the right of the image is empty sky.
            let left: Vec<(i64, Vec3)> = dense_rays(50_000, 60.0)
                .into_iter()
                .filter(|(_, d)| d.y > 0.2)
                .collect();
            rig.run(&room, left, t_kf, &mut buf, &mut grid);
            assert!(grid.associate(&Vec2::new(-0.5, 0.0), &cfg).is_ok());
            assert_eq!(
                grid.associate(&Vec2::new(0.3, 0.0), &cfg),
                Err(AssocReject::NoNeighbours)
            );
            // All around: points exist at 72 deg, but the grid ends at 64 deg.
            buf.clear();
            let all = spiral_cap(50_000, &Vec3::x(), 3.0)
                .into_iter()
                .enumerate()
                .map(|(i, d)| (100 * MS + i as i64 * 8_000, d));
            rig.run(&room, all, t_kf, &mut buf, &mut grid);
            assert!(grid.associate(&Vec2::new(1.5, 0.0), &cfg).is_ok());
            for x_n in [
                Vec2::new(3.0, 0.0),
                Vec2::new(0.0, 2.0),
                Vec2::new(-1e300, 0.0),
                Vec2::new(1e300, -1e300),
                Vec2::new(0.0, f64::MAX),
            ] {
                assert_eq!(
                    grid.associate(&x_n, &cfg),
                    Err(AssocReject::NoNeighbours),
                    "{x_n:?}"
                );
            }
            for x_n in [Vec2::new(f64::NAN, 0.0), Vec2::new(0.0, f64::INFINITY)] {
                assert_eq!(grid.associate(&x_n, &cfg), Err(AssocReject::NonFinite));
            }
            // A non-finite camera pose leaves the grid empty.
            let st = grid.build(
                &buf,
                &Vec3::new(f64::NAN, 0.0, 0.0),
                &Quat::identity(),
                t_kf,
                &cfg,
            );
            assert_eq!(st, GridStats::default());
            assert_eq!(
                grid.associate(&Vec2::new(0.0, 0.0), &cfg),
                Err(AssocReject::NoNeighbours)
            );
        });
    }

    #[test]
    fn a_cell_keeps_its_nearest_point_and_the_span_selects_times() {
        big_stack(|| {
            let rig = Rig::still();
            let ins = rig.motion.window::<256>(0, 1000 * MS, 5 * MS);
            let dir = [1.0f32, 0.06, 0.04];
            let at = |t_ms: i64, r: f32| LidarPoint {
                t_ns: t_ms * MS,
                p_l: dir.map(|c| c * r),
                intensity: 0.0,
            };
            let cfg = AssociationConfig::default();
            let (p_wc, q_wc) = rig.camera(0);
            let nearest = |grid: &Grid| -> Vec<f32> {
                grid.cells
                    .iter()
                    .flatten()
                    .filter(|c| c.r2 != f32::INFINITY)
                    .map(|c| libm::sqrtf(c.r2))
                    .collect()
            };
            for order in [[(100, 9.0), (450, 5.0)], [(100, 5.0), (450, 9.0)]] {
                let mut buf = PointBuffer::<64>::new();
                let mut grid = Grid::new();
                let pts = order.map(|(t, r)| at(t, r));
                buf.push_scan(&pts, &ins, &rig.cfg);
                let st = grid.build(&buf, &p_wc, &q_wc, 500 * MS, &cfg);
                assert_eq!((st.points, st.in_view, st.cells_filled), (2, 2, 1));
                // 5 m from the LiDAR, about 4.8 m from the camera 0.2 m ahead of it.
                let r = nearest(&grid);
                assert!(r.len() == 1 && r[0] > 4.7 && r[0] < 4.9, "{r:?}");
                // Span 0.2 s: only the point at 450 ms.
                let short = AssociationConfig { span_s: 0.2, ..cfg };
                let st = grid.build(&buf, &p_wc, &q_wc, 500 * MS, &short);
                assert_eq!(st.points, 1);
                let want = if order[1].1 < 6.0 { 4.8 } else { 8.8 };
                assert!((nearest(&grid)[0] - want).abs() < 0.1);
                // Keyframe at 300 ms: the later point is not used.
                let st = grid.build(&buf, &p_wc, &q_wc, 300 * MS, &cfg);
                assert_eq!(st.points, 1);
            }
        });
    }

    /// Livox-like rosette: 10k points per 0.1 s sweep, 70.4 deg FoV, five sweeps.
    fn rosette_rays() -> Vec<(i64, Vec3)> {
        (0..50_000i64)
            .map(|i| {
                (
                    i * 10_000,
                    rosette_dir(i as f64 * 1e-5, 35.2f64.to_radians()),
                )
            })
            .collect()
    }

    type Outcome = (Vec2, Option<f64>, Result<DepthMeasurement, AssocReject>);

    /// Moving rig in front of a tilted wall, range noise `sigma_m`; every bearing of a 25 x 19
    /// image grid with its true depth and association.
    fn rosette_run(sigma_m: f64, cfg: &AssociationConfig) -> (GridStats, Vec<Outcome>) {
        let rig = Rig::new(Motion {
            p0: Vec3::new(1.0, 2.0, 1.5),
            v: Vec3::new(0.8, 0.1, 0.0),
            q0: quat_exp(&Vec3::new(0.02, 0.01, 0.3)),
            yaw_rate: 0.2,
        });
        let t_kf = 500 * MS;
        let n_w = quat_exp(&Vec3::new(0.1, 0.0, 0.5)) * -Vec3::x();
        let on = rig.ahead(t_kf, 6.0, Vec3::zeros());
        let wall = [Shape::Plane {
            n: n_w,
            d: n_w.dot(&on),
        }];
        let (mut buf, mut grid) = (Buf::new(), Grid::new());
        let st = rig.run_noisy(&wall, rosette_rays(), sigma_m, t_kf, &mut buf, &mut grid);
        let out = (-12..=12)
            .flat_map(|i| (-9..=9).map(move |j| Vec2::new(0.05 * i as f64, 0.05 * j as f64)))
            .map(|x_n| {
                let truth = rig.true_depth(&wall, t_kf, &x_n);
                (x_n, truth, grid.associate(&x_n, cfg))
            })
            .collect();
        (st, out)
    }

    /// Fraction of in-cone bearings with a depth, and the RMS and worst depth errors.
    fn rosette_score(out: &[Outcome]) -> (usize, f64, f64, f64) {
        // Bearings inside the LiDAR cone (35.2 deg) with a neighbour radius to spare; the LiDAR
        // looks along the camera z within 2 deg, so the test is done in the camera.
        let cone_cos = libm::cos(33f64.to_radians());
        let (mut inside, mut ok, mut sum2, mut worst) = (0usize, 0usize, 0.0, 0.0f64);
        for (x_n, truth, r) in out {
            if Vec3::new(x_n.x, x_n.y, 1.0).normalize().z < cone_cos {
                continue;
            }
            inside += 1;
            if let (Ok(d), Some(t)) = (r, truth) {
                ok += 1;
                sum2 += (d.depth_m - t) * (d.depth_m - t);
                worst = worst.max((d.depth_m - t).abs());
            }
        }
        let frac = ok as f64 / inside.max(1) as f64;
        (inside, frac, libm::sqrt(sum2 / ok.max(1) as f64), worst)
    }

    #[test]
    fn rosette_density_gives_most_bearings_a_depth() {
        big_stack(|| {
            let (st, out) = rosette_run(0.0, &AssociationConfig::default());
            assert_eq!((st.points, st.in_view), (50_000, 50_000));
            let (inside, frac, _, worst) = rosette_score(&out);
            assert!(inside > 300, "{inside}");
            assert!(frac > 0.9, "{frac} of {inside} bearings got a depth");
            assert!(worst < 0.01, "worst depth error {worst}");
            // With the 2 cm range noise of a Mid-70.
            let (_, out) = rosette_run(0.02, &AssociationConfig::default());
            let (_, frac, rms, worst) = rosette_score(&out);
            assert!(frac > 0.9, "noisy: {frac} got a depth");
            // Measured: 98% with a depth, RMS 1.8 cm, worst 9.9 cm (5 sigma).
            assert!(
                rms < 0.025 && worst < 0.12,
                "noisy: rms {rms} worst {worst}"
            );
            // Five neighbours 5 cm apart with 2 cm noise tilt the plane wildly at times; the
            // range-bracket check keeps the error bounded (0.33 m without it).
            let five = AssociationConfig {
                neighbours: 5,
                ..AssociationConfig::default()
            };
            let (_, out) = rosette_run(0.02, &five);
            let (_, frac, _, worst) = rosette_score(&out);
            assert!(
                frac > 0.8 && worst < 0.15,
                "5 neighbours: {frac} worst {worst}"
            );
        });
    }

    #[test]
    fn same_input_gives_identical_bits() {
        big_stack(|| {
            let (st1, a) = rosette_run(0.02, &AssociationConfig::default());
            let (st2, b) = rosette_run(0.02, &AssociationConfig::default());
            assert_eq!(st1, st2);
            let bits = |r: &Result<DepthMeasurement, AssocReject>| match r {
                Ok(d) => Ok((
                    d.depth_m.to_bits(),
                    d.range_m.to_bits(),
                    d.plane_rms_m.to_bits(),
                    d.neighbours,
                )),
                Err(e) => Err(*e),
            };
            assert!(a.iter().zip(&b).all(|(x, y)| bits(&x.2) == bits(&y.2)));
            assert!(a.iter().filter(|x| x.2.is_ok()).count() > 300);
        });
    }
}
