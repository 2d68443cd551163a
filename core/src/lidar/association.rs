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
#[path = "association_tests.rs"]
mod tests;
